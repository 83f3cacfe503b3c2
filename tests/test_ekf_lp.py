"""`ekf-lp` (docs/estimators.md): the `ekf` inside, unchanged; VQF's inclination filter on what
it reports. Checked against the peer it takes its inclination filter from (VQF, with the bias
held at zero on both sides) and against the plain `ekf` (the low-pass feeds nothing back).
The numpy reference of tests/reference.py is compared in tests/test_reference.py."""
import numpy as np
import pytest

import fusion
from fusion import quat

FS = 100.0
UP = np.array([0.0, 0.0, 1.0])


def moving(n=3000, seed=0, fs=FS):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    gyr = np.c_[np.sin(0.7 * t), 0.5 * np.cos(1.3 * t), 0.3 * np.sin(0.4 * t + 1)] + 0.01 * rng.standard_normal((n, 3))
    # gravity in the body frame of the gyro's own attitude, plus a shaking linear acceleration
    q = fusion.make("gyro", fs).run(gyr, np.tile([0.0, 0.0, 9.81], (n, 1)))
    acc = quat.rotate_inverse(q, np.array([0.0, 0.0, 9.81])) + 0.5 * rng.standard_normal((n, 3))
    mag = quat.rotate_inverse(q, np.array([0.0, 20.0, -40.0]))
    return gyr, acc, mag


def low_passed_up(est, gyr, acc):
    """The low-pass's vertical (its unit vector, body frame) after each sample."""
    up = []
    for g, a in zip(gyr, acc):
        est.update(g, a)
        y = np.asarray(est.state()["fields"]["incl_y"])
        up.append(y / np.linalg.norm(y))
    return np.array(up)


@pytest.mark.parametrize("tau", [3.0, 0.5])
def test_inclination_is_vqfs_with_the_bias_held_at_zero(tau):
    """VQF's 6-D inclination is its Butterworth-low-passed accelerometer in the gyro frame;
    with both biases held at zero the low-pass must agree with it through the start, the
    hand-over to the Butterworth (at incl_lowpass s) and after, to round-off; and from the
    hand-over on, so must the reported inclination."""
    vqf = pytest.importorskip("vqf")
    gyr, acc, _ = moving()
    params = dict(bias_init_std=0.0, bias_noise=0.0, rest_time=0.0, incl_lowpass=tau)
    v = vqf.VQF(1.0 / FS, tauAcc=tau, motionBiasEstEnabled=False, restBiasEstEnabled=False)
    up_vqf = quat.rotate_inverse(np.asarray(v.updateBatch(gyr, acc)["quat6D"]), UP)
    assert np.abs(low_passed_up(fusion.make("ekf-lp", FS, **params), gyr, acc) - up_vqf).max() < 1e-9
    up = quat.rotate_inverse(fusion.make("ekf-lp", FS, **params).run(gyr, acc), UP)
    settled = np.arange(len(gyr)) >= round(tau * FS) - 1
    assert np.abs(up - up_vqf)[settled].max() < 1e-9


def test_the_start_turns_from_the_ekfs_inclination_to_the_mean():
    """During the running mean the reported vertical lies on the arc from the `ekf`'s to the
    mean's, at the part (time the mean spans) / incl_lowpass of its angle: the first sample
    reports the `ekf`'s attitude, and the turn grows to the whole at the hand-over."""
    gyr, acc, _ = moving(n=400, seed=3)
    lp, ekf = fusion.make("ekf-lp", FS), fusion.make("ekf", FS)
    mean_up = low_passed_up(lp, gyr, acc)
    lp.reset()
    up_lp = quat.rotate_inverse(lp.run(gyr, acc), UP)
    q_ekf = ekf.run(gyr, acc)
    up_ekf = quat.rotate_inverse(q_ekf, UP)
    # the point of the great-circle arc from the ekf's vertical to the mean's, at frac of its angle
    full = np.arccos(np.clip(np.sum(up_ekf * mean_up, 1), -1.0, 1.0))
    frac = np.minimum((np.arange(len(gyr)) + 1) / FS / 3.0, 1.0)
    tiny = full < 1e-6          # the arc is a point (the first sample: the ekf starts on it)
    s = np.where(tiny, 1.0, np.sin(full))
    w0 = np.where(tiny, 1.0 - frac, np.sin((1 - frac) * full) / s)
    w1 = np.where(tiny, frac, np.sin(frac * full) / s)
    on_arc = w0[:, None] * up_ekf + w1[:, None] * mean_up
    assert full[100:].max() > np.radians(0.5)       # the two differ: the test can tell
    np.testing.assert_allclose(up_lp, on_arc, atol=1e-9)


