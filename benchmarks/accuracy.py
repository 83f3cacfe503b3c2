#!/usr/bin/env python
"""Attitude accuracy of our estimators and of peer libraries, measured in the same run.

Methods: every estimator in ``fusion.available()`` (default parameters) and the peers
(vqf.VQF / vqf.BasicVQF, imufusion.Ahrs, ahrs.filters.Madgwick / Mahony / EKF, default
parameters), each fed in its own units and frame by benchmarks/peers.py and turned into
body -> ENU quaternions for scoring. Every run starts from the first sample, as users run them.

Data:

- recorded: every ``quality == 'ok'`` trial of ``fusion.datasets`` (its
  ``DATA_LOCATION``); 9-axis where the trial has a magnetometer, 6-axis on every trial.
- synthetic: every ``fusion.scenarios.SCENARIOS`` entry (100 Hz, 60 s, seed 0) and, where the
  module has them, every ``SEED_SCENARIOS`` entry (``seed_scenario(name, seed=0)``); 9-axis
  and 6-axis.

Timing: our estimators, imufusion (``set_sample_period`` before each sample) and the ``ahrs``
filters (their per-sample ``dt``) follow the time stamps; VQF takes one sample time at
construction, so it gets the mean step of the stamps, and where that is more than 0.1 % off
``1/fs`` (ese650) also ``1/fs`` as a second row, "vqf.VQF (Ts=1/fs)", the feeding of the reference figures
of the data folder's README ("Recorded IMU data with a reference orientation").

Scoring (benchmarks.compare.score_mode): RMSE in degrees of the total, heading and inclination
errors; in 6-axis mode after removing one constant heading offset per run. Per set and mode
the mean RMSE over its trials (or scenarios). In a cell whose reference heading is not north
(``compare.INCLINATION_ONLY``: diodem 9-axis) only the inclination is scored, and ranked.

Before scoring, every method runs an ideal (noise-free, bias-free) ``slow`` scenario; a peer
whose inclination RMSE (both modes) or 9-axis heading RMSE over the second half exceeds the
thresholds is fed wrongly (units or frame) and is not scored.

    .venv/bin/python benchmarks/accuracy.py            # a few minutes (pure-Python ahrs dominates)
    .venv/bin/python benchmarks/accuracy.py --quick    # under a minute
    .venv/bin/python benchmarks/accuracy.py --out DIR  # default results/benchmarks/
"""
import argparse
import math
import time
from pathlib import Path

import numpy as np

import fusion
from fusion import datasets, metrics, scenarios
from fusion.checks import arg_type, integer, number
from benchmarks import compare, loso, peers

ROOT = Path(__file__).resolve().parents[1]

ERRORS = ("total", "heading", "inclination")
FS = 100.0
SYNTHETIC, SEED = "synthetic", "seed scenarios"
SEED_ESTIMATORS = ("ekf", "aekf", "iir-ekf", "ukf", "cf-ekf")
BASELINES = ("gyro", "mahony")
# which source document ("The four source documents, in short") each seed estimator comes from, to find
# "its" seed scenarios when SEED_SCENARIOS does not say
SEED_DOC = {"ekf": "000", "aekf": "001", "iir-ekf": "003", "ukf": "003", "cf-ekf": "004"}
IDEAL = dict(name="slow", seed=0)
# ideal check (deg, RMSE over the second half): wrong units or frames give tens of degrees,
# every correctly fed method stays below 0.25 deg
IDEAL_MAX = dict(inclination=1.0, heading=2.0)
TARGETS = (("repoimu_tstick", "9-axis"), ("ese650", "6-axis"))
VQF = "vqf.VQF"
# the columns of the per-(set, mode) tables and of the overall table
SET_COLS = ["method", "group", "n_trials"] + list(ERRORS) + ["÷ best peer", "÷ VQF"]
OVERALL_COLS = ["set", "mode", "n", "best_ours", "ours_total", "ours_heading", "ours_inclination",
                "best_peer", "peer_total", "peer_heading", "peer_inclination", "ours / best peer"]


