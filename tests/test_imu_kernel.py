"""The IMU model's compiled streaming step (fusion/_imu.pyx) against the Python reference
(``IMU(..., compiled=False)``): same generator, same numbers, every error source on."""
import math

import numpy as np
import pytest

from fusion import imu

G = 9.81


def full_spec(sampling="hold", n_tones=8, mag_rate=70.0):
    """Every error source of the model on, the range small enough to saturate."""
    gyro = imu.SensorSpec(noise_density=0.01 * imu.DEG, bias_instability=20 * imu.DPH, bias_corr_time_s=5.0,
                          bias_random_walk=0.01 * imu.DEG, bias_turn_on=(1.0 * imu.DEG, 2.0 * imu.DEG, 0.5 * imu.DEG),
                          scale_error=0.03, misalignment=0.02, range=3.0, lsb=imu.DEG / 131.0, adc_bits=16,
                          lpf_hz=40.0, noise_bw_hz=55.0)
    acc = imu.SensorSpec(noise_density=300 * imu.UG, bias_instability=0.2 * imu.MG, bias_corr_time_s=3.0,
                         bias_random_walk=0.002, bias_turn_on=60 * imu.MG, scale_error=0.03, misalignment=0.02,
                         range=2.0 * imu.G0, lsb=imu.G0 / 16384.0, adc_bits=16, lpf_hz=30.0)
    mag = imu.MagSpec(noise_rms=0.6, range=120.0, lsb=0.15, adc_bits=14, rate_hz=mag_rate, hard_iron=40.0,
                      soft_iron=0.05)
    vib = imu.Vibration(60.0, 90.0, acc_rms=3.0, gyr_rms=0.05, n_tones=n_tones)
    return imu.IMUSpec("all-errors", gyro=gyro, acc=acc, mag=mag, rate_hz=200.0, jitter_s=50e-6,
                       vibration=vib, sampling=sampling)


def motion(n, seed=3):
    """True signals at 1 kHz with saturating peaks and a magnetic disturbance (a dipole
    passing by), so clipping, quantisation and the field's soft/hard iron all act."""
    r = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    f = r.uniform(0.1, 4.0, (3, 3))
    ph = r.uniform(0, 2 * np.pi, (3, 3))
    gyr = np.stack([3.5 * np.sin(2 * np.pi * f[0, i] * t + ph[0, i]) for i in range(3)], 1)
    acc = np.stack([15 * np.sin(2 * np.pi * f[1, i] * t + ph[1, i]) for i in range(3)], 1) + [0, 0, G]
    pts = np.stack([0.3 * np.sin(0.2 * t), 0.2 * np.cos(0.13 * t), 0.05 + 0 * t], 1)
    mag = (np.array([20.0, 5.0, -40.0]) + 10 * np.sin(t[:, None] * [1.0, 2.0, 0.5])
           + imu.dipole_field(pts, [0.0, 0.0, 0.0], [0.0, 0.0, 0.05]))
    return t, gyr, acc, mag


def run(sensor, gyr, acc, mag, dts):
    out = []
    for i in range(len(gyr)):
        s = sensor.step(gyr[i], acc[i], None if mag is None else mag[i], dt=None if dts is None else dts[i])
        if s is not None:
            out.append(s)
    return out


def assert_same(a, b):
    assert len(a) == len(b) > 0
    for f in ("t", "dt", "index"):
        np.testing.assert_allclose([getattr(s, f) for s in a], [getattr(s, f) for s in b], rtol=0, atol=1e-12)
    for f in ("gyr", "acc"):
        np.testing.assert_allclose(np.array([getattr(s, f) for s in a]), np.array([getattr(s, f) for s in b]),
                                   rtol=0, atol=1e-12)
    if a[0].mag is None:
        assert all(s.mag is None for s in b)
    else:
        np.testing.assert_allclose(np.array([s.mag for s in a]), np.array([s.mag for s in b]), rtol=0, atol=1e-12)


@pytest.mark.parametrize("sampling, n_tones, mag_rate, uneven, has_mag", [
    ("hold", 8, 70.0, False, True),
    ("hold", 3, None, True, True),
    ("average", 13, 70.0, False, True),
    ("average", 1, None, True, False),
])
def test_kernel_equals_python_reference(sampling, n_tones, mag_rate, uneven, has_mag):
    spec = full_spec(sampling, n_tones, mag_rate)
    n = 60_000                                          # 60 s at 1 kHz: 12,000 samples
    t, gyr, acc, mag = motion(n)
    dts = None
    if uneven:                                          # physics steps of 0.6 to 1.4 ms
        dts = np.random.default_rng(5).uniform(0.6e-3, 1.4e-3, n)
    if not has_mag:
        mag = None
    ref = imu.IMU(spec, np.random.default_rng(11), physics_rate_hz=1000.0, compiled=False)
    ker = imu.IMU(spec, np.random.default_rng(11), physics_rate_hz=1000.0)
    a, b = run(ref, gyr, acc, mag, dts), run(ker, gyr, acc, mag, dts)
    assert_same(a, b)
    g = np.array([s.gyr for s in b])
    lsb = imu.DEG / 131.0
    assert np.any(np.abs(g) >= 3.0 - lsb)               # the range clipped
    np.testing.assert_allclose(g / lsb, np.rint(g / lsb), atol=1e-9)   # whole LSB
    # a new record with reseeding: still the same
    ref.reset(np.random.default_rng(2))
    ker.reset(np.random.default_rng(2))
    assert_same(run(ref, gyr[:5000], acc[:5000], None if mag is None else mag[:5000], None),
                run(ker, gyr[:5000], acc[:5000], None if mag is None else mag[:5000], None))


