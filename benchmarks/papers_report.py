"""The report of the source documents' reproductions, written from the numbers of
``benchmarks.papers``: per section ``seedNNN.md`` (tables beside the documents' numbers, a
verdict per claimed effect computed from the paired per-seed differences), ``seedNNN_table``
and ``seedNNN_runs`` (CSV + Markdown), a PNG figure, and ``report.md`` with every section.

No conclusion is stored here: each sentence with a number is formatted from a measurement of
the run, and the reasons behind the numbers are in docs/papers.md, which the report points to.
tqdm and matplotlib are imported where they are used.
"""
import math
from pathlib import Path

import numpy as np

from benchmarks import compare
from benchmarks.papers import (DEG_ANGLES, NO_BIAS, ORDER, PAPER, QUICK_SEEDS, SECTIONS, SEEDS, UNITS, mean_sd,
                               measure)
from fusion import metrics, quat, scenarios
from fusion.constants import GRAVITY

__all__ = ["verdict", "write_section", "run_section", "reproduce"]

WHY = "Why the numbers are what they are: docs/papers.md, \"What did not reproduce, and why\".\n"


def verdict(diffs, claim):
    """Verdict on a claimed improvement from per-seed paired differences (positive = the claimed
    direction): reproduced if the mean is over 2 standard errors above 0, opposite if below."""
    m, sd = mean_sd(diffs)
    se = sd / math.sqrt(len(diffs)) if len(diffs) > 1 else 0.0
    if m > 2 * se and m > 0:
        return f"reproduced ({claim})"
    if m < -2 * se and m < 0:
        return f"**not reproduced: the opposite** ({claim})"
    return f"**not reproduced: no difference beyond the seed spread** ({claim})"


def _pm(values, digits=3):
    """``mean ± std`` over seeds."""
    m, sd = mean_sd(values)
    return f"{m:.{digits}f} ± {sd:.{digits}f}"


def _table_md(columns, n_text, lines):
    """A Markdown table: header of ``columns``, the first ``n_text`` left-aligned, ``lines``."""
    return ["| " + " | ".join(columns) + " |",
            "|" + "|".join(["---"] * n_text + ["---:"] * (len(columns) - n_text)) + "|", *lines, ""]


def _section_md(sec, intro, table, fig, more=(), notes=(), verdicts="Verdicts (paired over seeds):"):
    """A section's Markdown: title, ``intro``, its ``table`` (and ``more`` lines), a verdict
    per claim from the paired per-seed differences, ``notes``, where the reasons are, the figure."""
    claims = [f"- {p['label']}: " + verdict(p["diffs"], p["claim"]) for p in sec.paired]
    return [f"## {SECTIONS[sec.key]}\n", intro, *table, *more, verdicts + "\n", *claims, "", *notes, WHY,
            f"![{fig.stem.split('_')[-1]}]({fig.name})\n"]


def _subplots(nrows, ncols, figsize, **kwargs):
    fig = compare.new_figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def _plot_euler(runs, path, title, ncols):
    """Euler-angle error over time, an angle per row and a run per column (``runs``:
    ``{column title: (scenario, {estimator: per-sample Euler errors})}``)."""
    fig, axes = _subplots(3, ncols, figsize=(10, 7.5) if ncols == 1 else (12, 8), sharex="col", squeeze=False)
    for j, (ctitle, (s, errs)) in enumerate(runs.items()):
        for i, a in enumerate(ORDER):
            ax = axes[i, j]
            k = DEG_ANGLES.index(a)
            for n, e in errs.items():
                ax.plot(s.t, e[:, k], lw=0.8 if ncols == 1 else 0.7, label=f"{n} (RMSE {metrics.rmse(e[:, k]):.2f}°)")
            ax.axhline(0, color="k", lw=0.5)
            ax.set_ylabel(f"{a} error (deg)")
            ax.grid(alpha=0.3)
            ax.legend(loc="best", fontsize=8)
        if ncols > 1:
            axes[0, j].set_title(ctitle, fontsize=10)
        axes[-1, j].set_xlabel("time (s)")
    fig.suptitle(title)
    return compare.save_figure(fig, path)


# --- 000 -----------------------------------------------------------------------------------