class Item:
    """One recording to score: ``set`` (table group), ``name``, ``data`` (peers.Data with the
    reference in ``q_true``) and the modes it is scored in."""

    def __init__(self, set_, name, data, modes):
        self.set, self.name, self.data, self.modes = set_, name, data, modes


# ---------------------------------------------------------------------------------------------
# what to score

def recorded_items(root, quick, max_trials, trial_seconds, log):
    """Items for the 'ok' trials under ``root`` and the (key, reason) pairs of those skipped."""
    items, skipped, count = [], [], {}
    for tr in datasets.load_folder(root):
        if not tr.ok:
            skipped.append((tr.key, tr.quality))
            continue
        n = None if trial_seconds is None else int(round(trial_seconds * tr.fs))
        if not metrics.reference_rows(tr.quat[:n]).any():
            skipped.append((tr.key, "no reference quaternion (finite, non-zero) in the part scored"))
            continue
        if max_trials is not None and count.get(tr.set, 0) >= max_trials:
            continue
        count[tr.set] = count.get(tr.set, 0) + 1
        modes = compare.MODES if tr.has_mag else compare.MODES[1:]
        items.append(Item(tr.set, tr.name, peers.Data.from_trial(tr, n), modes))
    return items, skipped


def seed_scenario_names():
    """``SEED_SCENARIOS`` names, or () where fusion.scenarios has none (yet)."""
    return tuple(getattr(scenarios, "SEED_SCENARIOS", ()) or ())


def synthetic_items(duration, seed, only=None, seconds=None):
    items = []
    for name in scenarios.SCENARIOS:
        if only is None or name in only:
            sc = scenarios.make_scenario(name, fs=FS, duration=duration, seed=seed)
            items.append(Item(SYNTHETIC, name, peers.Data.from_scenario(sc), compare.MODES))
    for name in seed_scenario_names():
        if only is None or name in only:
            sc = scenarios.seed_scenario(name, seed=seed)
            n = None if seconds is None else max(int(round(seconds * sc.fs)), 2)
            modes = compare.MODES if sc.mag is not None else compare.MODES[1:]
            items.append(Item(SEED, name, peers.Data.from_scenario(sc, n), modes))
    return items


# ---------------------------------------------------------------------------------------------
# running and scoring

def score_run(method, d, mode, q_ref=None, tail=None):
    """Run ``method`` over ``d`` in ``mode`` and score it with benchmarks.compare.score_mode:
    ``(RMSE dict, heading offset removed in deg or None)``. ``tail``: score only the last
    ``tail`` samples (the ideal check, after convergence). ValueError on non-finite output
    (which RMSE over the finite rows would hide)."""
    q = method.run_enu(d, mode == "9-axis")
    if not np.isfinite(q).all():
        raise ValueError(f"non-finite output from sample {int(np.argmin(np.isfinite(q).all(axis=1)))}")
    q_ref = d.q_true if q_ref is None else q_ref
    if tail is not None:
        q, q_ref = q[-tail:], q_ref[-tail:]
    sc, _, offset, _ = compare.score_mode(q, q_ref, mode)
    return sc, offset


