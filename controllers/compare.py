"""How much does the attitude estimator matter to motion control? The grid

    task x scenario x estimator x controller x episode seeds

where controller is ``pid`` (the same gains everywhere), ``ppo`` (the PPO policy trained
with that estimator in the loop) or ``ppo-truth`` (the PPO policy trained on the true
attitude, run with that estimator), and the ``truth`` estimator row is the reference.
Every cell is an independent job (``run_job``), so the grid runs in a local process pool
or as Ray tasks with the same results for the same seeds.
"""
from __future__ import annotations

import csv
import math
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from controllers.evaluation import EPISODE_METRICS, MAIN_METRIC, aggregate, evaluate

__all__ = ["SCENARIOS", "CONTROLLERS", "plan", "run_job", "run_grid", "summarise", "write_outputs"]

#: environment arguments of each scenario (on top of the task's defaults)
SCENARIOS = {
    "flat": {},
    # magnetic dipoles in the floor (a steel plate, a motor) and bumps that shake the IMU,
    # in a smaller arena so that the robot meets them
    "disturbed": {"arena_size": 16.0, "mag_zones": "random", "n_mag_zones": 16, "bumps": 16},
}
CONTROLLERS = ("pid", "ppo", "ppo-truth")
#: metrics shown in the summary table per task (the first is the main one)
SHOWN = {"track": ("heading_rmse", "speed_rmse", "attitude_error", "heading_est_error"),
         "waypoints": ("success", "cross_track", "time_to_goal", "attitude_error", "heading_est_error")}


def _policy_stem(controller, task, estimator, policy_dir):
    from controllers.rl import policy_stem
    trained_with = "truth" if controller == "ppo-truth" else estimator
    return policy_stem("ppo", task, trained_with, policy_dir)


def plan(tasks, scenarios, estimators, controllers, episodes, seed, policy_dir=None, log=print):
    """The list of jobs (dicts); cells whose policy file is missing are left out with a message."""
    from controllers.rl import POLICY_DIR
    policy_dir = Path(policy_dir or POLICY_DIR)
    jobs, missing = [], set()
    for task in tasks:
        for sc in scenarios:
            if sc not in SCENARIOS:
                raise ValueError(f"unknown scenario {sc!r}; accepted: {', '.join(SCENARIOS)}")
            for est in estimators:
                for ctrl in controllers:
                    if ctrl not in CONTROLLERS:
                        raise ValueError(f"unknown controller {ctrl!r}; accepted: {', '.join(CONTROLLERS)}")
                    stem = None
                    if ctrl != "pid":
                        stem = _policy_stem(ctrl, task, est, policy_dir)
                        if not Path(str(stem) + ".zip").is_file():
                            missing.add(str(stem))
                            continue
                    jobs.append(dict(task=task, scenario=sc, estimator=est, controller=ctrl, episodes=episodes,
                                     seed=seed, policy=None if stem is None else str(stem),
                                     env_kwargs=dict(SCENARIOS[sc], task=task, estimator=est)))
    for m in sorted(missing):
        log(f"no policy {m}.zip: its cells are skipped (train it with scripts/train.py)")
    return jobs


def run_job(job):
    """Evaluate one cell; returns one row per episode (dicts of plain values; with
    ``job["record_path"]`` also the true path and the waypoints)."""
    record_path = bool(job.get("record_path", False))
    import torch
    torch.set_num_threads(1)
    from controllers.pid import PID
    from controllers.rl import load_policy
    from envs.sphere import SphereRobotEnv
    env = SphereRobotEnv(**job["env_kwargs"])
    try:
        if job["controller"] == "pid":
            ctrl = PID.for_env(env)
        else:
            ctrl = load_policy(job["policy"], env=env)
        res = evaluate(ctrl, episodes=job["episodes"], seed=job["seed"], record_path=record_path, env=env)
    finally:
        env.close()
    rows = []
    for i, ep in enumerate(res["episodes"]):
        row = {k: job[k] for k in ("task", "scenario", "estimator", "controller")}
        row["episode_seed"] = job["seed"] + i
        row.update({k: v for k, v in ep.items() if k in EPISODE_METRICS[job["task"]] or k == "steps"})
        if record_path:
            row.update(path=ep["path"], start=ep["start"], waypoints=ep["waypoints"],
                       waypoint_radius=env.waypoint_radius)
        rows.append(row)
    return rows


