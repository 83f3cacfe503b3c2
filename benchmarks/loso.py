#!/usr/bin/env python
"""Leave-one-set-out choice of estimator parameters on every recorded set, VQF in the same run.

Cells: every (set, mode) of the recorded data (``fusion.datasets``; 9-axis where the set has a magnetometer, 6-axis
on every set). A candidate's score in a cell is its mean total RMSE over the cell's 'ok'
trials divided by VQF's (online, defaults, the same feeding as benchmarks/accuracy.py), so
that sets of different difficulty weigh alike. For each held-out set, the grid point with the
lowest mean ratio over the OTHER sets' cells is chosen and scored on the held-out set: one
line per fold. A default is only as good as its worst fold.

    .venv/bin/python benchmarks/loso.py ekf                              # defaults vs VQF
    .venv/bin/python benchmarks/loso.py ekf --grid acc_lowpass=0,1,3 mag_update=heading,vector
    .venv/bin/python benchmarks/loso.py ekf --quick ...                  # every other trial

Values in --grid are parsed as Python literals where they are one (numbers, None, True),
strings otherwise. Nothing here looks at which set is running: the estimator gets the same
parameters on every trial.
"""
import argparse
import ast
import itertools
import time
from pathlib import Path

import numpy as np

import fusion
from fusion import datasets, metrics
from fusion.checks import arg_type, number
from benchmarks import compare, peers
from controllers.evaluation import MIN_BOOT, bootstrap_ci


ERRORS = ("total", "heading", "inclination")


class Cell:
    """One (set, mode) with its trials as peers.Data and VQF's scores on them."""

    def __init__(self, set_, mode, names, data):
        self.set, self.mode, self.names, self.data = set_, mode, names, data
        self.categories = categories(names)
        self.vqf = None

    @property
    def key(self):
        return f"{self.set} {self.mode}"


def categories(names):
    """A motion category per trial from its name: the first '_'-separated token that not every
    trial of the set shares (TStick_Test02_Trial1 -> Test02, exp02_motion03_seg1_rigid ->
    motion03, circle-100_carpus -> circle-100)."""
    toks = [n.split("_") for n in names]
    common = set.intersection(*(set(t) for t in toks)) if toks else set()
    out = []
    for n, t in zip(names, toks):
        rest = [x for x in t if x not in common]
        out.append(rest[0] if rest else n)
    return out


def load_cells(root=None, quick=False, seconds=None):
    root = Path(root) if root else datasets.default_data_dir()
    if root is None or not Path(root).is_dir():
        raise SystemExit(f"recorded data not found ({datasets.DATA_LOCATION})")
    by = {}
    for tr in datasets.load_folder(root, only_ok=True):
        if not metrics.reference_rows(tr.quat[:None if seconds is None else int(seconds * tr.fs)]).any():
            continue            # (nothing to score in the part scored)
        by.setdefault(tr.set, []).append(tr)
    cells = []
    for set_, trs in sorted(by.items()):
        if quick:
            trs = trs[::2]
        n = None if seconds is None else int(seconds * trs[0].fs)
        data = [peers.Data.from_trial(tr, n) for tr in trs]
        names = [tr.name for tr in trs]
        modes = compare.MODES if all(tr.has_mag for tr in trs) else compare.MODES[1:]
        cells += [Cell(set_, mode, names, data) for mode in modes]
    return cells


def score(run, d, mode):
    q = run(d, mode == "9-axis")
    if not np.isfinite(q).all():
        return {k: float("inf") for k in ERRORS}
    s, _, _, _ = compare.score_mode(q, d.q_true, mode)
    return s


def ours_runner(name, params):
    def run(d, nine):
        est = fusion.make(name, d.fs, **params)
        return est.run(d.gyr, d.acc, d.mag if nine else None, dt=d.dt)
    return run


def vqf_runner():
    m = peers.vqf_method("VQF")
    return lambda d, nine: m.run_enu(d, nine)


def score_cell(run, cell):
    """Per-trial score dicts of ``run`` on the cell's trials."""
    return [score(run, d, cell.mode) for d in cell.data]


def mean(rows, k="total"):
    return float(np.mean([r[k] for r in rows]))


def evaluate(name, params, cells):
    """{cell key: per-trial rows} for one candidate."""
    run = ours_runner(name, params)
    return {c.key: score_cell(run, c) for c in cells}


def ratio(rows, cell, k="total"):
    return mean(rows, k) / mean(cell.vqf, k)


def ratio_ci(rows, cell, k="total"):
    """95 % interval of ratio(rows, cell, k) (paired_ratio_ci)."""
    return paired_ratio_ci([r[k] for r in rows], [r[k] for r in cell.vqf])