def _report_000(sec, out):
    case = "seed000-static"
    diag, ps = case + NO_BIAS, sec.per_seed
    lines = [f"| {a} | {k} | {PAPER['000']['mahony'][a][i]:.4f} | {_pm(ps[(case, 'mahony', a, k)], 4)} "
             f"| {PAPER['000']['ekf'][a][i]:.4f} | {_pm(ps[(case, 'ekf', a, k)], 4)} "
             f"| {_pm(ps[(diag, 'mahony', a, k)], 4)} | {_pm(ps[(diag, 'ekf', a, k)], 4)} |"
             for a in ORDER for i, k in enumerate(metrics.STATS)]
    s = sec.figure[0]
    fig_path = _plot_euler({case: sec.figure}, out / "seed000_errors.png", ncols=1,
                           title=f"{case} (seed {s.seed}, {s.preset}, {s.fs:g} Hz): Euler-angle error")
    intro = (f"Scenario `{case}` ({scenarios.SEED_SCENARIOS[case]}), {len(sec.seeds)} seeds; "
             "errors in degrees against the truth, the paper's against its 0° ideal; ours mean ± std over "
             "seeds. The last two columns are a diagnosis, not the experiment: the same scenario with the "
             "gyro's turn-on bias residual set to 0.\n")
    table = _table_md(["angle", "stat", "paper CF", "ours `mahony`", "paper EKF", "ours `ekf`",
                       "`mahony`, no gyro bias", "`ekf`, no gyro bias"], 2, lines)
    return _section_md(sec, intro, table, fig_path), [fig_path]


# --- 001 -----------------------------------------------------------------------------------

def _report_001(sec, out):
    cases = ("seed001-slow", "seed001-fast", "seed001-faster")
    ps, lines, sw_lines = sec.per_seed, [], []
    for c in cases:
        for a in ("yaw", "pitch", "roll"):
            pa = f"{PAPER['001']['aekf'][a]:.2f}" if c == "seed001-faster" else ""
            pr = f"{PAPER['001']['ref17'][a]:.2f}" if c == "seed001-faster" else ""
            lines.append(f"| {c} | {a} | {_pm(ps[(c, 'ekf', a)], 2)} | {_pm(ps[(c, 'aekf', a)], 2)} | "
                         f"{_pm(ps[(c, 'reduction', a)], 0)} % | {pa} | {pr} |")
        cells = [_pm(ps[(c, k)], 1) if ps[(c, k)].size else "(none disturbed)"
                 for k in ("acc_rej_in", "acc_rej_out", "mag_rej_in", "mag_rej_out")]
        sw_lines.append(f"| {c} | " + " | ".join(cells) + " |")
    diff = ", ".join(f"`{c}` {d:.1e}" for c, d in sec.numbers["aekf_ekf_max_diff"].items())
    same_md = [f"Largest difference between the aekf's and the ekf's quaternion components over seeds: {diff}.\n"]
    fig_path = _plot_switching(*sec.figure, out / "seed001_switching.png")
    intro = (f"Scenarios `seed001-slow`, `-fast`, `-faster` ({scenarios.SEED_SCENARIOS['seed001-fast']}); "
             f"{len(sec.seeds)} seeds, RMSE in degrees, mean ± std over seeds; reduction = 1 - aekf/ekf per seed. "
             "The paper's table is its experiment C (our `seed001-faster`) against a Polhemus tracker, and "
             "compares with its ref. [17], not with a plain EKF.\n")
    table = _table_md(["scenario", "angle", "ours `ekf`", "ours `aekf`", "reduction", "paper aEKF",
                       "paper ref. [17]"], 2, lines)
    more = ["How the aekf switches (percentage of samples whose variance was raised): inside / outside "
            "the true disturbances (|a_lin| > 0.5 m/s²; magnet field > 5 % of the earth field).\n",
            *_table_md(["scenario", "acc rejected, disturbed", "acc rejected, quiet", "mag rejected, disturbed",
                        "mag rejected, quiet"], 1, sw_lines)]
    return _section_md(sec, intro, table, fig_path, more=more, notes=same_md), [fig_path]


