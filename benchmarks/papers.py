"""The source documents' experiments, re-run in simulation: the measurements (numbers only).

One section per document, each on its seed scenario (``fusion.scenarios.seed_scenario``) and
IMU preset, over several seeds, with the document's own numbers (``PAPER``, from the digest
"The four source documents, in short") beside ours. ``measure(key, seeds)`` returns a
``Section`` of numbers: the table of means over seeds, the per-seed rows, the per-seed values
of every reported cell, the paired per-seed differences behind each claimed effect and the
first seed's run for the figure. ``benchmarks.papers_report`` turns them into Markdown, CSV,
figures and verdicts (docs/papers.md explains what did and did not reproduce, and why):

- ``000``: static, 10 Hz, 150 s, mpu6050+mag3110: mean / std / MAE / RMSE per angle, ``mahony``
  (the complementary filter) against ``ekf`` (its Table 1).
- ``001``: slow, fast, faster arm motion with linear acceleration and a magnet passing, mti10 at
  256 Hz: RMSE per angle of ``ekf`` against ``aekf``, how often the aekf rejects each sensor
  inside and outside the disturbances.
- ``003``: static, dynamic, vibration at 200 Hz, icm20602+qmc5883l: roll variance / std of
  ``ekf``, ``ukf``, ``iir-ekf`` and the std reductions of its table.
- ``004``: static and fast at 500 Hz, mpu9250: per-angle RMSE and std of ``ekf`` and ``cf-ekf``,
  improvements beside the claimed 71 / 74 / 66 %, and the same without the gyro's turn-on bias
  residual (a diagnosis of the difference).

Estimators run with default parameters from the first sample (accelerometer + magnetometer
start), 9-axis, errors against the scenario's truth at the IMU sample instants.
"""
import math
from dataclasses import dataclass, field, replace

import numpy as np

import fusion
from fusion import imu, metrics, scenarios
from fusion._cfekf import seed_window

__all__ = ["SECTIONS", "PAPER", "SEEDS", "QUICK_SEEDS", "UNITS", "Section", "measure", "mean_sd"]

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
NO_BIAS = " (no gyro turn-on bias)"       # label suffix of the diagnosis runs

# the documents' own numbers, from the digest "The four source documents, in short"
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


@dataclass
class Section:
    """One section's measurements.

    ``table``: rows of means over seeds (``seedNNN_table``); ``runs``: per-seed rows
    (``seedNNN_runs``); ``per_seed``: the per-seed values of every cell the report shows (a key
    per cell, arrays over seeds); ``paired``: per claimed effect a dict ``label``, ``claim``,
    ``diffs`` (per-seed paired differences, positive = the claimed direction); ``figure``: the
    first seed's run for the figure; ``numbers``: further measured values (per section)."""
    key: str
    seeds: tuple
    table: list
    runs: list
    per_seed: dict
    paired: list
    figure: object = None
    numbers: dict = field(default_factory=dict)


def mean_sd(values):
    """Mean and sample std (0 for one value)."""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0


def _values(rows, key, **match):
    """``key`` of the rows that match every ``field=value`` in ``match``, as an array."""
    return np.array([r[key] for r in rows if all(r.get(k) == v for k, v in match.items())], dtype=float)


def _run(name, s, record=False, **params):
    """A fresh estimator over the scenario (9-axis); with ``record`` also the aekf's decisions."""
    est = fusion.make(name, s.fs, **params)
    if record:
        est.record_decisions()
    q = est.run(s.gyr, s.acc, s.mag, dt=s.dt)
    return (q, est.decisions) if record else q


def _no_turn_on_bias(preset):
    """The calibrated preset with the gyro's turn-on bias residual set to 0 (a diagnosis)."""
    spec = imu.preset(preset, calibrated=True)
    return spec.replace(gyro=replace(spec.gyro, bias_turn_on=0.0), name=spec.name + ", no gyro turn-on bias")


def _euler_runs(cases, names, seeds, tick, preset, params=None):
    """Every estimator on every (scenario, diagnosis?) case and seed: per-seed Euler-table rows
    (scenario label, seed, estimator, angle, mean, std, MAE, RMSE) and, per scenario, the
    first seed's per-sample Euler errors for figures (diagnosis runs: ``preset`` without the
    gyro's turn-on bias). params: {name: function of the scenario giving keyword arguments}
    where a source's own setting differs from the default."""
    runs, keep = [], {}
    for case, diagnosis in cases:
        label = case + (NO_BIAS if diagnosis else "")
        for seed in seeds:
            s = scenarios.seed_scenario(case, seed, imu=_no_turn_on_bias(preset) if diagnosis else None)
            for n in names:
                q = _run(n, s, **(params or {}).get(n, lambda s: {})(s))
                for ang, st in metrics.euler_table(q, s.q_true).items():
                    runs.append(dict(scenario=label, seed=seed, estimator=n, angle=ang, **st))
                if seed == seeds[0] and not diagnosis:
                    keep.setdefault(case, (s, {}))[1][n] = metrics.euler_errors(q, s.q_true)
            tick()
    return runs, keep