def ideal_check(methods, duration, log):
    """Every method on the ideal ``slow`` scenario, both modes. Returns (rows, failed) with
    ``failed[name] = reason``."""
    sc = scenarios.make_scenario(IDEAL["name"], fs=FS, duration=duration, seed=IDEAL["seed"], ideal=True)
    d = peers.Data.from_scenario(sc)
    rows, failed = [], {}
    for m in methods:
        for mode in compare.MODES:
            try:
                s, _ = score_run(m, d, mode, tail=d.n // 2)
            except Exception as e:                                     # noqa: BLE001
                s, why = {k: float("nan") for k in ERRORS}, f"{mode}: {type(e).__name__}: {e}"
            else:
                bad = [f"{k} {s[k]:.3g} deg > {lim:g}" for k, lim in IDEAL_MAX.items()
                       if (k != "heading" or mode == "9-axis") and not s[k] <= lim]
                why = f"{mode}: " + ", ".join(bad) if bad else ""
            if why:
                failed[m.name] = (failed[m.name] + "; " if m.name in failed else "") + why
            rows.append(dict(method=m.name, group=m.group, mode=mode, **s, ok=not why))
    return rows, failed


def run_all(jobs, progress=True):
    """Score every (item, mode, method) job: per-item rows and (what, reason) skips."""
    rows, skipped = [], []
    bar, log = None, print
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=len(jobs), desc="accuracy", unit="run")
        log = bar.write
    for item, mode, m in jobs:
        try:
            s, offset = score_run(m, item.data, mode)
        except Exception as e:                                         # noqa: BLE001
            skipped.append((f"{item.set}/{item.name} {mode} {m.name}", f"{type(e).__name__}: {e}"))
            log(f"skip {item.set}/{item.name} {mode} {m.name}: {type(e).__name__}: {e}")
        else:
            rows.append(dict(set=item.set, item=item.name, mode=mode, method=m.name, group=m.group,
                             n=item.data.n, **compare.inclination_only(item.set, mode, s),
                             heading_offset=float("nan") if offset is None else offset))
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    return rows, skipped


# ---------------------------------------------------------------------------------------------
# tables

def add_ratio(rows, by):
    """Each row's error (compare.ranked_by) over the best (lowest) peer's of its group (``by`` keys,
    which hold set and mode), in the column "÷ best peer", and over VQF's in "÷ VQF"; returns
    ``{group: (best ours row, best peer row)}``."""
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in by), []).append(r)
    best = {}
    for key, rs in groups.items():
        k = compare.ranked_by(rs[0]["set"], rs[0]["mode"])
        ours = [r for r in rs if r["group"] == "ours"]
        prs = [r for r in rs if r["group"] == "peer"]
        bo = min(ours, key=lambda r: r[k]) if ours else None
        bp = min(prs, key=lambda r: r[k]) if prs else None
        vqf = [r for r in rs if r["method"] == VQF]
        for r in rs:
            r["÷ best peer"] = r[k] / bp[k] if bp else float("nan")
            r["÷ VQF"] = r[k] / vqf[0][k] if vqf else float("nan")
        best[key] = (bo, bp)
    return best


def overall_rows(best):
    out = []
    for key, (bo, bp) in best.items():
        row = dict(zip(("set", "mode"), key), n=(bo or bp)["n_trials"],
                   best_ours=bo["method"] if bo else "")
        row.update({f"ours_{k}": bo[k] if bo else float("nan") for k in ERRORS})
        row["best_peer"] = bp["method"] if bp else ""
        row.update({f"peer_{k}": bp[k] if bp else float("nan") for k in ERRORS})
        row["ours / best peer"] = bo["÷ best peer"] if bo and bp else float("nan")
        out.append(row)
    return out


def seed_verdicts(rows, names):
    """Whether each seed estimator beats gyro and mahony (total RMSE) on its scenarios, per
    scenario and mode. "Its" scenarios: the SEED_SCENARIOS entries that name it (a dict spec
    with "estimator"/"estimators") or carry its source document's number; where it has none,
    every synthetic scenario."""
    seed_names = seed_scenario_names()
    spec_of = getattr(scenarios, "SEED_SCENARIOS", {})
    owned = {e: [] for e in SEED_ESTIMATORS}
    for sname in seed_names:
        spec = spec_of.get(sname) if isinstance(spec_of, dict) else None
        said = None
        if isinstance(spec, dict):
            said = spec.get("estimators", spec.get("estimator"))
        said = [said] if isinstance(said, str) else list(said or [])
        for e in SEED_ESTIMATORS:
            if e in said or (not said and SEED_DOC[e] in sname):
                owned[e].append(sname)
    by = {(r["set"], r["item"], r["mode"], r["method"]): r["total"] for r in rows
          if r["set"] in (SYNTHETIC, SEED)}
    items = sorted({(r["set"], r["item"]) for r in rows if r["set"] in (SYNTHETIC, SEED)},
                   key=lambda k: (k[0] != SYNTHETIC, k[1]))
    out = []
    for e in SEED_ESTIMATORS:
        if e not in names:
            continue
        mine = [(SEED, s) for s in owned[e] if (SEED, s) in items]
        scope = "its seed scenarios" if mine else "all synthetic scenarios (none of its own)"
        for set_, item in (mine or items):
            for mode in compare.MODES:
                v = by.get((set_, item, mode, f"fusion.{e}"))
                base = {b: by.get((set_, item, mode, f"fusion.{b}")) for b in BASELINES}
                if v is None or None in base.values():
                    continue
                out.append(dict(estimator=e, scope=scope, scenario=item, mode=mode, total=v,
                                **{f"{b}_total": base[b] for b in BASELINES},
                                beats_both="yes" if all(v < x for x in base.values()) else "no"))
    return out


