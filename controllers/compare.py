"""How much does the attitude estimator matter to motion control? The grid

    task x scenario x estimator x controller x episode seeds

where controller is ``pid`` (the same gains everywhere), ``ppo`` (the PPO policy trained
with that estimator in the loop) or ``ppo-truth`` (the PPO policy trained on the true
attitude, run with that estimator), and the ``truth`` estimator row is the reference: every
cell is compared with the ``truth`` cell of the same task, scenario and controller over the
same episode seeds (paired differences, ``controllers.evaluation.paired_difference``).

Every cell is an independent job (``run_job``), run in a local process pool or as Ray
tasks with the same results for the same seeds. Finished cells are cached under the output
folder (``cells/<key>.json``, written atomically), keyed by the cell and by the code version
(a hash of the package sources, the compiled kernels, the versions of ``VERSIONED`` and of
the cell's policy files), so that ``--resume`` continues an interrupted grid and a cache
from other code or another build is never reused.

The command line is ``main`` (``spherebot-compare``, ``scripts/compare_control.py``).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import signal
import sys
import textwrap
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from importlib import metadata
from pathlib import Path

import numpy as np

from fusion.checks import integer, require

from controllers.policy_io import check_writable, csv_text, save_figure, write_text
from controllers.evaluation import (BINARY_METRICS, EPISODE_METRICS, MAIN_METRIC, MIN_BOOT, MIN_TAIL, N_BOOT,
                                    SETTLE_BAND_DEG, SETTLE_WINDOW_S, interval, newcombe_paired, paired_difference)

__all__ = ["SCENARIOS", "CONTROLLERS", "ROBOTS", "TASKS", "SHOWN", "plan", "run_job", "run_grid", "summarise",
           "write_outputs", "paired_between", "code_version", "cell_key", "ray_session", "runtime_env",
           "min_detectable_success", "main"]

TASKS = ("track", "waypoints")
#: environment arguments of each scenario (on top of the task's defaults)
SCENARIOS = {
    "flat": {},
    # magnetic dipoles in the floor (a steel plate, a motor), bumps that shake the IMU and
    # slippery patches where the drive slips (dead reckoning drifts), in a smaller arena so
    # that the robot meets them
    "disturbed": {"arena_size": 16.0, "mag_zones": "random", "n_mag_zones": 16, "bumps": 16,
                  "slippery_patches": 8},
}
CONTROLLERS = ("pid", "ppo", "ppo-truth")
#: the robot of the grid (``--robot``) and the environment's ``realism=`` it sets: realistic is
#: the v1 robot (drive vibration, own magnetic field, latency, deadband, stiction, battery
#: sag, compliant servo; the environment's default), ideal the v0 robot (none of them)
ROBOTS = {"realistic": "real", "ideal": "ideal"}
#: metrics of the summary per task (the first is the main one, MAIN_METRIC)
SHOWN = {"track": ("heading_ss", "speed_ss", "settle_time", "attitude_error", "tilt_error", "heading_est_error"),
         "waypoints": ("success", "time_to_goal", "cross_track", "attitude_error", "tilt_error", "heading_est_error")}
UNITS = {"heading_ss": "deg", "speed_ss": "m/s", "settle_time": "s", "attitude_error": "deg", "tilt_error": "deg",
         "heading_est_error": "deg", "success": "", "time_to_goal": "s", "cross_track": "m"}
PACKAGE_ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fusion", "envs", "controllers")
#: the distributions whose versions are part of the code version: the physics, the
#: environment API, the policies' network and loader, the arrays
VERSIONED = ("pybullet", "gymnasium", "torch", "stable-baselines3", "numpy")
#: what the Ray runtime_env does not upload (build products, training work directories)
RAY_EXCLUDES = [".venv", "results", ".git", "build", "__pycache__", "*.c", "*.html", "*.run", "*.run.old-*",
                "*.egg-info"]
CACHE_DIR = "cells"


# ----------------------------------------------------------------------------------------
# planning

def _check_names(kind, names, accepted):
    names = list(names)
    bad = [n for n in names if n not in accepted]
    if bad or not names:
        what = f"unknown {kind}(s) {', '.join(map(repr, bad))}" if bad else f"no {kind} given"
        raise ValueError(f"{what}; accepted: {', '.join(accepted)}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:       # each would run its cells again and repeat their rows in episodes.csv
        raise ValueError(f"{kind}(s) {', '.join(map(repr, twice))} given more than once")
    return names


def _file_hash(paths):
    h = hashlib.sha256()
    for p in paths:
        h.update(Path(p).name.encode())
        h.update(Path(p).read_bytes())
    return h.hexdigest()


def _kernel_files():
    """The compiled kernels of the packages, the files this process imports them from (found
    as extension modules, not by their .pyx: a wheel ships none)."""
    import importlib.machinery
    import importlib.util
    import pkgutil
    out = []
    for pkg in PACKAGES:
        for m in sorted(pkgutil.iter_modules([str(PACKAGE_ROOT / pkg)]), key=lambda m: m.name):
            name = f"{pkg}.{m.name}"
            spec = importlib.util.find_spec(name) if m.name.startswith("_") else None
            if spec is not None and str(spec.origin).endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)):
                loaded = sys.modules.get(name)
                out.append(Path(loaded.__file__ if loaded is not None else spec.origin))
    return out


def code_version():
    """A hash of every source file of the packages (Python, Cython, hyperparameters), of the
    compiled kernels imported (their bytes: a build with other flags, FUSION_MARCH say,
    differs) and of the versions of ``VERSIONED``: a change anywhere gives a new version,
    so no cached cell of other code or another build is reused."""
    files = []
    for pkg in PACKAGES:
        d = PACKAGE_ROOT / pkg
        for pat in ("*.py", "*.pyx", "*.pxd", "*.yml"):      # subpackages too
            files += sorted(f for f in d.rglob(pat)
                            if not any(p == "__pycache__" or p.startswith(".") for p in f.relative_to(d).parts))
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(PACKAGE_ROOT)).encode())
        h.update(f.read_bytes())
    for f in _kernel_files():
        h.update(f.name.encode())
        h.update(f.read_bytes())
    for dist in VERSIONED:
        try:
            v = metadata.version(dist)
        except metadata.PackageNotFoundError:
            v = "absent"
        h.update(f"{dist}=={v}".encode())
    return h.hexdigest()[:16]


def _policy_files(stem):
    """The files ``load_policy`` reads for ``stem``: the zip (required), then the
    normalisation statistics and the metadata where present (all in the content hash)."""
    from controllers.rl import NORM_SUFFIX
    zip_path = Path(str(stem) + ".zip")
    return [zip_path] + [f for f in (Path(str(stem) + NORM_SUFFIX), Path(str(stem) + ".json")) if f.is_file()]


def plan(tasks, scenarios, estimators, controllers, episodes, seed, policy_dir=None, robot="realistic", log=print):
    """The list of jobs (dicts) on ``robot`` (a key of ``ROBOTS``: the environment's
    ``realism=``, part of every cell's env kwargs and so of its cache key); unknown names
    raise ValueError listing the accepted ones;
    cells whose policy file is missing are left out with a message. A job names its policy
    by file name (``policy``), directory (``policy_dir``: None for the package's shipped
    policies) and content hash (``policy_sha``)."""
    from envs.sphere import ESTIMATORS
    from controllers.rl import POLICY_DIR, policy_stem
    tasks = _check_names("task", tasks, TASKS)
    scenarios = _check_names("scenario", scenarios, tuple(SCENARIOS))
    estimators = _check_names("estimator", estimators, tuple(ESTIMATORS()))
    controllers = _check_names("controller", controllers, CONTROLLERS)
    if robot not in ROBOTS:
        raise ValueError(f"unknown robot {robot!r}; accepted: {', '.join(ROBOTS)}")
    integer("episodes", episodes, 1)
    integer("seed", seed, 0)
    pdir = Path(policy_dir) if policy_dir is not None else POLICY_DIR
    custom = None if pdir.resolve() == POLICY_DIR.resolve() else str(pdir.resolve())
    jobs, missing = [], set()
    for task in tasks:
        for sc in scenarios:
            for est in estimators:
                for ctrl in controllers:
                    name = sha = None
                    if ctrl != "pid":
                        stem = policy_stem("ppo", task, "truth" if ctrl == "ppo-truth" else est, pdir)
                        files = _policy_files(stem)
                        if not files[0].is_file():
                            missing.add(str(stem))
                            continue
                        name, sha = stem.name, _file_hash(files)[:16]
                    jobs.append(dict(task=task, scenario=sc, estimator=est, controller=ctrl, episodes=episodes,
                                     seed=seed, policy=name, policy_dir=custom if name else None, policy_sha=sha,
                                     env_kwargs=dict(SCENARIOS[sc], task=task, estimator=est,
                                                     realism=ROBOTS[robot])))
    for m in sorted(missing):
        log(f"no policy {m}.zip: its cells are skipped (train it with scripts/train.py)")
    _warn_estimator_changes(jobs, pdir, log)
    return jobs


def _warn_estimator_changes(jobs, pdir, log):
    """Name the policies of ``jobs`` whose JSON records estimator parameters other than the
    current ones (trained with another filter than the one their rows evaluate), and those
    that record none (trained before they were recorded)."""
    from controllers.rl import estimator_config
    changed, unrecorded = {}, []
    for j in jobs:
        if not j["policy"] or j["policy"] in changed or j["policy"] in unrecorded:
            continue
        meta = Path(pdir) / (j["policy"] + ".json")
        rec = json.loads(meta.read_text()) if meta.is_file() else {}
        now = json.loads(json.dumps(estimator_config(rec.get("estimator", j["estimator"]), rec.get("env_kwargs"))))
        if not now:
            continue                # truth, or a filter without parameters: nothing to have changed
        if "estimator_params" not in rec:
            unrecorded.append(j["policy"])
            continue
        was = rec["estimator_params"]
        diff = sorted(k for k in set(now) | set(was) if now.get(k) != was.get(k))
        if diff:
            changed[j["policy"]] = diff
    for name, diff in changed.items():
        log(f"warning: {name} was trained with other estimator parameters than the current ({', '.join(diff)})")
    if unrecorded:
        log(f"note: {len(unrecorded)} policies record no estimator parameters (trained before they were "
            f"recorded): {', '.join(sorted(unrecorded))}")


def _check_policies(jobs):
    """Every policy of ``jobs`` from a --policy-dir read once before the grid starts (a
    corrupt or unsafe file is a PolicyError, a ValueError, here rather than in the middle of
    the grid); the package's own are tested with it."""
    from controllers.rl import load_policy
    for pdir, name in sorted({(j["policy_dir"], j["policy"]) for j in jobs if j["policy_dir"]}):
        load_policy(Path(pdir) / name)


def cell_key(job, version):
    """The cache key of a job: its cell, episodes, seeds, environment, policy content and
    the code version (not where the policy lies on disk)."""
    keep = {k: v for k, v in job.items() if k not in ("policy_dir", "record_path")}
    blob = json.dumps(keep, sort_keys=True, default=str) + version
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def _work_id(job):
    """What a job computes, without its controller's label."""
    return json.dumps({k: v for k, v in job.items() if k not in ("controller", "policy_dir")}, sort_keys=True,
                      default=str)


# ----------------------------------------------------------------------------------------
# running

def run_job(job):
    """Evaluate one cell; returns one row per episode (dicts of plain values; with
    ``job["record_path"]`` also the true path and the waypoints)."""
    record_path = bool(job.get("record_path", False))
    if job["controller"] != "pid":        # a PID-only grid needs no torch
        import torch
        torch.set_num_threads(1)
    from controllers.pid import PID
    from controllers.rl import POLICY_DIR, load_policy
    from envs.sphere import SphereRobotEnv
    env = SphereRobotEnv(**job["env_kwargs"])
    try:
        if job["controller"] == "pid":
            ctrl = PID.for_env(env)
        else:
            # None: the policies shipped inside this (possibly Ray-uploaded) package
            # absolute: a bare name would resolve to a shipped policy of the same name first
            pdir = Path(job["policy_dir"]).resolve() if job.get("policy_dir") else POLICY_DIR
            ctrl = load_policy(pdir / job["policy"], env=env)
        from controllers.evaluation import evaluate
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
                       waypoint_radius=getattr(env, "waypoint_radius", None))   # the waypoints task only
        rows.append(row)
    return rows