# --- 000 -----------------------------------------------------------------------------------

def _measure_000(seeds, tick):
    names = ("mahony", "ekf")
    case = "seed000-static"
    runs, keep = _euler_runs([(case, False), (case, True)], names, seeds, tick, "mpu6050+mag3110")
    cases = (case, case + NO_BIAS)
    per_seed = {(c, n, a, k): _values(runs, k, scenario=c, estimator=n, angle=a)
                for c in cases for n in names for a in ORDER for k in metrics.STATS}
    table = []
    for a in ORDER:
        for i, k in enumerate(metrics.STATS):
            row = dict(angle=a, stat=k)
            for n in names:
                row[f"paper_{n}"] = PAPER["000"][n][a][i]
                row[n], row[f"{n}_sd"] = mean_sd(per_seed[(case, n, a, k)])
                row[f"{n}_no_bias"] = mean_sd(per_seed[(cases[1], n, a, k)])[0]
            table.append(row)
    paired = [dict(label=f"{a} {k}", claim="EKF below the complementary filter",
                   diffs=per_seed[(case, "mahony", a, k)] - per_seed[(case, "ekf", a, k)])
              for k in ("std", "RMSE") for a in ORDER]
    return Section("000", seeds, table, runs, per_seed, paired, figure=keep[case])


# --- 001 -----------------------------------------------------------------------------------

def _frac(x, m):
    """Fraction of the samples in mask ``m`` where ``x`` holds (NaN for an empty mask)."""
    return float(x[m].mean()) if m.any() else math.nan


def _runs_001(cases, names, seeds, tick):
    """(Euler rows, switching rows, per case the largest difference between the aekf's and the
    ekf's quaternion components over seeds, the first seed001-faster run kept for the figure)."""
    runs, sw, keep = [], [], None
    max_diff = dict.fromkeys(cases, 0.0)
    for case in cases:
        for seed in seeds:
            s = scenarios.seed_scenario(case, seed)
            qs = {"ekf": _run("ekf", s)}
            qs["aekf"], dec = _run("aekf", s, record=True)
            max_diff[case] = max(max_diff[case], float(np.abs(qs["aekf"] - qs["ekf"]).max()))
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
    return runs, sw, max_diff, keep


def _measure_001(seeds, tick):
    names = ("ekf", "aekf")
    cases = ("seed001-slow", "seed001-fast", "seed001-faster")
    runs, sw, max_diff, keep = _runs_001(cases, names, seeds, tick)
    per_seed, table, paired = {}, [], []
    for c in cases:
        for a in ("yaw", "pitch", "roll"):
            e, ae = (_values(runs, "RMSE", scenario=c, estimator=n, angle=a) for n in names)
            red = 100 * (1 - ae / e)
            per_seed.update({(c, "ekf", a): e, (c, "aekf", a): ae, (c, "reduction", a): red})
            pa = PAPER["001"]["aekf"][a] if c == "seed001-faster" else math.nan
            pr = PAPER["001"]["ref17"][a] if c == "seed001-faster" else math.nan
            table.append(dict(scenario=c, angle=a, ekf=mean_sd(e)[0], ekf_sd=mean_sd(e)[1], aekf=mean_sd(ae)[0],
                              aekf_sd=mean_sd(ae)[1], reduction_pct=mean_sd(red)[0], paper_aekf=pa, paper_ref17=pr))
            if c != "seed001-slow":
                paired.append(dict(label=f"{c} {a}", claim="aekf below ekf", diffs=e - ae))
        for k in ("acc_rej_in", "acc_rej_out", "mag_rej_in", "mag_rej_out"):
            v = 100 * _values(sw, k, scenario=c)
            per_seed[(c, k)] = v[~np.isnan(v)]          # empty where no sample was disturbed
    return Section("001", seeds, table, runs + sw, per_seed, paired, figure=keep,
                   numbers=dict(aekf_ekf_max_diff=max_diff))


# --- 003 -----------------------------------------------------------------------------------

