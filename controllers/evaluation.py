"""Closed-loop evaluation of a controller in the spherical-robot environment, and the
statistics of the comparison.

``evaluate(controller, env_kwargs, episodes, seed)`` runs ``episodes`` episodes (episode
``i`` reset with ``seed + i``) and scores them on the *true* state, whatever the controller
saw. Metrics per episode (``EPISODE_METRICS``; defined in docs/envs/sphere_bot_track.md and
sphere_bot_waypoints.md, "Metrics"):

- ``return``: the environment's reward summed over the episode;
- track: ``heading_ss`` and ``speed_ss`` (deg, m/s): rms of the true heading's and forward
  speed's error against the command, over the samples at least ``SETTLE_WINDOW_S`` after
  each command change (steady state: what a heading or tilt bias of the estimator moves);
  ``settle_time`` (s): per command, the time after which the heading error stays within
  ``SETTLE_BAND_DEG``, averaged over the commands held to their end (a command that never
  settles counts its whole duration); ``heading_rmse`` and ``speed_rmse``: over every sample
  after the first 2 s (turn transients included);
- waypoints: ``success`` (0/1: every waypoint reached before the time-out),
  ``time_to_goal`` (s; NaN when not reached), ``waypoints_reached``, ``cross_track`` (m: rms
  distance of the true position from the target path, the straight segment from the
  previous waypoint, or the start, to the current one);
- ``effort``: mean of drive^2 + steer^2 (action units);
- ``attitude_error`` (deg): rms of the estimator's total attitude error during the run;
- ``tilt_error`` (deg): rms of its inclination error (the tilt of the estimated vertical,
  heading left out; ``fusion.metrics.attitude_errors``' inclination): what an accelerometer
  disturbance such as drive vibration moves, hidden in ``attitude_error`` by the heading;
- ``heading_est_error`` (deg): rms of the estimated heading's error during the run.

``steps`` (not a metric: in the episode CSV) is the episode's length in control steps: an
episode that left the arena or got stuck is shorter, and its metrics cover that shorter run.

Statistics (``interval``, ``paired_difference``): success rates with Wilson score intervals
and paired differences by Newcombe's method 10 for paired proportions; continuous metrics
with expanded percentile bootstrap intervals (seeded, stratified when strata are given) of the mean
and of the interquartile mean (the robust aggregate of "Deep reinforcement learning at the
edge of the statistical precipice"), paired differences by bootstrap over the shared seeds.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from fusion.checks import integer

if TYPE_CHECKING:
    from controllers.base import Controller

__all__ = ["evaluate", "run_episode", "aggregate", "interval", "paired_difference", "wilson",
           "newcombe_paired", "bootstrap_ci", "iqm", "EPISODE_METRICS", "MIN_BOOT", "MAIN_METRIC", "BINARY_METRICS",
           "SETTLE_WINDOW_S", "SETTLE_BAND_DEG", "MIN_TAIL", "N_BOOT"]

EPISODE_METRICS = {
    "track": ("return", "heading_ss", "speed_ss", "settle_time", "heading_rmse", "speed_rmse", "effort",
              "attitude_error", "tilt_error", "heading_est_error"),
    "waypoints": ("return", "success", "time_to_goal", "waypoints_reached", "cross_track", "effort",
                  "attitude_error", "tilt_error", "heading_est_error"),
}
#: the metric each task is judged on, and whether larger is better
MAIN_METRIC = {"track": ("heading_ss", False), "waypoints": ("success", True)}
#: 0/1 metrics (Wilson / Newcombe intervals); the others are continuous (bootstrap)
BINARY_METRICS = ("success",)
#: (s) steady state: samples at least this long after a command change. The largest turn
#: (180 deg at the start) takes the PID about 3.2 s under truth, a 90 deg turn 2.4-2.8 s.
SETTLE_WINDOW_S = 3.0
#: (deg) the heading error band of the settling time
SETTLE_BAND_DEG = 10.0
Z95 = 1.959963984540054
N_BOOT = 2000
#: resamples beyond each end of a bootstrap interval at the least: an interval at a small
#: tail probability (a Bonferroni-adjusted 99.4 %, expanded to about 99.7 % at n = 30) from
#: N_BOOT resamples rests on 3 of them at each end, and whether it excluded 0 changed with the
#: bootstrap's seed (22 of 40 seeds starred one cell); bootstrap_ci draws enough for this many
MIN_TAIL = 100
#: the most resamples bootstrap_ci draws (in chunks of N_BOOT_CHUNK): a Bonferroni level
#: expanded at the fewest episodes (MIN_BOOT) would ask for over 10^8 for MIN_TAIL
N_BOOT_MAX = 200_000
N_BOOT_CHUNK = 20_000
#: the fewest values from which a bootstrap interval is given (NaN below): with fewer, the
#: expanded percentile interval is the data's range, which covers a normal mean 74 % of the
#: time at 3 values and 88 % at 4 (simulated), and a paired difference's excludes 0 whenever
#: all n differences share a sign, probability 2^(1-n) under no difference; 6 is the first n
#: where that is <= 5 % (coverage 94 % there)
MIN_BOOT = 6


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _segment_distance(p, a, b):
    ab = b - a
    L2 = float(ab @ ab)
    t = 0.0 if L2 == 0 else min(1.0, max(0.0, float((p - a) @ ab) / L2))
    return float(np.linalg.norm(p - (a + t * ab)))


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")


def _track_metrics(log, dt):
    """Steady-state errors and settling time from the per-step (command index, heading
    error deg, speed error m/s) of a track episode; the last command counts for the
    settling time only if it was held to its end (commands change every 3-8 s)."""
    cmd = np.array([r[0] for r in log])
    he = np.array([r[1] for r in log])
    se = np.array([r[2] for r in log])
    starts = np.r_[0, np.nonzero(np.diff(cmd))[0] + 1]
    ends = np.r_[starts[1:], len(cmd)]
    ss_h, ss_v, settle = [], [], []
    window = int(round(SETTLE_WINDOW_S / dt))
    for i, (a, b) in enumerate(zip(starts, ends)):
        ss_h.append(he[a + window:b])
        ss_v.append(se[a + window:b])
        if i == len(starts) - 1 and (b - a) * dt < 3.0 - 1e-9:
            continue                       # cut short by the episode's end
        out = np.nonzero(np.abs(he[a:b]) >= SETTLE_BAND_DEG)[0]
        if len(out) == 0:
            settle.append(0.0)
        elif out[-1] == b - a - 1:
            settle.append((b - a) * dt)    # never settled: its whole duration
        else:
            settle.append((out[-1] + 1) * dt)
    return {"heading_ss": _rms(np.concatenate(ss_h)), "speed_ss": _rms(np.concatenate(ss_v)),
            "settle_time": float(np.mean(settle)) if settle else float("nan")}


def _inclination_deg(qe, qt):
    """The inclination error (deg) of estimate ``qe`` against truth ``qt`` ([w, x, y, z]):
    ``2 atan2(hypot(e_x, e_y), hypot(e_w, e_z))`` of ``e = qe conj(qt)``, as
    ``fusion.metrics.attitude_errors`` (one sample, without arrays)."""
    aw, ax, ay, az = qe
    bw, bx, by, bz = qt[0], -qt[1], -qt[2], -qt[3]
    ew = aw * bw - ax * bx - ay * by - az * bz
    ex = aw * bx + ax * bw + ay * bz - az * by
    ey = aw * by - ax * bz + ay * bw + az * bx
    ez = aw * bz + ax * by - ay * bx + az * bw
    return math.degrees(2.0 * math.atan2(math.hypot(ex, ey), math.hypot(ew, ez)))


def _track_errors(info):
    """(heading error (deg), forward speed error (m/s)) of the true state against the command."""
    vc, hc = info["command"]
    psi = info["heading_true"]
    v = info["velocity"]
    return math.degrees(_wrap(psi - hc)), v[0] * math.cos(psi) + v[1] * math.sin(psi) - vc


def run_episode(controller: Controller, env: Any, seed: int, settle_s: float = 2.0,
                record_path: bool = False) -> dict[str, Any]:
    """One episode of ``controller`` in ``env`` (reset with ``seed``); returns a dict of the
    metrics of ``EPISODE_METRICS[task]`` (plus ``path`` and ``waypoints`` if asked).
    ``settle_s``: the start from rest left out of ``heading_rmse`` and ``speed_rmse``."""
    from envs.base import heading_of
    base = env.unwrapped
    task = base.task
    obs, info = env.reset(seed=seed)
    controller.reset()
    start = np.array(info["position"][:2])
    ret = 0.0
    sp, hd, eff, att, tilt, hest, xt, path, tlog = [], [], [], [], [], [], [], [], []
    settle = int(round(settle_s * base.control_hz))
    k = 0
    cmd_i, last_cmd = -1, None
    while True:
        a = np.asarray(controller.act(obs), dtype=np.float64)
        obs, r, terminated, truncated, info = env.step(a)
        ret += r
        k += 1
        a = np.clip(a, -1.0, 1.0)
        eff.append(float(a @ a))
        att.append(info["attitude_error_deg"])
        tilt.append(_inclination_deg(info["q_est"], info["q_true"]))
        # against the truth at the estimate's sample, as attitude_error (the physics step's
        # heading_true is up to an IMU period later: 0.06 deg rms under truth)
        hest.append(math.degrees(_wrap(info["heading_est"] - heading_of(*info["q_true"]))))
        pos = np.asarray(info["position"][:2])
        if record_path:
            path.append(pos.copy())
        if task == "track":
            if info["command"] != last_cmd:
                cmd_i, last_cmd = cmd_i + 1, info["command"]
            e_h, e_v = _track_errors(info)
            tlog.append((cmd_i, e_h, e_v))
            if k > settle:
                sp.append(e_v)
                hd.append(e_h)
        else:
            i = info["waypoint_index"]
            wps = base._waypoints
            prev = start if i == 0 else wps[i - 1]
            xt.append(_segment_distance(pos, prev, wps[i]))
        if terminated or truncated:
            break
    out = {"return": float(ret), "effort": float(np.mean(eff)), "attitude_error": _rms(att),
           "tilt_error": _rms(tilt), "heading_est_error": _rms(hest), "steps": k}
    if task == "track":
        out.update(speed_rmse=_rms(sp), heading_rmse=_rms(hd), **_track_metrics(tlog, 1.0 / base.control_hz))
    else:
        ok = bool(info.get("goal_reached", False))
        reached = info["waypoint_index"] + (1 if ok else 0)
        out.update(success=float(ok), time_to_goal=float(info["t"]) if ok else float("nan"),
                   waypoints_reached=float(reached), cross_track=_rms(xt))
    if record_path:
        out["path"] = np.array(path)
        out["start"] = start
        out["waypoints"] = base._waypoints.copy() if task == "waypoints" else None
    return out


def evaluate(controller: Controller, env_kwargs: dict[str, Any] | None = None, episodes: int = 10, seed: int = 0,
             record_path: bool = False, env: Any = None) -> dict[str, Any]:
    """Run ``controller`` for ``episodes`` episodes of ``SphereRobotEnv(**env_kwargs)``
    (or of ``env`` if given), episode ``i`` seeded ``seed + i``. Returns
    ``{"episodes": [per-episode dicts], "summary": aggregate(...)}``."""
    episodes = integer("episodes", episodes, 1)
    seed = integer("seed", seed, 0)
    own = env is None
    if own:
        from envs.sphere import SphereRobotEnv
        env = SphereRobotEnv(**dict(env_kwargs or {}))
    try:
        eps = [run_episode(controller, env, seed + i, record_path=record_path) for i in range(episodes)]
    finally:
        if own:
            env.close()
    return {"episodes": eps, "summary": aggregate(eps, env.unwrapped.task)}


def aggregate(episodes: Sequence[dict[str, Any]], task: str, seed: int = 0) -> dict[str, dict[str, float]]:
    """Per metric of ``EPISODE_METRICS[task]``: ``interval`` of its finite values (mean,
    lo, hi, iqm, iqm_lo, iqm_hi, n) plus the standard deviation ``std``."""
    out = {}
    for m in EPISODE_METRICS[task]:
        v = np.array([e[m] for e in episodes], dtype=float)
        v = v[np.isfinite(v)]
        out[m] = interval(v, m, seed=seed)
        out[m]["std"] = float(v.std(ddof=1)) if len(v) > 1 else float("nan")
    return out


# ----------------------------------------------------------------------------------------
# statistics

def wilson(k: float, n: int, z: float = Z95) -> tuple[float, float, float]:
    """Wilson score interval of a proportion: (k / n, lo, hi), inside [0, 1]."""
    if n <= 0:
        return float("nan"), float("nan"), float("nan")
    p = k / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    # the bounds are exactly 0 at k = 0 and 1 at k = n; rounding must not move them past p
    lo = 0.0 if k <= 0 else max(0.0, min(p, centre - half))
    hi = 1.0 if k >= n else min(1.0, max(p, centre + half))
    return p, lo, hi


def newcombe_paired(x: ArrayLike, y: ArrayLike, z: float = Z95) -> tuple[float, float, float]:
    """Difference mean(x) - mean(y) of paired 0/1 outcomes and its interval by Newcombe's
    method 10 ("Improved confidence intervals for the difference between binomial
    proportions based on paired data", 1998; the "square-and-add" interval of Fagerland et
    al.'s "Statistical analysis of contingency tables"): the Wilson intervals of both
    proportions combined with the corrected phi correlation of the pairs. Inside [-1, 1]."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = len(x)
    if n == 0:
        return float("nan"), float("nan"), float("nan")
    a = float(np.sum((x == 1) & (y == 1)))
    b = float(np.sum((x == 1) & (y == 0)))
    c = float(np.sum((x == 0) & (y == 1)))
    d = float(n - a - b - c)
    p1, l1, u1 = wilson(a + b, n, z)
    p2, l2, u2 = wilson(a + c, n, z)
    den = (a + b) * (c + d) * (a + c) * (b + d)
    # the correlation of the pairs, corrected towards 0 when positive (Newcombe's phi)
    ad_bc = a * d - b * c
    num = ad_bc - n / 2 if ad_bc > n / 2 else (ad_bc if ad_bc < 0 else 0.0)
    phi = num / math.sqrt(den) if den > 0 else 0.0
    D = p1 - p2
    dl = math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    du = math.sqrt(max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    return D, max(-1.0, D - dl), min(1.0, D + du)


def iqm(x: Any, axis: int = -1) -> Any:
    """Interquartile mean: the mean of the middle 50 % (scipy's trim_mean, 25 % cut each side)."""
    from scipy.stats import trim_mean
    return trim_mean(x, 0.25, axis=axis)


def _expanded_level(n, level):
    """The percentile level of the expanded percentile bootstrap (Hesterberg, "What teachers
    should know about the bootstrap", 2015): the plain percentile interval is too narrow by
    about sqrt((n - 1) / n) and by t against z; widened so that z_a = sqrt(n / (n - 1)) t_{n-1}.
    Measured: a paired difference of no effect excluded 0 in 11.5 % of runs at n = 8 with the
    plain interval, 6.5 % with the expanded one."""
    if n < 2:
        return level
    from scipy.stats import norm, t
    return 1.0 - 2.0 * norm.sf(math.sqrt(n / (n - 1)) * t.ppf((1 + level) / 2, n - 1))


def bootstrap_ci(values: Any, stat: Callable[..., Any] = np.mean, strata: Sequence[Any] | None = None,
                 n_boot: int = N_BOOT, seed: int = 0, level: float = 0.95) -> tuple[float, float]:
    """Expanded percentile bootstrap interval (lo, hi) of ``stat`` of ``values`` (1-D) at
    ``level`` (``_expanded_level``) from ``n_boot`` resamples, more where needed to leave
    MIN_TAIL of them beyond each end (at most N_BOOT_MAX), resampling with replacement within each stratum
    (``strata``: a label per value; None: one stratum), seeded. ``stat`` takes an
    (n_boot, n) array and ``axis=1``. A percentile interval of a mean or an IQM stays within
    the values' range. Fewer than ``MIN_BOOT`` values: (NaN, NaN)."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    if n < MIN_BOOT:        # no interval that would claim its level (one value: not [v, v])
        return float("nan"), float("nan")
    level = _expanded_level(n, level)
    gap = 1.0 - level
    n_boot = min(N_BOOT_MAX, max(n_boot, math.ceil(2 * MIN_TAIL / gap) if gap > 0 else N_BOOT_MAX))
    rng = np.random.default_rng(seed)
    labels = None
    if strata is not None:
        labels = np.asarray(strata)
        if labels.shape != (n,):
            raise ValueError(f"strata must have one label per value ({n}), got shape {labels.shape}")
        groups = [np.nonzero(labels == lab)[0] for lab in sorted(set(labels.tolist()), key=str)]
    boots = []
    for start in range(0, n_boot, N_BOOT_CHUNK):
        m = min(N_BOOT_CHUNK, n_boot - start)
        if labels is None:
            idx = rng.integers(0, n, size=(m, n))
        else:
            idx = np.concatenate([g[rng.integers(0, len(g), size=(m, len(g)))] for g in groups], axis=1)
        boots.append(stat(v[idx], axis=1))
    lo, hi = np.quantile(np.concatenate(boots), [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def interval(values: Any, metric: str, seed: int = 0) -> dict[str, float]:
    """The cell statistics of one metric's finite values: dict of mean, lo, hi (95 %:
    Wilson for a 0/1 metric, bootstrap otherwise), iqm, iqm_lo, iqm_hi (NaN for 0/1) and n."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    nan = float("nan")
    if n == 0:
        return {"mean": nan, "lo": nan, "hi": nan, "iqm": nan, "iqm_lo": nan, "iqm_hi": nan, "n": 0}
    if metric in BINARY_METRICS:
        p, lo, hi = wilson(float(v.sum()), n)
        return {"mean": p, "lo": lo, "hi": hi, "iqm": nan, "iqm_lo": nan, "iqm_hi": nan, "n": n}
    lo, hi = bootstrap_ci(v, np.mean, seed=seed)
    ilo, ihi = bootstrap_ci(v, iqm, seed=seed)
    return {"mean": float(v.mean()), "lo": lo, "hi": hi, "iqm": float(iqm(v)), "iqm_lo": ilo, "iqm_hi": ihi, "n": n}


def paired_difference(x: Any, y: Any, metric: str, seed: int = 0, level: float = 0.95) -> dict[str, float]:
    """mean(x - y) over the pairs where both are finite (the same episode seed under two
    estimators), with its interval at ``level``: Newcombe's paired method for a 0/1 metric,
    a bootstrap of the pairs otherwise. Returns dict of delta, lo, hi, n."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.shape != y.shape:
        raise ValueError(f"x and y must be paired (same shape), got {x.shape} and {y.shape}")
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = len(x)
    if n == 0:
        return {"delta": float("nan"), "lo": float("nan"), "hi": float("nan"), "n": 0}
    if metric in BINARY_METRICS:
        from scipy.stats import norm
        d, lo, hi = newcombe_paired(x, y, z=float(norm.isf((1 - level) / 2)))
    else:
        diff = x - y
        d = float(diff.mean())
        lo, hi = bootstrap_ci(diff, np.mean, seed=seed, level=level)
    return {"delta": d, "lo": lo, "hi": hi, "n": n}
