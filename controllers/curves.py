"""Training curves: the mean evaluation return of training runs against their timesteps.

A run's work directory ``<stem>.run/`` holds ``evaluations.npz``, the log of its evaluation
callback (``timesteps``, ``results``: one row of episode returns per evaluation; the first
row, at 0, is the starting policy's evaluation where the run recorded it), and ``<stem>.json``
says what the run was (task, estimator, seed). ``plot_training_curves`` draws one panel per
task and estimator: every seed's curve, and the mean over seeds with their spread (min-max).
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np


def load_run(stem: str | Path) -> dict[str, Any]:
    """The run ``stem`` (``<stem>.json`` and ``<stem>.run/evaluations.npz``): its task,
    estimator, seed, init_from, and per evaluation the timesteps and mean return."""
    stem = Path(stem)
    meta_path, log = Path(str(stem) + ".json"), Path(str(stem) + ".run") / "evaluations.npz"
    for p in (meta_path, log):
        if not p.is_file():
            raise FileNotFoundError(f"run {stem}: {p} does not exist")
    meta = json.loads(meta_path.read_text())
    try:
        with np.load(log, allow_pickle=False) as d:
            t, r = np.asarray(d["timesteps"], dtype=float), np.asarray(d["results"], dtype=float)
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f"run {stem}: {log} is not an evaluation log ({e})") from None
    if t.ndim != 1 or r.ndim != 2 or len(t) != len(r) or len(t) == 0:
        raise ValueError(f"run {stem}: {log} has timesteps {t.shape} and results {r.shape}; expected (n,) and (n, k)")
    return {"stem": stem, "task": meta.get("task"), "estimator": meta.get("estimator"), "seed": meta.get("seed"),
            "init_from": meta.get("init_from"), "timesteps": t, "mean_return": r.mean(axis=1)}


def seed_spread(runs: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(timesteps, mean, min, max) over ``runs`` at the timesteps every run evaluated at."""
    common = sorted(set.intersection(*(set(r["timesteps"].tolist()) for r in runs)))
    table = np.array([[r["mean_return"][r["timesteps"].tolist().index(t)] for t in common] for r in runs])
    return np.asarray(common), table.mean(axis=0), table.min(axis=0), table.max(axis=0)


def _panel(ax, runs, title):
    for r in sorted(runs, key=lambda r: r["seed"]):
        ax.plot(r["timesteps"], r["mean_return"], lw=0.8, alpha=0.6, marker=".", ms=3, label=f"seed {r['seed']}")
    t, mean, lo, hi = seed_spread(runs)
    if len(runs) > 1 and len(t):
        ax.fill_between(t, lo, hi, color="0.6", alpha=0.3, lw=0, label=f"min-max of {len(runs)} seeds")
        ax.plot(t, mean, color="k", lw=1.8, label="mean over seeds")
    from matplotlib.ticker import FuncFormatter
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k" if abs(x) >= 1000 else f"{x:g}"))
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("environment steps of the run")
    ax.set_ylabel("mean evaluation return")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")


def _start_label(runs):
    """What the runs started from, in a few words: the PID clone, or the policy they fine-tune
    (its seed suffix dropped: each seed starts from its own)."""
    starts = set()
    for r in runs:
        start = str(r["init_from"])
        if start.startswith("pid"):
            starts.add("from the PID clone")
        elif r["init_from"] is None:
            starts.add("from scratch")
        else:
            starts.add("fine-tuned from " + re.sub(r"(-seed\d+)?(\.zip)?$", "", Path(start).name))
    return ", ".join(sorted(starts))


def plot_training_curves(runs: list[dict[str, Any]], path: str | Path,
                         title: str | None = None) -> list[tuple[str, str]]:
    """Draw ``runs`` (from ``load_run``) into ``path``: one panel per (task, estimator), tasks
    in rows. Returns the panels drawn."""
    if not runs:
        raise ValueError("plot_training_curves: no runs to draw")
    from controllers.plots import new_figure
    tasks = sorted({r["task"] for r in runs})
    estimators = sorted({r["estimator"] for r in runs}, key=lambda e: (e != "truth", e))
    fig = new_figure(figsize=(4.6 * len(estimators), 3.4 * len(tasks)))
    axes = fig.subplots(len(tasks), len(estimators), squeeze=False)
    drawn = []
    for i, task in enumerate(tasks):
        for j, est in enumerate(estimators):
            ax = axes[i, j]
            cell = [r for r in runs if (r["task"], r["estimator"]) == (task, est)]
            if not cell:
                ax.set_axis_off()
                continue
            _panel(ax, cell, f"{task}, {est} ({_start_label(cell)})")
            drawn.append((task, est))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    from controllers.policy_io import save_figure
    save_figure(fig, path)
    return drawn
