"""The Cython kernels against the independent plain-numpy references of tests/reference.py.

Both implement docs/estimators.md; agreement to 1e-9 over a long, noisy, strongly moving run
checks every step of the kernels (propagation, corrections, hand-derived Jacobians, Joseph
form, sample handling, frame conversion) against a literal transcription of the text.
"""
import math

import numpy as np
import pytest

import fusion
import reference as ref
import reference_madgwick_ukf_cfekf as ref_ukf
from _helpers import (FIELD, FS, GYRO_BIAS, N, TOL, check_ned_and_given_start, check_skipped, check_uneven_dt,
                      compare_state, count_invalid, inject_invalid, qdiff, recovery_data, rest_data)

N_SHORT = 2_000     # dt / NED / skip variants (the reference is slow: ~0.1-0.4 ms per sample)

CASES = [("gyro", {}), ("mahony", {}), ("mahony", {"kp": 2.0, "ki": 0.1}), ("ekf", {}),
         ("ekf", {"gyro_noise": 0.003, "bias_noise": 1e-3, "acc_noise": 0.3, "mag_noise": 0.1,
                  "q_init_std": 0.2, "bias_init_std": 0.05}), ("ekf", {"mag_update": "heading"}),
         ("ekf", {"acc_lowpass": 0.5}), ("ekf-lp", {}), ("ekf-lp", {"incl_lowpass": 0.5, "acc_lowpass": 0.0})]
CASE_IDS = [name + ("-" + "-".join(f"{k}={v}" for k, v in p.items()) if p else "-defaults")
            for name, p in CASES]
NAMES = ["gyro", "mahony", "ekf", "ekf-lp"]


@pytest.fixture(scope="module")
def data(synthetic_data):
    return synthetic_data


# --- main runs ----------------------------------------------------------------------------

@pytest.mark.parametrize("nine_axis", [False, True], ids=["6axis", "9axis"])
@pytest.mark.parametrize("name, params", CASES, ids=CASE_IDS)
def test_kernel_equals_reference(data, name, params, nine_axis):
    _, gyr, acc, mag = data
    m = mag if nine_axis else None
    est = fusion.make(name, FS, **params)
    r = ref.make(name, FS, **params)
    q = est.run(gyr, acc, m)
    qr = r.run(gyr, acc, m)
    assert q.shape == qr.shape == (N, 4)
    assert qdiff(q, qr) < TOL
    compare_state(est, r)
    assert est.skipped == r.skipped == {"gyr": 0, "acc": 0, "mag": 0}


def test_the_run_is_demanding(data):
    """The data exercise what they should: fast turns, bias learning, attitude tracked."""
    q_true, gyr, acc, mag = data
    assert np.abs(gyr).max() > 3.0
    est = fusion.make("ekf", FS)
    q = est.run(gyr, acc, mag)
    e = ref.qmul(ref.qconj(q[-1]), q_true[-1])
    assert 2 * np.degrees(np.arctan2(np.linalg.norm(e[1:]), abs(e[0]))) < 5.0
    assert np.linalg.norm(est.bias - GYRO_BIAS) < 0.5 * np.linalg.norm(GYRO_BIAS)


# --- variants: uneven dt, NED, skipped samples ----------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_uneven_dt(data, name):
    _, gyr, acc, mag = data
    gyr, acc, mag = gyr[:N_SHORT], acc[:N_SHORT], mag[:N_SHORT]
    check_uneven_dt(fusion.make(name, FS), ref.make(name, FS), gyr, acc, mag)
    # a scalar dt is every sample's step
    est, r = fusion.make(name, FS), ref.make(name, FS)
    assert qdiff(est.run(gyr[:300], acc[:300], mag[:300], dt=0.013),
                 r.run(gyr[:300], acc[:300], mag[:300], dt=0.013)) < TOL
    compare_state(est, r)


@pytest.mark.parametrize("name", NAMES)
def test_ned(data, name):
    _, gyr, acc, mag = data
    gyr, acc, mag = gyr[:N_SHORT], acc[:N_SHORT], mag[:N_SHORT]
    check_ned_and_given_start(fusion.make(name, FS, frame="NED"), ref.make(name, FS, frame="NED"), gyr, acc, mag, 500)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("name", NAMES)
def test_skip_invalid_samples(data, name, frame):
    _, gyr, acc, mag = data
    gyr, acc, mag = inject_invalid(gyr, acc, mag)
    if frame == "NED":      # the frame change is at the boundary: a shorter run suffices
        gyr, acc, mag = gyr[:600], acc[:600], mag[:600]
    check_skipped(fusion.make(name, FS, frame=frame, on_invalid="skip"),
                  ref.make(name, FS, frame=frame, on_invalid="skip"), gyr, acc, mag, frame)
    # 6-axis too
    est = fusion.make(name, FS, frame=frame, on_invalid="skip")
    r = ref.make(name, FS, frame=frame, on_invalid="skip")
    assert qdiff(est.run(gyr[:500], acc[:500]), r.run(gyr[:500], acc[:500])) < TOL
    compare_state(est, r)
    assert est.skipped == r.skipped == dict(count_invalid(gyr[:500], acc[:500], mag[:500]), mag=0)


