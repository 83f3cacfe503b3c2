"""Scoring loops behind scripts/compare_estimators.py: every estimator on synthetic scenarios
and on recorded trials, tables as Markdown and CSV, error-over-time figures.

Numpy only at import; tqdm and matplotlib are imported where they are used.

Modes: ``"9-axis"`` runs with the magnetometer and scores total / heading / inclination
against the reference as it is; ``"6-axis"`` runs without it and scores after removing one
constant heading offset per run (``metrics.remove_heading_offset``), as the data folder's
README ("Recorded IMU data with a reference orientation") asks. Estimators start as users run
them: from the first sample (accelerometer, plus magnetometer in 9-axis mode), default
parameters unless given.
"""
import math
from pathlib import Path

import numpy as np

import fusion
from fusion import metrics
from controllers.plots import new_figure   # the one figure helper, re-exported here
from controllers.policy_io import csv_text, save_figure as write_figure, write_text

__all__ = ["MODES", "run_estimator", "score_mode", "compare_scenario", "compare_trials", "aggregate",
           "markdown_table", "write_table", "write_report", "print_written", "new_figure", "save_figure", "plot_errors",
           "REFERENCE_VQF"]

MODES = ("9-axis", "6-axis")
ERRORS = ("total", "heading", "inclination")
# (set, mode) cells whose reference heading is not magnetic north (the data folder's README:
# diodem's indoor field is strongly disturbed, its earth frame's y one IMU's mean field): only
# their inclination is scored; their total and heading are NaN (inclination_only)
INCLINATION_ONLY = {("diodem", "9-axis")}
INCLINATION_ONLY_NAMES = ", ".join(f"{s} {m}" for s, m in sorted(INCLINATION_ONLY))     # for reports


def ranked_by(set_, mode):
    """The error a cell is judged and ranked by: total, or inclination in an INCLINATION_ONLY cell."""
    return "inclination" if (set_, mode) in INCLINATION_ONLY else "total"


def inclination_only(set_, mode, scores):
    """``scores`` (RMSE per error) as scored in the cell (set_, mode): total and heading NaN in
    an INCLINATION_ONLY cell, whose heading reference is not north."""
    if (set_, mode) not in INCLINATION_ONLY:
        return scores
    return {k: (v if k == "inclination" else float("nan")) for k, v in scores.items()}

# the data folder's README ("Recorded IMU data with a reference orientation"): VQF (online, default
# parameters) on all 'ok' trials, degrees
REFERENCE_VQF = [
    dict(set="repoimu_tstick", mode="9-axis", total=1.92, heading=1.67, inclination=0.70),
    dict(set="repoimu_tstick", mode="6-axis", total=0.99, heading=0.60, inclination=0.70),
    dict(set="ese650", mode="6-axis", total=5.30, heading=4.10, inclination=2.55),
]


def run_estimator(name, fs, gyr, acc, mag=None, dt=None, q0=None, **params):
    """A fresh ``fusion.make(name, fs, **params)`` run over the arrays; (N, 4) quaternions.
    ``q0`` (optional) is the attitude before the first sample."""
    est = fusion.make(name, fs, **params)
    if q0 is not None:
        est.reset(q0)
    return est.run(gyr, acc, mag, dt=dt)


