"""``spherebot-estimators`` (``scripts/compare_estimators.py``): score every estimator (default
parameters) on the built-in synthetic scenarios and on the recorded trials of the data folder;
write Markdown + CSV tables and PNG figures.

    spherebot-estimators [--out results/compare] [--data DIR] [--estimators gyro ekf ...] [--quick]

Synthetic: 'static' (as seed 000's still experiment) and 'mixed', 9-axis and 6-axis, with the
seed papers' Euler table and total / heading / inclination RMSE. Recorded: 9-axis where the
trial has a magnetometer, 6-axis (one heading offset per trial removed) on every trial,
trials whose quality is not 'ok' skipped; per-trial rows and the mean RMSE over trials per
set and mode; a trial file that cannot be read is reported and skipped. The loops live in
benchmarks.compare (matplotlib is imported only to draw).
"""
import argparse
import sys
import time
from pathlib import Path

import fusion
from fusion import datasets, metrics, scenarios
from fusion.checks import require
from controllers.policy_io import check_writable
from benchmarks import compare

ERR_COLS = ["total", "heading", "inclination"]


def _seed(text):
    try:
        v = int(text)
    except ValueError:
        v = -1
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return v


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="spherebot-estimators", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="results/compare", help="output folder (default: %(default)s)")
    p.add_argument("--data", default=None,
                   help=f"recorded-data folder, an error if absent "
                        f"(default: {datasets.DATA_LOCATION}, skipped if absent)")
    p.add_argument("--estimators", nargs="+", default=None, metavar="NAME",
                   help=f"estimators to score, names or comma-separated lists (default: all of {fusion.available()})")
    p.add_argument("--quick", action="store_true",
                   help="short scenarios and the first 2 'ok' trials per set (a smoke run)")
    p.add_argument("--plot-trial", default=None, metavar="SET/TRIAL",
                   help="recorded trial for the error figure (default: the first scored one with a magnetometer "
                        "whose heading reference is north)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="synthetic scenario seed, an integer >= 0 (default: %(default)s)")
    return p.parse_args(argv)


def _synthetic(names, args, out):
    """Score ``names`` on the synthetic scenarios: (score rows, Euler rows, files written)."""
    written = []
    durations = {"static": 30.0, "mixed": 20.0} if args.quick else {"static": 150.0, "mixed": 60.0}
    syn_scores, syn_euler, syn_curves = [], [], {}
    for sname, dur in durations.items():
        sc = scenarios.make_scenario(sname, fs=100.0, duration=dur, seed=args.seed)
        s_rows, e_rows, curves = compare.compare_scenario(names, sc)
        syn_scores += s_rows
        syn_euler += e_rows
        syn_curves[sname] = (sc, curves)
    written += compare.write_table(syn_scores, out / "synthetic_scores",
                                   ["scenario", "mode", "estimator"] + ERR_COLS,
                                   title="Synthetic scenarios: RMSE (deg)")
    written += compare.write_table(syn_euler, out / "synthetic_euler",
                                   ["scenario", "mode", "estimator", "angle", "mean", "std", "MAE", "RMSE"],
                                   digits=4, title="Synthetic scenarios: Euler-angle errors (deg), as the seed papers")
    sc, curves = syn_curves["mixed"]
    written.append(compare.plot_errors(
        {"9-axis (gyro + acc + mag)": curves["9-axis"],
         "6-axis (gyro + acc), one heading offset removed": curves["6-axis"]},
        out / "synthetic_mixed_error.png", t=sc.t,
        title=f"Synthetic 'mixed' scenario (seed {args.seed}, {sc.fs:g} Hz, {sc.t[-1] + sc.dt[0]:g} s): total error"))
    return syn_scores, syn_euler, written


def _load_recorded(args):
    """The recorded trials to score, before anything is written (a bad --plot-trial stops the
    run here): (data folder or None, trials, unreadable (key, reason), the trial to plot)."""
    data_dir = Path(args.data) if args.data else datasets.default_data_dir()
    if data_dir is None:
        return None, [], [], None
    unreadable = []
    try:
        trials = datasets.load_folder(data_dir, unreadable=unreadable)
    except ValueError as e:             # (two trials with one key; bad files are in unreadable)
        sys.exit(f"error: {e}")
    usable = {tr.key: tr.ok and metrics.reference_rows(tr.quat).any() for tr in trials}
    if args.quick:
        keep, count = [], {}
        for tr in trials:          # trials that cannot be scored stay in, to be reported as skipped
            if not usable[tr.key] or count.get(tr.set, 0) < 2:
                count[tr.set] = count.get(tr.set, 0) + usable[tr.key]
                keep.append(tr)
        trials = keep
    scored = [tr.key for tr in trials if usable[tr.key]]
    if args.plot_trial is not None and args.plot_trial not in scored:
        sys.exit(f"error: --plot-trial {args.plot_trial!r} is not a scored trial of {data_dir}"
                 f"{' (--quick keeps 2 per set)' if args.quick else ''}; scored: {', '.join(scored[:8])}"
                 f"{', ...' if len(scored) > 8 else ''}")
    plot_key = args.plot_trial or next((tr.key for tr in trials if usable[tr.key] and tr.has_mag
                                        and (tr.set, "9-axis") not in compare.INCLINATION_ONLY),
                                       next(iter(scored), None))
    return data_dir, trials, unreadable, plot_key


def _recorded(names, recorded, out):
    """Score ``names`` on the recorded trials (``_load_recorded``'s; none without the data
    folder): (aggregate rows, skipped (key, reason), files written)."""
    written = []
    data_dir, trials, unreadable, plot_key = recorded
    trial_rows, agg_rows, skipped = [], [], []
    if data_dir is None:
        print(f"recorded data: folder not found ({datasets.DATA_LOCATION}); skipping the recorded-trial comparison")
    else:
        for key, reason in unreadable:
            print(f"skipped unreadable trial file {key}: {reason}")
        print(f"recorded data: {len(trials)} trials in {data_dir}")
        trial_rows, skipped, tcurves = compare.compare_trials(names, trials, keep_curves=(plot_key,))
        skipped = unreadable + skipped
        if skipped:
            print(f"skipped {len(skipped)} (quality not 'ok' or not scoreable): "
                  + ", ".join(k for k, _ in skipped))
        agg_rows = compare.aggregate(trial_rows)
        written += compare.write_table(trial_rows, out / "trials",
                                       ["set", "trial", "mode", "estimator", "n"] + ERR_COLS + ["heading_offset"],
                                       title="Recorded trials: RMSE (deg) per trial "
                                             "(6-axis: heading offset removed, deg)")
        written += compare.write_table(agg_rows, out / "trials_aggregate",
                                       ["set", "mode", "estimator", "n_trials"] + ERR_COLS,
                                       title="Recorded trials: mean RMSE over trials (deg)")
        if plot_key in tcurves:
            panels = {f"{m} ({'gyro + acc + mag' if m == '9-axis' else 'gyro + acc, one heading offset removed'})": c
                      for m, c in tcurves[plot_key].items()}
            written.append(compare.plot_errors(panels, out / f"trial_{plot_key.replace('/', '_')}_error.png",
                                               title=f"Recorded trial {plot_key}: total error"))
    return agg_rows, skipped, written


def _report(names, syn_scores, syn_euler, agg_rows, skipped, written, out):
    """report.md (appended to ``written``); returns the two summary tables (Markdown)."""
    syn_md = compare.markdown_table(syn_scores, ["scenario", "mode", "estimator"] + ERR_COLS)
    agg_md = compare.markdown_table(agg_rows, ["set", "mode", "estimator", "n_trials"] + ERR_COLS) \
        if agg_rows else "(recorded data not found: skipped)\n"
    parts = ["# Estimator comparison\n",
             f"Estimators: {', '.join(names)} (default parameters). Errors in degrees; 6-axis: one "
             "constant heading offset per run removed (least squares) before scoring.\n",
             "## Synthetic scenarios (RMSE)\n", syn_md,
             "## Synthetic scenarios: Euler-angle errors (seed papers' table)\n",
             compare.markdown_table(syn_euler,
                                    ["scenario", "mode", "estimator", "angle", "mean", "std", "MAE", "RMSE"], 4),
             "## Recorded trials: mean RMSE over trials\n", agg_md]
    cells = sorted(f"{s} {m}" for s, m in compare.INCLINATION_ONLY if any(r["set"] == s and r["mode"] == m
                                                                           for r in agg_rows))
    if cells:
        parts.append(f"{', '.join(cells)}: inclination only (total and heading blank: not scored); its "
                     "reference heading is not magnetic north (the data folder's README).\n")
    if agg_rows:
        parts += ["Reference (the data folder's README, \"Recorded IMU data with a reference orientation\"; VQF "
                  "online, default parameters; VQF takes one "
                  "constant sample time 1/fs, while the rows above use the trials' time stamps, which "
                  "matters on ese650's uneven stamps):\n",
                  compare.markdown_table(compare.REFERENCE_VQF, ["set", "mode"] + ERR_COLS, 2)]
    written.append(compare.write_report(out / "report.md", parts, skipped, written, skipped_title="Skipped"))
    return syn_md, agg_md


def main(argv=None):
    args = parse_args(argv)
    require("spherebot-estimators", "plot")
    t_start = time.perf_counter()
    names = [n for arg in (fusion.available() if args.estimators is None else args.estimators)
             for n in arg.split(",") if n]
    if not names:
        sys.exit(f"error: --estimators names no estimator; available: {fusion.available()}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        sys.exit(f"error: --estimators names {twice} more than once (each would be scored twice)")
    unknown = [n for n in names if n not in fusion.available()]
    if unknown:
        sys.exit(f"error: unknown estimator(s) {unknown}; available: {fusion.available()}")
    # only the default folder may be absent (an installed package without the data)
    if args.data is not None and not Path(args.data).is_dir():
        sys.exit(f"error: --data {args.data!r} is not a folder; give the recorded-data folder "
                 f"or leave --data out (default: {datasets.DATA_LOCATION})")
    recorded = _load_recorded(args)
    out = Path(args.out)
    try:
        check_writable(out)
    except ValueError as e:
        sys.exit(f"error: {e}")
    syn_scores, syn_euler, written = _synthetic(names, args, out)
    agg_rows, skipped, more = _recorded(names, recorded, out)
    written += more
    syn_md, agg_md = _report(names, syn_scores, syn_euler, agg_rows, skipped, written, out)

    print("\nSynthetic scenarios, RMSE (deg):\n" + syn_md)
    print("Recorded trials, mean RMSE over trials (deg):\n" + agg_md)
    compare.print_written(written, out, time.perf_counter() - t_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