def run_grid(jobs, backend="local", workers=None, address=None, progress=True):
    """Run the jobs; returns the rows in job order. backend: "local" (process pool of
    ``workers``, default the CPU count) or "ray" (``address``: an existing cluster, or None
    to start a local one)."""
    from tqdm.auto import tqdm
    results = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc="control grid", unit="cell", disable=not progress)
    if backend == "local":
        import multiprocessing as mp
        n = workers or os.cpu_count() or 1
        if n == 1:
            for i, j in enumerate(jobs):
                results[i] = run_job(j)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("forkserver")) as pool:
                futs = {pool.submit(run_job, j): i for i, j in enumerate(jobs)}
                for f in as_completed(futs):
                    results[futs[f]] = f.result()
                    bar.update()
    elif backend == "ray":
        import ray
        started = False
        if not ray.is_initialized():
            ray.init(address=address, num_cpus=None if address else (workers or os.cpu_count()),
                     include_dashboard=False, log_to_driver=False)
            started = True
        try:
            remote = ray.remote(num_cpus=1)(run_job)
            refs = [remote.remote(j) for j in jobs]
            index = {r: i for i, r in enumerate(refs)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for r in done:
                    results[index[r]] = ray.get(r)
                    bar.update()
        finally:
            if started:
                ray.shutdown()
    else:
        raise ValueError(f"unknown backend {backend!r}; accepted: local, ray")
    bar.close()
    return [row for rows in results for row in rows]


def summarise(rows):
    """One summary row per (task, scenario, estimator, controller): mean, 95 % CI half-width
    of each shown metric, and the degradation of the main metric against the ``truth`` row
    of the same controller (in %, positive = worse than truth)."""
    groups = {}
    for r in rows:
        groups.setdefault((r["task"], r["scenario"], r["estimator"], r["controller"]), []).append(r)
    out = []
    for (task, sc, est, ctrl), eps in groups.items():
        agg = aggregate(eps, task)
        row = {"task": task, "scenario": sc, "estimator": est, "controller": ctrl, "episodes": len(eps)}
        for m in SHOWN[task]:
            row[m] = agg[m]["mean"]
            row[m + "_ci95"] = agg[m]["ci95"]
        out.append(row)
    ref = {(r["task"], r["scenario"], r["controller"]): r for r in out if r["estimator"] == "truth"}
    for r in out:
        main, higher_better = MAIN_METRIC[r["task"]]
        t = ref.get((r["task"], r["scenario"], r["controller"]))
        deg = float("nan")
        if t is not None and math.isfinite(t[main]) and math.isfinite(r[main]):
            if higher_better:
                deg = 100.0 * (t[main] - r[main]) / t[main] if t[main] > 0 else float("nan")
            else:
                deg = 100.0 * (r[main] - t[main]) / t[main] if t[main] > 0 else float("nan")
        r["main_metric"] = main
        r["degradation_pct"] = deg
    order = {"truth": -1}
    out.sort(key=lambda r: (r["task"], r["scenario"], r["controller"], order.get(r["estimator"], 0), r["estimator"]))
    return out


def _fmt(v, ci=None):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    s = f"{v:.3g}"
    if ci is not None and isinstance(ci, float) and math.isfinite(ci):
        s += f" ± {ci:.2g}"
    return s


def write_outputs(rows, summary, out_dir, path_rows=None, log=print):
    """Per-episode CSV, summary Markdown + CSV, degradation bar chart, path map (PNG)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    keys = sorted({k for r in rows for k in r}, key=lambda k: (k not in ("task", "scenario", "estimator",
                                                                         "controller", "episode_seed"), k))
    with open(out / "episodes.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    skeys = sorted({k for r in summary for k in r}, key=lambda k: (k not in ("task", "scenario", "estimator",
                                                                            "controller", "episodes"), k))
    with open(out / "summary.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=skeys)
        w.writeheader()
        w.writerows(summary)
    lines = ["# Control under each attitude estimator", "",
             "Mean ± 95 % confidence half-width over episodes (same seeds in every row); "
             "degradation: the task's main metric against the `truth` row of the same controller "
             "and scenario (positive = worse). Scored on the true state.", ""]
    for task in sorted({r["task"] for r in summary}):
        for sc in sorted({r["scenario"] for r in summary if r["task"] == task}):
            rs = [r for r in summary if r["task"] == task and r["scenario"] == sc]
            main = MAIN_METRIC[task][0]
            lines += [f"## {task}, {sc} (main metric: {main})", ""]
            cols = ["controller", "estimator", "episodes"] + list(SHOWN[task]) + ["degradation %"]
            lines.append("| " + " | ".join(cols) + " |")
            lines.append("|" + "---|" * len(cols))
            for r in rs:
                cells = [r["controller"], r["estimator"], str(r["episodes"])]
                cells += [_fmt(r[m], r[m + "_ci95"]) for m in SHOWN[task]]
                cells.append(_fmt(r["degradation_pct"]))
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
    (out / "summary.md").write_text("\n".join(lines))
    _plot_degradation(summary, out / "degradation.png")
    if path_rows:
        _plot_paths(path_rows, out / "paths.png")
    log(f"wrote {out}/summary.md, summary.csv, episodes.csv, degradation.png" + (", paths.png" if path_rows else ""))
    return out


def _plot_degradation(summary, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    panels = sorted({(r["task"], r["scenario"]) for r in summary})
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 3.2 * len(panels)), squeeze=False)
    for ax, (task, sc) in zip(axes[:, 0], panels):
        rs = [r for r in summary if r["task"] == task and r["scenario"] == sc and r["estimator"] != "truth"]
        ests = sorted({r["estimator"] for r in rs})
        ctrls = [c for c in CONTROLLERS if any(r["controller"] == c for r in rs)]
        width = 0.8 / max(1, len(ctrls))
        x = np.arange(len(ests))
        for k, c in enumerate(ctrls):
            vals = [next((r["degradation_pct"] for r in rs if r["estimator"] == e and r["controller"] == c),
                         np.nan) for e in ests]
            ax.bar(x + (k - (len(ctrls) - 1) / 2) * width, vals, width, label=c)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(x, ests)
        ax.set_ylabel("degradation vs truth (%)")
        ax.set_title(f"{task}, {sc}: {MAIN_METRIC[task][0]} (positive = worse than the true attitude)")
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_paths(path_rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 7))
    first = path_rows[0]
    if first.get("waypoints") is not None:
        wp = np.vstack([first["start"][None, :], first["waypoints"]])
        ax.plot(wp[:, 0], wp[:, 1], "k--", lw=1.5, label="target path")
        for x, y in wp[1:]:          # reached when the true position enters the circle
            ax.add_patch(plt.Circle((x, y), first["waypoint_radius"], fill=False, color="k", lw=0.8))
    for r in path_rows:
        p = r["path"]
        ax.plot(p[:, 0], p[:, 1], lw=1.2, label=f"{r['estimator']} ({r['controller']})")
    ax.plot(*first["start"], "k^", ms=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(f"{first['task']}, {first['scenario']}, seed {first['episode_seed']}: true paths")
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