def _plot_switching(s, qs, dec, path):
    fig, axes = _subplots(4, 1, figsize=(10, 10), sharex=True)
    t = s.t

    def shade(ax, mask, color, label):
        return ax.fill_between(t, 0, 1, where=mask, color=color, alpha=0.25,
                               transform=ax.get_xaxis_transform(), label=label)
    ax = axes[0]
    ax.plot(t, np.linalg.norm(s.acc, axis=1) - GRAVITY, lw=0.7, label="|a| - g (m/s²)")
    ax.plot(t, np.linalg.norm(s.a_lin, axis=1), lw=0.7, label="|true linear acceleration| (m/s²)")
    shade(ax, s.acc_disturbed, "tab:red", "acc disturbed (truth)")
    ax.set_ylabel("m/s²")
    ax.legend(loc="upper left", fontsize=8)
    ax = axes[1]
    b = quat.rotate(s.q_true, s.mag) - s.field
    ax.plot(t, np.linalg.norm(b, axis=1), lw=0.7, color="tab:purple", label="|measured field - earth field| (µT)")
    shade(ax, s.mag_disturbed, "tab:purple", "mag disturbed (truth)")
    ax.set_ylabel("µT")
    ax.legend(loc="upper left", fontsize=8)
    ax = axes[2]
    ax.step(t, 1.0 + 0.8 * ((dec & 1) > 0), where="post", lw=0.8, label="accelerometer: R raised")
    ax.step(t, 0.8 * ((dec & 2) > 0), where="post", lw=0.8, label="magnetometer: R raised")
    ax.set_yticks([0, 0.8, 1.0, 1.8])
    ax.set_yticklabels(["mag own R", "mag R × 1e4", "acc own R", "acc R × 1e4"], fontsize=8)
    ax.set_title("aekf: measurement variance per sample", fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    ax = axes[3]
    for n, q in qs.items():
        err = metrics.attitude_errors(q, s.q_true)
        ax.plot(t, err["inclination"], lw=0.8, label=f"{n} inclination (RMSE {metrics.rmse(err['inclination']):.2f}°)")
        ax.plot(t, err["heading"], lw=0.8, ls="--", label=f"{n} heading (RMSE {metrics.rmse(err['heading']):.2f}°)")
    ax.set_ylabel("error (deg)")
    ax.set_xlabel("time (s)")
    ax.legend(loc="upper left", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"seed001-faster (seed {s.seed}, {s.preset}, {s.fs:g} Hz): the aekf's switching")
    return compare.save_figure(fig, path)


# --- 003 -----------------------------------------------------------------------------------

def _report_003(sec, out):
    ps, lines = sec.per_seed, []
    for row in sec.table:
        c, p = row["case"], PAPER["003"][row["case"]]
        paper_vars = "" if math.isnan(p["ekf"]) else f"{p['ekf']:g} / {p['ukf']:g} / {p['iir']:g}"
        lines.append(f"| {c} | {row['samples']} | {_pm(ps[(c, 'ekf', 'var')], 5)} | {_pm(ps[(c, 'ukf', 'var')], 5)} | "
                     f"{_pm(ps[(c, 'iir-ekf', 'var')], 5)} | {_pm(ps[(c, 'red_vs_ekf')], 1)} % / "
                     f"{_pm(ps[(c, 'red_vs_ukf')], 1)} % | {paper_vars} | "
                     f"{p['red_ekf']:.2f} % / {p['red_ukf']:.2f} % |")
    cutoff = sec.numbers["cutoff_hz"]
    fig_path = _plot_spectra(*sec.figure, cutoff, out / "seed003_spectra.png")
    intro = (f"Scenarios `seed003-static`, `-dynamic`, `-vibration` (icm20602+qmc5883l at 200 Hz); "
             f"{len(sec.seeds)} seeds. Roll error (estimate - truth) variance in deg², mean ± std over seeds; for "
             "the still cases this is the variance of the roll output the paper reports. Reductions are of the "
             "std, per seed, as the paper's percentages are (its 33.52 % = 1 - sqrt(0.001048 / 0.002371)).\n")
    table = _table_md(["case", "samples", "`ekf` var", "`ukf` var", "`iir-ekf` var", "std reduction vs EKF / vs UKF",
                       "paper var EKF / UKF / IIR-EKF", "paper reduction vs EKF / UKF"], 1, lines)
    notes = [f"Share of the accelerometer's vibration tones that the 200 Hz sampling aliases below the `iir-ekf`'s "
             f"{cutoff:g} Hz cut-off: {_pm(ps['alias_share_pct'], 0)} % per seed.\n"]
    return _section_md(sec, intro, table, fig_path, notes=notes), [fig_path]


def _plot_spectra(s, qs, cutoff, path):
    fig, axes = _subplots(3, 1, figsize=(10, 9))
    ax = axes[0]
    f, a_acc = metrics.spectrum(s.acc[:, 1], s.fs)
    ax.semilogy(f, np.maximum(a_acc, 1e-6), lw=0.7, color="gray")
    ax.axvline(cutoff, color="k", ls=":", lw=1, label=f"Butterworth cut-off {cutoff:g} Hz")
    ax.set_ylabel("acc y amplitude (m/s²)")
    ax.set_title(f"accelerometer y under the scenario's vibration, sampled at {s.fs:g} Hz", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    roll = {n: np.degrees(quat.to_euler(q)[:, 2]) for n, q in qs.items()}
    for ax, logx in ((axes[1], False), (axes[2], True)):
        for (n, r), lw in zip(roll.items(), (2.2, 1.2, 0.6)):    # wide to narrow: all three visible
            f, amp = metrics.spectrum(r, s.fs)
            (ax.loglog if logx else ax.semilogy)(f[1:], np.maximum(amp[1:], 1e-7), lw=lw, label=n)
        ax.axvline(cutoff, color="k", ls=":", lw=1)
        ax.set_ylabel("roll amplitude (deg)")
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_title("FFT of the roll estimate (linear frequency axis)", fontsize=9)
    axes[2].set_title("the same, log frequency axis", fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.set_xlabel("frequency (Hz)")
    fig.suptitle(f"seed003-vibration (seed {s.seed}, {s.preset})")
    return compare.save_figure(fig, path)


# --- 004 -----------------------------------------------------------------------------------

def _report_004(sec, out):
    ps, lines = sec.per_seed, []
    for row in sec.table:
        c, a = row["scenario"], row["angle"]
        cells = [cell for k in ("RMSE", "std")
                 for cell in (_pm(ps[(c, a, "ekf", k)], 2), _pm(ps[(c, a, "cf-ekf", k)], 2),
                              f"{_pm(ps[(c, a, 'improvement', k)], 0)} %")]
        lines.append(f"| {c} | {a} | " + " | ".join(cells) + f" | {PAPER['004'][a]:.0f} % |")
    fig_path = _plot_euler({f"{case} (seed {s.seed})": (s, errs) for case, (s, errs) in sec.figure.items()},
                           out / "seed004_errors.png", ncols=len(sec.figure),
                           title="mpu9250 at 500 Hz: Euler-angle error, ekf vs cf-ekf")
    intro = (f"Scenarios `seed004-static`, `seed004-fast` (mpu9250 at 500 Hz); {len(sec.seeds)} seeds; errors in "
             "degrees, mean ± std over seeds; improvement = 1 - cf-ekf/ekf per seed. The patent claims the static "
             "accuracy improves by 71 % (roll), 74 % (pitch), 66 % (yaw) over a plain EKF; it does not say "
             "which statistic. The last block is a diagnosis, not the experiment: the same static scenario "
             "with the gyro's turn-on bias residual set to 0.\n")
    table = _table_md(["scenario", "angle", "`ekf` RMSE", "`cf-ekf` RMSE", "improvement", "`ekf` std",
                       "`cf-ekf` std", "improvement", "claimed"], 2, lines)
    return _section_md(sec, intro, table, fig_path, verdicts="Verdicts on RMSE (paired over seeds):"), [fig_path]


# --- files ---------------------------------------------------------------------------------

_REPORTS = {"000": _report_000, "001": _report_001, "003": _report_003, "004": _report_004}


def _columns(rows):
    cols = {}
    for r in rows:
        cols.update(dict.fromkeys(r))
    return list(cols)


def write_section(sec, out):
    """Write one measured ``Section`` into folder ``out``; returns ``(markdown lines, files)``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md, figs = _REPORTS[sec.key](sec, out)
    title = SECTIONS[sec.key]
    files = list(compare.write_table(sec.table, out / f"seed{sec.key}_table", digits=5,
                                     title=title + " (mean over seeds)"))
    files += compare.write_table(sec.runs, out / f"seed{sec.key}_runs", columns=_columns(sec.runs), digits=5,
                                 title=title + " (per seed)")
    section_md = out / f"seed{sec.key}.md"
    section_md.write_text("\n".join(md))
    return md, [section_md, *files, *figs]


def run_section(key, out, seeds, tick=lambda: None):
    """Measure section ``key`` over ``seeds`` and write it into ``out``: ``(markdown, files)``."""
    return write_section(measure(key, seeds, tick), out)


def reproduce(out="results/papers", sections=tuple(SECTIONS), seeds=None, quick=False, progress=True):
    """Run ``sections`` (keys of ``SECTIONS``) over ``seeds`` (default ``SEEDS``, or
    ``QUICK_SEEDS`` with ``quick``) into ``out``: per section ``seedNNN.md``,
    ``seedNNN_table.csv/.md`` (mean over seeds), ``seedNNN_runs.csv/.md`` (per seed) and PNG
    figures, plus ``report.md`` with every section. Returns the list of files written."""
    sections = list(sections)
    bad = [k for k in sections if k not in SECTIONS]
    if bad or not sections:
        raise ValueError(f"sections must be some of {', '.join(SECTIONS)}; got {sections!r}")
    seeds = tuple(seeds) if seeds is not None else (QUICK_SEEDS if quick else SEEDS)
    out = Path(out)
    bar = None

    def tick():
        return None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=sum(UNITS[k] for k in sections) * len(seeds), desc="papers", unit="scenario")
        tick = bar.update
    parts = ["# The source documents, reproduced in simulation\n",
             f"Seeds {', '.join(map(str, seeds))}; default estimator parameters; calibrated IMU presets "
             "(fusion.imu); scenarios from fusion.scenarios.seed_scenario. docs/papers.md explains the "
             "sections.\n"]
    files = []
    try:
        for k in sections:
            md, f = run_section(k, out, seeds, tick)
            parts += md
            files += f
    finally:
        if bar is not None:
            bar.close()
    report = out / "report.md"
    report.write_text("\n".join(parts))
    return [report, *files]
