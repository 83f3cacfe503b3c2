"""The source documents' experiments, re-run in simulation (behind scripts/reproduce_papers.py).

One section per document, each on its seed scenario (``fusion.scenarios.seed_scenario``) and
IMU preset, over several seeds (mean ± sample std over seeds), with the document's own numbers
(../shared/seeds/README.md) beside ours and a plain verdict on each claimed effect:

- ``000``: static, 10 Hz, 150 s, mpu6050+mag3110: mean / std / MAE / RMSE per angle, ``mahony``
  (the complementary filter) against ``ekf`` (its Table 1).
- ``001``: slow, fast, faster arm motion with linear acceleration and a magnet passing, mti10 at
  256 Hz: RMSE per angle of ``ekf`` against ``aekf``, how often the aekf rejects each sensor
  inside and outside the disturbances, and a figure of the switching of R over time.
- ``003``: static, dynamic, vibration at 200 Hz, icm20602+qmc5883l: roll variance / std of
  ``ekf``, ``ukf``, ``iir-ekf`` and the std reductions of its table, the FFT of the roll estimate
  under vibration.
- ``004``: static and fast at 500 Hz, mpu9250: per-angle RMSE and std of ``ekf`` and ``cf-ekf``,
  improvements beside the claimed 71 / 74 / 66 %, and the same without the gyro's turn-on bias
  residual (a diagnosis of the difference).

Estimators run with default parameters from the first sample (accelerometer + magnetometer
start), 9-axis, errors against the scenario's truth at the IMU sample instants. Numpy at import;
tqdm and matplotlib where used.
"""
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

import fusion
from fusion import imu, metrics, quat, scenarios
from benchmarks import compare
from fusion.constants import GRAVITY

__all__ = ["SECTIONS", "PAPER", "SEEDS", "QUICK_SEEDS", "reproduce", "run_section"]

SECTIONS = {
    "000": "Seed 000: complementary filter vs EKF, robot held still (Table 1)",
    "001": "Seed 001: adaptive EKF from predicted measurements, arm motion",
    "003": "Seed 003: IIR-EKF (Butterworth prefilter) vs EKF and UKF, roll noise",
    "004": "Seed 004: complementary filter as the EKF's measurement (CF-EKF)",
}
SEEDS = tuple(range(10))
QUICK_SEEDS = (0, 1, 2)
ORDER = ("pitch", "roll", "yaw")          # the papers' order
DEG_ANGLES = metrics.ANGLES               # (yaw, pitch, roll): column order of euler_errors

# ../shared/seeds/README.md
PAPER = {
    "000": {"mahony": {"pitch": (-0.1327, 0.6362, 0.2170, 0.6491), "roll": (-0.0078, 0.2122, 0.0956, 0.2124),
                       "yaw": (-0.1303, 0.7721, 0.6992, 0.7829)},
            "ekf": {"pitch": (-0.1286, 0.2267, 0.1561, 0.2626), "roll": (-0.0066, 0.0681, 0.0530, 0.0685),
                    "yaw": (-0.0469, 0.7164, 0.6224, 0.7180)}},
    "001": {"aekf": {"yaw": 4.5292, "pitch": 2.7761, "roll": 3.2584},
            "ref17": {"yaw": 5.0276, "pitch": 3.2613, "roll": 3.9735}},
    "003": {"static": dict(ekf=0.002371, ukf=0.0019104, iir=0.001048, red_ekf=33.52, red_ukf=25.94),
            "dynamic": dict(ekf=math.nan, ukf=math.nan, iir=math.nan, red_ekf=5.26, red_ukf=1.68),
            "vibration": dict(ekf=1.1053, ukf=0.7582, iir=0.0721, red_ekf=74.46, red_ukf=69.16)},
    "004": {"roll": 71.0, "pitch": 74.0, "yaw": 66.0},
}


# --- small helpers -------------------------------------------------------------------------

def _run(name, s, record=False, **params):
    """A fresh estimator over the scenario (9-axis); with ``record`` also the aekf's decisions."""
    est = fusion.make(name, s.fs, **params)
    if record:
        est.record_decisions()
    q = est.run(s.gyr, s.acc, s.mag, dt=s.dt)
    return (q, est.decisions) if record else q


