#!/usr/bin/env python
"""Compare motion control under every attitude estimator: PID, PPO trained with that
estimator, and PPO trained on the true attitude, against the `truth` reference.

    .venv/bin/python scripts/compare_control.py --quick          # what `make demo` runs
    .venv/bin/python scripts/compare_control.py --episodes 20 --backend ray

Writes results/control/{summary.md, summary.csv, episodes.csv, degradation.png, paths.png}.
"""
import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import fusion                                    # noqa: E402
from controllers import compare                  # noqa: E402


def _list(s):
    return [x for x in s.split(",") if x]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default="track,waypoints")
    ap.add_argument("--scenarios", default=",".join(compare.SCENARIOS))
    ap.add_argument("--estimators", default=",".join(["truth"] + fusion.available()))
    ap.add_argument("--controllers", default=",".join(compare.CONTROLLERS))
    ap.add_argument("--episodes", type=int, default=10, help="episodes per cell (seeds seed .. seed+episodes-1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="4 episodes per cell (the demo)")
    ap.add_argument("--backend", choices=("local", "ray"), default="local")
    ap.add_argument("--workers", type=int, default=None, help="local processes / Ray CPUs (default: all cores)")
    ap.add_argument("--address", default=None, help="Ray cluster address (default: start a local one)")
    ap.add_argument("--policy-dir", default=None, help="default controllers/policies")
    ap.add_argument("--out", default="results/control")
    ap.add_argument("--no-progress", action="store_true")
    a = ap.parse_args(argv)
    episodes = 4 if a.quick else a.episodes
    t0 = time.perf_counter()
    try:
        jobs = compare.plan(_list(a.tasks), _list(a.scenarios), _list(a.estimators), _list(a.controllers),
                            episodes, a.seed, policy_dir=a.policy_dir)
        from envs.sphere import ESTIMATORS
        bad = [e for e in _list(a.estimators) if e not in ESTIMATORS()]
        if bad:
            raise ValueError(f"unknown estimator(s) {', '.join(bad)}; accepted: {', '.join(ESTIMATORS())}")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{len(jobs)} cells x {episodes} episodes on backend {a.backend}")
    rows = compare.run_grid(jobs, backend=a.backend, workers=a.workers, address=a.address,
                            progress=not a.no_progress)
    summary = compare.summarise(rows)
    # one waypoints episode per estimator, PID, first scenario: the map of true paths
    path_jobs = [dict(j, episodes=1, record_path=True) for j in jobs
                 if j["task"] == "waypoints" and j["controller"] == "pid" and j["scenario"] == _list(a.scenarios)[0]]
    path_rows = compare.run_grid(path_jobs, backend=a.backend, workers=a.workers, address=a.address,
                                 progress=False) if path_jobs else None
    compare.write_outputs(rows, summary, a.out, path_rows=path_rows)
    print((Path(a.out) / "summary.md").read_text())
    print(f"done in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