def score_mode(q_est, q_ref, mode):
    """One run scored in ``mode``: ``(RMSE dict, per-sample errors dict, heading offset removed
    in deg or None, the quaternions scored)``."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    offset = None
    if mode == "6-axis":
        q_est, psi = metrics.remove_heading_offset(q_est, q_ref, return_offset=True)
        offset = math.degrees(psi)
    err = metrics.attitude_errors(q_est, q_ref)
    if not np.isfinite(err["total"]).any():        # (as metrics.score: a mean of NaN would blank the set's)
        raise ValueError("no rows with a reference quaternion (finite, non-zero) to score")
    return {k: metrics.rmse(err[k]) for k in ERRORS}, err, offset, q_est


def compare_scenario(names, scenario, modes=MODES, params=None):
    """Every estimator in ``names`` on one ``fusion.scenarios.Scenario``.

    Returns ``(score_rows, euler_rows, curves)``: RMSE rows (scenario, mode, estimator, total,
    heading, inclination), the seeds' Euler table rows (scenario, mode, estimator, angle, mean,
    std, MAE, RMSE; in 6-axis mode after removing the heading offset) and
    ``curves[mode][estimator] = total error (deg) per sample`` for plots.
    """
    params = params or {}
    score_rows, euler_rows, curves = [], [], {m: {} for m in modes}
    for mode in modes:
        mag = scenario.mag if mode == "9-axis" else None
        for name in names:
            q = run_estimator(name, scenario.fs, scenario.gyr, scenario.acc, mag, dt=scenario.dt,
                              **params.get(name, {}))
            sc, err, offset, q_scored = score_mode(q, scenario.q_true, mode)
            score_rows.append(dict(scenario=scenario.name, mode=mode, estimator=name, **sc))
            for ang, st in metrics.euler_table(q_scored, scenario.q_true).items():
                euler_rows.append(dict(scenario=scenario.name, mode=mode, estimator=name, angle=ang, **st))
            curves[mode][name] = err["total"]
    return score_rows, euler_rows, curves


def compare_trials(names, trials, params=None, log=print, progress=True, keep_curves=()):
    """Every estimator on every scoreable trial (``fusion.datasets.Trial``): 9-axis where the
    trial has a magnetometer, 6-axis always. Trials whose quality is not 'ok' are skipped
    (``log`` says why).

    Returns ``(rows, skipped, curves)``: one row per trial, mode and estimator (set, trial,
    mode, estimator, n, total, heading, inclination, heading_offset; total and heading NaN in
    an INCLINATION_ONLY cell), the skipped ``(trial key, reason)`` pairs, and
    ``curves[trial key][mode][estimator] = (t, total error)`` for the trial keys in
    ``keep_curves`` (not in INCLINATION_ONLY cells).
    """
    params = params or {}
    rows, skipped, curves = [], [], {}
    scoreable = []
    for tr in trials:
        if not tr.ok:
            skipped.append((tr.key, tr.quality))
            log(f"skip {tr.key}: quality {tr.quality!r}")
        elif not metrics.reference_rows(tr.quat).any():
            skipped.append((tr.key, "no reference quaternion (finite, non-zero)"))
            log(f"skip {tr.key}: no reference quaternion (finite, non-zero)")
        else:
            scoreable.append(tr)
    jobs = [(tr, mode, name) for tr in scoreable
            for mode in (MODES if tr.has_mag else MODES[1:]) for name in names]
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=len(jobs), desc="recorded trials", unit="run")
        log = bar.write
    for tr, mode, name in jobs:
        try:
            q = run_estimator(name, tr.fs, tr.gyr, tr.acc, tr.mag if mode == "9-axis" else None,
                              dt=tr.dt, **params.get(name, {}))
            sc, err, offset, _ = score_mode(q, tr.quat, mode)
            sc = inclination_only(tr.set, mode, sc)
        except ValueError as exc:     # bad samples (on_invalid='raise'), non-finite output or nothing to score
            skipped.append((f"{tr.key} {mode} {name}", str(exc)))
            log(f"skip {tr.key} {mode} {name}: {exc}")
        else:
            rows.append(dict(set=tr.set, trial=tr.name, mode=mode, estimator=name,
                             n=int(np.isfinite(err["total"]).sum()), **sc,
                             heading_offset=offset if offset is not None else float("nan")))
            if tr.key in keep_curves and (tr.set, mode) not in INCLINATION_ONLY:
                curves.setdefault(tr.key, {}).setdefault(mode, {})[name] = (tr.t, err["total"])
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    return rows, skipped, curves


def aggregate(rows, by=("set", "mode", "estimator"), values=ERRORS):
    """Mean of each value over the rows of each group (e.g. mean RMSE over trials); groups in
    first-seen order, with ``n_trials`` (the number of rows averaged)."""
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in by), []).append(r)
    out = []
    for key, rs in groups.items():
        row = dict(zip(by, key), n_trials=len(rs))
        for v in values:
            row[v] = float(np.mean([r[v] for r in rs]))
        out.append(row)
    return out


def _fmt(v, digits):
    if isinstance(v, (float, np.floating)):
        return "" if math.isnan(v) else f"{v:.{digits}f}"
    return str(v).replace("|", "\\|")     # a literal | would end the Markdown cell


def markdown_table(rows, columns=None, digits=3):
    """A GitHub Markdown table of ``rows`` (dicts); floats with ``digits`` decimals."""
    if not rows:
        return "(no rows)\n"
    columns = list(columns or rows[0].keys())
    lines = ["| " + " | ".join(columns) + " |",
             "|" + "|".join("---" if isinstance(rows[0].get(c), str) else "---:" for c in columns) + "|"]
    lines += ["| " + " | ".join(_fmt(r.get(c, ""), digits) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_table(rows, stem, columns=None, digits=3, title=None):
    """Write ``<stem>.csv`` (full precision) and ``<stem>.md``; returns both paths."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    columns = list(columns or (rows[0].keys() if rows else []))
    csv_path, md_path = stem.with_suffix(".csv"), stem.with_suffix(".md")
    write_text(csv_path, csv_text([{c: (repr(float(r[c])) if isinstance(r.get(c), (float, np.floating))
                                          else r.get(c, "")) for c in columns} for r in rows], columns))
    write_text(md_path, (f"# {title}\n\n" if title else "") + markdown_table(rows, columns, digits))
    return csv_path, md_path


