"""Prefilter kernels against scipy.signal, and the IIR-EKF as the reference EKF fed through
scipy's Butterworth (an EKF with a prefilter in front, not a second EKF)."""
import numpy as np
import pytest
from scipy import signal

import fusion
import reference as ref
from _helpers import synthetic


@pytest.mark.parametrize("fs, fc", [(200.0, 40.0), (100.0, 5.0), (500.0, 240.0), (256.0, 0.5)])
def test_butterworth_equals_scipy(fs, fc):
    b, a = signal.butter(2, fc, fs=fs)             # bilinear with pre-warping, as seed 003
    bf = fusion.Butterworth(fs, fc)
    assert np.allclose(bf.coefficients[0], b, rtol=1e-12, atol=0)
    assert np.allclose(bf.coefficients[1], a, rtol=1e-12, atol=0)
    x = np.random.default_rng(0).normal(3.0, 1.0, (5000, 3))
    zi = signal.lfilter_zi(b, a)
    expected = np.column_stack([signal.lfilter(b, a, x[:, k], zi=zi * x[0, k])[0] for k in range(3)])
    assert np.abs(bf.run(x) - expected).max() < 1e-9


def test_butterworth_attenuates_vibration_and_passes_motion():
    fs = 200.0
    t = np.arange(4000) / fs
    slow = np.sin(2 * np.pi * 1.0 * t)
    fast = np.sin(2 * np.pi * 90.0 * t)
    y = fusion.Butterworth(fs, 40.0).run(np.column_stack([slow, fast, slow + fast]))[1000:]
    assert np.std(y[:, 1]) < 0.25 * np.std(fast)          # |H(90 Hz)| ~ 0.18
    assert np.abs(y[:, 0] - slow[1000:]).max() < 0.1      # phase lag only


def test_sliding_mean_equals_numpy():
    x = np.random.default_rng(1).normal(0, 1, (3000, 3)) + 1e6   # offset: rounding must not creep
    for n in (1, 2, 10, 37):
        got = fusion.SlidingMean(n).run(x)
        c = np.cumsum(np.vstack([np.zeros((1, 3)), x]), axis=0)
        idx = np.arange(1, len(x) + 1)
        lo = np.maximum(idx - n, 0)
        expected = (c[idx] - c[lo]) / (idx - lo)[:, None]
        assert np.abs(got - expected).max() < 1e-6


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "10"])
def test_sliding_mean_window_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match="window"):
        fusion.SlidingMean(bad)


@pytest.mark.parametrize("fc", [100.0, 150.0, 0.0, -3.0])
def test_butterworth_cutoff_must_be_below_nyquist(fc):
    with pytest.raises(ValueError, match="cutoff_hz"):
        fusion.Butterworth(200.0, fc)
    with pytest.raises(ValueError, match="cutoff_hz"):
        fusion.make("iir-ekf", 200.0, cutoff_hz=fc)


def test_butterworth_cutoff_has_a_floor_where_its_rounding_holds():
    """Below 1e-7 fs the coefficients' rounding (1e-16) reaches 1 + a1 + a2, the DC gain's
    denominator (several % off at 1e-8 fs, negative, a pole above 1, from about 2.4e-9 fs), so
    such a cutoff is refused; at the floor the DC gain holds to 1e-3 (5e-4 measured)."""
    from fusion._prefilter import CUTOFF_MIN
    for est in ("iir-ekf", "triad"):
        with pytest.raises(ValueError, match="cutoff_hz must be at least 1e-07 fs"):
            fusion.make(est, 200.0, cutoff_hz=0.5e-7 * 200.0)
    fusion.Butterworth(1000.0049, 0.0001)       # the bound as its message prints it (1.0000049e-4)
    b, a = fusion.Butterworth(1.0, CUTOFF_MIN).coefficients
    assert abs(b.sum() / a.sum() - 1.0) < 1e-3
    assert np.all(np.abs(np.roots(a)) < 1.0)


def test_iir_ekf_default_cutoff_follows_the_sample_rate():
    assert fusion.make("iir-ekf", 200.0).cutoff_hz == 40.0
    assert fusion.make("iir-ekf", 50.0).cutoff_hz == pytest.approx(22.5)


@pytest.mark.parametrize("filter_mag", [False, True])
@pytest.mark.parametrize("nine_axis", [False, True])
def test_iir_ekf_is_the_reference_ekf_behind_scipys_butterworth(filter_mag, nine_axis):
    fs, fc = 100.0, 15.0
    _, gyr, acc, mag = synthetic(n=4000, fs=fs)
    b, a = signal.butter(2, fc, fs=fs)
    zi = signal.lfilter_zi(b, a)

    def lp(x):
        return np.column_stack([signal.lfilter(b, a, x[:, k], zi=zi * x[0, k])[0] for k in range(3)])

    expected = ref.RefEKF(fs).run(gyr, lp(acc), (lp(mag) if filter_mag else mag) if nine_axis else None)
    est = fusion.make("iir-ekf", fs, cutoff_hz=fc, filter_mag=filter_mag)
    got = est.run(gyr, acc, mag if nine_axis else None)
    sign = np.sign(np.sum(got * expected, axis=1))[:, None]
    assert np.abs(got - sign * expected).max() < 1e-9
    est.reset()     # the prefilter forgets too: the same run again gives the same numbers
    assert np.array_equal(est.run(gyr, acc, mag if nine_axis else None), got)