def test_kernel_mixes_with_simulate_as_the_reference_does():
    """simulate and step share one state: a record made of step, simulate, step pieces is the
    same with the kernel as with the Python step."""
    spec = full_spec()
    t, gyr, acc, mag = motion(9000)
    out = []
    for compiled in (False, True):
        s = imu.IMU(spec, np.random.default_rng(4), physics_rate_hz=1000.0, compiled=compiled)
        a = run(s, gyr[:3000], acc[:3000], mag[:3000], None)
        rec = s.simulate(t[3000:6000], gyr[3000:6000], acc[3000:6000], mag[3000:6000])
        b = run(s, gyr[6000:], acc[6000:], mag[6000:], None)
        out.append((a, rec, b))
    assert_same(out[0][0], out[1][0])
    assert_same(out[0][2], out[1][2])
    for f in ("t", "gyr", "acc", "mag", "dt", "index"):
        np.testing.assert_allclose(getattr(out[0][1], f), getattr(out[1][1], f), rtol=0, atol=1e-12)


def test_kernel_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="compiled"):
        imu.IMU("mpu9250", np.random.default_rng(0), compiled="yes")
    s = imu.IMU("mpu9250", np.random.default_rng(0), physics_rate_hz=1000.0)
    with pytest.raises(ValueError, match="gyr_true"):
        s.step("abc", (0, 0, G), (1, 2, 3))
    with pytest.raises(ValueError, match="acc_true"):
        s.step((0, 0, 0), (0, 0), (1, 2, 3))
    s.step((0, 0, 0), (0, 0, G), (1, 2, 3))
    with pytest.raises(ValueError, match="mag_true must be given"):
        s.step((0, 0, 0), (0, 0, G))
    with pytest.raises(ValueError, match="dt"):
        s.step((0, 0, 0), (0, 0, G), (1, 2, 3), dt=-1.0)
    with pytest.raises(ValueError, match="finite"):
        for _ in range(10):
            s.step((math.nan, 0, 0), (0, 0, G), (1, 2, 3))


def test_copy_and_pickle_continue_the_record():
    """A copy (or a pickled IMU) taken mid-record continues it as the original does."""
    import copy
    import pickle
    t, gyr, acc, mag = motion(4000)
    s = imu.IMU(full_spec(), np.random.default_rng(8), physics_rate_hz=1000.0)
    run(s, gyr[:2000], acc[:2000], mag[:2000], None)
    c, p = copy.deepcopy(s), pickle.loads(pickle.dumps(s))
    a = run(s, gyr[2000:], acc[2000:], mag[2000:], None)
    assert_same(a, run(c, gyr[2000:], acc[2000:], mag[2000:], None))
    assert_same(a, run(p, gyr[2000:], acc[2000:], mag[2000:], None))


@pytest.mark.parametrize("compiled", [True, False])
def test_step_refuses_a_bad_row_on_a_step_without_a_sample(compiled):
    """A NaN on a physics step whose IMU sample is not due is refused on that step, naming the
    argument (it used to enter the low-pass and fail the next samples as if they were bad);
    a scalar, a string or a complex row and a dt that is not a number are refused alike."""
    s = imu.IMU("mpu9250", np.random.default_rng(0), physics_rate_hz=1000.0, compiled=compiled)
    s.step((0.0, 0.0, 0.0), (0.0, 0.0, G))
    with pytest.raises(ValueError, match="gyr_true must be 3 finite real numbers"):
        s.step((math.nan, 0.0, 0.0), (0.0, 0.0, G))
    for bad in (5.0, "1 2 3", np.array([1j, 0, 0]), np.array([True, False, True]),
                np.array([np.longdouble("1e400"), 0, 0]), (True, 0.0, 9.81)):
        with pytest.raises(ValueError, match="acc_true must be 3 finite real numbers"):
            s.step((0.0, 0.0, 0.0), bad)
    with pytest.raises(ValueError, match="acc_true is a masked array"):
        s.step((0.0, 0.0, 0.0), np.ma.masked_array([0.0, 0.0, G], [1, 0, 0]))
    for dt in (np.array([0.001]), "0.001", True):
        with pytest.raises(ValueError, match="dt must be a real number"):
            s.step((0.0, 0.0, 0.0), (0.0, 0.0, G), dt=dt)
    out = [s.step((0.0, 0.0, 0.0), (0, 0, 9.81)) for _ in range(20)]     # ints accepted
    assert any(o is not None for o in out) and all(np.isfinite(o.acc).all() for o in out if o is not None)
