"""Glitches (docs/robustness.md): a saturated gyro, samples that drop out (invalid rows
skipped with on_invalid="skip") and a gap in time (one long dt). Every estimator that
corrects its attitude recovers its inclination to within 2 degrees within the documented
time after the glitch ends; the table of measured times is in docs/robustness.md."""
import numpy as np
import pytest

import fusion
from fusion.scenarios import make_scenario

FS = 100.0
START, LENGTH = 30.0, 1.0           # the glitch: from 30 s, 1 s long
TOL_DEG = 2.0
# documented bound on the recovery time (s), every case not in SLOW (measured at most
# 19.4 s: docs/robustness.md)
RECOVERY_S = 25.0
NAMES = [n for n in fusion.available() if n != "gyro"]     # gyro never corrects: no recovery
# The EKF family with its robust magnetometer option (docs/robustness.md): with the default
# 3-D update (seed 003) a large heading error after a glitch tilts the estimate for good.
PARAMS = {n: {"mag_update": "heading"} for n in ("ekf", "iir-ekf", "aekf")}
# Known failures (docs/robustness.md): a saturated gyro is not detected without gyro_range,
# and the EKF family keeps a tilt error above 2 deg long after it at its default tuning.
# Dropouts and gaps are recovered by the covariance growth of docs/robustness.md,
# "Recovery", and with a magnetometer by the heading-only update.
SLOW = {(n, "saturated gyro", m) for n in ("ekf", "ukf", "aekf") for m in (9, 6)}
SLOW |= {("iir-ekf", k, m) for n, k, m in SLOW if n == "ekf"}


def inclination_deg(q, q_true):
    w1, x1, y1, z1 = q.T
    w2, x2, y2, z2 = (q_true * [1, -1, -1, -1]).T
    e = np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                  w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)
    return np.degrees(2 * np.arctan2(np.hypot(e[:, 1], e[:, 2]), np.hypot(e[:, 0], e[:, 3])))


def glitched(kind, seed=2):
    """(gyr, acc, mag, dt, q_true, index of the first sample after the glitch)."""
    sc = make_scenario("mixed", fs=FS, duration=90.0, seed=seed)
    gyr, acc, mag, q = sc.gyr.copy(), sc.acc.copy(), sc.mag.copy(), sc.q_true
    dt = np.full(len(gyr), 1 / FS)
    i0, i1 = int(START * FS), int((START + LENGTH) * FS)
    if kind == "saturated gyro":     # a +-250 deg/s part at 0.25 of its range: rails for 1 s
        gyr[i0:i1] = np.clip(gyr[i0:i1], -0.3, 0.3)
    elif kind == "dropout":          # every sensor invalid for 1 s
        gyr[i0:i1] = np.nan
        acc[i0:i1] = np.nan
        mag[i0:i1] = np.nan
    elif kind == "time gap":         # 1 s without samples: the next one comes with a long dt
        keep = np.r_[0:i0, i1:len(gyr)]
        dt[i1] = LENGTH + 1 / FS
        return gyr[keep], acc[keep], mag[keep], dt[keep], q[keep], i0 + 1
    return gyr, acc, mag, dt, q, i1


def recovery_time(name, kind, nine_axis):
    """Seconds after the glitch until the inclination error stays below TOL_DEG (inf if it
    never does), and the error just before the glitch."""
    gyr, acc, mag, dt, q_true, after = glitched(kind)
    est = fusion.make(name, FS, on_invalid="skip", **PARAMS.get(name, {}))
    est.reset(q_true[0])
    q = est.run(gyr, acc, mag if nine_axis else None, dt=dt)
    err = inclination_deg(q, q_true)
    before = err[int((START - 1) * FS):int(START * FS)].max()
    bad = np.flatnonzero(err[after:] >= TOL_DEG)
    t = 0.0 if bad.size == 0 else (bad[-1] + 1) / FS
    return (np.inf if bad.size and bad[-1] == len(err) - after - 1 else t), before


CASES = [pytest.param(n, k, m, marks=pytest.mark.xfail(
    strict=True, reason="does not recover at default tuning (docs/robustness.md)"))
    if (n, k, m) in SLOW else (n, k, m)
    for n in NAMES for k in ("saturated gyro", "dropout", "time gap") for m in (9, 6)]


@pytest.mark.parametrize("name, kind, axes", CASES)
def test_recovers_within_the_documented_time(name, kind, axes):
    t, before = recovery_time(name, kind, axes == 9)
    assert before < TOL_DEG          # converged before the glitch
    assert t <= RECOVERY_S, (name, kind, axes, t)


def test_the_glitches_do_disturb():
    """The glitches are real: the gyro alone is left off by more than the tolerance."""
    for kind in ("saturated gyro", "time gap"):
        t, _ = recovery_time("gyro", kind, True)
        assert t == np.inf


if __name__ == "__main__":       # the table of docs/robustness.md
    print("| estimator | " + " | ".join(f"{k} 9-axis | {k} 6-axis" for k in ("saturated gyro", "dropout", "time gap")) + " |")
    for name in fusion.available():
        cells = []
        for kind in ("saturated gyro", "dropout", "time gap"):
            for nine in (True, False):
                t, before = recovery_time(name, kind, nine)
                cells.append("never" if np.isinf(t) else f"{t:.2f}")
        label = name + "".join(f", {k}={v!r}" for k, v in PARAMS.get(name, {}).items())
        print(f"| {label} | " + " | ".join(cells) + " |")