def paired_ratio_ci(x, y):
    """95 % interval of mean(x) / mean(y) by a paired bootstrap of the trials: each resample
    draws the same trials for x and y (ours and VQF), so the interval is of the ratio alone,
    not of how hard the trials drawn were. Whether a cell is above VQF beyond the trials' spread."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)

    def stat(idx, axis):
        idx = idx.astype(int)
        return x[idx].mean(axis=axis) / y[idx].mean(axis=axis)
    return bootstrap_ci(np.arange(len(x)), stat)


def fmt_ratio(rows, cell, k="total"):
    lo, hi = ratio_ci(rows, cell, k)
    return f"{ratio(rows, cell, k):.3f} [{lo:.3f}, {hi:.3f}]"


def parse_grid(items):
    grid = {}
    for it in items or ():
        if "=" not in it:
            raise SystemExit(f"--grid entries are name=v1,v2,...; got {it!r}")
        k, vs = it.split("=", 1)
        vals = []
        for v in vs.split(","):
            try:
                vals.append(ast.literal_eval(v))
            except (ValueError, SyntaxError):
                vals.append(v)
        grid[k] = vals
    return grid


def fmt_params(p):
    return ", ".join(f"{k}={v!r}" for k, v in p.items()) or "(defaults)"


def table(name, results, cells, with_cat=False):
    """Per cell: ours total/heading/inclination, VQF's, ratios with their 95 % intervals (ratio_ci)."""
    lines = [f"| cell | n | {name} total / heading / incl | VQF total / heading / incl | total ratio [95 % CI] "
             f"| incl ratio [95 % CI] |",
             "|---|---|---|---|---|---|"]
    for c in cells:
        rs = results[c.key]
        lines.append(f"| {c.key} | {len(rs)} | " + " / ".join(f"{mean(rs, k):.2f}" for k in ERRORS)
                     + " | " + " / ".join(f"{mean(c.vqf, k):.2f}" for k in ERRORS)
                     + f" | {fmt_ratio(rs, c)} | {fmt_ratio(rs, c, 'inclination')} |")
        if with_cat:
            cats = sorted(set(c.categories))
            if len(cats) < len(c.categories):
                for cat in cats:
                    idx = [i for i, x in enumerate(c.categories) if x == cat]
                    o = [rs[i] for i in idx]
                    v = [c.vqf[i] for i in idx]
                    lines.append(f"|   {cat} | {len(idx)} | " + " / ".join(f"{mean(o, k):.2f}" for k in ERRORS)
                                 + " | " + " / ".join(f"{mean(v, k):.2f}" for k in ERRORS)
                                 + f" | {mean(o) / mean(v):.2f}"
                                 + f" | {mean(o, 'inclination') / mean(v, 'inclination'):.2f} |")
    return "\n".join(lines)


def objective(results, cells):
    """Mean over the cells of ours / VQF (total) plus the same for inclination, halved
    (inclination alone in compare.INCLINATION_ONLY cells): the figure a candidate is chosen by."""
    def one(c):
        inc = ratio(results[c.key], c, "inclination")
        return inc if compare.ranked_by(c.set, c.mode) == "inclination" else 0.5 * (ratio(results[c.key], c) + inc)
    return float(np.mean([one(c) for c in cells]))