# ---------------------------------------------------------------------------------------------
# figure

def bar_chart(agg, path, title):
    """One panel per (set, mode): mean RMSE of the cell's error (compare.ranked_by) of
    every method, ours and peers in two colours, log axis (the gyro-only rows are orders of
    magnitude above the rest)."""
    groups = {}
    for r in agg:
        groups.setdefault((r["set"], r["mode"]), []).append(r)
    ncol = 2
    nrow = math.ceil(len(groups) / ncol)
    height = max(len(rs) for rs in groups.values()) * 0.32 + 1.2
    fig = compare.new_figure(figsize=(15, height * nrow))
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for ax, ((set_, mode), rs) in zip(axes.flat, groups.items()):
        k = compare.ranked_by(rs[0]["set"], rs[0]["mode"])
        rs = sorted(rs, key=lambda r: r[k])
        y = np.arange(len(rs))
        vals = np.array([r[k] for r in rs])
        colours = ["tab:blue" if r["group"] == "ours" else "tab:orange" for r in rs]
        ax.barh(y, vals, color=colours)
        ax.set_yticks(y, [r["method"] for r in rs], fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.set_xlim(min(vals.min() * 0.5, 0.1), vals.max() * 3)
        for yi, v in zip(y, vals):
            ax.text(v * 1.08, yi, f"{v:.2f}", va="center", fontsize=7)
        ax.set_title(f"{set_}, {mode} (n={rs[0]['n_trials']})", fontsize=10)
        ax.set_xlabel(f"mean {k} RMSE (deg, log)", fontsize=8)
        ax.grid(True, axis="x", which="both", alpha=0.3)
    for ax in list(axes.flat)[len(groups):]:
        ax.set_visible(False)
    from matplotlib.patches import Patch
    fig.legend(handles=[Patch(color="tab:blue", label="ours (fusion.*)"),
                        Patch(color="tab:orange", label="peers")], loc="upper right")
    fig.suptitle(title)
    return compare.save_figure(fig, path, dpi=100, rect=(0, 0, 0.93, 0.97))


def ratio_chart(rows, path):
    """Every method scored on every recorded cell against VQF (loso.ratio_figure): one marker
    per cell (its ranked error, compare.ranked_by) with its 95 % paired-bootstrap interval
    over the cell's trials, the bar their mean over the cells. VQF itself and the rows not
    scored in every cell (ese650's second VQF feeding) are not drawn."""
    cells, order = {}, {}
    for r in rows:
        if r["set"] not in (SYNTHETIC, SEED):
            cells.setdefault((r["set"], r["mode"]), {}).setdefault(r["method"], {})[r["item"]] = r
            order.setdefault(r["method"], len(order))
    per_cell, ratios = [], {}
    for (set_, mode), by in sorted(cells.items()):
        if VQF not in by:
            continue
        k = compare.ranked_by(set_, mode)
        items = sorted(by[VQF])
        v = [by[VQF][i][k] for i in items]
        xs = {m: [by[m][i][k] for i in items] for m in by if m != VQF and set(by[m]) == set(items)}
        per_cell.append((f"{set_} {mode} ({k})", xs, v))
        for m, x in xs.items():
            ratios.setdefault(m, []).append(np.mean(x) / np.mean(v))
    bars = {m: float(np.mean(ratios[m])) for m in sorted(ratios, key=order.get)
            if len(ratios[m]) == len(per_cell)}
    if not bars:
        return None
    per_cell = [(label, {m: x for m, x in xs.items() if m in bars}, v) for label, xs, v in per_cell]
    return loso.ratio_figure(per_cell, bars, path, f"mean over the {len(per_cell)} recorded cells",
                             "Every method on every recorded set and mode: mean RMSE over VQF's on the same "
                             "trials (left of the dashed line: better than VQF)")


# ---------------------------------------------------------------------------------------------

def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="2 'ok' trials per set, 20 s scenarios (under about a minute)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"),
                    help="output folder (default: %(default)s)")
    ap.add_argument("--data", default=None,
                    help=f"recorded-data folder (default: {datasets.DATA_LOCATION})")
    ap.add_argument("--max-trials", type=arg_type(integer, low=1), default=None,
                    help="at most this many 'ok' trials per set (>= 1)")
    ap.add_argument("--trial-seconds", type=arg_type(number, low=0.0, open_low=True), default=None,
                    help="score only the first S seconds of each trial and seed scenario (> 0)")
    ap.add_argument("--scenarios", nargs="+", default=None, metavar="NAME",
                    help="only these synthetic / seed scenarios")
    ap.add_argument("--duration", type=arg_type(number, low=0.0, high=1e4, open_low=True), default=None,
                    help="synthetic scenario length in s (default 60, quick 20)")
    ap.add_argument("--seed", type=arg_type(integer, low=0), default=0, help="scenario seed (default: %(default)s)")
    ap.add_argument("--no-progress", action="store_true", help="no tqdm bar")
    args = ap.parse_args(argv)
    known = list(scenarios.SCENARIOS) + list(seed_scenario_names())
    unknown = sorted(set(args.scenarios or ()) - set(known))
    if unknown:
        ap.error(f"--scenarios: unknown {unknown}; accepted: {', '.join(known)}")
    if args.data is not None and not Path(args.data).is_dir():
        ap.error(f"--data {args.data!r} is not a folder (leave it out for {datasets.DATA_LOCATION})")
    return args


