"""fusion.imu: the IMU sensor model (docs/imu.md)."""
import math

import numpy as np
import pytest

from fusion import imu

G = 9.81
FIELD = np.array([5.0, 20.0, -40.0])          # uT, a body-frame field


def static_inputs(n):
    return np.zeros((n, 3)), np.tile([0.0, 0.0, G], (n, 1)), np.tile(FIELD, (n, 1))


def moving_inputs(n, fs, seed=0):
    """Smooth, non-trivial true signals at the physics rate."""
    r = np.random.default_rng(seed)
    t = np.arange(n) / fs
    f = r.uniform(0.2, 3.0, (3, 3))
    ph = r.uniform(0, 2 * np.pi, (3, 3))
    gyr = np.stack([np.sin(2 * np.pi * f[0, i] * t + ph[0, i]) for i in range(3)], 1)
    acc = np.stack([2 * np.sin(2 * np.pi * f[1, i] * t + ph[1, i]) for i in range(3)], 1) + [0, 0, G]
    mag = np.stack([10 * np.sin(2 * np.pi * f[2, i] * t + ph[2, i]) for i in range(3)], 1) + FIELD
    return t, gyr, acc, mag


def stream(sensor, gyr, acc, mag, dt):
    out = []
    for i in range(len(gyr)):
        s = sensor.step(gyr[i], acc[i], None if mag is None else mag[i], dt=None if i == 0 else dt[i])
        if s is not None:
            out.append(s)
    return out


