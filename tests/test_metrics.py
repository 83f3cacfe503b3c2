"""fusion.quat and fusion.metrics on analytic cases."""
import subprocess
import sys

import numpy as np
import pytest

from fusion import metrics, quat

RNG = np.random.default_rng(0)


def random_quats(n, rng=RNG):
    return quat.normalise(rng.standard_normal((n, 4)))


def qz(deg):
    return quat.from_axis_angle([0, 0, 1], np.radians(deg))


# --- quat --------------------------------------------------------------------------------

def test_quat_basics_against_rotation_matrices():
    q = random_quats(200)
    p = random_quats(200)
    v = RNG.standard_normal((200, 3))
    R = quat.to_matrix(q)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(quat.rotate(q, v), np.einsum("nij,nj->ni", R, v))
    assert np.allclose(quat.rotate_inverse(q, quat.rotate(q, v)), v)
    # rotate agrees with the sandwich product q [0, v] q*
    sandwich = quat.mul(quat.mul(q, np.concatenate([np.zeros((200, 1)), v], 1)), quat.conj(q))[:, 1:]
    assert np.allclose(quat.rotate(q, v), sandwich)
    # composition: R(p ⊗ q) = R(p) R(q)
    assert np.allclose(quat.to_matrix(quat.mul(p, q)), quat.to_matrix(p) @ R)
    assert np.allclose(quat.mul(q, quat.conj(q)), [1, 0, 0, 0], atol=1e-12)


def test_euler_round_trip_and_convention():
    e = np.column_stack([RNG.uniform(-np.pi, np.pi, 500), RNG.uniform(-1.5, 1.5, 500),
                         RNG.uniform(-np.pi, np.pi, 500)])
    assert np.allclose(quat.to_euler(quat.from_euler(e)), e, atol=1e-9)
    # yaw 90 deg maps body x onto east -> north (ENU, counter-clockwise about z up)
    q = quat.from_euler([np.pi / 2, 0, 0])
    assert np.allclose(quat.rotate(q, [1, 0, 0]), [0, 1, 0], atol=1e-12)
    # ZYX order: R = Rz(yaw) Ry(pitch) Rx(roll)
    y, p, r = 0.3, -0.4, 0.5
    c, s = np.cos, np.sin
    Rz = np.array([[c(y), -s(y), 0], [s(y), c(y), 0], [0, 0, 1]])
    Ry = np.array([[c(p), 0, s(p)], [0, 1, 0], [-s(p), 0, c(p)]])
    Rx = np.array([[1, 0, 0], [0, c(r), -s(r)], [0, s(r), c(r)]])
    assert np.allclose(quat.to_matrix(quat.from_euler([y, p, r])), Rz @ Ry @ Rx)


def test_to_rotvec_inverts_from_rotvec():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.r_[rng.uniform(0, np.pi - 1e-6, 197), 0.0, 1e-10, np.pi - 1e-9]
    rv = axes * angles[:, None]
    assert np.allclose(quat.to_rotvec(quat.from_rotvec(rv)), rv, atol=1e-9, rtol=0)
    assert np.allclose(quat.to_rotvec(-quat.from_rotvec(rv)), rv, atol=1e-9, rtol=0)   # sign-blind
    # an angle past pi comes back as the shorter rotation the other way
    assert np.allclose(quat.to_rotvec(quat.from_rotvec([0, 0, 1.5 * np.pi])), [0, 0, -0.5 * np.pi])


def test_exp_integrates_a_constant_rate_exactly():
    w = np.array([0.3, -1.1, 2.0])
    q = np.array([1.0, 0, 0, 0])
    for _ in range(1000):
        q = quat.mul(q, quat.exp(w, 0.001))
    assert quat.angle(q, quat.from_rotvec(w)) < 1e-12
    assert np.allclose(quat.exp(np.zeros(3), 0.01), [1, 0, 0, 0])
    tiny = quat.from_rotvec([1e-9, 0, 0])
    assert np.isclose(tiny[1], 5e-10, rtol=1e-12)


