"""fusion.scenarios.seed_scenario: the source documents' experiments through fusion.imu."""
import numpy as np
import pytest

import fusion
from fusion import imu, metrics, quat, scenarios

# documented (IMU preset, output rate Hz, samples)
EXPECTED = {
    "seed000-static": ("mpu6050+mag3110", 10.0, 1500),
    "seed001-slow": ("mti10", 256.0, 7680),
    "seed001-fast": ("mti10", 256.0, 5632),
    "seed001-faster": ("mti10", 256.0, 5632),
    "seed003-static": ("icm20602+qmc5883l", 200.0, 5000),
    "seed003-dynamic": ("icm20602+qmc5883l", 200.0, 4417),
    "seed003-vibration": ("icm20602+qmc5883l", 200.0, 5000),
    "seed004-static": ("mpu9250", 500.0, 30000),
    "seed004-fast": ("mpu9250", 500.0, 15000),
    "linear-acceleration": ("icm20602+qmc5883l", 200.0, 12000),
    "magnetic-disturbance": ("icm20602+qmc5883l", 200.0, 12000),
}
STATIC = ("seed000-static", "seed003-static", "seed003-vibration", "seed004-static")


def test_the_names_are_the_documented_ones():
    assert list(scenarios.SEED_SCENARIOS) == list(EXPECTED)
    assert all(isinstance(d, str) and d for d in scenarios.SEED_SCENARIOS.values())


@pytest.mark.parametrize("name", list(EXPECTED))
def test_generates_with_documented_rate_and_length(name):
    preset, fs, n = EXPECTED[name]
    s = scenarios.seed_scenario(name, seed=1)
    assert s.name == name and s.fs == fs and s.n == n
    assert s.preset == imu.preset(preset, calibrated=True).name
    for a in (s.gyr, s.acc, s.mag, s.omega, s.a_lin):
        assert a.shape == (n, 3) and np.isfinite(a).all()
    assert s.q_true.shape == (n, 4) and np.allclose(np.linalg.norm(s.q_true, axis=1), 1.0)
    # sample instants at the rate, with the preset's small jitter only
    assert np.allclose(s.t, np.arange(n) / fs, atol=0.2 / fs)
    assert np.abs(s.dt - 1.0 / fs).max() < 0.1 / fs and abs(s.dt.mean() * fs - 1.0) < 1e-3
    assert s.acc_disturbed.shape == s.mag_disturbed.shape == (n,)


@pytest.mark.parametrize("name", [n for n in EXPECTED if n != "seed003-vibration"])
def test_truth_is_what_an_ideal_gyro_integrates(name):
    """Ideal sensor, gyro integration from the true start: the mid-step rate (mean of two
    point samples) reproduces q_true to O(dt²); one sample of misalignment would be ~ω dt."""
    s = scenarios.seed_scenario(name, seed=2, imu="ideal")
    if name in STATIC:
        assert not s.omega.any()
        assert np.degrees(quat.angle(s.q_true, s.q_true[0])).max() == 0.0
    mid = 0.5 * (s.gyr[1:] + s.gyr[:-1])
    est = fusion.make("gyro", s.fs)
    est.reset(s.q_true[0])
    q = est.run(mid, s.acc[1:], None, dt=s.dt[1:])
    err = np.degrees(quat.angle(q, s.q_true[1:]))
    assert err.max() < 0.1
    if name not in STATIC:
        shifted = np.degrees(quat.angle(q[:-1], s.q_true[2:]))
        assert err.max() < 0.2 * shifted.max()
    # the ideal accelerometer and magnetometer read the truth (specific force, field + disturbance)
    f = quat.rotate(s.q_true, s.acc) - s.a_lin
    assert np.allclose(f, [0, 0, scenarios.G], atol=0.05 if s.params["lever"] else 1e-9)