@pytest.mark.parametrize("name", NAMES)
def test_initialisation_with_a_magnetometer_parallel_to_gravity(data, name):
    """Exactly parallel or antiparallel field: the magnetometer is ignored (yaw 0)."""
    _, gyr, acc, mag = data
    for sign in (1.0, -1.0):
        m = mag[:200].copy()
        m[0] = sign * 3.0 * acc[0]
        est, r = fusion.make(name, FS), ref.make(name, FS)
        q, qr = est.run(gyr[:200], acc[:200], m), r.run(gyr[:200], acc[:200], m)
        assert qdiff(q, qr) < TOL
        compare_state(est, r)
        q6 = ref.initial_attitude(acc[0])
        assert abs(ref.euler_zyx(q6)[0]) < 1e-15
        assert np.abs(ref.initial_attitude(acc[0], m[0]) - q6).max() == 0.0


@pytest.mark.parametrize("name", ["mahony", "ekf"])
def test_vertical_field_after_initialisation(name):
    """A field along gravity carries no heading: no correction (ekf: the update is skipped
    because sqrt(nx² + ny²) < 1e-9, and that is not counted as a skipped sample)."""
    n = 60
    gyr = np.zeros((n, 3))
    acc = np.tile([0.0, 0.0, ref.G], (n, 1))
    mag = np.tile([0.0, 0.0, -40.0], (n, 1))
    q0 = ref.normalise(np.array([1.0, 0.0, 0.0, 0.3]))      # level: n = R(q) z is vertical
    est, r, six = fusion.make(name, FS), ref.make(name, FS), fusion.make(name, FS)
    for e in (est, r, six):
        e.reset(q0)
    q = est.run(gyr, acc, mag)
    assert qdiff(q, r.run(gyr, acc, mag)) < TOL
    compare_state(est, r)
    assert np.abs(q - six.run(gyr, acc)).max() < 1e-15
    assert est.skipped == r.skipped == {"gyr": 0, "acc": 0, "mag": 0}
    # and mixed with tilted / horizontal-field samples
    mag[::3] = [3.0, 20.0, -40.0]
    q0 = ref.normalise(np.array([1.0, 0.01, 0.0, 0.02]))
    est, r = fusion.make(name, FS), ref.make(name, FS)
    est.reset(q0)
    r.reset(q0)
    assert qdiff(est.run(gyr, acc, mag), r.run(gyr, acc, mag)) < TOL
    compare_state(est, r)


@pytest.mark.parametrize("params", [{"kp": 0.0, "ki": 0.0}, {"kp": 0.0, "ki": 0.2},
                                    {"kp": 3.0, "ki": 0.0}])
def test_mahony_with_a_zero_gain(data, params):
    _, gyr, acc, mag = data
    est, r = fusion.make("mahony", FS, **params), ref.make("mahony", FS, **params)
    assert qdiff(est.run(gyr[:1000], acc[:1000], mag[:1000]),
                 r.run(gyr[:1000], acc[:1000], mag[:1000])) < TOL
    compare_state(est, r)


@pytest.mark.parametrize("name", NAMES)
def test_reset_to_a_given_attitude(data, name):
    _, gyr, acc, mag = data
    q0 = [0.3, -0.5, 0.2, 0.7]         # not unit: normalised
    est, r = fusion.make(name, FS), ref.make(name, FS)
    est.run(gyr[:100], acc[:100], mag[:100])
    r.run(gyr[:100], acc[:100], mag[:100])
    est.reset(q0)
    r.reset(q0)
    compare_state(est, r)
    assert qdiff(est.run(gyr[:500], acc[:500], mag[:500]),
                 r.run(gyr[:500], acc[:500], mag[:500])) < TOL
    compare_state(est, r)


# (run equals repeated update: tests/test_contract.py)


# --- the reference itself -----------------------------------------------------------------