def fmt_target(label, row):
    return (f"{label:<28s} total {row['total']:6.2f}  heading {row['heading']:6.2f}  "
            f"inclination {row['inclination']:6.2f}")


def _ideal_phase(methods, quick):
    """The noise-free check of every method's feeding (printed): (rows, failed, the methods to
    score, the peers refused)."""
    by_name = {m.name: m for m in methods}
    ideal_dur = 30.0 if quick else 60.0
    print(f"\nideal check: noise-free, bias-free '{IDEAL['name']}' scenario ({ideal_dur:g} s, "
          f"{FS:g} Hz), RMSE over the second half (deg); a peer passes with inclination <= "
          f"{IDEAL_MAX['inclination']:g} (both modes) and 9-axis heading <= {IDEAL_MAX['heading']:g}:")
    ideal_rows, failed = ideal_check(methods, ideal_dur, print)
    for m in methods:
        cells = [r for r in ideal_rows if r["method"] == m.name]
        line = " | ".join(f"{r['mode']} total {r['total']:.3f} heading {r['heading']:.3f} "
                          f"incl {r['inclination']:.3f}" for r in cells)
        verdict = "ok" if m.name not in failed else \
            ("FAILED: not scored: " if m.group == "peer" else "FAILED (ours: scored anyway): ") + failed[m.name]
        print(f"  {m.name:<16s} {line}  {verdict}", flush=True)
    scored = [m for m in methods if m.group == "ours" or m.name not in failed]
    refused = {n: why for n, why in failed.items() if by_name[n].group == "peer"}
    return ideal_rows, failed, scored, refused