def test_quat_shape_errors():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        quat.mul(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        quat.rotate([1, 0, 0, 0], [1, 0])


def test_quat_refuses_inputs_that_would_score_a_wrong_number():
    """A masked array (its mask dropped: 96 deg instead of 2), complex, bool or string
    quaternions, a column of steps that broadcast to N x N, a zero axis (NaN): each a ValueError
    naming the argument."""
    q = random_quats(5)
    masked = np.ma.masked_array(q, mask=np.zeros_like(q, bool))
    with pytest.raises(ValueError, match="q_ref is a masked array"):
        metrics.score(q, masked)
    for bad in (q + 1j, np.ones((5, 4), bool), q.astype(str)):
        with pytest.raises(ValueError, match="must hold real numbers"):
            metrics.score(bad, q)
    with pytest.raises(ValueError, match=r"dt must be a scalar or have shape \(5,\)"):
        quat.exp(np.ones((5, 3)), np.full((5, 1), 0.01))
    assert quat.exp(np.ones(3), np.full(5, 0.01)).shape == (5, 4)      # one rate, five steps
    with pytest.raises(ValueError, match=r"dt must be a scalar or have shape \(5,\)"):
        quat.exp(np.ones((5, 3)), np.full((2, 5), 0.01))
    with pytest.raises(ValueError, match="axis must be finite and non-zero"):
        quat.from_axis_angle([0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="six_axis must be True or False"):
        metrics.score(q, q, six_axis="False")


# --- attitude errors ---------------------------------------------------------------------

@pytest.mark.parametrize("deg", [10.0, -10.0, 90.0])
def test_pure_heading_offset(deg):
    q_ref = random_quats(100)
    q_est = quat.mul(qz(deg), q_ref)          # turned about the earth z axis
    err = metrics.attitude_errors(q_est, q_ref)
    assert np.allclose(err["total"], abs(deg))
    assert np.allclose(err["heading"], abs(deg))
    assert np.allclose(err["inclination"], 0, atol=1e-6)


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [1, 1, 0]])
def test_pure_inclination_offset(axis):
    q_ref = random_quats(100)
    q_est = quat.mul(quat.from_axis_angle(axis, np.radians(5)), q_ref)  # earth-horizontal axis
    err = metrics.attitude_errors(q_est, q_ref)
    assert np.allclose(err["total"], 5)
    assert np.allclose(err["inclination"], 5)
    assert np.allclose(err["heading"], 0, atol=1e-6)


def test_pure_roll_offset_at_identity():
    q_est = quat.from_euler([0, 0, np.radians(5)])
    err = metrics.attitude_errors(q_est, [1, 0, 0, 0])
    assert np.allclose([err["total"], err["inclination"], err["heading"]], [[5], [5], [0]])


def test_errors_match_the_readme_formulas_and_ignore_sign():
    q_ref, q_est = random_quats(300), random_quats(300)
    e = quat.mul(q_est, quat.conj(q_ref))
    w, x, y, z = e.T
    err = metrics.attitude_errors(-q_est, q_ref)         # q and -q: same attitude
    assert np.allclose(err["total"], np.degrees(2 * np.arccos(np.abs(w))))
    assert np.allclose(err["heading"], np.degrees(2 * np.arctan(np.abs(z / w))))
    assert np.allclose(err["inclination"], np.degrees(2 * np.arccos(np.sqrt(w * w + z * z))))


def test_combined_heading_then_tilt():
    q_ref = random_quats(50)
    q_est = quat.mul(quat.mul(quat.from_axis_angle([1, 0, 0], np.radians(3)), qz(20)), q_ref)
    err = metrics.attitude_errors(q_est, q_ref)
    assert np.allclose(err["inclination"], 3)
    assert np.allclose(err["heading"], 20, atol=0.1)  # heading of the swing-twist split
    tot = np.degrees(quat.angle(q_est, q_ref))
    assert np.allclose(err["total"], tot)


def test_nan_reference_rows_are_ignored():
    q_ref = random_quats(100)
    q_est = quat.mul(qz(10), q_ref)
    q_ref_nan = q_ref.copy()
    q_ref_nan[::3] = np.nan
    q_est_bad = q_est.copy()
    q_est_bad[::3] = quat.mul(qz(170), q_ref[::3])     # would dominate if not ignored
    s = metrics.score(q_est_bad, q_ref_nan)
    assert np.allclose([s["total"], s["heading"], s["inclination"]], [10, 10, 0], atol=1e-6)
    assert np.isnan(metrics.attitude_errors(q_est, q_ref_nan)["total"][0])
    with pytest.raises(ValueError, match="finite reference"):
        metrics.score(q_est, np.full((100, 4), np.nan))