def _runs_003(cases, names, seeds, tick):
    """(roll-error rows, per vibration seed the share of accelerometer tones aliased below the
    IIR-EKF's cut-off, its cut-off in Hz, the first vibration run kept for the figure)."""
    runs, alias_share, keep = [], [], None
    for case in cases:
        for seed in seeds:
            s = scenarios.seed_scenario(f"seed003-{case}", seed)
            qs = {n: _run(n, s) for n in names}
            for n, q in qs.items():
                d = metrics.euler_errors(q, s.q_true)[:, DEG_ANGLES.index("roll")]
                runs.append(dict(case=case, seed=seed, estimator=n, n=s.n, var=float(d.var()), std=float(d.std())))
            cutoff = fusion.make("iir-ekf", s.fs).cutoff_hz
            if case == "vibration":
                tones = s.params["imu_constants"]["vibration_hz"][3:]          # accelerometer axes
                alias = np.abs(tones - s.fs * np.round(tones / s.fs))
                alias_share.append(float((alias < cutoff).mean()))
                if keep is None:
                    keep = (s, qs)
            tick()
    return runs, alias_share, cutoff, keep


def _measure_003(seeds, tick):
    names = ("ekf", "ukf", "iir-ekf")
    cases = ("static", "dynamic", "vibration")
    runs, alias_share, cutoff, keep = _runs_003(cases, names, seeds, tick)
    per_seed, table, paired = {}, [], []
    for c in cases:
        p = PAPER["003"][c]
        std = {n: _values(runs, "std", case=c, estimator=n) for n in names}
        per_seed.update({(c, n, "var"): _values(runs, "var", case=c, estimator=n) for n in names})
        per_seed[(c, "red_vs_ekf")] = red_e = 100 * (1 - std["iir-ekf"] / std["ekf"])
        per_seed[(c, "red_vs_ukf")] = red_u = 100 * (1 - std["iir-ekf"] / std["ukf"])
        row = dict(case=c, samples=int(_values(runs, "n", case=c, estimator="ekf")[0]))
        for n in names:
            row[f"{n}_var"], row[f"{n}_var_sd"] = mean_sd(per_seed[(c, n, "var")])
        row.update(red_vs_ekf_pct=mean_sd(red_e)[0], red_vs_ukf_pct=mean_sd(red_u)[0], paper_ekf=p["ekf"],
                   paper_ukf=p["ukf"], paper_iir=p["iir"], paper_red_vs_ekf=p["red_ekf"],
                   paper_red_vs_ukf=p["red_ukf"])
        table.append(row)
        paired.append(dict(label=c, claim="IIR-EKF roll std below the EKF's", diffs=std["ekf"] - std["iir-ekf"]))
    per_seed["alias_share_pct"] = 100 * np.array(alias_share)
    return Section("003", seeds, table, runs, per_seed, paired, figure=keep, numbers=dict(cutoff_hz=cutoff))


# --- 004 -----------------------------------------------------------------------------------

def _measure_004(seeds, tick):
    names = ("ekf", "cf-ekf")
    cases = [("seed004-static", False), ("seed004-fast", False), ("seed004-static", True)]
    # the patent's sliding mean as it sets it: 20 ms at the scenario's rate (our default has none)
    runs, keep = _euler_runs(cases, names, seeds, tick, "mpu9250",
                             params={"cf-ekf": lambda s: {"window": seed_window(s.fs)}})
    per_seed, table, paired = {}, [], []
    for c in dict.fromkeys(r["scenario"] for r in runs):
        for a in ORDER:
            row = dict(scenario=c, angle=a, claimed_pct=PAPER["004"][a])
            for k in ("RMSE", "std"):
                e, cf = (_values(runs, k, scenario=c, estimator=n, angle=a) for n in names)
                imp = 100 * (1 - cf / e)
                per_seed.update({(c, a, "ekf", k): e, (c, a, "cf-ekf", k): cf, (c, a, "improvement", k): imp})
                row.update({f"ekf_{k}": mean_sd(e)[0], f"cfekf_{k}": mean_sd(cf)[0],
                            f"improvement_{k}_pct": mean_sd(imp)[0]})
                if k == "RMSE" and not c.endswith(NO_BIAS):
                    paired.append(dict(label=f"{c} {a}", claim="cf-ekf below ekf", diffs=e - cf))
            table.append(row)
    return Section("004", seeds, table, runs, per_seed, paired, figure=keep)


# --- driver --------------------------------------------------------------------------------

_MEASURES = {"000": _measure_000, "001": _measure_001, "003": _measure_003, "004": _measure_004}
UNITS = {"000": 2, "001": 3, "003": 3, "004": 3}        # scenario runs per seed (progress bar)


def measure(key, seeds=SEEDS, tick=lambda: None):
    """Run section ``key`` (one of ``SECTIONS``) over ``seeds``: a ``Section`` of numbers;
    ``tick()`` is called after each scenario run."""
    if key not in _MEASURES:
        raise ValueError(f"unknown section {key!r}; available: {', '.join(_MEASURES)}")
    seeds = tuple(seeds)
    if not seeds or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seeds):
        raise ValueError(f"seeds must be a non-empty sequence of integers >= 0, got {seeds!r}")
    return _MEASURES[key](seeds, tick)