def runtime_env(policy_dir=None):
    """The Ray ``runtime_env`` of the grid's tasks: the package directories by content
    (``py_modules``: sources and compiled kernels) and the policy directory (default the
    package's shipped policies) as the ``working_dir``, the tasks' current directory; no
    path on the driver is used by a worker."""
    from controllers.rl import POLICY_DIR
    return {"py_modules": [str(PACKAGE_ROOT / p) for p in PACKAGES],
            "working_dir": str(policy_dir or POLICY_DIR),
            # the policies travel once, as the working_dir
            "excludes": list(RAY_EXCLUDES) + ["controllers/policies/", "policies/"]}


def _custom_policy_dir(jobs):
    dirs = {j["policy_dir"] for j in jobs if j.get("policy_dir")}
    if len(dirs) > 1:
        raise ValueError(f"the jobs of one Ray run must share one policy directory, got {sorted(dirs)}")
    return next(iter(dirs), None)


@contextlib.contextmanager
def ray_session(address=None, workers=None, policy_dir=None):
    """One Ray session for a whole run: joins the cluster at ``address`` (or starts a local
    one of ``workers`` CPUs) with ``runtime_env(policy_dir)`` (Ray uploads local directories
    only for a whole session, not per task) and shuts it down at the end. If Ray is already
    initialised, it is used as it is: then the caller's ``ray.init`` must pass
    ``runtime_env=compare.runtime_env()``."""
    import ray
    if ray.is_initialized():
        yield ray
        return
    ray.init(address=address, num_cpus=None if address else (workers or os.cpu_count()),
             runtime_env=runtime_env(policy_dir), include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def _load_cached(path, key):
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(d, dict) or d.get("key") != key or not isinstance(d.get("rows"), list):
        return None
    return d["rows"]


def _not_the_jobs_rows(rows, job):
    """Why cached ``rows`` are not the rows of ``job`` (its cell, one per episode seed, every
    metric a number); None if they are."""
    seeds = [job["seed"] + i for i in range(job["episodes"])]
    if len(rows) != len(seeds):
        return f"{len(rows)} rows for {len(seeds)} episodes"
    for r, seed in zip(rows, seeds, strict=True):
        if not isinstance(r, dict) or r.get("episode_seed") != seed:
            return f"a row that is not episode seed {seed}'s"
        wrong = [k for k in ("task", "scenario", "estimator", "controller") if r.get(k) != job[k]]
        wrong += [m for m in EPISODE_METRICS[job["task"]]
                  if isinstance(r.get(m), bool) or not isinstance(r.get(m), (int, float))]
        if wrong:
            return f"episode seed {seed}: {', '.join(wrong)} missing or wrong"
    return None


def _open_cache(jobs, cache_dir, resume, results, log):
    """(cache folder, each job's cell key); with ``resume`` fills ``results`` with the cells
    already cached for this code version."""
    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    version = code_version()
    keys = [cell_key(j, version) for j in jobs]
    if resume:
        for i, k in enumerate(keys):
            rows = _load_cached(cache / f"{k}.json", k)
            why = None if rows is None else _not_the_jobs_rows(rows, jobs[i])
            if why:         # an edited or damaged file: the cell runs again
                log(f"resume: {cache / f'{k}.json'} is not this cell's ({why}); running it again")
                rows = None
            results[i] = rows
        n = sum(r is not None for r in results)
        log(f"resume: {n} of {len(jobs)} cells cached for this code version ({version})")
    return cache, keys


def _run_local(jobs, todo, workers, done):
    """The jobs ``todo`` in a process pool of ``workers`` (default the CPU count), each
    finished one handed to ``done(i, rows)``."""
    import multiprocessing as mp
    n = workers or os.cpu_count() or 1
    if n == 1 or len(todo) <= 1:
        for i in todo:
            done(i, run_job(jobs[i]))
        return
    pool = ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("forkserver"))
    try:
        futs = {pool.submit(run_job, jobs[i]): i for i in todo}
        for f in as_completed(futs):
            done(futs[f], f.result())
    except BaseException:
        # Ctrl-C, SIGTERM or a failed cell: stop the workers now (the finished cells
        # are cached) instead of waiting for the queued ones
        procs = list((pool._processes or {}).values())   # shutdown() forgets them
        for proc in procs:
            proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _run_ray(jobs, todo, address, workers, done):
    """The jobs ``todo`` as Ray tasks, each finished one handed to ``done(i, rows)``."""
    with ray_session(address, workers, _custom_policy_dir([jobs[i] for i in todo])) as ray:
        remote = ray.remote(num_cpus=1)(run_job)
        # the policies are in the task's working directory
        ray_jobs = {i: (dict(jobs[i], policy_dir=".") if jobs[i].get("policy") else jobs[i]) for i in todo}
        refs = {remote.remote(ray_jobs[i]): i for i in todo}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for r in ready:
                done(refs[r], ray.get(r))