def test_the_ekf_inside_is_unchanged():
    """Bias, covariance and internal attitude are the `ekf`'s to round-off (the `ekf`'s run
    inlines its step into its loop, `ekf-lp` calls it: the compiler may round them apart);
    only the reported attitude differs, and by an inclination (a turn about a horizontal
    axis)."""
    gyr, acc, mag = moving(seed=1)
    lp, ekf = fusion.make("ekf-lp", FS), fusion.make("ekf", FS)
    q_lp, q_ekf = lp.run(gyr, acc, mag), ekf.run(gyr, acc, mag)
    assert np.abs(lp.bias - ekf.bias).max() < 1e-12
    assert np.abs(lp.covariance - ekf.covariance).max() < 1e-12 * np.abs(ekf.covariance).max()
    assert np.abs(np.asarray(lp.state()["fields"]["q"]) - ekf.state()["fields"]["q"]).max() < 1e-12
    turn = quat.mul(q_lp, quat.conj(q_ekf))         # c with q_lp = c ⊗ q_ekf: no vertical part
    assert np.abs(turn[:, 3]).max() < 1e-12
    assert 0.05 < np.degrees(quat.angle(q_lp, q_ekf)).max() < 10.0


def test_a_lost_gyro_restarts_the_low_pass():
    """A step the gyro did not measure (here a NaN sample, skipped) restarts the running mean
    from the next accelerometer sample; a gap of more than two periods too. The first sample
    weighs one period, not the gap it follows (a 1 s gap gave one jolted sample the weight of
    100: 11.5 deg of tilt 0.5 s later)."""
    gyr, acc, _ = moving(n=600, seed=2)
    est = fusion.make("ekf-lp", FS, on_invalid="skip")
    est.run(gyr[:400], acc[:400])
    assert est.state()["fields"]["incl_t"] == 3.0       # settled (400 samples > 3 s)
    est.update(np.full(3, np.nan), acc[400])
    assert est.state()["fields"]["incl_t"] == pytest.approx(0.01)
    est.update(gyr[401], acc[401])
    assert est.state()["fields"]["incl_t"] == pytest.approx(0.02)
    est.update(gyr[402], acc[402], dt=0.05)
    assert est.state()["fields"]["incl_t"] == pytest.approx(0.01)
    est.update(gyr[403], acc[403], dt=100.0)
    assert est.state()["fields"]["incl_t"] == pytest.approx(0.01)


@pytest.mark.parametrize("bad", [0.0, -1.0, 1e5, np.nan, "3", 0.0105])
def test_bad_incl_lowpass_is_a_value_error(bad):
    with pytest.raises(ValueError, match="incl_lowpass"):
        fusion.make("ekf-lp", FS, incl_lowpass=bad)
    fusion.make("ekf-lp", FS, incl_lowpass=0.0111)     # just over 1.1 sample periods: accepted
    fusion.make("ekf-lp", 100.0, incl_lowpass=0.011)    # 1.1 periods as written (1.1 / 100 rounds above it)


def test_the_default_at_a_rate_too_low_for_it():
    """Not given, incl_lowpass is 3 s or 1.1 sample periods where that is longer (below
    0.37 Hz), as iir-ekf's cutoff is lowered; given, a too-short one is refused."""
    assert fusion.make("ekf-lp", 100.0).incl_lowpass == 3.0
    assert fusion.make("ekf-lp", 0.01).incl_lowpass == pytest.approx(110.0)
    with pytest.raises(ValueError, match="incl_lowpass must be at least 1.1 sample periods"):
        fusion.make("ekf-lp", 0.01, incl_lowpass=3.0)


def test_incl_lowpass_has_a_ceiling_where_the_butterworth_holds():
    """Its cutoff √2 / (2π incl_lowpass) must be at least 1e-7 fs (fusion._prefilter's floor),
    so incl_lowpass at most 2.25e6 / fs; not given, the default is held below it (fs above
    750 kHz); given, a longer one is refused."""
    assert fusion.make("ekf-lp", 1e6).incl_lowpass == pytest.approx(np.sqrt(2) / (2e-7 * np.pi * 1e6))
    fusion.make("ekf-lp", 1e3, incl_lowpass=2250.0)
    fusion.make("ekf-lp", 1e3, incl_lowpass=2250.79)           # the bound as the message prints it
    fusion.make("ekf-lp", 7.0, incl_lowpass=0.157)              # (1.1 / 7 = 0.15714...)
    fusion.make("ekf-lp", 2222.2222, incl_lowpass=1012.86)      # (1012.8596...)
    with pytest.raises(ValueError, match="incl_lowpass must be at most 2250.79 s"):
        fusion.make("ekf-lp", 1e3, incl_lowpass=2260.0)


def test_a_refused_reinit_changes_nothing():
    """A second __init__ refused by the base's checks (here the frame) leaves incl_lowpass and
    the coefficients as they were."""
    gyr, acc, _ = moving(n=500, seed=3)
    e, same = fusion.make("ekf-lp", FS), fusion.make("ekf-lp", FS)
    with pytest.raises(ValueError, match="frame"):
        e.__init__(FS, frame="bogus", incl_lowpass=0.5)
    assert e.incl_lowpass == 3.0
    assert np.array_equal(e.run(gyr, acc), same.run(gyr, acc))