def _ms(values):
    """Mean and sample std (0 for one value) of finite values."""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0


def _pm(values, digits=3):
    m, sd = _ms(values)
    return f"{m:.{digits}f} ± {sd:.{digits}f}"


def _verdict(diffs, claim):
    """Verdict on a claimed improvement from per-seed paired differences (positive = the claimed
    direction): reproduced if the mean is over 2 standard errors above 0, opposite if below."""
    m, sd = _ms(diffs)
    se = sd / math.sqrt(len(diffs)) if len(diffs) > 1 else 0.0
    if m > 2 * se and m > 0:
        return f"reproduced ({claim})"
    if m < -2 * se and m < 0:
        return f"**not reproduced: the opposite** ({claim})"
    return f"**not reproduced: no difference beyond the seed spread** ({claim})"


def _no_turn_on_bias(preset):
    """The calibrated preset with the gyro's turn-on bias residual set to 0 (a diagnosis)."""
    spec = imu.preset(preset, calibrated=True)
    return spec.replace(gyro=replace(spec.gyro, bias_turn_on=0.0), name=spec.name + ", no gyro turn-on bias")


def _euler_runs(cases, names, seeds, tick, preset):
    """Every estimator on every (scenario, diagnosis?) case and seed: per-seed Euler-table rows
    (scenario label, seed, estimator, angle, mean, std, MAE, RMSE) and, per scenario, the
    first seed's per-sample Euler errors for figures (diagnosis runs: ``preset`` without the
    gyro's turn-on bias)."""
    runs, keep = [], {}
    for case, diagnosis in cases:
        label = case + (" (no gyro turn-on bias)" if diagnosis else "")
        for seed in seeds:
            s = scenarios.seed_scenario(case, seed, imu=_no_turn_on_bias(preset) if diagnosis else None)
            for n in names:
                q = _run(n, s)
                for ang, st in metrics.euler_table(q, s.q_true).items():
                    runs.append(dict(scenario=label, seed=seed, estimator=n, angle=ang, **st))
                if seed == seeds[0] and not diagnosis:
                    keep.setdefault(case, (s, {}))[1][n] = metrics.euler_errors(q, s.q_true)
            tick()
    return runs, keep


def _subplots(nrows, ncols, figsize, **kwargs):
    fig = compare.new_figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


# --- 000 -----------------------------------------------------------------------------------