@pytest.mark.parametrize("bad", [[np.nan, 0, 0, 0], [np.inf, 0, 0, 0], [0, 0, 0, 0]])
@pytest.mark.parametrize("fn", [metrics.score, lambda a, b: metrics.score(a, b, six_axis=True),
                                metrics.heading_offset, metrics.attitude_errors, metrics.euler_table])
def test_bad_estimate_rows_are_an_error_not_dropped(fn, bad):
    # was: dropped with the reference's lost rows, so a filter that fails on most rows scored 0
    q_ref = random_quats(10)
    q_est = q_ref.copy()
    q_est[3:] = bad
    with pytest.raises(ValueError, match=r"q_est must be a finite, nonzero quaternion .*7 of 10 rows .*row 3"):
        fn(q_est, q_ref)
    q_ref[3:] = np.nan              # the same rows without a reference are dropped, as documented
    with np.errstate(invalid="ignore"):     # 6-axis turns the inf rows too: inf * 0
        fn(q_est, q_ref)
    assert metrics.score(q_est, q_ref)["total"] < 1e-6


def test_heading_offset_removal():
    q_ref = random_quats(400)
    wobble = np.radians(2.0) * np.sin(np.linspace(0, 20, 400))
    q_est = quat.mul(quat.from_axis_angle(np.tile([0, 0, 1.0], (400, 1)), np.radians(37) + wobble), q_ref)
    q_corr, psi = metrics.remove_heading_offset(-q_est, q_ref, return_offset=True)
    assert np.isclose(np.degrees(psi), 37 + np.degrees(wobble.mean()), atol=1e-3)   # the mean heading
    # the residual is the zero-mean wobble only
    err = metrics.attitude_errors(q_corr, q_ref)
    assert np.allclose(err["heading"], np.degrees(np.abs(wobble - np.mean(wobble))), atol=0.02)
    s6 = metrics.score(q_est, q_ref, six_axis=True)
    s9 = metrics.score(q_est, q_ref)
    assert s9["heading"] > 36 and s6["heading"] < 1.5 and s6["inclination"] < 1e-6
    # a pure tilt error is left alone
    q_tilt = quat.mul(quat.from_axis_angle([0, 1, 0], np.radians(4)), q_ref)
    assert abs(metrics.heading_offset(q_tilt, q_ref)) < 1e-9
    assert np.isclose(metrics.score(q_tilt, q_ref, six_axis=True)["inclination"], 4)


def test_shape_errors():
    with pytest.raises(ValueError, match="same number of rows"):
        metrics.attitude_errors(random_quats(5), random_quats(6))
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        metrics.score(np.zeros((5, 3)), random_quats(5))
    with pytest.raises(ValueError):
        metrics.euler_table(np.zeros((2, 5, 4)), np.zeros((2, 5, 4)))


# --- Euler table -------------------------------------------------------------------------

def test_euler_table_constant_offset():
    n = 200
    e_true = np.column_stack([RNG.uniform(-3, 3, n), RNG.uniform(-0.5, 0.5, n), RNG.uniform(-0.5, 0.5, n)])
    off = np.radians([2.0, -1.0, 0.5])
    table = metrics.euler_table(quat.from_euler(e_true + off), quat.from_euler(e_true))
    assert list(table) == ["yaw", "pitch", "roll"]
    for ang, d in zip(table, np.degrees(off)):
        st = table[ang]
        assert np.isclose(st["mean"], d) and np.isclose(st["MAE"], abs(d))
        assert np.isclose(st["RMSE"], abs(d)) and st["std"] < 1e-9


def test_euler_table_wraps_yaw_and_matches_definitions():
    # yaw 179 deg estimated as -179 deg: a 2 deg error, not 358
    t = metrics.euler_table(quat.from_euler([np.radians(-179), 0, 0]), quat.from_euler([np.radians(179), 0, 0]))
    assert np.isclose(t["yaw"]["mean"], 2.0)
    e = np.radians(RNG.normal(0, 1.0, (1000, 3)))
    base = np.column_stack([RNG.uniform(-3, 3, 1000), np.zeros(1000), np.zeros(1000)])
    tab = metrics.euler_table(quat.from_euler(base + e), quat.from_euler(base))
    d = np.degrees(e)
    for i, ang in enumerate(metrics.ANGLES):
        assert np.isclose(tab[ang]["RMSE"] ** 2, tab[ang]["mean"] ** 2 + tab[ang]["std"] ** 2)
        assert np.isclose(tab[ang]["mean"], d[:, i].mean(), atol=1e-6)
        assert np.isclose(tab[ang]["MAE"], np.abs(d[:, i]).mean(), atol=1e-6)