def _items(args, quick, duration, max_trials, trial_seconds):
    """What to score (printed): (recorded + synthetic items, the trials not scored)."""
    root = Path(args.data) if args.data else datasets.default_data_dir()
    items, skipped = [], []
    if root is None or not Path(root).is_dir():
        print(f"\nrecorded data: folder not found ({args.data or datasets.DATA_LOCATION}); "
              "scoring the synthetic scenarios only")
    else:
        items, skipped = recorded_items(root, quick, max_trials, trial_seconds, print)
        print(f"\nrecorded data: {len(items)} 'ok' trials from {root}"
              + (f" (first {max_trials} per set)" if max_trials is not None else "")
              + (f", first {trial_seconds:g} s of each" if trial_seconds is not None else ""))
        if skipped:
            print("  not scored: " + ", ".join(f"{k} ({why})" for k, why in skipped))
    only = set(args.scenarios) if args.scenarios else None
    syn = synthetic_items(duration, args.seed, only, trial_seconds)
    n_seed = sum(it.set == SEED for it in syn)
    print(f"synthetic: {sum(it.set == SYNTHETIC for it in syn)} scenarios ({duration:g} s, seed {args.seed}); "
          + (f"{n_seed} seed scenarios" if hasattr(scenarios, "SEED_SCENARIOS")
             else "fusion.scenarios has no SEED_SCENARIOS yet"))
    return items + syn, skipped


def _jobs(items, scored):
    """Every (item, mode, method) run, with the README's VQF feeding (nominal 1/fs) added where
    the nominal rate is off the stamps' mean by > 0.1 %: (jobs, that VQF method or None)."""
    vqf_nominal = peers.vqf_method("VQF", nominal=True) if VQF in {m.name for m in scored} else None
    jobs = []
    for it in items:
        for mode in it.modes:
            jobs += [(it, mode, m) for m in scored]
            if vqf_nominal is not None and abs(it.data.ts * it.data.fs - 1.0) > 1e-3:
                jobs.append((it, mode, vqf_nominal))
    return jobs, vqf_nominal


def _category_rows(rows):
    """Per motion category, where a recorded set's trial names carry one (benchmarks/loso.py)."""
    cat_rows = []
    for set_ in sorted({r["set"] for r in rows} - {SYNTHETIC, SEED}):
        trial_names = sorted({r["item"] for r in rows if r["set"] == set_})
        cat = dict(zip(trial_names, loso.categories(trial_names)))
        if len(set(cat.values())) < len(trial_names):
            sub = [dict(r, category=cat[r["item"]]) for r in rows if r["set"] == set_]
            cat_rows += compare.aggregate(sub, by=("set", "category", "mode", "method", "group"))
    add_ratio(cat_rows, ("set", "category", "mode"))
    return cat_rows


def _write_tables(out, rows, agg, best, cat_rows, per_item, overall, ideal_rows, verdicts):
    """The CSV + Markdown tables and the bar chart; returns the files written."""
    written = []
    for (set_, mode) in best:
        sub = [r for r in agg if (r["set"], r["mode"]) == (set_, mode)]
        stem = out / f"accuracy_{set_.replace(' ', '_')}_{mode}"
        kind = 'trials' if set_ not in (SYNTHETIC, SEED) else 'scenarios'
        only = ("; its reference heading is not north: inclination only, the ratios are of inclination"
                if compare.ranked_by(sub[0]["set"], sub[0]["mode"]) == "inclination" else "")
        written += compare.write_table(sub, stem, SET_COLS, title=f"{set_}, {mode}: mean RMSE (deg) over "
                                       f"{sub[0]['n_trials']} {kind}{only}")
    if cat_rows:
        written += compare.write_table(cat_rows, out / "accuracy_categories",
                                       ["set", "category", "mode", "method", "group", "n_trials"] + list(ERRORS)
                                       + ["÷ best peer", "÷ VQF"],
                                       title="Recorded sets per motion category: mean RMSE (deg)")
    if per_item:
        written += compare.write_table(per_item, out / "accuracy_scenarios",
                                       ["set", "item", "mode", "method", "group", "n"] + list(ERRORS) + ["÷ best peer"],
                                       title="Synthetic scenarios: RMSE (deg) per scenario")
    ocols = list(overall[0].keys()) if overall else ["set"]
    written += compare.write_table(overall, out / "accuracy_overall", ocols,
                                   title="Overall: best of ours vs best peer (mean RMSE, deg)")
    written += compare.write_table(rows, out / "accuracy_runs",
                                   ["set", "item", "mode", "method", "group", "n"] + list(ERRORS) + ["heading_offset"],
                                   title="Every run: RMSE (deg); 6-axis: heading offset removed (deg)")
    written += compare.write_table(ideal_rows, out / "accuracy_ideal_check",
                                   ["method", "group", "mode"] + list(ERRORS) + ["ok"], digits=4,
                                   title=f"Ideal check: noise-free '{IDEAL['name']}' scenario, "
                                         "RMSE over the second half (deg)")
    if verdicts:
        written += compare.write_table(verdicts, out / "accuracy_seed_verdicts", list(verdicts[0].keys()),
                                       title="Seed estimators vs gyro and mahony (total RMSE, deg)")
    png = bar_chart(agg, out / "accuracy.png", "Mean total RMSE per set and mode (6-axis: one heading "
                    f"offset per run removed; {compare.INCLINATION_ONLY_NAMES}: inclination)") if agg else None
    ratio_png = ratio_chart(rows, out / "accuracy_ratio.png")
    return written + [p for p in (png, ratio_png) if p]