def run_grid(jobs, backend="local", workers=None, address=None, progress=True, cache_dir=None, resume=False,
             log=print):
    """Run the jobs; returns the rows in job order. backend: "local" (process pool of
    ``workers``, default the CPU count) or "ray" (inside ``ray_session`` when Ray is not
    initialised yet: ``address`` joins an existing cluster). With ``cache_dir`` every
    finished cell is written there (atomically); with ``resume`` the cells already there
    for this code version are not run again."""
    from tqdm.auto import tqdm
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}; accepted: local, ray")
    results = [None] * len(jobs)
    cache = keys = None
    if cache_dir is not None and not any(j.get("record_path") for j in jobs):
        cache, keys = _open_cache(jobs, cache_dir, resume, results, log)
    # cells that run the same thing (ppo and ppo-truth under truth: one policy) run once
    same = {}
    for i, j in enumerate(jobs):
        if results[i] is None:
            same.setdefault(_work_id(j), []).append(i)
    todo = [ids[0] for ids in same.values()]
    copies = {ids[0]: ids[1:] for ids in same.values()}
    bar = tqdm(total=len(jobs), initial=sum(r is not None for r in results), desc="control grid", unit="cell",
               disable=not progress)

    def done(i, rows):
        for k in [i] + copies[i]:
            results[k] = [dict(r, controller=jobs[k]["controller"]) for r in rows]
            if cache is not None:
                write_text(cache / f"{keys[k]}.json",
                              json.dumps({"key": keys[k], "job": jobs[k], "rows": results[k]}, default=str))
            bar.update()

    if backend == "local":
        _run_local(jobs, todo, workers, done)
    elif todo:
        _run_ray(jobs, todo, address, workers, done)
    bar.close()
    return [row for rows in results for row in rows]