# --- spectrum ----------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1000, 1001])
def test_spectrum_amplitudes(n):
    fs = 200.0
    t = np.arange(n) / fs
    f1 = 20 * fs / n * np.floor(n / 20 / 10)        # on a bin
    x = 0.7 + 1.5 * np.sin(2 * np.pi * f1 * t)
    f, a = metrics.spectrum(x, fs, detrend=False)
    assert f.shape == a.shape == (n // 2 + 1,)
    assert np.isclose(f[1], fs / n) and np.isclose(f[-1], fs / n * (n // 2))
    k = int(round(f1 * n / fs))
    assert np.isclose(a[k], 1.5) and np.isclose(a[0], 0.7)
    _, a2 = metrics.spectrum(np.column_stack([x, 2 * x]), fs)
    assert a2.shape == (n // 2 + 1, 2) and np.isclose(a2[k, 1], 3.0) and a2[0, 0] < 1e-12


def test_spectrum_errors():
    with pytest.raises(ValueError, match="at least 2"):
        metrics.spectrum([1.0], 100)
    with pytest.raises(ValueError, match="fs"):
        metrics.spectrum(np.zeros(10), 0)
    with pytest.raises(ValueError, match="finite"):
        metrics.spectrum([0.0, np.nan, 1.0], 100)


def test_metrics_import_is_light():
    code = ("import sys, fusion.metrics, fusion.quat, fusion.datasets, fusion.scenarios, benchmarks.compare; "
            "bad = [m for m in ('matplotlib', 'torch', 'tqdm', 'scipy') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=str(__import__("pathlib").Path(__file__).parents[1]))


def test_an_estimate_of_huge_or_tiny_scale_is_scored_as_its_rotation():
    """A finite estimate whose squared components overflow (1e200) or underflow (1e-200) is
    the same rotation as its unit copy: normalised through its largest component, scored as
    such (its norm read as inf or 0 made it NaN, or a perfect 0 deg)."""
    ref = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    turn = np.array([np.cos(np.radians(15)), np.sin(np.radians(15)), 0.0, 0.0])    # 30 deg about x
    for scale in (1e200, 1e-200):
        est = np.tile(turn, (4, 1))
        est[1] *= scale
        np.testing.assert_allclose(quat.normalise(est), np.tile(turn, (4, 1)), rtol=0, atol=1e-15)
        s = metrics.score(est, ref)
        assert abs(s["inclination"] - 30.0) < 1e-9 and abs(s["total"] - 30.0) < 1e-9, s
    assert np.isnan(quat.normalise([[0.0, 0.0, 0.0, 0.0], [np.inf, 0.0, 0.0, 0.0]])).all()


def test_euler_table_drops_a_zero_reference_row_as_score_does():
    est = np.tile([np.cos(0.05), 0.0, 0.0, np.sin(0.05)], (5, 1))      # 5.73 deg of yaw
    ref = np.tile([1.0, 0.0, 0.0, 0.0], (5, 1))
    ref[2] = 0.0
    t = metrics.euler_table(est, ref)
    assert abs(t["yaw"]["RMSE"] - np.degrees(0.1)) < 1e-9 and np.isfinite(t["roll"]["mean"]), t
    assert abs(metrics.score(est, ref)["heading"] - np.degrees(0.1)) < 1e-9


def test_a_row_without_a_reference_is_dropped_whatever_the_estimate():
    """A zero reference row is no reference (as a non-finite one): the estimate there is not
    judged, even NaN; on a row with a reference a NaN estimate is an error."""
    est = np.array([[1.0, 0.0, 0.0, 0.0], [np.nan] * 4])
    e = metrics.attitude_errors(est, [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    assert e["total"][0] == 0.0 and np.isnan(e["total"][1])
    with pytest.raises(ValueError, match="rows without a reference"):
        metrics.attitude_errors(est, [[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