def _section_000(seeds, out, tick):
    names = ("mahony", "ekf")
    case, diag = "seed000-static", "seed000-static (no gyro turn-on bias)"
    runs, keep = _euler_runs([(case, False), (case, True)], names, seeds, tick, "mpu6050+mag3110")
    def get(c, n, a, k):
        return [r[k] for r in runs if r["scenario"] == c and r["estimator"] == n and r["angle"] == a]
    table, lines = [], []
    for a in ORDER:
        for i, k in enumerate(metrics.STATS):
            row = dict(angle=a, stat=k)
            for n in names:
                row[f"paper_{n}"] = PAPER["000"][n][a][i]
                row[n], row[f"{n}_sd"] = _ms(get(case, n, a, k))
                row[f"{n}_no_bias"] = _ms(get(diag, n, a, k))[0]
            table.append(row)
            lines.append(f"| {a} | {k} | {PAPER['000']['mahony'][a][i]:.4f} | {_pm(get(case, 'mahony', a, k), 4)} "
                         f"| {PAPER['000']['ekf'][a][i]:.4f} | {_pm(get(case, 'ekf', a, k), 4)} "
                         f"| {_pm(get(diag, 'mahony', a, k), 4)} | {_pm(get(diag, 'ekf', a, k), 4)} |")
    verdicts = []
    for k in ("std", "RMSE"):
        for a in ORDER:
            d = np.array(get(case, "mahony", a, k)) - np.array(get(case, "ekf", a, k))
            verdicts.append(f"- {a} {k}: " + _verdict(d, "EKF below the complementary filter"))
    s, errs = keep[case]
    fig, axes = _subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for ax, a in zip(axes, ORDER):
        i = DEG_ANGLES.index(a)
        for n in names:
            ax.plot(s.t, errs[n][:, i], lw=0.8, label=f"{n} (RMSE {metrics.rmse(errs[n][:, i]):.2f}°)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{a} error (deg)")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"seed000-static (seed {s.seed}, {s.preset}, {s.fs:g} Hz): Euler-angle error")
    fig_path = _save(fig, out / "seed000_errors.png")
    md = [f"## {SECTIONS['000']}\n",
          f"Scenario `seed000-static` ({scenarios.SEED_SCENARIOS[case]}), {len(seeds)} seeds; "
          "errors in degrees against the truth, the paper's against its 0° ideal; ours mean ± std over "
          "seeds. The last two columns are a diagnosis, not the experiment: the same scenario with the "
          "gyro's turn-on bias residual set to 0.\n",
          "| angle | stat | paper CF | ours `mahony` | paper EKF | ours `ekf` "
          "| `mahony`, no gyro bias | `ekf`, no gyro bias |",
          "|---|---|---:|---:|---:|---:|---:|---:|", *lines, "",
          "Verdicts (paired over seeds):\n", *verdicts, "",
          "Why our means are larger than the paper's: the calibrated MPU-6050 keeps a 2 % "
          "cross-axis misalignment and a few mg of accelerometer bias (docs/imu.md), which tilt "
          "the accelerometer's vertical by up to about 1° at our random start tilts (up to 15°); no "
          "filter can see that, and the paper, scoring against its own 0° ideal, would not see it "
          "either. Where the two filters differ, the difference is the calibrated gyro's turn-on bias "
          "residual (0.8 °/s): the complementary filter's PI loop holds an offset of about "
          "bias / kp ≈ 1.6° until its integral (time constant kp/ki = 100 s) has learned the bias, "
          "while the EKF estimates it in its state; without that residual (last two columns) the two "
          "filters give the same numbers to a few hundredths of a degree. The paper's EKF advantage "
          "therefore reproduces only where the gyro bias matters, and its size depends on the bias "
          "each seed draws.\n",
          f"![errors]({fig_path.name})\n"]
    return md, table, runs, [fig_path]


# --- 001 -----------------------------------------------------------------------------------

def _frac(x, m):
    """Fraction of the samples in mask ``m`` where ``x`` holds (NaN for an empty mask)."""
    return float(x[m].mean()) if m.any() else math.nan


def _runs_001(cases, names, seeds, tick):
    """(Euler rows, switching rows, the first seed001-faster run kept for the figure)."""
    runs, sw = [], []
    keep = None
    for case in cases:
        for seed in seeds:
            s = scenarios.seed_scenario(case, seed)
            qs = {"ekf": _run("ekf", s)}
            qs["aekf"], dec = _run("aekf", s, record=True)
            for n in names:
                for ang, st in metrics.euler_table(qs[n], s.q_true).items():
                    runs.append(dict(scenario=case, seed=seed, estimator=n, angle=ang, RMSE=st["RMSE"]))
            acc_rej, mag_rej = (dec & 1) > 0, (dec & 2) > 0
            sw.append(dict(scenario=case, seed=seed,
                           acc_rej_in=_frac(acc_rej, s.acc_disturbed), acc_rej_out=_frac(acc_rej, ~s.acc_disturbed),
                           mag_rej_in=_frac(mag_rej, s.mag_disturbed), mag_rej_out=_frac(mag_rej, ~s.mag_disturbed)))
            if case == "seed001-faster" and keep is None:
                keep = (s, qs, dec)
            tick()
    return runs, sw, keep