def test_static_scenarios_hold_still_and_noise_is_the_sensors():
    s = scenarios.seed_scenario("seed003-static", seed=0)
    assert not s.omega.any() and not s.a_lin.any() and not s.disturbed.any()
    # calibrated icm20602: residual turn-on bias ~0.05 deg/s, white noise ~0.04 deg/s per sample
    assert np.degrees(np.abs(s.gyr.mean(axis=0))).max() < 0.3
    assert 0.01 < np.degrees(s.gyr.std(axis=0)).mean() < 0.2


def test_reproducible_and_seed_dependent():
    a = scenarios.seed_scenario("seed001-fast", seed=5)
    b = scenarios.seed_scenario("seed001-fast", seed=5)
    c = scenarios.seed_scenario("seed001-fast", seed=6)
    for f in ("q_true", "gyr", "acc", "mag", "t"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert not np.allclose(a.q_true, c.q_true)
    assert not np.allclose(a.gyr, c.gyr)


def test_disturbance_episodes_are_there():
    fast = scenarios.seed_scenario("seed001-fast", seed=0)
    # still until 6.5 s and after 15.4 s, arm-like linear acceleration in between
    still = (fast.t < 6.4) | (fast.t > 15.5)
    assert not fast.omega[still].any()
    assert fast.acc_disturbed[~still].mean() > 0.2 and not fast.acc_disturbed[still].any()
    assert 0.5 < fast.mag_disturbed.sum() / fast.fs < 10.0          # an episode of seconds
    lin = scenarios.seed_scenario("linear-acceleration", seed=0)
    run = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], lin.acc_disturbed.astype(int), [0]]))))[::2]
    assert len(run) == 3 and run.min() / lin.fs > 2.5                # sustained, not bursts
    mag = scenarios.seed_scenario("magnetic-disturbance", seed=0)
    disturbed_field = quat.rotate(mag.q_true, mag.mag)               # earth frame, with the magnet
    dev = np.linalg.norm(disturbed_field - mag.field, axis=1)
    assert dev[mag.mag_disturbed].max() > 10.0 and np.median(dev[~mag.mag_disturbed]) < 3.0
    assert not mag.acc_disturbed.any()


def test_vibration_aliases_into_the_accelerometer_spectrum():
    vib = scenarios.seed_scenario("seed003-vibration", seed=0)
    calm = scenarios.seed_scenario("seed003-static", seed=0)
    f, amp = metrics.spectrum(vib.acc[:, 0], vib.fs)
    _, amp0 = metrics.spectrum(calm.acc[:, 0], calm.fs)
    tones = vib.params["imu_constants"]["vibration_hz"][3]             # accelerometer x
    assert ((tones >= 130) & (tones <= 200)).all()
    alias = np.abs(tones - vib.fs * np.round(tones / vib.fs))          # 130-200 Hz -> 0-70 Hz
    peak = f[np.argmax(amp)]
    assert np.abs(alias - peak).min() < 0.1
    assert amp.max() > 0.1 and amp0.max() < 0.02 and peak <= 70.0


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown seed scenario .*seed000-static"):
        scenarios.seed_scenario("seed002-static")
    for bad in (0.0, -1.0, float("nan"), float("inf"), "10", True, 0.001):
        with pytest.raises(ValueError, match="duration"):
            scenarios.seed_scenario("seed003-static", duration=bad)
    with pytest.raises(ValueError, match="unknown IMU preset .*mpu9250"):
        scenarios.seed_scenario("seed003-static", imu="bmi160")
    with pytest.raises(ValueError, match="seed"):
        scenarios.seed_scenario("seed003-static", seed=-1)


def test_duration_and_imu_overrides():
    s = scenarios.seed_scenario("seed004-static", duration=2.0, imu="mti10", calibrated=False)
    assert s.n == 1000 and s.fs == 500.0 and s.preset == "mti10"
    spec = imu.preset("ideal")
    s = scenarios.seed_scenario("seed000-static", duration=5.0, imu=spec)
    assert s.n == 50 and np.array_equal(s.gyr, np.zeros((50, 3)))
