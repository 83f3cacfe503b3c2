"""``spherebot-papers`` (``scripts/reproduce_papers.py``): re-run the four source documents'
experiments in simulation, each on its seed scenario and IMU preset, and write Markdown + CSV
tables (beside the documents' own numbers) and PNG figures.

    spherebot-papers [--out results/papers] [--sections 000 001 003 004] [--seeds N] [--quick]

The sections and what did not reproduce: docs/papers.md. The measurements are
benchmarks.papers, the report benchmarks.papers_report.
"""
import argparse
import sys
import time

from benchmarks import compare, papers, papers_report
from controllers.policy_io import check_writable
from fusion.checks import require


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="spherebot-papers", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="results/papers", help="output folder (default: %(default)s)")
    p.add_argument("--sections", nargs="+", default=list(papers.SECTIONS), choices=list(papers.SECTIONS),
                   metavar="KEY", help=f"sections to run (default: all of {list(papers.SECTIONS)})")
    p.add_argument("--seeds", type=int, default=None, metavar="N",
                   help=f"number of seeds 0..N-1 (default: {len(papers.SEEDS)}, "
                        f"{len(papers.QUICK_SEEDS)} with --quick)")
    p.add_argument("--quick", action="store_true", help="fewer seeds (a smoke run, well under a minute)")
    return p.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    require("spherebot-papers", "plot")
    if args.seeds is not None and args.seeds < 1:
        sys.exit(f"error: --seeds must be >= 1, got {args.seeds}")
    twice = sorted({s for s in args.sections if args.sections.count(s) > 1})
    if twice:
        sys.exit(f"error: --sections names {twice} more than once")
    try:
        check_writable(args.out)
    except ValueError as e:
        sys.exit(f"error: {e}")
    t0 = time.perf_counter()
    seeds = range(args.seeds) if args.seeds is not None else None
    try:
        files = papers_report.reproduce(args.out, sections=args.sections, seeds=seeds, quick=args.quick)
    except KeyboardInterrupt:
        print(f"\ninterrupted: the files written so far in {args.out} mix this run's and the one "
              f"before it; run again to have them all from one", file=sys.stderr)
        return 130
    print(files[0].read_text())
    compare.print_written(files, args.out, time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