def _section_001(seeds, out, tick):
    names = ("ekf", "aekf")
    cases = ("seed001-slow", "seed001-fast", "seed001-faster")
    runs, sw, keep = _runs_001(cases, names, seeds, tick)

    def get(c, n, a):
        return [r["RMSE"] for r in runs if r["scenario"] == c and r["estimator"] == n and r["angle"] == a]
    table, lines, verdicts = [], [], []
    for c in cases:
        for a in ("yaw", "pitch", "roll"):
            e, ae = np.array(get(c, "ekf", a)), np.array(get(c, "aekf", a))
            red = 100 * (1 - ae / e)
            pa = PAPER["001"]["aekf"][a] if c == "seed001-faster" else math.nan
            pr = PAPER["001"]["ref17"][a] if c == "seed001-faster" else math.nan
            table.append(dict(scenario=c, angle=a, ekf=_ms(e)[0], ekf_sd=_ms(e)[1], aekf=_ms(ae)[0],
                              aekf_sd=_ms(ae)[1], reduction_pct=_ms(red)[0], paper_aekf=pa, paper_ref17=pr))
            lines.append(f"| {c} | {a} | {_pm(e, 2)} | {_pm(ae, 2)} | {_pm(red, 0)} % | "
                         f"{'' if math.isnan(pa) else f'{pa:.2f}'} | {'' if math.isnan(pr) else f'{pr:.2f}'} |")
            if c != "seed001-slow":
                verdicts.append(f"- {c} {a}: " + _verdict(e - ae, "aekf below ekf"))
    sw_lines = []

    def cell(rs, k):
        col = [100 * r[k] for r in rs if not math.isnan(r[k])]
        return _pm(col, 1) if col else "(none disturbed)"
    for c in cases:
        rs = [r for r in sw if r["scenario"] == c]
        sw_lines.append(f"| {c} | {cell(rs, 'acc_rej_in')} | {cell(rs, 'acc_rej_out')} | "
                        f"{cell(rs, 'mag_rej_in')} | {cell(rs, 'mag_rej_out')} |")
    fig_path = _plot_switching(*keep, out / "seed001_switching.png")
    md = [f"## {SECTIONS['001']}\n",
          f"Scenarios `seed001-slow`, `-fast`, `-faster` ({scenarios.SEED_SCENARIOS['seed001-fast']}); "
          f"{len(seeds)} seeds, RMSE in degrees, mean ± std over seeds; reduction = 1 - aekf/ekf per seed. "
          "The paper's table is its experiment C (our `seed001-faster`) against a Polhemus tracker, and "
          "compares with its ref. [17], not with a plain EKF.\n",
          "| scenario | angle | ours `ekf` | ours `aekf` | reduction | paper aEKF | paper ref. [17] |",
          "|---|---|---:|---:|---:|---:|---:|", *lines, "",
          "How the aekf switches (percentage of samples whose variance was raised): inside / outside "
          "the true disturbances (|a_lin| > 0.5 m/s²; magnet field > 5 % of the earth field).\n",
          "| scenario | acc rejected, disturbed | acc rejected, quiet "
          "| mag rejected, disturbed | mag rejected, quiet |",
          "|---|---:|---:|---:|---:|", *sw_lines, "",
          "Verdicts (paired over seeds):\n", *verdicts, "",
          "Our absolute errors are smaller than the paper's: our reference is the simulation's exact "
          "truth, the paper's a magnetic tracker (itself disturbed by metal, aligned to the IMU by "
          "hand), and its arm motion is unknown beyond slow / fast / faster. In `seed001-slow` the aekf "
          "rejects nothing and gives the ekf's numbers exactly (docs/aekf.md: bit for bit).\n",
          f"![switching]({fig_path.name})\n"]
    return md, table, runs + sw, [fig_path]


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
    return _save(fig, path)


# --- 003 -----------------------------------------------------------------------------------

def _runs_003(cases, names, seeds, tick):
    """(roll-error rows, per vibration seed the share of accelerometer tones aliased below the
    IIR-EKF's cut-off, the first vibration run kept for the figure)."""
    runs, alias_share, keep = [], [], None
    for case in cases:
        for seed in seeds:
            s = scenarios.seed_scenario(f"seed003-{case}", seed)
            qs = {n: _run(n, s) for n in names}
            for n, q in qs.items():
                d = metrics.euler_errors(q, s.q_true)[:, DEG_ANGLES.index("roll")]
                runs.append(dict(case=case, seed=seed, estimator=n, n=s.n, var=float(d.var()), std=float(d.std())))
            if case == "vibration":
                tones = s.params["imu_constants"]["vibration_hz"][3:]          # accelerometer axes
                alias = np.abs(tones - s.fs * np.round(tones / s.fs))
                alias_share.append(float((alias < fusion.make("iir-ekf", s.fs).cutoff_hz).mean()))
                if keep is None:
                    keep = (s, qs)
            tick()
    return runs, alias_share, keep