def test_reference_building_blocks():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = ref.normalise(rng.standard_normal(4))
        p = ref.normalise(rng.standard_normal(4))
        w = rng.standard_normal(3) * 3
        v = rng.standard_normal(3)
        # Ω, Ξ and L are the product matrices they claim to be
        wq = np.r_[0.0, w]
        assert np.allclose(ref.qmul(q, wq), ref.omega_matrix(w) @ q, atol=1e-15)
        assert np.allclose(ref.qmul(q, wq), ref.xi_matrix(q) @ w, atol=1e-15)
        assert np.allclose(ref.qmul(p, q), ref.left_matrix(p) @ q, atol=1e-15)
        # R(q) v = q ⊗ [0, v] ⊗ q*
        assert np.allclose(ref.rotmat(q) @ v, ref.qmul(ref.qmul(q, np.r_[0.0, v]), ref.qconj(q))[1:],
                           atol=1e-14)
        # Φ is the exponential of a constant rate: q ⊗ [cos(θ/2), sin(θ/2) ω/|ω|]
        dt = 0.05
        th = np.linalg.norm(w) * dt
        dq = np.r_[np.cos(th / 2), np.sin(th / 2) * w / np.linalg.norm(w)]
        assert np.allclose(ref.phi(w, dt) @ q, ref.qmul(q, dq), atol=1e-15)
        # Shepperd's conversion round trip (sign: w >= 0)
        qs = q if q[0] >= 0 else -q
        assert np.allclose(ref.quat_from_matrix(ref.rotmat(q)), qs, atol=1e-14)
        # the initial attitude recovers a true attitude from exact readings
        acc = ref.rotmat(q).T @ [0, 0, ref.G]
        mag = ref.rotmat(q).T @ FIELD
        assert np.allclose(ref.initial_attitude(acc, mag), qs, atol=1e-12)
        q6 = ref.initial_attitude(acc)
        assert np.allclose(ref.rotmat(q6).T @ [0, 0, 1], acc / ref.G, atol=1e-14)
        assert abs(ref.euler_zyx(q6)[0]) < 1e-14
        # complex-step Jacobians equal central differences of the same functions
        z = ref.normalise(mag)
        for f in (ref.acc_model, lambda x, z=z: ref.mag_model(x, z)):
            value, J = ref.complex_step_jacobian(f, q)
            assert np.abs(value - f(q)).max() < 1e-15
            h = 1e-6
            Jfd = np.column_stack([(f(q + h * e) - f(q - h * e)) / (2 * h) for e in np.eye(4)])
            assert np.allclose(J, Jfd, atol=1e-8)
    assert np.array_equal(ref.phi(np.zeros(3), 0.01), np.eye(4))


def test_reference_mag_model_is_the_measured_direction_when_heading_is_right():
    """At the true attitude, h(q) of the magnetometer update is the measured direction
    (the field folded onto north has the same direction as the true field's)."""
    q = ref.normalise(np.array([0.8, 0.2, -0.1, 0.5]))
    m = ref.rotmat(q).T @ FIELD
    z = ref.normalise(m)
    assert np.allclose(ref.mag_model(q, z), z, atol=1e-15)
    assert np.allclose(ref.acc_model(q), ref.rotmat(q).T @ [0, 0, 1], atol=1e-15)
    assert math.isclose(np.linalg.norm(ref.mag_model(q, z)), 1.0, rel_tol=1e-15)