def assert_same(rec, samples, has_mag=True):
    assert len(rec) == len(samples)
    np.testing.assert_allclose(rec.t, [s.t for s in samples], rtol=0, atol=1e-9)
    np.testing.assert_allclose(rec.dt, [s.dt for s in samples], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(rec.index, [s.index for s in samples])
    np.testing.assert_allclose(rec.gyr, [s.gyr for s in samples], rtol=0, atol=1e-9)
    np.testing.assert_allclose(rec.acc, [s.acc for s in samples], rtol=0, atol=1e-9)
    if has_mag:
        np.testing.assert_allclose(rec.mag, [s.mag for s in samples], rtol=0, atol=1e-9)
    else:
        assert rec.mag is None and all(s.mag is None for s in samples)


# ---------------------------------------------------------------------------------------
# presets


def test_presets_are_there_and_simulate():
    assert imu.available() == ["ideal", "mpu6050+mag3110", "mti10", "icm20602+qmc5883l", "mpu9250"]
    rates = {"ideal": 100.0, "mpu6050+mag3110": 10.0, "mti10": 256.0, "icm20602+qmc5883l": 200.0, "mpu9250": 500.0}
    for name, spec in imu.PRESETS.items():
        assert imu.preset(name) is spec and spec.name == name and spec.rate_hz == rates[name]
        n = 1000
        t = np.arange(n) / 1000.0
        rec = imu.IMU(name, np.random.default_rng(0)).simulate(t, *static_inputs(n))
        assert rec.gyr.shape == rec.acc.shape == rec.mag.shape == (len(rec), 3)
        assert abs(len(rec) - spec.rate_hz) <= 1 and rec.fs == spec.rate_hz
        assert np.all(np.isfinite(rec.gyr)) and np.all(np.isfinite(rec.acc))
        cal = imu.preset(name, calibrated=True)
        assert cal.gyro.bias_turn_on == spec.gyro.bias_turn_on_calibrated
        assert cal.mag.hard_iron == spec.mag.hard_iron_calibrated


def test_mti10_reproduces_seed001_standard_deviations():
    """Seed 001 quotes the MTi-10's standard deviations 0.006 / 0.008 / 0.001: rad/s, m/s^2
    and (Xsens' field unit, normalised to the earth field of about 0.5 G) 0.5 mG = 0.05 uT."""
    n = 60 * 256
    t = np.arange(n) / 256.0
    rec = imu.IMU("mti10", np.random.default_rng(1)).simulate(t, *static_inputs(n))
    assert np.std(rec.gyr, axis=0) == pytest.approx([0.006] * 3, rel=0.15)
    assert np.std(rec.acc, axis=0) == pytest.approx([0.008] * 3, rel=0.2)   # 80 ug/sqrt(Hz): 0.0089
    assert np.std(rec.mag, axis=0) == pytest.approx([0.001 * 50.0] * 3, rel=0.15)


# ---------------------------------------------------------------------------------------
# noise: Allan deviation


def test_allan_deviation_of_white_noise():
    r = np.random.default_rng(0)
    x = r.standard_normal((200_000, 2)) * 0.3
    taus, ad = imu.allan_deviation(x, 100.0, taus=[0.01, 0.1, 1.0, 10.0])
    np.testing.assert_allclose(taus, [0.01, 0.1, 1.0, 10.0])
    expect = 0.3 / np.sqrt(taus * 100.0)          # sigma / sqrt(m)
    np.testing.assert_allclose(ad, np.stack([expect] * 2, 1), rtol=0.06)


def test_allan_static_gyro_mpu6050_matches_preset():
    """Seed 000's part, 20000 s static at 10 Hz: ARW (the -1/2 line and the curve at 1 s) and
    the flat floor / 0.664 within 20 % of the preset's figures. The ARW is the output's: its
    5 Hz DLPF's noise bandwidth (7.85 Hz) aliases at 10 Hz, density_at(10) = 1.31 x the
    datasheet's density (docs/imu.md)."""
    spec = imu.preset("mpu6050+mag3110")
    fs, n = spec.rate_hz, 200_000
    t = np.arange(n) / fs
    rec = imu.IMU(spec, np.random.default_rng(7)).simulate(t, *static_inputs(n)[:2])
    taus, ad = imu.allan_deviation(rec.gyr, fs)
    g = spec.gyro
    floor_window = (taus >= g.bias_corr_time_s / 15) & (taus <= g.bias_corr_time_s / 1.5)
    for ax in range(3):
        sm = imu.allan_summary(taus, ad[:, ax], fs)
        arw = g.density_at(fs) / math.sqrt(2.0)                      # 8.1e-5 rad/s sqrt(s)
        assert sm["arw"] == pytest.approx(arw, rel=0.2)
        assert sm["adev_1s"] == pytest.approx(arw, rel=0.2)
        floor = np.median(ad[floor_window, ax])
        assert floor / imu.ALLAN_FLOOR == pytest.approx(g.bias_instability, rel=0.2)   # 10 deg/h
        # and the whole curve follows the model (white, bias instability, random walk, LSB)
        ok = taus <= 300.0                          # >= 60 clusters
        np.testing.assert_allclose(ad[ok, ax], g.allan(taus[ok], fs), rtol=0.25)
    # velocity random walk of the accelerometer from the same record
    taus, ad = imu.allan_deviation(rec.acc, fs, taus=np.arange(1, 11) / fs)
    for ax in range(3):
        assert imu.allan_summary(taus, ad[:, ax], fs)["arw"] == pytest.approx(spec.acc.density_at(fs) / math.sqrt(2.0),
                                                                              rel=0.2)


def test_allan_static_gyro_icm20602_matches_preset():
    """Seed 003's part at 200 Hz: its +-2000 deg/s LSB (0.061 deg/s) is as large as the noise
    per sample, so the quantisation adds to the white noise as the model says."""
    spec = imu.preset("icm20602+qmc5883l")
    fs, n = spec.rate_hz, 120_000
    t = np.arange(n) / fs
    rec = imu.IMU(spec, np.random.default_rng(3)).simulate(t, *static_inputs(n)[:2])
    taus, ad = imu.allan_deviation(rec.gyr, fs, taus=[0.01, 0.02, 0.05, 0.1, 1.0])
    g = spec.gyro
    # its DLPF's noise bandwidth (306.6 Hz) exceeds the 100 Hz Nyquist rate: the output's
    # white noise is aliased, 1.75x the datasheet density (changed with the NBW model)
    assert g.density_at(fs) == pytest.approx(1.755 * g.noise_density, rel=0.01)
    for ax in range(3):
        sm = imu.allan_summary(taus, ad[:, ax], fs)
        assert sm["arw"] == pytest.approx(g.density_at(fs) / np.sqrt(2.0), rel=0.2)
        assert sm["adev_1s"] == pytest.approx(float(g.allan(1.0, fs)), rel=0.1)
    assert g.allan(1.0, fs) > 1.05 * g.arw                          # the LSB term is visible


# ---------------------------------------------------------------------------------------
# quantisation and saturation


def test_quantisation_is_whole_lsb_and_saturation_clips_to_the_range():
    spec = imu.preset("icm20602+qmc5883l")
    n = 2000
    t = np.arange(n) / 1000.0
    gyr = np.tile([0.3, -0.2, 0.1], (n, 1))
    gyr[n // 2:, 0] = 5000 * imu.DEG                    # beyond +-2000 deg/s
    gyr[n // 2:, 1] = -5000 * imu.DEG
    acc = np.tile([1.0, -2.0, G], (n, 1))
    acc[n // 2:, 2] = 20 * G                            # beyond +-8 g
    acc[n // 2:, 0] = -20 * G
    mag = np.tile(FIELD, (n, 1))
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t, gyr, acc, mag)
    for out, s in ((rec.gyr, spec.gyro), (rec.acc, spec.acc), (rec.mag, spec.mag)):
        codes = out / s.lsb
        np.testing.assert_allclose(codes, np.rint(codes), rtol=0, atol=1e-6)
    late = rec.index >= n // 2 + 5                      # past the low-pass settling
    lo, hi = spec.gyro.code_limits()
    assert (lo, hi) == (-32768.0, 32767.0)              # int16 words: +-1998 deg/s, not 2000
    assert np.all(rec.gyr[late, 0] == hi * spec.gyro.lsb)
    assert np.all(rec.gyr[late, 1] == lo * spec.gyro.lsb)
    lo, hi = spec.acc.code_limits()
    assert np.all(rec.acc[late, 2] == hi * spec.acc.lsb)
    assert np.all(rec.acc[late, 0] == lo * spec.acc.lsb)
    assert np.all(np.abs(rec.gyr) <= spec.gyro.range) and np.all(np.abs(rec.acc) <= spec.acc.range)
    # unquantised sensor with a range: clipped to exactly the range
    plain = imu.preset("ideal").replace(gyro=imu.SensorSpec(range=1.0), acc=imu.SensorSpec(range=5.0))
    rec = imu.IMU(plain, np.random.default_rng(0)).simulate(t, gyr, acc, mag)
    late = rec.index >= n // 2
    assert np.all(rec.gyr[late, 0] == 1.0) and np.all(rec.gyr[late, 1] == -1.0)
    assert np.all(rec.acc[late, 2] == 5.0) and np.all(rec.acc[late, 0] == -5.0)
    np.testing.assert_array_equal(rec.gyr[~late], gyr[rec.index[~late]])


# ---------------------------------------------------------------------------------------
# ideal sensor, reproducibility, streaming


@pytest.mark.parametrize("physics", [1000.0, 200.0])
def test_ideal_sensor_returns_the_true_signals(physics):
    n = int(3 * physics)
    t, gyr, acc, mag = moving_inputs(n, physics)
    spec = imu.preset("ideal").replace(rate_hz=200.0)
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t + 5.0, gyr, acc, mag)
    step = int(round(physics / 200.0))
    np.testing.assert_array_equal(rec.index, np.arange(0, n, step))
    np.testing.assert_array_equal(rec.gyr, gyr[::step])
    np.testing.assert_array_equal(rec.acc, acc[::step])
    np.testing.assert_array_equal(rec.mag, mag[::step])
    np.testing.assert_allclose(rec.t, t[::step] + 5.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec.dt, 1 / 200.0, rtol=1e-9)
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t, gyr, acc)     # 6-axis
    assert rec.mag is None


def test_reproducible_with_a_seed_and_different_with_another():
    n = 3000
    t, gyr, acc, mag = moving_inputs(n, 1000.0)
    runs = [imu.IMU("mpu9250", np.random.default_rng(s)).simulate(t, gyr, acc, mag) for s in (42, 42, 43)]
    for f in ("t", "gyr", "acc", "mag", "dt", "index"):
        np.testing.assert_array_equal(getattr(runs[0], f), getattr(runs[1], f))
    assert not np.allclose(runs[0].gyr, runs[2].gyr)
    assert not np.allclose(runs[0].acc, runs[2].acc)
    # the caller's generator advances by the same amount however the IMU is used
    r1, r2 = np.random.default_rng(5), np.random.default_rng(5)
    imu.IMU("mpu9250", r1).simulate(t, gyr, acc, mag)
    imu.IMU("mpu9250", r2)
    assert r1.random() == r2.random()
    # reset redraws the constants; reset(rng) reseeds
    a = imu.IMU("mpu9250", np.random.default_rng(1))
    c0 = a.constants
    a.reset()
    assert not np.allclose(c0["gyro_bias"], a.constants["gyro_bias"])
    assert not np.allclose(c0["acc_matrix"], a.constants["acc_matrix"])
    a.reset(rng=np.random.default_rng(1))
    b = imu.IMU("mpu9250", np.random.default_rng(1))
    np.testing.assert_array_equal(a.simulate(t, gyr, acc, mag).gyr, b.simulate(t, gyr, acc, mag).gyr)


CASES = [
    # preset, physics rate, changes
    ("icm20602+qmc5883l", 1000.0, dict(vibration=imu.VIBRATION_SEED003, jitter_s=200e-6)),
    ("icm20602+qmc5883l", 240.0, dict(jitter_s=100e-6)),             # not a whole number of steps
    ("mpu9250", 1000.0, {}),                                          # magnetometer at 100 Hz of 500
    ("mti10", 1000.0, dict(jitter_s=50e-6)),                          # "average" sampling
    ("mpu6050+mag3110", 100.0, {}),
]


@pytest.mark.parametrize("name,physics,changes", CASES)
def test_streaming_equals_batch(name, physics, changes):
    spec = imu.preset(name).replace(**changes)
    n = int(4 * physics)
    t, gyr, acc, mag = moving_inputs(n, physics, seed=2)
    dt = np.full(n, 1.0 / physics)
    rec = imu.IMU(spec, np.random.default_rng(9)).simulate(t, gyr, acc, mag)
    live = imu.IMU(spec, np.random.default_rng(9), physics_rate_hz=physics)
    assert_same(rec, stream(live, gyr, acc, mag, dt))
    # in chunks, and mixing the two
    a = imu.IMU(spec, np.random.default_rng(9))
    k1, k2 = n // 3, n // 3 + n // 4
    r1 = a.simulate(t[:k1], gyr[:k1], acc[:k1], mag[:k1])
    s2 = stream_continue(a, gyr[k1:k2], acc[k1:k2], mag[k1:k2], 1.0 / physics)
    r3 = a.simulate(t[k2:], gyr[k2:], acc[k2:], mag[k2:])
    assert len(s2) > 0
    for f in ("t", "gyr", "acc", "mag", "dt", "index"):
        mid = np.array([getattr(s, f) for s in s2])       # step() counts steps since reset
        got = np.concatenate([getattr(r1, f), mid, getattr(r3, f) + (k2 if f == "index" else 0)])
        np.testing.assert_allclose(got, getattr(rec, f), rtol=0, atol=1e-9, err_msg=f)


def stream_continue(sensor, gyr, acc, mag, dt):
    out = []
    for i in range(len(gyr)):
        s = sensor.step(gyr[i], acc[i], mag[i], dt)
        if s is not None:
            out.append(s)
    return out


def test_long_records_are_simulated_in_chunks(monkeypatch):
    n = 5000
    t, gyr, acc, mag = moving_inputs(n, 1000.0, seed=3)
    spec = imu.preset("mti10").replace(jitter_s=50e-6)
    whole = imu.IMU(spec, np.random.default_rng(1)).simulate(t, gyr, acc, mag)
    monkeypatch.setattr(imu, "_CHUNK", 777)
    chunked = imu.IMU(spec, np.random.default_rng(1)).simulate(t, gyr, acc, mag)
    for f in ("t", "gyr", "acc", "mag", "dt", "index"):
        np.testing.assert_allclose(getattr(chunked, f), getattr(whole, f), rtol=0, atol=1e-9, err_msg=f)


def test_streaming_with_uneven_steps_and_no_magnetometer():
    spec = imu.preset("icm20602+qmc5883l")
    r = np.random.default_rng(4)
    dt = r.uniform(0.6e-3, 1.4e-3, 3000)
    t = np.cumsum(dt) - dt[0]
    _, gyr, acc, _ = moving_inputs(3000, 1000.0)
    rec = imu.IMU(spec, np.random.default_rng(2)).simulate(t, gyr, acc)
    assert_same(rec, stream(imu.IMU(spec, np.random.default_rng(2)), gyr, acc, None, np.diff(t, prepend=0.0)),
                has_mag=False)


def test_timing_jitter_and_magnetometer_hold():
    spec = imu.preset("mpu9250").replace(jitter_s=100e-6)
    n = 20000
    t = np.arange(n) / 10000.0                                     # 10 kHz physics
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t, *moving_inputs(n, 10000.0)[1:])
    k = np.arange(len(rec))
    assert np.std(rec.t - k / 500.0) == pytest.approx(100e-6, rel=0.15)
    assert np.std(rec.dt[1:]) == pytest.approx(math.sqrt(2) * 100e-6, rel=0.15)
    # the AK8963 refreshes at 100 Hz: the 500 Hz output holds each reading for 5 samples
    changed = np.any(np.diff(rec.mag, axis=0) != 0, axis=1)
    assert 0.15 < changed.mean() < 0.25
    assert np.all(np.diff(np.flatnonzero(changed)) >= 3)


# ---------------------------------------------------------------------------------------
# constant errors


def test_turn_on_bias_gain_matrix_and_iron_statistics():
    spec = imu.preset("mpu9250")
    a = imu.IMU(spec, np.random.default_rng(0))
    draws = []
    for _ in range(300):
        a.reset()
        draws.append(a.constants)
    gb = np.array([d["gyro_bias"] for d in draws])
    assert np.std(gb, axis=0) == pytest.approx([spec.gyro.bias_turn_on] * 3, rel=0.2)
    ab = np.array([d["acc_bias"] for d in draws])
    assert np.std(ab, axis=0) == pytest.approx(spec.acc.bias_turn_on, rel=0.2)
    M = np.array([d["gyro_matrix"] for d in draws])
    assert np.std(M[:, [0, 1, 2], [0, 1, 2]]) == pytest.approx(spec.gyro.scale_error, rel=0.15)
    assert np.std(M[:, [0, 1, 2], [1, 2, 0]]) == pytest.approx(spec.gyro.misalignment, rel=0.15)
    h = np.array([d["mag_hard_iron"] for d in draws])
    assert np.std(h) == pytest.approx(spec.mag.hard_iron, rel=0.15)
    S = np.array([d["mag_soft_iron"] for d in draws])
    np.testing.assert_allclose(S, np.swapaxes(S, 1, 2))            # soft iron is symmetric
    # the output is S m + h (+ noise): averaged over a static record
    n = 20000
    t = np.arange(n) / 1000.0
    rec = a.simulate(t, *static_inputs(n))
    c = a.constants
    np.testing.assert_allclose(rec.mag.mean(0), c["mag_soft_iron"] @ FIELD + c["mag_hard_iron"], atol=0.3)
    assert np.linalg.norm(rec.gyr.mean(0) - c["gyro_bias"]) < 0.01
    # calibrated: small residuals
    cal = imu.IMU(imu.preset("mpu9250", calibrated=True), np.random.default_rng(0))
    assert np.all(np.abs(cal.constants["mag_hard_iron"]) < 5 * spec.mag.hard_iron_calibrated)


def test_magnetometer_units():
    n = 1000
    t = np.arange(n) / 1000.0
    gyr, acc, mag = static_inputs(n)
    ut = imu.IMU("mti10", np.random.default_rng(0)).simulate(t, gyr, acc, mag)
    gauss = imu.IMU("mti10", np.random.default_rng(0), mag_unit="G").simulate(t, gyr, acc, mag / 100.0)
    np.testing.assert_allclose(gauss.mag * 100.0, ut.mag, rtol=1e-12)


# ---------------------------------------------------------------------------------------
# vibration


def spectrum(x, fs):
    x = x - x.mean()
    return np.fft.rfftfreq(len(x), 1 / fs), np.abs(np.fft.rfft(x)) * 2 / len(x)


def test_vibration_aliases_when_sampled():
    """170 Hz vibration read at 200 Hz without low-pass appears at 30 Hz, at full amplitude;
    a low-pass before the sampling (or averaging over the period) is what attenuates it."""
    fp, n = 1000.0, 20000
    t = np.arange(n) / fp
    vib = imu.Vibration(170.0, 170.0, acc_rms=1.0, gyr_rms=0.1)
    spec = imu.preset("ideal").replace(rate_hz=200.0, vibration=vib)
    gyr, acc, _ = static_inputs(n)
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t, gyr, acc)
    for out, rms in ((rec.acc, 1.0), (rec.gyr, 0.1)):
        for ax in range(3):
            f, a = spectrum(out[:, ax], 200.0)
            peak = int(np.argmax(a))
            assert f[peak] == pytest.approx(30.0, abs=0.1)
            assert a[peak] == pytest.approx(math.sqrt(2) * rms, rel=0.05)
            assert a[peak] > 1000 * np.median(a)
            assert np.std(out[:, ax]) == pytest.approx(rms, rel=0.05)
    # a 20 Hz first-order low-pass leaves |H(170 Hz)| = 0.12 of it, at the same 30 Hz
    lp = spec.replace(gyro=imu.SensorSpec(lpf_hz=20.0), acc=imu.SensorSpec(lpf_hz=20.0))
    rec = imu.IMU(lp, np.random.default_rng(0)).simulate(t, gyr, acc)
    f, a = spectrum(rec.acc[:, 0], 200.0)
    assert f[np.argmax(a)] == pytest.approx(30.0, abs=0.1)
    assert a.max() == pytest.approx(math.sqrt(2) / math.hypot(1, 170 / 20), rel=0.15)
    # averaging over the 5 ms period: |sinc| = 0.18
    avg = spec.replace(sampling="average")
    rec = imu.IMU(avg, np.random.default_rng(0)).simulate(t, gyr, acc)
    f, a = spectrum(rec.acc[:, 0], 200.0)
    assert a.max() == pytest.approx(math.sqrt(2) * abs(math.sin(math.pi * 0.85) / (5 * math.sin(math.pi * 0.17))),
                                    rel=0.1)