def _target_text(best, agg, vqf_nominal):
    """Best of ours against VQF (both feedings) and the data README's VQF figures, per target."""
    ref = {(r["set"], r["mode"]): r for r in compare.REFERENCE_VQF}
    lines = []
    for set_, mode in TARGETS:
        if (set_, mode) not in best:
            lines.append(f"{set_} {mode}: not measured (no data)")
            continue
        bo, _ = best[(set_, mode)]
        sub = {r["method"]: r for r in agg if (r["set"], r["mode"]) == (set_, mode)}
        lines.append(f"{set_} {mode} ({bo['n_trials']} trials, mean RMSE in deg):")
        lines.append("  " + fmt_target(f"best of ours: {bo['method']}", bo))
        for name in (VQF, vqf_nominal.name if vqf_nominal else None):
            if name in sub:
                v = sub[name]
                lines.append("  " + fmt_target(name, v) + f"   ours / this = {bo['total'] / v['total']:.2f} "
                             f"({'ours better' if bo['total'] < v['total'] else 'VQF better'})")
        if (set_, mode) in ref:
            lines.append("  " + fmt_target("VQF, data README", ref[(set_, mode)]))
    return "\n".join(lines)


def _verdict_text(verdicts):
    """Per seed estimator: on how many scenarios it beats gyro and mahony, and where not."""
    lines = []
    for e in SEED_ESTIMATORS:
        vs = [v for v in verdicts if v["estimator"] == e]
        if not vs:
            continue
        wins = [v for v in vs if v["beats_both"] == "yes"]
        losses = ", ".join(f"{v['scenario']} {v['mode']} ({v['total']:.2f} vs gyro {v['gyro_total']:.2f}, "
                           f"mahony {v['mahony_total']:.2f})" for v in vs if v["beats_both"] == "no")
        lines.append(f"  {e:<8s} beats gyro and mahony on {len(wins)}/{len(vs)} ({vs[0]['scope']})"
                     + (f"; not on: {losses}" if losses else ""))
    return "\n".join(lines) or "  (no synthetic rows)"