def test_acc_lowpass_is_a_kalman_filter_option():
    """docs/estimators.md: ekf, iir-ekf and aekf take it; out of range is refused. A level body at rest for
    2 s, then shaken back and forth (zero-mean linear acceleration of 3-5 m/s², a good gyro):
    the low-passed vertical holds the tilt nearer level than the raw samples do."""
    n = 6000
    rng = np.random.default_rng(3)
    t = np.arange(n) / FS
    shaking = t > 2.0
    acc = np.tile([0.0, 0.0, 9.81], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    acc[:, 0] += shaking * 5.0 * np.sin(2 * np.pi * 2.0 * t)
    acc[:, 1] += shaking * 3.0 * np.sin(2 * np.pi * 1.3 * t + 1.0)
    gyr = rng.normal(0, 0.001, (n, 3))
    tilt = {}
    for tau in (0.0, 2.0):
        for name in ("ekf", "iir-ekf", "aekf"):
            est = fusion.make(name, FS, acc_lowpass=tau)
            assert est.acc_lowpass == tau
            est.reset([1.0, 0.0, 0.0, 0.0])
            q = est.run(gyr, acc)
            tilt[name, tau] = np.degrees(2 * np.arctan2(np.hypot(q[n // 2:, 1], q[n // 2:, 2]),
                                                        np.hypot(q[n // 2:, 0], q[n // 2:, 3]))).mean()
    for name in ("ekf", "iir-ekf", "aekf"):
        assert tilt[name, 2.0] < 0.5 * tilt[name, 0.0], tilt    # measured 0.06 vs 0.59 deg (ekf), 0.06 vs 1.35 (aekf)
    for bad in (-1.0, np.inf, "1"):
        for name in ("ekf", "aekf"):
            with pytest.raises(ValueError, match="acc_lowpass"):
                fusion.make(name, FS, acc_lowpass=bad)


@pytest.mark.parametrize("tilt_deg", [0.0, 35.0])
@pytest.mark.parametrize("name", ["ekf", "iir-ekf", "aekf", "ukf"])
def test_start_end_grows_the_tilt_variance(name, tilt_deg):
    """docs/estimators.md, "The start": on the sample that ends the low-pass's running-mean
    start the tilt variance (about the two horizontal axes) grows by the mean's,
    (acc_noise / g)² / (acc_lowpass + dt), and the heading's does not. A body at rest, level or
    tilted, the angle covariance (in the navigation frame) before and after that sample (the
    update that follows takes well under 5 % of it back: its noise, acc_noise² / dt, is far
    above the variance). And with acc_lowpass below one step and a large acc_noise the growth
    stops at pi², an angle's."""
    tau, acc_noise = 0.5, 0.8
    q0 = ref.normalise(np.array([math.cos(math.radians(tilt_deg) / 2), math.sin(math.radians(tilt_deg) / 2), 0.0, 0.0]))
    g_body = ref.rotmat(q0).T @ np.array([0.0, 0.0, 9.81])
    rng = np.random.default_rng(4)

    def angle_cov(est):
        P = est.covariance
        if name == "ukf":
            S = P[:3, :3]
        else:
            Xi = ref.xi_matrix(est.quaternion)
            S = 4 * Xi.T @ P[:4, :4] @ Xi
        R = ref.rotmat(est.quaternion)              # body-frame angle -> navigation frame
        return R @ S @ R.T

    def jumps(est, n):
        out = []
        for _ in range(n):
            before = angle_cov(est)
            est.run(rng.normal(0, 1e-3, (1, 3)), g_body[None] + rng.normal(0, 0.02, (1, 3)))
            d = angle_cov(est) - before
            out.append((d[0, 0], d[1, 1], d[2, 2]))
        return np.array(out)

    est = fusion.make(name, FS, acc_lowpass=tau, acc_noise=acc_noise, rest_time=0.0)
    est.reset(q0)
    v = (acc_noise / 9.81) ** 2 / (tau + 1 / FS)
    j = jumps(est, int(2 * tau * FS))
    k = int(np.argmax(j[:, 0]))
    assert k == round(tau * FS), k                          # the sample with lp_time = tau
    assert 0.95 * v < j[k, 0] < 1.001 * v and 0.95 * v < j[k, 1] < 1.001 * v, (j[k], v)
    assert abs(j[k, 2]) < 2e-3 * v, j[k]                    # heading untouched
    assert (np.delete(j[:, :2], k, axis=0) < 0.01 * v).all()    # once
    big = fusion.make(name, FS, acc_lowpass=1e-3, acc_noise=50.0, rest_time=0.0)
    big.reset(q0)
    assert jumps(big, 3)[:, :2].max() <= math.pi ** 2 * (1 + 1e-9)


@pytest.mark.parametrize("motion_rate", [1.0, 30.0])       # 30: the pi² cap is reached
def test_recovery_inflation(data, motion_rate):
    """docs/robustness.md, "Recovery": saturated samples (gyro_range), a run of dropped
    samples and a time gap grow the attitude covariance the same way in kernel and reference."""
    gyr, acc, mag, dt = recovery_data(data)
    params = dict(gyro_range=0.5, motion_rate=motion_rate)
    est = fusion.make("ekf", FS, on_invalid="skip", **params)
    r = ref.make("ekf", FS, on_invalid="skip", **params)
    assert qdiff(est.run(gyr, acc, mag, dt=dt), r.run(gyr, acc, mag, dt=dt)) < TOL
    compare_state(est, r)


def test_mahony_recovery_does_not_overshoot_at_low_rates():
    """At 5 Hz the raised gain (20 kp dt = 2) would turn by twice the error each step and
    swing the estimate from side to side; capped, each recovery step corrects at most half
    the error. A level, still body started 30 deg off in roll, one saturated sample at the
    start: the roll error shrinks without changing sign, in kernel and reference alike."""
    fs, n = 5.0, 100
    gyr = np.zeros((n, 3))
    gyr[0] = [0.5, 0.0, 0.0]                   # on the rail of a 0.505 rad/s gyro
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    start = [np.cos(np.radians(15)), np.sin(np.radians(15)), 0.0, 0.0]
    est = fusion.make("mahony", fs, gyro_range=0.505)
    r = ref.make("mahony", fs, gyro_range=0.505)
    for e in (est, r):
        e.reset(start)
    q = est.run(gyr, acc)
    assert qdiff(q, r.run(gyr, acc)) < TOL
    roll = np.degrees(2 * np.arctan2(q[:, 1], q[:, 0]))
    ramp = roll[:int(3 * fs)]                   # the 3 s of raised gain
    assert (ramp > 0).all() and np.all(np.diff(ramp) < 0), ramp[:8]
    assert np.abs(roll[-20:]).max() < 0.01


@pytest.mark.parametrize("nine_axis", [False, True], ids=["6axis", "9axis"])
def test_mahony_recovery_gain(data, nine_axis):
    """docs/robustness.md, "Recovery": after saturated samples the kernel raises kp and holds
    the integral as the reference does, by the batch and by the per-sample path."""
    gyr, acc, mag, dt = recovery_data(data)
    m = mag if nine_axis else None
    # the rail (0.5) 1 % below the range, as after a bias correction: within the 2 % margin
    est = fusion.make("mahony", FS, on_invalid="skip", gyro_range=0.505)
    r = ref.make("mahony", FS, on_invalid="skip", gyro_range=0.505)
    assert qdiff(est.run(gyr, acc, m, dt=dt), r.run(gyr, acc, m, dt=dt)) < TOL
    compare_state(est, r)
    plain = fusion.make("mahony", FS, on_invalid="skip")
    assert qdiff(plain.run(gyr, acc, m, dt=dt), est.run(gyr, acc, m, dt=dt)) > 1e-3   # it acts


@pytest.mark.parametrize("name", ["ekf", "iir-ekf", "aekf"])
def test_heading_only_magnetometer_cannot_tilt(name):
    """A level, static sensor whose field points 60 deg east of the start heading (a large
    heading error, as after a glitch): the 3-D update tilts the estimate on its way, the
    heading-only update turns it about the vertical alone."""
    n = 2000
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    gyr = np.zeros((n, 3))
    dip, east = np.radians(48.0), np.radians(60.0)
    mag = np.tile([np.sin(east) * np.cos(dip), np.cos(east) * np.cos(dip), -np.sin(dip)], (n, 1))
    tilt = {}
    for mode in ("vector", "heading"):
        # rest detection off: its zero-rate update corrects the bias through correlations
        # the turn leaves in P, which tilts by 6e-4 deg here; this test is about the gain
        est = fusion.make(name, FS, mag_update=mode, rest_time=0.0)
        est.reset([1.0, 0.0, 0.0, 0.0])
        q = est.run(gyr, acc, mag)
        tilt[mode] = np.degrees(2 * np.arctan2(np.hypot(q[:, 1], q[:, 2]), np.hypot(q[:, 0], q[:, 3]))).max()
    assert tilt["heading"] < 1e-6 < 0.1 < tilt["vector"], tilt


@pytest.mark.parametrize("name, params", [("ekf", {}), ("ekf", {"acc_update": "tilt", "mag_update": "heading"}),
                                          ("ekf", {"rest_time": 0.3, "rest_noise": 0.01}), ("mahony", {}),
                                          ("mahony", {"rest_time": 0.3, "rest_tau": 0.2, "ki": 0.05})],
                         ids=["defaults", "tilt-heading", "short-rest", "mahony", "mahony-short-rest"])
@pytest.mark.parametrize("nine_axis", [False, True], ids=["6axis", "9axis"])
def test_rest_update_equals_reference(data, name, params, nine_axis):
    """docs/estimators.md, "Rest": the detector and the zero-rate update of the kernel, by the
    batch and by the per-sample path, against the reference, on a record whose still spells
    the detector finds (and whose motion it must not take for rest)."""
    gyr, acc, mag = rest_data(data)
    m = mag if nine_axis else None
    est, r = fusion.make(name, FS, **params), ref.make(name, FS, **params)
    dt = np.full(N_SHORT, 1 / FS)
    dt[700] = 0.05         # a longer step inside the motion
    assert qdiff(est.run(gyr, acc, m, dt=dt), r.run(gyr, acc, m, dt=dt)) < TOL
    compare_state(est, r)
    assert est.rest_samples == r.rest_samples
    # found in both still spells (the second after its low-passes forget the motion), and
    # only there: at most (400 - 1 - rest_time fs) + (600 - rest_time fs)
    first = 400 - 1 - est.rest_time * FS
    assert first + 100 < est.rest_samples <= first + 600 - est.rest_time * FS
    one = fusion.make(name, FS, **params)
    q1 = np.array([one.update(g, a, None if m is None else m[i], dt=dt[i])
                   for i, (g, a) in enumerate(zip(gyr, acc))])
    assert np.abs(q1 - fusion.make(name, FS, **params).run(gyr, acc, m, dt=dt)).max() < 1e-15
    assert one.rest_samples == est.rest_samples


def _turning_point(axis, rate):
    """10 s at FS of a rotation about body axis (0: x, a tilt; 2: z, the vertical) at the
    rates rate(t) (rad/s), ideal sensors: (gyr, acc)."""
    t = np.arange(int(10 * FS)) / FS
    w = rate(t)
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) / FS)])
    gyr = np.zeros((t.size, 3))
    gyr[:, axis] = w
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 1))
    if axis == 0:
        acc[:, 1], acc[:, 2] = 9.81 * np.sin(angle), 9.81 * np.cos(angle)
    return gyr, acc


@pytest.mark.parametrize("name", ["ekf", "aekf", "mahony", "madgwick", "ukf", "cf-ekf"])
def test_a_turning_point_is_not_rest(name):
    """Motion that the still tests alone take for rest (rate and accelerometer within their
    tolerances of their low-passes, the mean rate under rest_gyro_tol for over rest_time).
    The turning point of a slow turn about the vertical (the rate through zero at 2 deg/s^2,
    under 2 deg/s for 2 s) ends every still run by the gyro's drift test. A steady tilt at
    1.8 deg/s after 2 s at rest: the rest ends within 0.1 s, by the gyro's drift test while
    its low-pass follows the step, by the accelerometer's after (the gyro's low-pass no longer
    moves). With the drift test off both are taken for rest for over a second; the ekf kernel
    equals its reference on both."""
    ramp = _turning_point(2, lambda t: np.radians(2.0) * (t - 5.0))
    tilt = _turning_point(0, lambda t: np.where(t < 2.0, 0.0, np.radians(1.8)))
    n0 = int(2 * FS)
    for (gyr, acc), off, still, most_on in ((ramp, {"rest_gyro_drift_tol": 0.0}, 0, 0),
                                            (tilt, {"rest_acc_drift_tol": 0.0}, n0, 0.1 * FS)):
        for p, most in (({}, most_on), (off, None)):
            est = fusion.make(name, FS, **p)
            est.run(gyr[:still], acc[:still])
            before = est.rest_samples
            est.run(gyr[still:], acc[still:])
            moving = est.rest_samples - before
            if most is None:
                assert moving > FS, moving
            else:
                assert moving <= most, moving
        if name == "ekf":
            for p in ({}, off):
                est, r = fusion.make(name, FS, **p), ref.make(name, FS, **p)
                assert qdiff(est.run(gyr, acc), r.run(gyr, acc)) < TOL
                assert est.rest_samples == r.rest_samples


@pytest.mark.parametrize("name", ["ekf", "mahony"])
def test_rest_at_1khz(name):
    """At 1 kHz a still sensor's per-sample noise (here 0.54 deg/s per gyro axis, the
    scenarios' densities) often fails the still tests' tolerances: they judge the samples
    through a 10 ms low-pass above 100 Hz, and a still sensor is at rest for nearly the whole
    run after rest_time (the raw samples: 12.5 % here). The kernel equals its reference."""
    from fusion.scenarios import make_scenario
    fs = 1000.0
    sc = make_scenario("static", fs=fs, duration=10.0, seed=0)
    est, r = fusion.make(name, fs), ref.make(name, fs)
    assert qdiff(est.run(sc.gyr, sc.acc), r.run(sc.gyr, sc.acc)) < TOL
    assert est.rest_samples == r.rest_samples
    assert est.rest_samples > 0.9 * (sc.n - est.rest_time * fs)


def test_rest_starts_with_the_running_mean():
    """The rest low-passes are the running mean of their first 0.5 s: a still sensor whose
    first sample is noisy is at rest after rest_time (a start at that one sample would hold
    its noise, 0.2 deg/s, over the drift tolerance for most of a second)."""
    rng = np.random.default_rng(7)
    n = int(5 * FS)
    gyr = np.radians([0.3, -0.2, 0.1]) + rng.normal(0, 0.002, (n, 3))
    gyr[0] += np.radians([0.15, -0.15, 0.15])
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    est = fusion.make("ekf", FS)
    est.run(gyr, acc)
    assert est.rest_samples == n - 1 - round(est.rest_time * FS) + 1


@pytest.mark.parametrize("name", ["ekf", "ukf", "cf-ekf"])
def test_the_first_zero_rate_update_takes_the_still_run(name):
    """A still run is known to be rest only rest_time after it began; its first zero-rate
    update measures the bias with the mean of the run's samples so far (the noise density over
    that time), not with the one sample that ends the wait. Still from the first sample (the
    run from sample 1, at rest from sample k = rest_time fs), a bias prior far wider than the
    measurement's noise: the bias right after sample k is the mean of samples 1..k, where the
    sample k alone is over 0.1 deg/s off it (a spike there, under every rest tolerance)."""
    rng = np.random.default_rng(11)
    n = int(2 * FS)
    gyr = np.radians([0.3, -0.2, 0.1]) + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    est = fusion.make(name, FS, bias_init_std=0.5, rest_noise=1e-6)
    k = round(est.rest_time * FS)
    gyr[k] += np.radians([0.15, -0.15, 0.15])
    for i in range(k + 1):
        est.update(gyr[i], acc[i], dt=1 / FS)
        assert est.rest_samples == (i == k)
    run = gyr[1:k + 1].mean(axis=0)
    assert np.abs(gyr[k] - run).max() > np.radians(0.1)
    assert np.abs(est.bias - run).max() < np.radians(0.002), np.degrees([est.bias, run])


@pytest.mark.parametrize("name", ["ekf", "iir-ekf", "aekf", "mahony"])
def test_rest_learns_the_whole_gyro_bias(name):
    """A still sensor with a constant gyro bias, 6-axis: the accelerometer sees only the
    horizontal part of the bias, so without rest detection the vertical part is never learned
    and the heading drifts; with it (the default) the whole bias is learned within seconds.
    A steady turn (10 deg/s, smooth) and a shaken sensor are not rest."""
    n = int(20 * FS)
    rng = np.random.default_rng(4)
    bias = np.radians([0.8, -0.5, 1.2])                 # deg/s: under the 2 deg/s limit
    gyr = bias + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    for rest_time in (1.5, 0.0):
        est = fusion.make(name, FS, rest_time=rest_time)
        est.reset([1.0, 0.0, 0.0, 0.0])
        q = est.run(gyr, acc)
        yaw = np.degrees(2 * np.arctan2(q[:, 3], q[:, 0]))
        drift = abs(yaw[-1] - yaw[n // 2])              # over the last 10 s
        if rest_time:
            assert est.at_rest and est.rest_samples > n - 2 * FS
            assert np.abs(est.bias - bias).max() < np.radians(0.05), np.degrees(est.bias)
            assert drift < 0.2, drift
        else:
            assert drift > 5.0, drift                   # about 1 deg/s unlearned
            assert not est.at_rest and est.rest_samples == 0
            assert abs(est.bias[2] - bias[2]) > np.radians(0.5), np.degrees(est.bias)
    turning = gyr + np.radians([0.0, 0.0, 10.0])
    shaken = acc + rng.normal(0, 1.0, (n, 3))
    for g, a in ((turning, acc), (gyr, shaken)):
        est = fusion.make(name, FS)
        est.run(g, a)
        assert est.rest_samples == 0 and not est.at_rest


def slow_steady_turn(fs=FS, rate_dps=1.0, seed=5):
    """5 s still (the gyro bias learned), a steady turn about the vertical at rate_dps for
    2.6 s (under rest_gyro_tol: once its low-passes settle the still tests and the drift tests
    pass, for about 1.6 s), 5.4 s still: (gyr, acc, the bias in rad/s)."""
    rng = np.random.default_rng(seed)
    n = int(13 * fs)
    bias = np.radians([0.3, -0.2, 0.4])
    gyr = bias + rng.normal(0, 0.002, (n, 3))
    gyr[int(5 * fs):int(7.6 * fs), 2] += np.radians(rate_dps)
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    return gyr, acc, bias


@pytest.mark.parametrize("name", ["ekf", "ukf", "aekf", "cf-ekf"])
def test_the_bias_gate_keeps_a_known_bias(name):
    """rest_bias_gate: a steady 1 deg/s turn about the vertical passes every rest test for
    about 1.6 s once its low-passes settle (under rest_gate_time). Without the gate (0: the
    default of aekf and cf-ekf) the zero-rate updates take the turn for bias: after the 5.4 s of rest that
    follow, the vertical bias is still 0.14 deg/s off (nothing else corrects it in 6-axis) and
    the heading has lost about 1.1 deg of the turn's 2.6. With it at 2 the bias, learned in the
    first 5 s, is within 0.02 deg/s and the heading within 0.05 deg. The ekf and ukf kernels
    equal their references."""
    gyr, acc, bias = slow_steady_turn()
    out = {}
    for gate in (2.0, 0.0):
        p = {"rest_bias_gate": gate}
        est = fusion.make(name, FS, **p)
        est.reset([1.0, 0.0, 0.0, 0.0])
        q = est.run(gyr, acc)
        yaw = np.degrees(2 * np.arctan2(q[-1, 3], q[-1, 0]))
        out[gate > 0] = (abs(np.degrees(est.bias[2] - bias[2])), yaw)
        if name in ("ekf", "ukf"):
            r = (ref if name == "ekf" else ref_ukf).make(name, FS, **p)
            r.reset([1.0, 0.0, 0.0, 0.0])
            assert qdiff(q, r.run(gyr, acc)) < TOL
            assert est.rest_samples == r.rest_samples
    (gated, yaw_gated), (open_, yaw_open) = out[True], out[False]
    assert gated < 0.04 < 0.1 < open_, out
    assert abs(yaw_gated - 2.6) < 0.1 < 0.8 < abs(yaw_open - 2.6), out


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_a_bias_beyond_the_gate_is_learned_after_rest_gate_time(name):
    """A turn-on bias of 1.9 deg/s about the vertical (under rest_gyro_tol, beyond the gate at
    2: 2 x bias_init_std 0.5 deg/s + 0.2 deg/s) on a still, level sensor: the gate holds the
    zero-rate update until the still run is rest_gate_time long, then the run's first update
    takes its 2 s of samples: the bias is learned at once (a first update of the one sample
    left it about 0.7 deg/s off)."""
    n = int(6 * FS)
    rng = np.random.default_rng(9)
    bias = np.radians([0.2, -0.1, 1.9])
    gyr = bias + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    est = fusion.make(name, FS, rest_bias_gate=2.0)
    est.run(gyr[:int(2.0 * FS)], acc[:int(2.0 * FS)])
    assert est.at_rest and abs(est.bias[2]) < np.radians(0.1), np.degrees(est.bias)
    est.run(gyr[int(2.0 * FS):int(2.02 * FS)], acc[int(2.0 * FS):int(2.02 * FS)])   # lifted at 2 s
    assert abs(np.degrees(est.bias[2] - bias[2])) < 0.05, np.degrees(est.bias)
    est.run(gyr[int(2.02 * FS):int(2.2 * FS)], acc[int(2.02 * FS):int(2.2 * FS)])
    est.run(gyr[int(2.2 * FS):], acc[int(2.2 * FS):])
    assert abs(np.degrees(est.bias[2] - bias[2])) < 0.05, np.degrees(est.bias)
    est2 = fusion.make(name, FS, rest_bias_gate=2.0, rest_gate_time=1e4)    # the gate never lifted
    est2.run(gyr, acc)
    assert abs(est2.bias[2]) < np.radians(0.1), np.degrees(est2.bias)


def test_rest_parameters_are_checked():
    for name in ("rest_time", "rest_gyro_tol", "rest_acc_tol", "rest_noise", "rest_bias_gate", "rest_gate_time"):
        for bad in (-1.0, np.inf, "1", None):
            with pytest.raises(ValueError, match=name):
                fusion.make("ekf", FS, **{name: bad})
    for name in ("rest_time", "rest_gyro_tol", "rest_acc_tol", "rest_tau"):     # mahony's (no rest_noise)
        for bad in (-1.0, np.inf, np.nan, "1", None, 1e5):
            with pytest.raises(ValueError, match=name):
                fusion.make("mahony", FS, **{name: bad})
    with pytest.raises(ValueError, match="rest_tau"):
        fusion.make("mahony", FS, rest_tau=0.0)         # a time constant: > 0 (rest_time 0 turns it off)
    for name in ("rest_noise", "rest_bias_gate", "rest_gate_time"):    # not mahony's: no zero-rate update
        with pytest.raises(ValueError, match=name):
            fusion.make("mahony", FS, **{name: 1.0})
    with pytest.raises(ValueError, match="acc_update"):
        fusion.make("aekf", FS, acc_update="heading")
    assert fusion.make("ekf", FS, rest_time=0.0).rest_time == 0.0
    assert fusion.make("ekf", FS, rest_bias_gate=0.0).rest_bias_gate == 0.0     # off
    for bad in (0.3, 101.0):                # 0, or 0.5 to 100 standard deviations
        with pytest.raises(ValueError, match="rest_bias_gate"):
            fusion.make("ekf", FS, rest_bias_gate=bad)
    with pytest.raises(ValueError, match="rest_gate_time"):
        fusion.make("ukf", FS, rest_gate_time=0.0)
    assert fusion.make("ekf", FS).acc_update == "vector" and fusion.make("aekf", FS).acc_update == "tilt"


@pytest.mark.parametrize("name", ["ekf", "aekf"])
def test_tilt_only_accelerometer_cannot_turn_the_heading(data, name):
    """After a moving run (P full of correlations), one accelerometer update with a reading
    20 deg off the estimate's vertical (and the gyro equal to the bias: no rotation
    predicted): with the full gain ("vector") the correction also turns the attitude about
    the vertical and moves the bias along the body vertical; with the projected gain ("tilt")
    it does neither (to rounding)."""
    _, gyr, acc, _ = data
    turn, along = {}, {}
    for mode in ("vector", "tilt"):
        gates = {"acc_norm_tol": 100.0, "acc_pred_tol": 100.0} if name == "aekf" else {}
        est = fusion.make(name, FS, acc_update=mode, rest_time=0.0, acc_lowpass=0.0, **gates)
        est.run(gyr[:1000], acc[:1000])
        q0, b0 = est.quaternion, est.bias
        up = ref.rotmat(q0).T @ [0.0, 0.0, 1.0]
        side = np.cross(up, [1.0, 0.0, 0.0])
        reading = 9.81 * (np.cos(np.radians(20)) * up + np.sin(np.radians(20)) * side / np.linalg.norm(side))
        q1 = est.update(b0, reading)
        d = ref.qmul(q1, ref.qconj(q0))                 # the correction, navigation frame
        turn[mode] = abs(2 * np.arctan2(d[3], d[0]))     # its part about the vertical
        along[mode] = abs((est.bias - b0) @ up)
        assert np.degrees(2 * np.arccos(min(1.0, abs(d[0])))) > 0.01        # it corrected
    assert turn["tilt"] < 1e-12 < 1e-6 < turn["vector"], turn
    assert along["tilt"] < 1e-15 < 1e-9 < along["vector"], along