def test_vibration_band_rms():
    fp, n = 2000.0, 40000
    t = np.arange(n) / fp
    spec = imu.preset("ideal").replace(rate_hz=500.0, vibration=imu.VIBRATION_SEED003)
    rec = imu.IMU(spec, np.random.default_rng(0)).simulate(t, *static_inputs(n)[:2])
    assert np.std(rec.acc, axis=0) == pytest.approx([0.2 * imu.G0] * 3, rel=0.1)
    assert np.std(rec.gyr, axis=0) == pytest.approx([3.0 * imu.DEG] * 3, rel=0.1)
    f, a = spectrum(rec.acc[:, 0], 500.0)
    assert 130.0 <= f[np.argmax(a)] <= 200.0
    hz = imu.IMU(spec, np.random.default_rng(0)).constants["vibration_hz"]
    assert hz.shape == (6, 8) and np.all((hz >= 130.0) & (hz <= 200.0))


# ---------------------------------------------------------------------------------------
# magnetic disturbance helper


def test_dipole_field():
    m = imu.dipole_moment_for(20.0, 0.1)
    assert m == pytest.approx(0.1)
    on_axis = imu.dipole_field([0.0, 0.0, 0.1], [0.0, 0.0, 0.0], [0.0, 0.0, m])
    np.testing.assert_allclose(on_axis, [0.0, 0.0, 20.0], atol=1e-12)
    side = imu.dipole_field(np.array([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]), [0.0, 0.0, 0.0], [0.0, 0.0, m])
    np.testing.assert_allclose(side, [[0.0, 0.0, -10.0], [0.0, 0.0, -1.25]], atol=1e-12)
    near = imu.dipole_field([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, m])
    assert np.all(np.isfinite(near))