def _section_003(seeds, out, tick):
    names = ("ekf", "ukf", "iir-ekf")
    cases = ("static", "dynamic", "vibration")
    runs, alias_share, keep = _runs_003(cases, names, seeds, tick)

    def get(c, n, k):
        return np.array([r[k] for r in runs if r["case"] == c and r["estimator"] == n])
    table, lines, verdicts = [], [], []
    for c in cases:
        p = PAPER["003"][c]
        red_e = 100 * (1 - get(c, "iir-ekf", "std") / get(c, "ekf", "std"))
        red_u = 100 * (1 - get(c, "iir-ekf", "std") / get(c, "ukf", "std"))
        row = dict(case=c, samples=int(get(c, "ekf", "n")[0]))
        for n in names:
            row[f"{n}_var"], row[f"{n}_var_sd"] = _ms(get(c, n, "var"))
        row.update(red_vs_ekf_pct=_ms(red_e)[0], red_vs_ukf_pct=_ms(red_u)[0], paper_ekf=p["ekf"], paper_ukf=p["ukf"],
                   paper_iir=p["iir"], paper_red_vs_ekf=p["red_ekf"], paper_red_vs_ukf=p["red_ukf"])
        table.append(row)
        paper_vars = "" if math.isnan(p["ekf"]) else f"{p['ekf']:g} / {p['ukf']:g} / {p['iir']:g}"
        lines.append(f"| {c} | {row['samples']} | {_pm(get(c, 'ekf', 'var'), 5)} | {_pm(get(c, 'ukf', 'var'), 5)} | "
                     f"{_pm(get(c, 'iir-ekf', 'var'), 5)} | {_pm(red_e, 1)} % / {_pm(red_u, 1)} % | {paper_vars} | "
                     f"{p['red_ekf']:.2f} % / {p['red_ukf']:.2f} % |")
        verdicts.append(f"- {c}: " + _verdict(get(c, "ekf", "std") - get(c, "iir-ekf", "std"),
                                               "IIR-EKF roll std below the EKF's"))
    fig_path = _plot_spectra(*keep, out / "seed003_spectra.png")
    md = [f"## {SECTIONS['003']}\n",
          f"Scenarios `seed003-static`, `-dynamic`, `-vibration` (icm20602+qmc5883l at 200 Hz); {len(seeds)} seeds. "
          "Roll error (estimate - truth) variance in deg², mean ± std over seeds; for the still cases this "
          "is the variance of the roll output the paper reports. Reductions are of the std, per seed, as "
          "the paper's percentages are (its 33.52 % = 1 - sqrt(0.001048 / 0.002371)).\n",
          "| case | samples | `ekf` var | `ukf` var | `iir-ekf` var | std reduction vs EKF / vs UKF | "
          "paper var EKF / UKF / IIR-EKF | paper reduction vs EKF / UKF |",
          "|---|---:|---:|---:|---:|---:|---:|---:|", *lines, "",
          "Verdicts (paired over seeds):\n", *verdicts, "",
          "Why the prefilter changes little here: (1) the EKF's default accelerometer noise "
          "(`acc_noise` 1.0, a tilt time constant of about 10 s) already averages the accelerometer "
          "over seconds, so there is nothing left above the Butterworth's 40 Hz cut-off for it to "
          "remove in the still and moving cases; (2) under vibration the roll noise comes from the "
          "accelerometer's vibration *aliased* by the 200 Hz sampling (130-200 Hz appear at 0-70 Hz; "
          "the physics rate is 2 kHz and the chip's 218 Hz low-pass lets them through). A digital "
          "filter after the sampling cannot tell an alias from motion: the tones between 160 and 200 Hz "
          f"land below 40 Hz and pass it ({_pm(100 * np.array(alias_share), 0)} % of the accelerometer's "
          "tones per seed), and those landing within a few Hz of 0 dominate the roll error, as the "
          "spectrum below shows. A 200 Hz roll signal cannot carry the paper's 130-200 Hz noise at all "
          "(its Nyquist limit is 100 Hz); either the paper's spectra were taken at a higher rate or its "
          "vibration reached the filter in a way we do not model. The UKF matches the EKF: at these "
          "small per-sample corrections the linearisation is exact enough.\n",
          f"![spectra]({fig_path.name})\n"]
    return md, table, runs, [fig_path]