# ----------------------------------------------------------------------------------------
# statistics

def _cell_key(r):
    return r["task"], r["scenario"], r["estimator"], r["controller"]


def summarise(rows, seed=0):
    """One summary row per (task, scenario, estimator, controller): for each metric of
    ``SHOWN[task]`` its mean with a 95 % interval (``<m>``, ``<m>_lo``, ``<m>_hi``; 0/1
    metrics Wilson, others bootstrap) and for continuous metrics the interquartile mean
    (``<m>_iqm``, ``_iqm_lo``, ``_iqm_hi``); against the ``truth`` cell of the same task,
    scenario and controller, the paired difference over the shared episode seeds
    (``delta_<m>``, ``delta_<m>_lo``, ``delta_<m>_hi``; NaN without a truth cell) and
    ``separated``: whether the main metric's difference excludes 0 at the family's level,
    95 % Bonferroni-adjusted over the k estimators compared with the same truth cell
    (level 1 - 0.05 / k: ``sep_level``, the interval ``sep_lo``, ``sep_hi``), so that the
    chance of any false ``*`` among them stays within 5 %."""
    groups = {}
    for r in rows:
        groups.setdefault(_cell_key(r), {})[r["episode_seed"]] = r
    out, family = [], {}
    for (task, sc, est, ctrl), eps in groups.items():
        row = {"task": task, "scenario": sc, "estimator": est, "controller": ctrl, "episodes": len(eps),
               "main_metric": MAIN_METRIC[task][0]}
        truth = groups.get((task, sc, "truth", ctrl))
        seeds = sorted(set(eps) & set(truth)) if truth else []
        for m in SHOWN[task]:
            v = np.array([eps[s][m] for s in sorted(eps)], dtype=float)
            st = interval(v[np.isfinite(v)], m, seed=seed)
            row[m], row[m + "_lo"], row[m + "_hi"] = st["mean"], st["lo"], st["hi"]
            if m not in BINARY_METRICS:
                row[m + "_iqm"], row[m + "_iqm_lo"], row[m + "_iqm_hi"] = st["iqm"], st["iqm_lo"], st["iqm_hi"]
            if est == "truth" and truth is not None:
                d = {"delta": 0.0, "lo": 0.0, "hi": 0.0}       # the reference itself
            elif seeds:
                d = paired_difference([eps[s][m] for s in seeds], [truth[s][m] for s in seeds], m, seed=seed)
            else:
                d = {"delta": float("nan"), "lo": float("nan"), "hi": float("nan")}
            row["delta_" + m], row["delta_" + m + "_lo"], row["delta_" + m + "_hi"] = d["delta"], d["lo"], d["hi"]
        row["separated"] = False
        row["sep_level"] = row["sep_lo"] = row["sep_hi"] = float("nan")
        if est != "truth" and seeds:
            family.setdefault((task, sc, ctrl), []).append((row, eps, truth, seeds))
        out.append(row)
    for members in family.values():
        level = 1.0 - 0.05 / len(members)
        for row, eps, truth, seeds in members:
            main = row["main_metric"]
            d = paired_difference([eps[s][main] for s in seeds], [truth[s][main] for s in seeds], main,
                                  seed=seed, level=level)
            row["sep_level"], row["sep_lo"], row["sep_hi"] = level, d["lo"], d["hi"]
            row["separated"] = bool(math.isfinite(d["lo"]) and (d["lo"] > 0 or d["hi"] < 0))
    out.sort(key=lambda r: (r["task"], r["scenario"], r["controller"], _rank_key(r)))
    return out


def paired_between(rows, a, b, seed=0):
    """Estimator ``a`` minus estimator ``b`` paired over their shared episode seeds, per
    (task, scenario, controller) where both ran: one dict per group with ``n`` (the shared
    seeds) and, for each metric of ``SHOWN[task]``, ``delta_<m>``, ``delta_<m>_lo``,
    ``delta_<m>_hi`` (``paired_difference``: Newcombe for 0/1 metrics, bootstrap
    otherwise). ``rows``: ``run_grid``'s rows or those of ``episodes.csv`` (read with
    ``csv.DictReader``: numbers as text are converted)."""
    def num(v):
        return float("nan") if v in ("", None) else float(v)
    cells = {}
    for r in rows:
        cells.setdefault((r["task"], r["scenario"], r["estimator"], r["controller"]), {})[int(r["episode_seed"])] = r
    names = {k[2] for k in cells}
    for e in (a, b):
        if e not in names:
            raise ValueError(f"estimator {e!r} is not in the rows; they hold: {', '.join(sorted(names))}")
    out = []
    for (task, sc, est, ctrl), xa in sorted(cells.items()):
        xb = cells.get((task, sc, b, ctrl))
        if est != a or xb is None:
            continue
        seeds = sorted(set(xa) & set(xb))
        row = {"task": task, "scenario": sc, "controller": ctrl, "a": a, "b": b, "n": len(seeds)}
        for m in SHOWN[task]:
            d = paired_difference([num(xa[s][m]) for s in seeds], [num(xb[s][m]) for s in seeds], m, seed=seed)
            row["delta_" + m], row["delta_" + m + "_lo"], row["delta_" + m + "_hi"] = d["delta"], d["lo"], d["hi"]
        out.append(row)
    return out