def loso(name, grid, cells, base=None, log=print):
    """Every grid point on every cell, then one fold per set. Returns (points, folds)."""
    base = dict(base or {})
    keys = list(grid)
    points = []
    for vals in itertools.product(*(grid[k] for k in keys)):
        p = dict(base, **dict(zip(keys, vals)))
        t0 = time.perf_counter()
        res = evaluate(name, p, cells)
        points.append((p, res))
        log(f"  {fmt_params(p)}: " + "  ".join(f"{c.key} {ratio(res[c.key], c):.2f}" for c in cells)
            + f"  | all {objective(res, cells):.3f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    sets = sorted({c.set for c in cells})
    folds = []
    for held in sets:
        train = [c for c in cells if c.set != held]
        test = [c for c in cells if c.set == held]
        p, res = min(points, key=lambda pr: objective(pr[1], train))
        folds.append(dict(held_out=held, chosen=fmt_params({k: p[k] for k in keys}),
                          train=objective(res, train),
                          **{f"{c.mode} total (ratio)": f"{mean(res[c.key]):.2f} ({ratio(res[c.key], c):.2f})"
                             for c in test}))
    return points, folds


def ratio_chart(results, cells, path):
    """The defaults' chart (ratio_figure): bar = the figure a candidate is chosen by (objective)."""
    per_cell = []
    for c in cells:
        k = compare.ranked_by(c.set, c.mode)
        per_cell.append((f"{c.key} ({k})", {n: [r[k] for r in results[n][c.key]] for n in results},
                         [r[k] for r in c.vqf]))
    return ratio_figure(per_cell, {n: objective(results[n], cells) for n in results}, path,
                        "mean figure (total + inclination ratio) / 2",
                        "Defaults on every recorded set: ratio to VQF (left of the dashed line: better than VQF)")


def ratio_figure(per_cell, bars, path, bar_label, title):
    """One row per method: a bar (``bars``: method -> value) and one marker per cell with its
    95 % paired-bootstrap interval (paired_ratio_ci). ``per_cell``: [(label, {method: per-trial
    errors}, VQF's per-trial errors on the same trials)]; a method a cell lacks has no marker
    there. Log axis, 1 = VQF."""
    names = list(bars)
    fig = compare.new_figure(figsize=(11, 0.42 * len(names) + 1.8))
    ax = fig.subplots()
    y = np.arange(len(names))
    ax.barh(y, [bars[n] for n in names], color="lightsteelblue", label=bar_label)
    markers = "osD^vP*X"
    step = 0.7 / max(1, len(per_cell))
    for j, (label, xs, v) in enumerate(per_cell):
        have = [i for i, n in enumerate(names) if n in xs]
        r = np.array([np.mean(xs[names[i]]) / np.mean(v) for i in have])
        ci = np.array([paired_ratio_ci(xs[names[i]], v) for i in have])
        off = y[have] + (j - (len(per_cell) - 1) / 2) * step
        ax.errorbar(r, off, xerr=np.abs(ci.T - r), fmt=markers[j % len(markers)], ms=4, elinewidth=0.8,
                    capsize=1.5, zorder=3, label=label)
    ax.axvline(1.0, color="k", lw=1, ls="--")
    ax.set_yticks(y, names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("mean RMSE ÷ VQF's on the same trials (markers: each cell's ratio with its 95 % "
                  f"paired-bootstrap interval, none under {MIN_BOOT} trials)")
    ax.set_xscale("log")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.grid(True, axis="x", which="both", alpha=0.3)
    return compare.save_figure(fig, path, dpi=100)


def worst_trials(results, cells):
    """The trial with the largest ratio to VQF, per error: total where the cell is judged by
    it (not compare.INCLINATION_ONLY), inclination in every cell. {error: (ratio, cell key, trial)}."""
    worst = {}
    for c in cells:
        for n, o, v in zip(c.names, results[c.key], c.vqf):
            for k in ("inclination",) if (c.set, c.mode) in compare.INCLINATION_ONLY else ("total", "inclination"):
                r = o[k] / v[k]
                if r > worst.get(k, (-1.0,))[0]:
                    worst[k] = (r, c.key, n)
    return worst


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("estimator", nargs="+", help="fusion.available() names")
    ap.add_argument("--grid", nargs="*", default=None, metavar="NAME=V1,V2")
    ap.add_argument("--set", nargs="*", default=None, metavar="NAME=V",
                    help="fixed parameters besides the grid")
    ap.add_argument("--quick", action="store_true", help="every other trial of each set")
    ap.add_argument("--seconds", type=arg_type(number, low=0.0, open_low=True), default=None,
                    help="first S s of each trial (> 0)")
    ap.add_argument("--categories", action="store_true", help="per motion category rows")
    ap.add_argument("--data", default=None)
    ap.add_argument("--png", default=None, metavar="PATH",
                    help="bar chart of the defaults' ratios to VQF, one marker per cell (no --grid)")
    args = ap.parse_args(argv)
    if args.png and args.grid:
        ap.error("--png draws the defaults' ratios: give it without --grid")
    unknown = [n for n in args.estimator if n not in fusion.available()]
    if unknown:
        ap.error(f"unknown estimator(s) {unknown}; accepted: {', '.join(fusion.available())}")
    t0 = time.perf_counter()
    cells = load_cells(args.data, args.quick, args.seconds)
    vqf = vqf_runner()
    for c in cells:
        c.vqf = score_cell(vqf, c)
    print(f"{len(cells)} cells: " + ", ".join(f"{c.key} ({len(c.data)})" for c in cells)
          + f"; VQF scored in {time.perf_counter() - t0:.0f} s", flush=True)
    base = {k: v[0] for k, v in parse_grid(args.set).items()}
    results = {}
    for name in args.estimator:
        if args.grid:
            grid = parse_grid(args.grid)
            print(f"\n## {name}: grid {grid}, fixed {fmt_params(base)}")
            points, folds = loso(name, grid, cells, base)
            print("\nleave-one-set-out (chosen on the other sets by mean ours/VQF ratio of total and inclination):")
            print(compare.markdown_table(folds, None, 3))
        else:
            res = results[name] = evaluate(name, base, cells)
            print(f"\n## {name} ({fmt_params(base)}): all {objective(res, cells):.3f}")
            print(table(name, res, cells, args.categories))
            print("worst single trial against VQF: " + "; ".join(
                f"{k} {r:.2f}x ({key}, {trial})" for k, (r, key, trial) in worst_trials(res, cells).items()))
    if args.png and results:
        print(f"wrote {ratio_chart(results, cells, Path(args.png))}")
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
