#!/usr/bin/env python
"""Training curves of finished runs (controllers.curves): mean evaluation return against
timesteps, every seed and their spread, one panel per task and estimator.

    python scripts/training_curves.py logs/v1 --estimators truth ekf --out docs/training_curves.png
"""
import argparse
import sys
from pathlib import Path

from controllers.curves import load_run, plot_training_curves


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="run stems, or folders searched for <stem>.json beside <stem>.run/")
    ap.add_argument("--estimators", nargs="+", default=None, help="only the runs with these estimators")
    ap.add_argument("--out", default="docs/training_curves.png", help="the PNG (default: %(default)s)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    if out.is_dir() or (out.parent.exists() and not out.parent.is_dir()):
        ap.error(f"--out {a.out!r} must be a PNG file path in a folder")
    stems = []
    for p in map(Path, a.runs):
        stems += [j.with_suffix("") for j in sorted(p.glob("*.json")) if j.with_suffix(".run").is_dir()] \
            if p.is_dir() else [p]
    try:
        runs = [load_run(s) for s in stems]
        runs = [r for r in runs if a.estimators is None or r["estimator"] in a.estimators]
        drawn = plot_training_curves(runs, a.out, title="PPO: mean return of the periodic evaluations "
                                                        "(5 episodes each)")
    except (ValueError, FileNotFoundError) as e:
        ap.error(str(e))
    for r in runs:
        print(f"{r['task']:9s} {r['estimator']:8s} seed {r['seed']}: {len(r['timesteps'])} evaluations, "
              f"best {r['mean_return'].max():.1f} at {int(r['timesteps'][r['mean_return'].argmax()])}")
    print(f"{a.out}: {len(drawn)} panels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