def _report(out, settings, overall_md, target_txt, verdict_txt, feeding, ideal_rows, refused, agg, best, skipped,
            written):
    """accuracy.md; returns its path."""
    report = ["# Estimator accuracy: ours and peers, same run\n",
              f"Settings: {settings}; errors in degrees; 6-axis: one constant heading offset per run removed. "
              "Mean RMSE over the trials / scenarios of each set. 'ours / best peer' = best of ours / best peer "
              f"(total; inclination in {compare.INCLINATION_ONLY_NAMES}, whose reference heading is not "
              "north: its total and heading are not scored).\n",
              "## Overall\n", overall_md,
              "## Targets\n", "```\n" + target_txt + "\n```\n",
              "## Seed estimators vs gyro and mahony (total RMSE)\n", "```\n" + verdict_txt + "\n```\n",
              "## Feeding\n", "\n".join(f"- {m.name}: {m.feeding}" for m in feeding) + "\n",
              "## Ideal check\n", compare.markdown_table(ideal_rows, ["method", "mode"] + list(ERRORS) + ["ok"], 4)]
    if refused:
        report += ["Not scored (failed the ideal check):\n",
                   "\n".join(f"- {n}: {why}" for n, why in refused.items()) + "\n"]
    for (set_, mode) in best:
        sub = [r for r in agg if (r["set"], r["mode"]) == (set_, mode)]
        report += [f"## {set_}, {mode}\n", compare.markdown_table(sub, SET_COLS, 3)]
    return compare.write_report(out / "accuracy.md", report, skipped, written)


def main(argv=None):
    args = parse_args(argv)
    t_start = time.perf_counter()
    quick = args.quick
    duration = args.duration if args.duration is not None else (20.0 if quick else 60.0)
    max_trials = args.max_trials if args.max_trials is not None else (2 if quick else None)
    trial_seconds = args.trial_seconds if args.trial_seconds is not None else (20.0 if quick else None)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    print("# Estimator accuracy: ours and peers, same run\n")
    methods = peers.all_methods(print)
    print("feeding:")
    for m in methods:
        if m.group == "peer":
            print(f"  {m.name:<16s} {m.feeding}")
    print(f"  {'fusion.*':<16s} {methods[0].feeding}")
    ideal_rows, failed, scored, refused = _ideal_phase(methods, quick)
    items, skipped = _items(args, quick, duration, max_trials, trial_seconds)
    jobs, vqf_nominal = _jobs(items, scored)
    print(f"{len(jobs)} runs\n", flush=True)
    rows, run_skips = run_all(jobs, progress=not args.no_progress)
    skipped += run_skips

    order = {m.name: i for i, m in enumerate(scored + ([vqf_nominal] if vqf_nominal else []))}
    agg = compare.aggregate(rows, by=("set", "mode", "method", "group"))
    agg.sort(key=lambda r: (r["set"] in (SYNTHETIC, SEED), r["set"], compare.MODES.index(r["mode"]),
                            order[r["method"]]))
    best = add_ratio(agg, ("set", "mode"))
    per_item = [dict(r) for r in rows if r["set"] in (SYNTHETIC, SEED)]
    cat_rows = _category_rows(rows)
    add_ratio(per_item, ("set", "item", "mode"))
    overall = overall_rows(best)
    verdicts = seed_verdicts(rows, fusion.available())
    written = _write_tables(out, rows, agg, best, cat_rows, per_item, overall, ideal_rows, verdicts)

    target_txt, verdict_txt = _target_text(best, agg, vqf_nominal), _verdict_text(verdicts)
    overall_md = compare.markdown_table(overall, OVERALL_COLS, 2)
    settings = f"{'quick' if quick else 'full'}; synthetic {duration:g} s at {FS:g} Hz, seed {args.seed}"
    written.append(_report(out, settings, overall_md, target_txt, verdict_txt,
                           methods + ([vqf_nominal] if vqf_nominal else []), ideal_rows, refused, agg, best, skipped,
                           written))

    print("\nOverall (mean RMSE, deg):\n" + overall_md)
    print("TARGET COMPARISONS (VQF measured in this run):\n" + target_txt + "\n")
    print("SEED ESTIMATORS vs gyro and mahony (total RMSE, per scenario and mode):\n" + verdict_txt + "\n")
    if refused:
        print("NOT SCORED (failed the ideal check): " + "; ".join(f"{n}: {w}" for n, w in refused.items()))
    print(f"wrote {len(written)} files to {out.resolve()}/ (accuracy.md, accuracy.png, ...)")
    print(f"total {time.perf_counter() - t_start:.0f} s")
    return dict(rows=rows, agg=agg, overall=overall, ideal=ideal_rows, failed=failed,
                verdicts=verdicts, skipped=skipped, written=written)

if __name__ == "__main__":
    main()