# ---------------------------------------------------------------------------------------
# bad input


_RNG = np.random.default_rng(0)


@pytest.mark.parametrize("build, match", [
    (lambda: imu.preset("bmi088"), "unknown IMU preset 'bmi088'; available: ideal, mpu6050"),
    (lambda: imu.preset("mpu9250", calibrated="yes"), "calibrated must be True or False, got 'yes'"),
    (lambda: imu.IMU("bmi088", _RNG), "unknown IMU preset"),
    (lambda: imu.IMU(3, _RNG), "spec_or_preset_name must be an IMUSpec or one of"),
    (lambda: imu.IMU("ideal", 0), "rng must be a numpy.random.Generator"),
    (lambda: imu.IMU("ideal", _RNG, physics_rate_hz=-1.0), "physics_rate_hz must be finite and > 0"),
    (lambda: imu.IMU("mpu9250", _RNG, physics_rate_hz=100.0), "physics_rate_hz must be >= the IMU rate"),
    (lambda: imu.IMU("ideal", _RNG, mag_unit="tesla"), "mag_unit must be one of uT, nT"),
    (lambda: imu.preset("ideal").replace(rate_hz=0.0), "IMUSpec.rate_hz must be finite and > 0"),
    (lambda: imu.SensorSpec(lpf_hz=0.0), "SensorSpec.lpf_hz must be .* > 0"),
    (lambda: imu.SensorSpec(noise_density=-1.0), "SensorSpec.noise_density must be finite and >= 0"),
    (lambda: imu.SensorSpec(bias_turn_on=(1.0, 2.0)), "SensorSpec.bias_turn_on must be finite and >= 0, or 3 such"),
    (lambda: imu.Vibration(200.0, 100.0), "Vibration.f_high_hz must be >= f_low_hz"),
    (lambda: imu.preset("ideal").replace(sampling="mean"), "IMUSpec.sampling must be one of hold, average"),
    (lambda: imu.allan_deviation(np.zeros(100), 10.0, taus=[100.0]), "taus must lie between"),
    (lambda: imu.dipole_field([0, 0, 0], [0, 0], [0, 0, 1]), "center must have shape"),
])
def test_bad_spec_names_the_argument(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def _bad_row(x, row, col):
    bad = x.copy()
    bad[row, col] = np.nan
    return bad


_T = np.arange(10) / 1000.0
_GYR, _ACC, _MAG = static_inputs(10)


@pytest.mark.parametrize("args, match", [
    ((_T, _GYR[:, :2], _ACC), r"gyr_true must have shape \(N, 3\) with N = len\(t\) = 10, got \(10, 2\)"),
    ((_T, _GYR, _ACC[:5]), r"acc_true must have shape \(N, 3\)"),
    ((_T, _GYR, _ACC, _MAG.T), r"mag_true must have shape \(N, 3\)"),
    ((_T[:, None], _GYR, _ACC), "t must be a 1-D array of times"),
    ((_T[::-1], _GYR, _ACC), "t must be strictly increasing"),
    ((_T, _bad_row(_GYR, 3, 1), _ACC), "gyr_true must be finite; row 3"),
    ((np.arange(10) * 0.05, _GYR, _ACC), "the physics step must not exceed the IMU period"),
])
def test_bad_simulate_input_names_the_argument(args, match):
    with pytest.raises(ValueError, match=match):
        imu.IMU("ideal", np.random.default_rng(0)).simulate(*args)


def test_bad_step_input_names_the_argument():
    a = imu.IMU("ideal", np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"gyr_true must be 3 finite real numbers"):
        a.step([0.0, 1.0], [0.0, 0.0, G])
    with pytest.raises(ValueError, match=r"acc_true must be 3 finite real numbers"):
        a.step([0.0, 0.0, 0.0], "up")
    a.step([0.0, 0.0, 0.0], [0.0, 0.0, G])
    with pytest.raises(ValueError, match="dt must be given"):
        a.step([0.0, 0.0, 0.0], [0.0, 0.0, G])
    with pytest.raises(ValueError, match="dt must be > 0"):
        a.step([0.0, 0.0, 0.0], [0.0, 0.0, G], dt=0.0)
    b = imu.IMU("ideal", np.random.default_rng(0))
    b.simulate(_T, _GYR, _ACC)
    with pytest.raises(ValueError, match="t must continue the current record"):
        b.simulate(_T, _GYR, _ACC)


def test_per_sample_noise_from_the_dlpf_noise_bandwidth():
    """MPU-9250 at 200 Hz, register-default DLPF: the per-sample noise is density x
    sqrt(NBW) (235 Hz accelerometer, 306.6 Hz gyro), not density x sqrt(fs / 2): the
    output register point-samples the filtered signal, so the bandwidth above 100 Hz aliases."""
    base = imu.preset("mpu9250")
    quiet = dict(bias_instability=0.0, bias_random_walk=0.0, bias_turn_on=0.0, scale_error=0.0,
                 misalignment=0.0, lsb=0.0, adc_bits=None)
    from dataclasses import replace
    spec = base.replace(gyro=replace(base.gyro, **quiet), acc=replace(base.acc, **quiet), mag=None,
                        rate_hz=200.0, jitter_s=0.0)
    n = 40_000
    t = np.arange(n) / 200.0
    rec = imu.IMU(spec, np.random.default_rng(5)).simulate(t, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)))
    acc_sd = (rec.acc - [0.0, 0.0, 9.81]).std(axis=0)
    gyr_sd = rec.gyr.std(axis=0)
    np.testing.assert_allclose(acc_sd, base.acc.noise_density * np.sqrt(235.0), rtol=0.03)
    np.testing.assert_allclose(gyr_sd, base.gyro.noise_density * np.sqrt(306.6), rtol=0.03)
    assert acc_sd.min() > 1.4 * base.acc.noise_density * np.sqrt(100.0)


