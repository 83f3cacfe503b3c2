"""Helpers shared by the test modules (imported as ``from _helpers import ...``; fixtures are
in conftest.py). The synthetic run, the invalid-sample injection and the comparisons against
the numpy references of reference.py."""
import numpy as np
from hypothesis import HealthCheck

import reference as ref
from fusion.constants import GRAVITY as G

FS = 100.0
N = 10_000          # the main runs
TOL = 1e-9
GYRO_BIAS = np.array([0.01, -0.02, 0.015])
FIELD = np.array([0.0, 0.4, -0.3])     # ENU, dip 36.9 deg, times MAG_SCALE

# hypothesis settings of the property tests
SETTINGS = dict(deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


# --- synthetic data -----------------------------------------------------------------------

def integrate_rates(w, fs, q0=(0.9, 0.1, -0.3, 0.2)):
    """The attitude of body rates ``w`` ((n, 3), rad/s) at ``fs``: exact per-sample rotation
    increments chained from ``q0`` (normalised)."""
    th = np.linalg.norm(w, axis=1) / fs
    axis = w / np.maximum(np.linalg.norm(w, axis=1), 1e-300)[:, None]
    dq = np.column_stack([np.cos(th / 2), np.sin(th / 2)[:, None] * axis])
    q = np.empty((len(w), 4))
    qk = ref.normalise(np.array(q0, dtype=float))
    for i in range(len(w)):
        qk = ref.qmul(qk, dq[i])
        q[i] = qk
    return q


def synthetic(n=N, fs=FS, seed=11, mag_scale=50.0):
    """Noisy readings of a body turning with a smooth rate (peaks of a few rad/s).

    Returns (q_true, gyr, acc, mag). The true attitude is integrated exactly for a rate held
    over each sample interval; gyro = rate + constant bias + noise; accelerometer =
    R^T [0, 0, 9.81] + linear-acceleration bursts + noise; magnetometer = R^T FIELD * scale + noise.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    w = np.zeros((n, 3))
    for k in range(3):                       # slow sinusoids
        for _ in range(4):
            w[:, k] += rng.uniform(0.2, 1.0) * np.sin(2 * np.pi * rng.uniform(0.02, 0.5) * t
                                                      + rng.uniform(0, 2 * np.pi))
    for c in rng.uniform(0.05, 0.95, 8) * t[-1]:       # bursts of fast turning
        w += np.exp(-0.5 * ((t - c) / 0.3) ** 2)[:, None] * rng.uniform(-3, 3, 3)
    q = integrate_rates(w, fs)
    # R(q)^T v for all rows at once
    Rt = np.stack([ref.rotmat(qi).T for qi in q])
    lin = np.zeros((n, 3))
    for c in rng.uniform(0.05, 0.95, 12) * t[-1]:      # linear-acceleration bursts
        lin += np.exp(-0.5 * ((t - c) / 0.2) ** 2)[:, None] * rng.uniform(-5, 5, 3)
    acc = Rt @ np.array([0.0, 0.0, ref.G]) + lin + 0.05 * rng.standard_normal((n, 3))
    mag = (Rt @ FIELD) * mag_scale + 0.5 * rng.standard_normal((n, 3))
    gyr = w + GYRO_BIAS + 0.005 * rng.standard_normal((n, 3))
    return q, gyr, acc, mag


def qdiff(qk, qr):
    """Max abs difference over all quaternion components (no sign alignment: the spec fixes
    the sign, w >= 0 at initialisation and then as propagated)."""
    d = np.abs(np.asarray(qk) - np.asarray(qr)).max(initial=0.0)
    if d > TOL:     # say whether it is only the sign
        s = np.sign(np.sum(qk * qr, axis=-1, keepdims=True))
        d_aligned = np.abs(qk - s * qr).max()
        print(f"quaternions differ by {d:.3g}; after sign alignment {d_aligned:.3g}")
    return d


def compare_state(est, r, rel_cov=TOL):
    """Final euler, bias and covariance of kernel `est` and reference `r`."""
    assert np.abs(est.quaternion - r.quaternion).max() < TOL
    # euler: wrap the difference (yaw/roll near ±pi)
    de = np.angle(np.exp(1j * (est.euler - r.euler)))
    assert np.abs(de).max() < TOL
    if r.bias is None:
        assert est.bias is None
    else:
        assert np.abs(est.bias - r.bias).max() < TOL
    if r.covariance is None:
        assert est.covariance is None
    else:
        P, Pr = est.covariance, r.covariance
        assert P.shape == (7, 7)
        assert np.abs(P - Pr).max() < rel_cov * np.abs(Pr).max()


def inject_invalid(gyr, acc, mag):
    """Copies (of 2000 samples) with NaN / inf / all-zero rows, also before the first valid
    accelerometer."""
    gyr, acc, mag = gyr[:2000].copy(), acc[:2000].copy(), mag[:2000].copy()
    acc[0:4] = np.nan                 # not initialised until row 4
    acc[[7, 300, 301]] = 0.0
    acc[[450, 1700]] = [np.inf, 0, 0]
    gyr[1] = np.nan                   # invalid gyro before initialisation
    gyr[[5, 120, 121, 122, 1900]] = np.nan
    gyr[900] = [0.0, -np.inf, 1.0]
    gyr[[60, 61]] = 0.0               # zero rate: valid
    mag[2] = 0.0                      # invalid magnetometer before initialisation
    mag[[4, 250, 800, 801, 1999]] = np.nan   # row 4: initialisation without magnetometer
    mag[1100] = 0.0
    acc[[500, 1500]] = np.nan         # both invalid in the same sample
    mag[[500, 1500]] = 0.0
    gyr[1500] = np.nan
    return gyr, acc, mag


def count_invalid(gyr, acc, mag):
    """What est.skipped must hold: every invalid vector (gyro: non-finite; acc/mag: non-finite
    or all zero), the samples before initialisation included."""
    bad_g = ~np.isfinite(gyr).all(axis=1)
    bad_a = ~np.isfinite(acc).all(axis=1) | ~acc.any(axis=1)
    bad_m = ~np.isfinite(mag).all(axis=1) | ~mag.any(axis=1)
    return {"gyr": int(bad_g.sum()), "acc": int(bad_a.sum()), "mag": int(bad_m.sum())}


def check_uneven_dt(est, r, gyr, acc, mag, compare=compare_state):
    """A kernel against its reference over uneven steps (2-30 ms, a fixed draw)."""
    dt = np.random.default_rng(5).uniform(0.002, 0.03, len(gyr))
    assert qdiff(est.run(gyr, acc, mag, dt=dt), r.run(gyr, acc, mag, dt=dt)) < TOL
    compare(est, r)


def check_ned_and_given_start(est, r, gyr, acc, mag, n6, compare=compare_state):
    """A NED kernel ``est`` against its NED reference ``r``: the run, then a start attitude
    given in NED and ``n6`` samples 6-axis."""
    assert qdiff(est.run(gyr, acc, mag), r.run(gyr, acc, mag)) < TOL
    compare(est, r)
    q0 = ref.normalise(np.array([0.3, -0.5, 0.2, 0.7]))
    est.reset(q0)
    r.reset(q0)
    assert np.abs(est.quaternion - q0).max() < 1e-15
    assert qdiff(est.run(gyr[:n6], acc[:n6]), r.run(gyr[:n6], acc[:n6])) < TOL
    compare(est, r)


def check_skipped(est, r, gyr, acc, mag, frame, compare=compare_state):
    """A kernel and its reference, both on_invalid="skip", over samples with invalid rows: the
    same output, the same counts of skipped updates, the identity (in ``frame``) until the
    first valid sample. Returns the kernel's output."""
    expected = count_invalid(gyr, acc, mag)
    q, qr = est.run(gyr, acc, mag), r.run(gyr, acc, mag)
    assert qdiff(q, qr) < TOL
    compare(est, r)
    assert est.skipped == r.skipped == expected
    identity = ref.C_NED if frame == "NED" else ref.IDENTITY
    assert np.array_equal(q[:4], np.tile(identity, (4, 1)))
    return q


def bad_message(exc):
    assert isinstance(exc, ValueError) and len(str(exc)) > 10, repr(exc)


def check_output(est, q, n):
    assert q.shape == (n, 4)
    assert np.isfinite(q).all()
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max(initial=0.0) < 1e-9
    P = est.covariance
    if P is not None:
        assert np.isfinite(P).all()
        assert np.array_equal(P, P.T) or np.abs(P - P.T).max() <= 1e-12 * np.abs(P).max()
        assert np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0.0


def recovery_data(data, n=2000):
    """Saturated samples (at 0.5 rad/s), a run of dropped samples and a time gap."""
    _, gyr, acc, mag = data
    gyr, acc, mag = gyr[:n].copy(), acc[:n].copy(), mag[:n]
    gyr[300:350] = np.clip(gyr[300:350], -0.5, 0.5)
    gyr[800:850] = np.nan
    acc[800:850] = np.nan
    dt = np.full(n, 1 / FS)
    dt[1200] = 0.7
    return gyr, acc, mag, dt


def rest_data(data, n_still=400, n=2000):
    """The synthetic run, its first n_still samples replaced by a still sensor (gyro = bias
    + noise, level accelerometer and constant field + noise), and a still spell in the middle."""
    _, gyr, acc, mag = (x[:n].copy() for x in data)
    rng = np.random.default_rng(8)
    for a, b in ((0, n_still), (1200, 1800)):
        gyr[a:b] = GYRO_BIAS + 0.005 * rng.standard_normal((b - a, 3))
        acc[a:b] = acc[a] + 0.05 * rng.standard_normal((b - a, 3))
        mag[a:b] = mag[a] + 0.5 * rng.standard_normal((b - a, 3))
    return gyr, acc, mag


# --- bodies and errors of the analytic tests (tests/test_estimators.py and others) -----------

MAG_N = np.array([0.0, 0.22, -0.42])   # a northern-hemisphere field in ENU (dip about 62 deg)


def qmul(p, q):
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def qconj(q):
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def to_body(q, v):
    """R(q)^T v for unit quaternions q (..., 4)."""
    qv = np.concatenate([np.zeros(q.shape[:-1] + (1,)), np.broadcast_to(v, q.shape[:-1] + (3,))], -1)
    return qmul(qmul(qconj(q), qv), q)[..., 1:]


def axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def inclination(p, q):
    """Inclination part of the rotation between attitudes (rad), per row."""
    e = qmul(p, qconj(q))
    return 2 * np.arctan2(np.hypot(e[..., 1], e[..., 2]), np.hypot(e[..., 0], e[..., 3]))


def static_body(q, n, seed=0, noise=(0.0, 0.0, 0.0), bias=(0, 0, 0)):
    rng = np.random.default_rng(seed)
    gyr = np.asarray(bias, float) + noise[0] * rng.standard_normal((n, 3))
    acc = to_body(q, [0, 0, G]) + noise[1] * rng.standard_normal((n, 3))
    mag = to_body(q, MAG_N) + noise[2] * rng.standard_normal((n, 3))
    return gyr, acc, mag


# --- the aekf's scene: bursts of linear acceleration and a magnetic disturbance ------------

MAG_SCALE = 50.0
DISTURBANCE = (40.0, 55.0)              # s: a ferrous object near the sensor


def hann_bursts(rng, t, centres, dur_range, amp):
    """Sum of Hann-windowed bursts (navigation frame), each with a random constant vector."""
    out = np.zeros((len(t), 3))
    active = np.zeros(len(t), bool)
    for c in centres:
        d = rng.uniform(*dur_range)
        x = (t - c) / d + 0.5
        inside = (x > 0) & (x < 1)
        out[inside] += np.sin(np.pi * x[inside])[:, None] ** 2 * rng.uniform(-amp, amp, 3)
        active |= inside
    return out, active


def scenario(n=N, fs=FS, seed=21, turn=1.0, burst_amp=6.0, n_bursts=14, disturb=DISTURBANCE,
             disturb_field=(0.3, 0.1, 0.1), acc_noise=0.05, mag_noise=0.5):
    """A turning body with linear-acceleration bursts and a magnetic disturbance episode.

    Returns (q_true, gyr, acc, mag, burst, dist): readings as in _helpers.synthetic
    (exact attitude, gyro = rate + bias + noise) with Hann bursts of linear acceleration up to
    burst_amp per axis, 0.5-2.5 s long, and from disturb[0] to disturb[1] s a disturbing field
    disturb_field * MAG_SCALE (navigation frame, ramped in and out over 1 s) added to the
    earth's; burst / dist: boolean masks of the samples concerned.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    w = np.zeros((n, 3))
    for k in range(3):
        for _ in range(3):
            w[:, k] += turn * rng.uniform(0.1, 0.5) * np.sin(2 * np.pi * rng.uniform(0.02, 0.3) * t
                                                            + rng.uniform(0, 2 * np.pi))
    q = integrate_rates(w, fs)
    Rt = np.stack([ref.rotmat(qi).T for qi in q])
    centres = np.sort(rng.uniform(0.03, 0.97, n_bursts)) * t[-1]
    lin, burst = hann_bursts(rng, t, centres, (0.5, 2.5), burst_amp)
    d = np.zeros((n, 3))
    dist = np.zeros(n, bool)
    if disturb is not None:
        ramp = np.clip(np.minimum(t - disturb[0], disturb[1] - t), 0.0, 1.0)
        d = ramp[:, None] * np.asarray(disturb_field) * MAG_SCALE
        dist = ramp > 0
    acc = np.einsum("nij,nj->ni", Rt, np.array([0.0, 0.0, ref.G]) + lin) + acc_noise * rng.standard_normal((n, 3))
    mag = np.einsum("nij,nj->ni", Rt, FIELD * MAG_SCALE + d) + mag_noise * rng.standard_normal((n, 3))
    gyr = w + GYRO_BIAS + 0.005 * rng.standard_normal((n, 3))
    return q, gyr, acc, mag, burst, dist


def errors_deg(q, q_true):
    """(inclination, heading) errors per sample, degrees (earth-frame error quaternion)."""
    e = np.array([ref.qmul(a, ref.qconj(b)) for a, b in zip(q, q_true)])
    incl = 2 * np.arctan2(np.hypot(e[:, 1], e[:, 2]), np.hypot(e[:, 0], e[:, 3]))
    head = 2 * np.arctan2(np.abs(e[:, 3]), np.abs(e[:, 0]))
    return np.degrees(incl), np.degrees(head)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))