def write_report(path, parts, skipped, written, skipped_title="Not scored"):
    """A Markdown report: ``parts`` (joined by newlines), then the skipped ``(what, reason)``
    pairs and the list of ``written`` files; returns ``path``."""
    path = Path(path)
    if skipped:
        parts = parts + [f"## {skipped_title}\n", markdown_table([dict(what=k, reason=r) for k, r in skipped])]
    parts = parts + ["## Files\n", "\n".join(f"- {Path(p).name}" for p in written) + "\n"]
    write_text(path, "\n".join(parts))
    return path


def print_written(files, out, seconds):
    """The closing lines of a command: the files written into ``out`` and the time taken."""
    print(f"wrote {len(files)} files to {Path(out).resolve()}/:")
    for f in files:
        print(f"  {f}")
    print(f"done in {seconds:.1f} s")


def plot_errors(panels, path, title, t=None, fs=None):
    """One PNG: a panel per entry of ``panels`` (``{panel title: {label: err or (t, err)}}``),
    total error in degrees over time on a log axis. ``t`` or ``fs`` gives the time axis of
    plain error arrays."""
    fig = new_figure(figsize=(13, 3.4 * len(panels)))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)
    for ax, (ptitle, curves) in zip(axes[:, 0], panels.items()):
        for label, c in curves.items():
            tt, e = c if isinstance(c, tuple) else (t if t is not None else np.arange(len(c)) / fs, c)
            ax.semilogy(tt, np.maximum(e, 1e-3), lw=0.9, label=f"{label} (RMSE {metrics.rmse(e):.2f}°)")
        ax.set_title(ptitle, fontsize=10)
        ax.set_ylabel("total error (deg)")
        ax.set_ylim(bottom=1e-2)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)   # beside the curves
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(title)
    return save_figure(fig, path)


def save_figure(fig, path, dpi=110, rect=None):
    """Lay ``fig`` out (tight, within ``rect`` if given) and write it to ``path`` whole or not
    at all (controllers.policy_io.save_figure; its folder made); returns the path."""
    fig.tight_layout(**({} if rect is None else dict(rect=rect)))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_figure(fig, path, dpi=dpi)
    return path