def test_calibration_removes_most_of_scale_and_cross_axis():
    for name in ("mpu9250", "icm20602+qmc5883l", "mpu6050+mag3110"):
        raw, cal = imu.preset(name), imu.preset(name, calibrated=True)
        for a, b in ((raw.gyro, cal.gyro), (raw.acc, cal.acc)):
            assert b.scale_error <= 0.5 * a.scale_error and b.misalignment <= 0.25 * a.misalignment
        m = imu.IMU(cal, np.random.default_rng(0)).constants["acc_matrix"]
        assert np.abs(m - np.eye(3)).max() < 0.02          # 3 % / 2 % raw: 5 sigma of 0.3 %


def test_a_reset_without_rng_does_not_depend_on_how_the_last_record_was_made():
    """simulate() peeks whole 512-row noise blocks past its last sample, step() does not: after a
    record of exactly 512 samples the batch IMU had drawn one block more, and a reset() without rng gave
    the next record other constants than the streaming one's (gyro turn-on bias -0.003 / -0.198 /
    -0.252 against -0.345 / 0.058 / 0.415 deg/s). Each record after the first now draws from
    generators spawned for it."""
    spec = imu.preset("mpu9250", calibrated=True)
    phys = 2 * spec.rate_hz
    n = 1024                                        # 512 samples: one block exactly
    t, z, a = np.arange(n) / phys, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1))
    out = []
    for mode in ("stream", "batch"):
        m = imu.IMU(spec, np.random.default_rng(0), physics_rate_hz=phys)
        if mode == "stream":
            assert sum(m.step(z[i], a[i]) is not None for i in range(n)) == 512
        else:
            assert len(m.simulate(t, z, a)) == 512
        m.reset()
        out.append(m.constants["gyro_bias"])
    np.testing.assert_array_equal(out[0], out[1])
