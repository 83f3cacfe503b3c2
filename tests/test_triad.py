"""`triad` (docs/estimators.md, "triad"): the kernel against its numpy reference
(tests/reference_triad.py, Wahba's problem by the SVD), an analytic static case, and the
property that defines it: no gyro, so no drift whatever the gyro reads."""
import numpy as np
import pytest

import fusion
import reference as ref
from _helpers import FIELD, FS, TOL, count_invalid, inject_invalid, qdiff
from reference_triad import RefTriad

N_REF = 3_000       # the reference's SVD per sample is slow


@pytest.mark.parametrize("nine_axis", [False, True], ids=["6axis", "9axis"])
@pytest.mark.parametrize("params", [{}, {"cutoff_hz": 5.0}], ids=["raw", "cutoff5"])
@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_kernel_equals_reference(synthetic_data, nine_axis, params, frame):
    _, gyr, acc, mag = (a[:N_REF] for a in synthetic_data)
    m = mag if nine_axis else None
    q = fusion.make("triad", FS, frame=frame, **params).run(gyr, acc, m)
    qr = RefTriad(FS, frame=frame, **params).run(gyr, acc, m)
    assert qdiff(q, qr) < TOL


def test_skip_invalid_samples(synthetic_data):
    _, gyr, acc, mag = (a[:N_REF] for a in synthetic_data)
    gyr, acc, mag = inject_invalid(gyr, acc, mag)
    for params in ({}, {"cutoff_hz": 5.0}):
        est, r = fusion.make("triad", FS, on_invalid="skip", **params), RefTriad(FS, on_invalid="skip", **params)
        assert qdiff(est.run(gyr, acc, mag), r.run(gyr, acc, mag)) < TOL
        assert est.skipped == r.skipped == count_invalid(gyr, acc, mag)


def test_a_still_sensor_gives_its_attitude_exactly():
    """Noise-free readings at a known attitude: that attitude, in ENU and NED."""
    q_true = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    R = ref.rotmat(q_true)
    acc, mag = R.T @ [0.0, 0.0, ref.G], R.T @ FIELD
    n = 10
    q = fusion.make("triad", FS).run(np.zeros((n, 3)), np.tile(acc, (n, 1)), np.tile(mag, (n, 1)))
    assert qdiff(q, np.tile(q_true, (n, 1))) < 1e-12
    q_ned = fusion.make("triad", FS, frame="NED").update([0, 0, 0], acc, mag)
    assert qdiff(q_ned[None], ref.qmul(ref.C_NED, q_true)[None]) < 1e-12


def test_the_gyro_is_not_used(synthetic_data):
    """No drift: any gyro reading, even a huge bias, leaves the output unchanged."""
    _, gyr, acc, mag = synthetic_data
    q = fusion.make("triad", FS).run(gyr, acc, mag)
    assert np.array_equal(q, fusion.make("triad", FS).run(gyr + 5.0, acc, mag))
    q_true = synthetic_data[0]
    err = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(q * q_true, axis=1)), 0, 1)))
    assert err[-1000:].mean() < 2 * err[:1000].mean() + 1.0      # no growth over the run


def test_noise_passes_through_and_the_low_pass_averages_it():
    """A still, noisy sensor: the raw estimate carries the accelerometer's noise (about
    0.05 / 9.81 rad = 0.3 deg per axis); cutoff_hz=1 averages it to well below."""
    q_true = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    R = ref.rotmat(q_true)
    rng = np.random.default_rng(4)
    n = 3000
    acc = R.T @ [0.0, 0.0, ref.G] + 0.05 * rng.standard_normal((n, 3))
    mag = R.T @ FIELD + 0.002 * rng.standard_normal((n, 3))
    errs = {}
    for c in (None, 1.0):
        q = fusion.make("triad", FS, cutoff_hz=c).run(np.zeros((n, 3)), acc, mag)
        errs[c] = np.degrees(2 * np.arccos(np.clip(np.abs(q[500:] @ q_true), 0, 1)))
    assert 0.1 < errs[None].mean() < 1.0 and errs[None].max() > 0.5
    assert errs[1.0].max() < 0.5 * errs[None].max() and errs[1.0].mean() < 0.3 * errs[None].mean()


def test_cutoff_is_checked():
    for bad in (0.0, -1.0, 50.0, np.nan, "5"):
        with pytest.raises(ValueError, match="cutoff_hz"):
            fusion.make("triad", FS, cutoff_hz=bad)
    assert fusion.make("triad", FS).cutoff_hz is None
    assert fusion.make("triad", FS, cutoff_hz=5).cutoff_hz == 5.0