def _rank_key(r):
    """truth first, then the estimators from the least to the most harm to the main metric."""
    if r["estimator"] == "truth":
        return (0, 0.0, "")
    d = r["delta_" + r["main_metric"]]
    harm = -d if MAIN_METRIC[r["task"]][1] else d
    return (1, harm if math.isfinite(harm) else math.inf, r["estimator"])


def min_detectable_success(n: int, level: float = 0.95) -> int | None:
    """The smallest number of failed runs out of ``n`` (against a truth that succeeds in
    all ``n``) whose paired interval at ``level`` excludes 0; None if even ``n`` failures do not."""
    from scipy.stats import norm
    z = float(norm.isf((1 - level) / 2))
    for k in range(1, n + 1):
        x = np.r_[np.zeros(k), np.ones(n - k)]
        if newcombe_paired(x, np.ones(n), z)[2] < 0:
            return k
    return None


# ----------------------------------------------------------------------------------------
# outputs

def _fmt(v, lo=None, hi=None, pct=False, unit=" %"):
    if v is None or not math.isfinite(v):
        return "-"
    f = (lambda x: f"{100 * x:.0f}") if pct else (lambda x: f"{x:.3g}")
    s = f(v) + (unit if pct else "")
    if lo is not None and math.isfinite(lo):
        s += f" [{f(lo)}, {f(hi)}]"
    return s


def _summary_table(task, scenario, rs):
    """The Markdown lines of one (task, scenario) table of summary.md."""
    main = MAIN_METRIC[task][0]
    lines = [f"## {task}, {scenario} (main metric: {main})", ""]
    cols = ["controller", "estimator", "n", f"Δ {main} vs truth"] + \
           [f"{m} ({UNITS[m]})" if UNITS[m] else m for m in SHOWN[task]]
    if main not in BINARY_METRICS:
        cols.insert(5, f"{main} IQM")
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for r in rs:
        pct = main in BINARY_METRICS
        dm = "delta_" + main
        delta = (_fmt(r[dm], r[dm + "_lo"], r[dm + "_hi"], pct=pct, unit=" pp")
                 + (" *" if r["separated"] else ""))
        if r["estimator"] == "truth" or not math.isfinite(r[dm]):
            delta = "(reference)" if r["estimator"] == "truth" else "- (no truth cell)"
        cells = [r["controller"], f"`{r['estimator']}`", str(r["episodes"]), delta]
        for m in SHOWN[task]:
            cells.append(_fmt(r[m], r[m + "_lo"], r[m + "_hi"], pct=m in BINARY_METRICS))
            if m == main and m not in BINARY_METRICS:
                cells.append(_fmt(r[m + "_iqm"], r[m + "_iqm_lo"], r[m + "_iqm_hi"]))
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    return lines


#: the controllers of the headline table (ppo-truth, the truth policy under each estimator, is in the full tables)
HEADLINE_CONTROLLERS = ("pid", "ppo")


def _signed(x, pct):
    s = f"{100 * x:+.0f}" if pct else f"{x:+.2f}"
    return "0" if pct and s in ("+0", "-0") else s


def _headline_cell(r, main):
    """The truth row's value with its interval, or the paired difference against truth."""
    pct = main in BINARY_METRICS
    if r["estimator"] == "truth":
        return _fmt(r[main], r[main + "_lo"], r[main + "_hi"], pct=pct)
    d, lo, hi = (r["delta_" + main + k] for k in ("", "_lo", "_hi"))
    if not math.isfinite(d):
        return "-"
    unit = " pp" if pct else ""
    ci = f" [{_signed(lo, pct)}, {_signed(hi, pct)}]" if math.isfinite(lo) else ""
    return f"{_signed(d, pct)}{unit}{ci}" + (" *" if r["separated"] else "")


def headline_table(summary):
    """The README's table: one row per estimator, one column per task x controller x floor
    (HEADLINE_CONTROLLERS), each the main metric: its value for `truth`, the paired
    difference against `truth` for the others; rows ranked as the first column's. Markdown
    lines; [] when the grid has no truth cell to compare with."""
    order = {name: i for i, name in enumerate(SCENARIOS)}
    cols = sorted({(r["task"], r["controller"], r["scenario"]) for r in summary
                   if r["controller"] in HEADLINE_CONTROLLERS},
                  key=lambda c: (TASKS.index(c[0]), HEADLINE_CONTROLLERS.index(c[1]),
                                 order.get(c[2], len(order)), c[2]))
    if not cols or not any(r["estimator"] == "truth" for r in summary):
        return []
    cell = {(r["task"], r["controller"], r["scenario"], r["estimator"]): r for r in summary}
    first = cols[0]
    ranked = sorted({r["estimator"] for r in summary},
                    key=lambda e: _rank_key(cell[first + (e,)]) if first + (e,) in cell else (2, math.inf, e))
    heads, last_task = [], None
    for task, ctrl, sc in cols:
        heads.append(f"{task}, {ctrl.upper()}, {sc}" if task != last_task else f"{ctrl.upper()}, {sc}")
        last_task = task
    lines = ["| estimator | " + " | ".join(heads) + " |", "|---|" + "---|" * len(cols)]
    for e in ranked:
        cells = [_headline_cell(cell[c + (e,)], MAIN_METRIC[c[0]][0]) if c + (e,) in cell else "-" for c in cols]
        lines.append(f"| `{e}` | " + " | ".join(cells) + " |")
    return lines