def _plot_spectra(s, qs, path):
    fig, axes = _subplots(3, 1, figsize=(10, 9))
    ax = axes[0]
    f, a_acc = metrics.spectrum(s.acc[:, 1], s.fs)
    ax.semilogy(f, np.maximum(a_acc, 1e-6), lw=0.7, color="gray")
    ax.axvline(40.0, color="k", ls=":", lw=1, label="Butterworth cut-off 40 Hz")
    ax.set_ylabel("acc y amplitude (m/s²)")
    ax.set_title("accelerometer y under 130-200 Hz vibration, sampled at 200 Hz: aliases in 0-70 Hz", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    roll = {n: np.degrees(quat.to_euler(q)[:, 2]) for n, q in qs.items()}
    for ax, logx in ((axes[1], False), (axes[2], True)):
        for (n, r), lw in zip(roll.items(), (2.2, 1.2, 0.6)):    # wide to narrow: all three visible
            f, amp = metrics.spectrum(r, s.fs)
            (ax.loglog if logx else ax.semilogy)(f[1:], np.maximum(amp[1:], 1e-7), lw=lw, label=n)
        ax.axvline(40.0, color="k", ls=":", lw=1)
        ax.set_ylabel("roll amplitude (deg)")
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_title("FFT of the roll estimate (linear frequency axis)", fontsize=9)
    axes[2].set_title("the same, log frequency axis: the error sits below 1 Hz", fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.set_xlabel("frequency (Hz)")
    fig.suptitle(f"seed003-vibration (seed {s.seed}, {s.preset})")
    return _save(fig, path)


# --- 004 -----------------------------------------------------------------------------------

def _section_004(seeds, out, tick):
    names = ("ekf", "cf-ekf")
    cases = [("seed004-static", False), ("seed004-fast", False), ("seed004-static", True)]
    runs, keep = _euler_runs(cases, names, seeds, tick, "mpu9250")
    labels = list(dict.fromkeys(r["scenario"] for r in runs))
    def get(c, n, a, k):
        return np.array([r[k] for r in runs
                         if r["scenario"] == c and r["estimator"] == n and r["angle"] == a])
    table, lines, verdicts = [], [], []
    for c in labels:
        for a in ORDER:
            row = dict(scenario=c, angle=a, claimed_pct=PAPER["004"][a])
            cells = []
            for k in ("RMSE", "std"):
                e, cf = get(c, "ekf", a, k), get(c, "cf-ekf", a, k)
                imp = 100 * (1 - cf / e)
                row.update({f"ekf_{k}": _ms(e)[0], f"cfekf_{k}": _ms(cf)[0], f"improvement_{k}_pct": _ms(imp)[0]})
                cells += [_pm(e, 2), _pm(cf, 2), f"{_pm(imp, 0)} %"]
                if k == "RMSE" and "no gyro" not in c:
                    verdicts.append(f"- {c} {a}: " + _verdict(e - cf, "cf-ekf below ekf"))
            table.append(row)
            lines.append(f"| {c} | {a} | " + " | ".join(cells) + f" | {PAPER['004'][a]:.0f} % |")
    fig_path = _plot_004(keep, out / "seed004_errors.png")
    md = [f"## {SECTIONS['004']}\n",
          f"Scenarios `seed004-static`, `seed004-fast` (mpu9250 at 500 Hz); {len(seeds)} seeds; errors in degrees, "
          "mean ± std over seeds; improvement = 1 - cf-ekf/ekf per seed. The patent claims the static "
          "accuracy improves by 71 % (roll), 74 % (pitch), 66 % (yaw) over a plain EKF; it does not say "
          "which statistic. The last block is a diagnosis, not the experiment: the same static scenario "
          "with the gyro's turn-on bias residual set to 0.\n",
          "| scenario | angle | `ekf` RMSE | `cf-ekf` RMSE | improvement "
          "| `ekf` std | `cf-ekf` std | improvement | claimed |",
          "|---|---|---:|---:|---:|---:|---:|---:|---:|", *lines, "",
          "Verdicts on RMSE (paired over seeds):\n", *verdicts, "",
          "Why: the cf-ekf's measurement is the complementary filter's quaternion, followed with a time "
          "constant of about 1 s (docs/cfekf.md). With the EKF's bias fed back into that filter (the "
          "default, `bias_feedback`) it no longer carries the offset of about bias / kp ≈ 2.4° that the "
          "calibrated MPU-9250's residual gyro bias (1.2 °/s) gives a complementary filter whose "
          "integral needs 100 s (`mahony`: 5.9° total RMSE on seed004-static against the cf-ekf's "
          "2.0°, benchmarks/README.md). Against the plain EKF, which estimates the bias in its "
          "state too, the structure brings no gain: tilt within the seed spread, and heading worse "
          "in fast driving (swings of 1-3° that follow the turns): the filter's magnetometer "
          "correction (time constant 1/kp = 2 s) follows the magnetometer's orientation-dependent "
          "calibration residual more closely than the EKF. What is left in both (about 1-2° of mean "
          "error) is the accelerometer's misalignment and bias residual, which no filter sees.\n",
          f"![errors]({fig_path.name})\n"]
    return md, table, runs, [fig_path]


def _plot_004(keep, path):
    fig, axes = _subplots(3, len(keep), figsize=(12, 8), sharex="col", squeeze=False)
    for j, (case, (s, errs)) in enumerate(keep.items()):
        for i, a in enumerate(ORDER):
            ax = axes[i, j]
            k = DEG_ANGLES.index(a)
            for n, e in errs.items():
                ax.plot(s.t, e[:, k], lw=0.7, label=f"{n} (RMSE {metrics.rmse(e[:, k]):.2f}°)")
            ax.axhline(0, color="k", lw=0.5)
            ax.set_ylabel(f"{a} error (deg)")
            ax.grid(alpha=0.3)
            ax.legend(loc="best", fontsize=8)
        axes[0, j].set_title(f"{case} (seed {s.seed})", fontsize=10)
        axes[-1, j].set_xlabel("time (s)")
    fig.suptitle("mpu9250 at 500 Hz: Euler-angle error, ekf vs cf-ekf")
    return _save(fig, path)


# --- driver --------------------------------------------------------------------------------

_RUNNERS = {"000": _section_000, "001": _section_001, "003": _section_003, "004": _section_004}
_UNITS = {"000": 2, "001": 3, "003": 3, "004": 3}        # scenario runs per seed (progress bar)


def run_section(key, out, seeds, tick=lambda: None):
    """Run one section into folder ``out``; returns ``(markdown lines, files written)``."""
    if key not in _RUNNERS:
        raise ValueError(f"unknown section {key!r}; available: {', '.join(_RUNNERS)}")
    seeds = tuple(seeds)
    if not seeds or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seeds):
        raise ValueError(f"seeds must be a non-empty sequence of integers >= 0, got {seeds!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md, table, runs, figs = _RUNNERS[key](seeds, out, tick)
    files = list(compare.write_table(table, out / f"seed{key}_table", digits=5,
                                     title=SECTIONS[key] + " (mean over seeds)"))
    files += compare.write_table(runs, out / f"seed{key}_runs", columns=_columns(runs), digits=5,
                                 title=SECTIONS[key] + " (per seed)")
    section_md = out / f"seed{key}.md"
    section_md.write_text("\n".join(md))
    return md, [section_md, *files, *figs]


def _columns(rows):
    cols = {}
    for r in rows:
        cols.update(dict.fromkeys(r))
    return list(cols)


def reproduce(out="results/papers", sections=tuple(_RUNNERS), seeds=None, quick=False, progress=True):
    """Run ``sections`` (keys of ``SECTIONS``) over ``seeds`` (default ``SEEDS``, or
    ``QUICK_SEEDS`` with ``quick``) into ``out``: per section ``seedNNN.md``,
    ``seedNNN_table.csv/.md`` (mean over seeds), ``seedNNN_runs.csv/.md`` (per seed) and PNG
    figures, plus ``report.md`` with every section. Returns the list of files written."""
    sections = list(sections)
    bad = [k for k in sections if k not in _RUNNERS]
    if bad or not sections:
        raise ValueError(f"sections must be some of {', '.join(_RUNNERS)}; got {sections!r}")
    seeds = tuple(seeds) if seeds is not None else (QUICK_SEEDS if quick else SEEDS)
    out = Path(out)
    bar = None
    def tick():
        return None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=sum(_UNITS[k] for k in sections) * len(seeds), desc="papers", unit="scenario")
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