def _summary_intro(summary, command, seconds):
    """summary.md's opening lines: the command, how each cell is read, what the episodes detect."""
    ns = sorted({r["episodes"] for r in summary})
    lines = ["# Control under each attitude estimator", ""]
    if command:
        lines += [f"Command: `{command}`" + (f" ({seconds:.0f} s)" if seconds is not None else ""), ""]
    lines += [
        "Each cell: mean [95 % interval] over its episodes (the same seeds in every cell), scored on the "
        "true state. Success: Wilson interval; the other metrics: expanded "
        f"percentile bootstrap (at least {N_BOOT:,} resamples, and enough to leave {MIN_TAIL} beyond each end; "
        "seeded); IQM = interquartile mean. Δ: the paired difference against the `truth` cell of the same "
        "controller and floor over the same seeds (success: Newcombe's paired interval, in percentage "
        "points; others: paired bootstrap; none from fewer than "
        f"{MIN_BOOT} episodes); `*`: the main metric's difference excludes 0 at the level of its family, "
        "95 % Bonferroni-adjusted over the estimators compared with the same truth cell (1 - 0.05 / k; "
        "summary.csv: sep_level, sep_lo, sep_hi), so that any false `*` among them has at most a 5 % chance. "
        "Rows ranked by Δ of the main metric, from the least harm. Track "
        "metrics: steady state = samples at least "
        f"{SETTLE_WINDOW_S:g} s after each command change; settle = time until the heading error stays "
        f"within {SETTLE_BAND_DEG:g} deg.", ""]
    levels = sorted({r["sep_level"] for r in summary if math.isfinite(r["sep_level"])})
    for n in ns:
        for level in levels or [0.95]:
            k = min_detectable_success(n, level)
            lines.append(f"With {n} episodes per cell, a success difference against a truth that reaches every "
                         f"goal gets its `*` (level {100 * level:.2f} %) from {k} failed runs of {n} "
                         f"({100 * k / n:.0f} percentage points)." if k else
                         f"With {n} episodes per cell no success difference gets a `*` (level {100 * level:.2f} %).")
    lines.append("")
    return lines


def write_outputs(rows, summary, out_dir, path_rows=None, log=print, command=None, seconds=None):
    """Per-episode CSV, summary Markdown + CSV, the headline figure, the path map (PNG)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    first = ("task", "scenario", "estimator", "controller", "episode_seed")
    keys = sorted({k for r in rows for k in r}, key=lambda k: (k not in first, first.index(k) if k in first else 0, k))
    # each file is written whole or not at all (an interrupted write keeps the previous one)
    write_text(out / "episodes.csv", csv_text(rows, keys))
    sfirst = ("task", "scenario", "estimator", "controller", "episodes", "main_metric", "separated")
    skeys = sorted({k for r in summary for k in r},
                   key=lambda k: (k not in sfirst, sfirst.index(k) if k in sfirst else 0, k))
    write_text(out / "summary.csv", csv_text(summary, skeys))
    lines = _summary_intro(summary, command, seconds)
    head = headline_table(summary)
    if head:
        mains = ", ".join(f"{t}: {MAIN_METRIC[t][0]}" for t in TASKS if any(r["task"] == t for r in summary))
        lines += ["## Headline table", "",
                  f"The main metric ({mains}): `truth` rows give the value, the others the paired difference "
                  "against `truth` (same controller, floor and seeds) with its 95 % interval; `*`: it excludes 0 "
                  "at its family's Bonferroni-adjusted level (above). Rows in the order of the first column. "
                  "Also in headline.md.", ""] + head + [""]
        write_text(out / "headline.md", "\n".join(head) + "\n")
    for task in sorted({r["task"] for r in summary}):
        for sc in sorted({r["scenario"] for r in summary if r["task"] == task}):
            lines += _summary_table(task, sc, [r for r in summary if r["task"] == task and r["scenario"] == sc])
    why = _plot_headline(summary, out / "headline.png")
    if why:
        lines += ["## Headline figure", "", why, ""]
        log(why)
    write_text(out / "summary.md", "\n".join(lines))
    if path_rows:
        _plot_paths(path_rows, out / "paths.png")
    # an earlier run's file that this run does not make would be read as this run's
    stale = [n for n, made in (("headline.md", head), ("headline.png", not why), ("paths.png", path_rows)) if not made]
    for name in stale:
        (out / name).unlink(missing_ok=True)
    log(f"wrote {out}/summary.md, summary.csv, episodes.csv" + (", headline.md" if head else "")
        + ("" if why else ", headline.png")
        + (", paths.png" if path_rows else ""))
    return out


_LABEL = {"heading_ss": "Δ steady-state heading error vs truth (deg)",
          "success": "Δ success rate vs truth (percentage points)"}
_COLOR = {"pid": "tab:blue", "ppo": "tab:orange", "ppo-truth": "tab:green"}


def _headline_panel(ax, summary, task, sc):
    """One panel of the headline figure: (task, floor) ``sc``."""
    main, higher = MAIN_METRIC[task]
    pct = 100.0 if main in BINARY_METRICS else 1.0
    rs = [r for r in summary if r["task"] == task and r["scenario"] == sc and r["estimator"] != "truth"]
    ctrls = [c for c in CONTROLLERS if any(r["controller"] == c for r in rs)]
    # rank by the first controller's difference (the least harm at the top)
    ref = {r["estimator"]: _rank_key(r)[1] for r in rs if r["controller"] == ctrls[0]}
    ests = sorted({r["estimator"] for r in rs}, key=lambda e: (ref.get(e, math.inf), e))
    y = np.arange(len(ests))[::-1]
    off = 0.22
    for k, c in enumerate(ctrls):
        for e, yy in zip(ests, y):
            r = next((r for r in rs if r["estimator"] == e and r["controller"] == c), None)
            if r is None:
                continue
            d, lo, hi = (r["delta_" + main] * pct, r["delta_" + main + "_lo"] * pct,
                         r["delta_" + main + "_hi"] * pct)
            yk = yy + (k - (len(ctrls) - 1) / 2) * off
            ax.errorbar([d], [yk], xerr=[[d - lo], [hi - d]] if math.isfinite(lo) else None, fmt="o",
                        color=_COLOR[c], ms=5, capsize=3, label=c)
            # the cell's own value beside its interval (success as an absolute rate)
            ax.annotate(_fmt(r[main], pct=main in BINARY_METRICS) + ("" if pct > 1 else f" {UNITS[main]}"),
                        (hi if math.isfinite(hi) else d, yk), xytext=(4, 0), textcoords="offset points",
                        va="center", fontsize=7, color=_COLOR[c])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_yticks(y, ests)
    ax.set_ylim(-0.6, len(ests) - 0.4)
    truth = {r["controller"]: r for r in summary
             if r["task"] == task and r["scenario"] == sc and r["estimator"] == "truth"}
    unit = "" if main in BINARY_METRICS else f" {UNITS[main]}"
    ref_txt = ", ".join(f"{c} {_fmt(truth[c][main], pct=main in BINARY_METRICS)}{unit}"
                        for c in ctrls if c in truth)
    worse = "left" if higher else "right"
    # two lines, so that the title fits the axes at any width
    ax.set_title(f"{task}, {sc} floor — under truth: {ref_txt}\n({worse} = worse; labels: the cell's own value)",
                 fontsize=9)
    ax.margins(x=0.12)
    ax.set_xlabel(_LABEL.get(main, f"Δ {main} vs truth"))
    ax.grid(axis="x", alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    uniq = dict(zip(labels, handles))
    ax.legend(uniq.values(), uniq.keys(), fontsize=8, loc="best")


def _plot_headline(summary, path):
    """One panel per task and floor: the estimators ranked by the paired difference of the
    main metric against truth, one point with its 95 % interval per controller. Returns
    None, or why there is no figure (nothing is written then)."""
    order = {name: i for i, name in enumerate(SCENARIOS)}
    panels = sorted({(r["task"], r["scenario"]) for r in summary
                     if r["estimator"] != "truth" and math.isfinite(r["delta_" + r["main_metric"]])},
                    key=lambda p: (p[0], order.get(p[1], len(order)), p[1]))
    if not panels:
        if not any(r["estimator"] == "truth" for r in summary):
            return ("No headline figure: the grid has no `truth` estimator, and the figure shows each "
                    "estimator's paired difference against it (add `truth` to --estimators).")
        return "No headline figure: the grid has no estimator besides `truth` to compare with it."
    from controllers.plots import new_figure
    sizes = [len({r["estimator"] for r in summary if (r["task"], r["scenario"]) == p}) - 1 for p in panels]
    height = sum(1.0 + 0.42 * s for s in sizes) + 0.4
    fig = new_figure(figsize=(8.5, height))
    axes = fig.subplots(len(panels), 1,
                             gridspec_kw={"height_ratios": [1.0 + 0.42 * s for s in sizes]}, squeeze=False)
    for ax, (task, sc) in zip(axes[:, 0], panels):
        _headline_panel(ax, summary, task, sc)
    n = sorted({r["episodes"] for r in summary})
    few = (f"\n(heading: no interval from fewer than {MIN_BOOT} episodes; points are means)"
           if min(n) < MIN_BOOT else "")
    fig.suptitle(f"Estimators ranked by their paired difference against the true attitude "
                 f"({'/'.join(map(str, n))} episodes per cell, 95 % intervals){few}", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.5 if few else 0.3) / height))     # the title's lines above the panels
    save_figure(fig, path)
    return None


def _plot_paths(path_rows, path):
    from matplotlib.patches import Circle

    from controllers.plots import new_figure
    fig = new_figure(figsize=(7, 7))
    ax = fig.subplots()
    first = path_rows[0]
    if first.get("waypoints") is not None:
        wp = np.vstack([first["start"][None, :], first["waypoints"]])
        ax.plot(wp[:, 0], wp[:, 1], "k--", lw=1.5, label="target path")
        for x, y in wp[1:]:          # reached when the true position enters the circle
            ax.add_patch(Circle((x, y), first["waypoint_radius"], fill=False, color="k", lw=0.8))
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
    save_figure(fig, path)


# ----------------------------------------------------------------------------------------
# command line

QUICK = dict(episodes=3, estimators="truth,ekf-lp,ekf,mahony,gyro", controllers="pid,ppo")
FULL_EPISODES = 30


def _list(s):
    return [x.strip() for x in s.split(",") if x.strip()]


_DESCRIPTION = (
    "Compare motion control under each attitude estimator: the PID, PPO trained with that estimator "
    "and PPO trained on the true attitude, every cell against the `truth` cell of the same controller "
    "and floor over the same episode seeds.")
_EPILOG = (
    "Writes <out>/summary.md (the table), summary.csv (<metric>, <metric>_lo, <metric>_hi, "
    "delta_<metric>, ...), episodes.csv, headline.png (estimators ranked by their paired difference "
    "against truth), headline.md (the README's table: the main metric per estimator, task, controller and floor) "
    "and paths.png; finished cells are cached in <out>/cells/. Metrics: "
    "docs/envs/sphere_bot_track.md and sphere_bot_waypoints.md.")
_EXAMPLES = (
    "  spherebot-compare --quick                       # the demo (make demo), under a minute\n"
    "  spherebot-compare --full --backend ray --address auto   # every cell, 30 episodes, on a cluster\n"
    "  spherebot-compare --full --resume               # continue an interrupted run")


def _parser():
    import fusion
    all_est = ["truth"] + fusion.available()
    ap = argparse.ArgumentParser(prog="spherebot-compare", description=textwrap.fill(_DESCRIPTION, 78),
                                 epilog=textwrap.fill(_EPILOG, 78) + "\n\n" + _EXAMPLES,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default=",".join(TASKS), metavar="LIST",
                    help=f"comma-separated tasks (default: all). Accepted: {', '.join(TASKS)}")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS), metavar="LIST",
                    help=f"comma-separated floors (default: all). Accepted: {', '.join(SCENARIOS)}: flat = the "
                         "environment's defaults; disturbed = 16 magnetic dipoles, 16 bumps and 8 slippery "
                         "patches in a 16 m arena")
    ap.add_argument("--estimators", default=None, metavar="LIST",
                    help=f"comma-separated estimators; include truth for the differences and the figure "
                         f"(default: all; --quick: {QUICK['estimators']}). Accepted: {', '.join(all_est)}")
    ap.add_argument("--controllers", default=None, metavar="LIST",
                    help=f"comma-separated controllers (default: all; --quick: {QUICK['controllers']}). "
                         "Accepted: pid (the same gains everywhere), "
                         "ppo (the policy trained with that estimator), ppo-truth (the policy trained on the true "
                         "attitude, run with that estimator)")
    ap.add_argument("--episodes", type=int, default=None, metavar="N",
                    help=f"episodes per cell, seeds SEED .. SEED+N-1 (default 10; --quick {QUICK['episodes']}; "
                         f"--full {FULL_EPISODES})")
    ap.add_argument("--seed", type=int, default=0, help="first episode seed (default 0)")
    ap.add_argument("--robot", choices=tuple(ROBOTS), default="realistic",
                    help="realistic: the v1 robot (SphereBot*-v1: drive vibration, its own magnetic field, "
                         "latency, deadband, stiction, battery sag, compliant servo); ideal: the v0 robot "
                         "(SphereBot*-v0, none of them; the shipped PPO policies were trained on v1) "
                         "(default realistic, the environment's default)")
    ap.add_argument("--quick", action="store_true",
                    help=f"the demo: {QUICK['episodes']} episodes per cell, estimators {QUICK['estimators']}, "
                         f"controllers {QUICK['controllers']} (35-50 s on 2 cores)")
    ap.add_argument("--full", action="store_true",
                    help=f"the full grid: every estimator, {FULL_EPISODES} episodes per cell "
                         "(about 25 min on 2 cores for the README's truth and 9 estimators; "
                         "use --backend ray on a cluster, and --resume after an interruption)")
    ap.add_argument("--backend", choices=("local", "ray"), default=None,
                    help="local: a process pool on this machine; ray: Ray tasks (one session per run; the "
                         "package and policies travel in the runtime_env) (default local; ray with --address)")
    ap.add_argument("--workers", type=int, default=None, metavar="N",
                    help="local processes, or the CPUs of a Ray cluster started here (default: all cores)")
    ap.add_argument("--address", default=None,
                    help="address of an existing Ray cluster to join, e.g. auto or ray://host:10001 "
                         "(default: start a local one); implies --backend ray")
    ap.add_argument("--policy-dir", default=None, metavar="DIR",
                    help="where the ppo-<task>-<estimator>.zip policies are (default: the package's "
                         "controllers/policies)")
    ap.add_argument("--out", default="results/control", metavar="DIR",
                    help="output folder, also holding the cell cache (default results/control)")
    ap.add_argument("--resume", action="store_true",
                    help="reuse the cells already finished in <out>/cells/ by the same code and policies "
                         "(cells of other code versions are never reused)")
    ap.add_argument("--no-paths", action="store_true",
                    help="skip paths.png (one extra waypoints episode per estimator)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def main(argv=None):
    """The command line (``spherebot-compare``); returns the exit status."""
    ap = _parser()
    a = ap.parse_args(argv)
    if threading.current_thread() is not threading.main_thread():
        return _main(ap, a, argv)
    # a kill (SIGTERM) unwinds like Ctrl-C: the pool's workers are stopped, not orphaned;
    # the caller's handler is put back at the end (main may run inside another program)
    old = signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        return _main(ap, a, argv)
    except KeyboardInterrupt:
        print(f"\ninterrupted: the finished cells are kept in {Path(a.out) / CACHE_DIR}; the same command "
              f"with --resume continues", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, old)


def _main(ap, a, argv):
    import fusion
    t0 = time.perf_counter()
    if a.quick and a.full:
        ap.error("--quick and --full exclude each other")
    episodes = a.episodes if a.episodes is not None else (
        QUICK["episodes"] if a.quick else FULL_EPISODES if a.full else 10)
    estimators = a.estimators or (QUICK["estimators"] if a.quick else ",".join(["truth"] + fusion.available()))
    controllers = a.controllers or (QUICK["controllers"] if a.quick else ",".join(CONTROLLERS))
    if a.address and a.backend == "local":
        ap.error("--address joins a Ray cluster: give it with --backend ray (or without --backend)")
    backend = a.backend or ("ray" if a.address else "local")
    require("spherebot-compare", "sim")
    if any(c.startswith("ppo") for c in _list(controllers)):
        require("spherebot-compare with a ppo controller", "rl")
    if backend == "ray":
        require("spherebot-compare --backend ray", "ray")
    try:
        if a.workers is not None and a.workers < 1:
            raise ValueError(f"--workers must be >= 1, got {a.workers}")
        jobs = plan(_list(a.tasks), _list(a.scenarios), _list(estimators), _list(controllers),
                    episodes, a.seed, policy_dir=a.policy_dir, robot=a.robot)
        if not jobs:
            raise ValueError("no cell to run: every cell of the grid lacks its policy (see above)")
        _check_policies(jobs)
        check_writable(a.out)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{len(jobs)} cells x {episodes} episodes on backend {backend}")
    # one waypoints episode per estimator, PID, first scenario: the map of true paths
    path_jobs = [] if a.no_paths else [
        dict(j, episodes=1, record_path=True) for j in jobs
        if j["task"] == "waypoints" and j["controller"] == "pid" and j["scenario"] == jobs[0]["scenario"]]
    kw = dict(backend=backend, workers=a.workers, address=a.address)
    with (ray_session(a.address, a.workers, _custom_policy_dir(jobs)) if backend == "ray"
          else contextlib.nullcontext()):
        rows = run_grid(jobs, progress=not a.no_progress, cache_dir=Path(a.out) / CACHE_DIR, resume=a.resume, **kw)
        path_rows = run_grid(path_jobs, progress=False, **kw) if path_jobs else None
    summary = summarise(rows)
    seconds = time.perf_counter() - t0
    command = "spherebot-compare " + " ".join(sys.argv[1:] if argv is None else argv)
    write_outputs(rows, summary, a.out, path_rows=path_rows, command=command.strip(), seconds=seconds)
    print((Path(a.out) / "summary.md").read_text())
    print(f"done in {time.perf_counter() - t0:.0f} s")
    return 0
