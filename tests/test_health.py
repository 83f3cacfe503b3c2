"""Covariance health (docs/robustness.md): every filter with a covariance keeps it finite,
symmetric and positive definite under extreme but valid inputs, and its quaternion unit."""
import numpy as np
import pytest

import fusion
from fusion._core import DT_MIN, DT_MAX
from fusion.constants import GRAVITY

FILTERS = [n for n in fusion.available() if fusion.make(n, 100.0).covariance is not None]
G = np.array([0.0, 0.0, GRAVITY])
FIELD = np.array([0.0, 0.4, -0.3])


def test_the_filters_with_a_covariance():
    assert FILTERS == ["ekf", "ekf-lp", "iir-ekf", "ukf", "cf-ekf", "aekf"]


def noisy(n, seed, rate=0.5, acc_scale=1.0):
    rng = np.random.default_rng(seed)
    gyr = rng.normal(0, rate, (n, 3))
    acc = acc_scale * (G + rng.normal(0, 0.5, (n, 3)))
    mag = FIELD + rng.normal(0, 0.01, (n, 3))
    return gyr, acc, mag


def cases():
    n = 400
    g, a, m = noisy(n, 1)
    yield "huge rates", dict(gyr=noisy(n, 2, rate=1e3)[0], acc=a, mag=m)
    yield "rates near the validity limit", dict(gyr=noisy(n, 3, rate=1e150)[0], acc=a, mag=m)
    yield "long gaps", dict(gyr=g, acc=a, mag=m, dt=np.where(np.arange(n) % 7 == 0, DT_MAX, 0.01))
    yield "every step the longest", dict(gyr=g, acc=a, mag=m, dt=DT_MAX)
    yield "every step the shortest", dict(gyr=g, acc=a, mag=m, dt=DT_MIN)
    yield "gaps and fast turning", dict(gyr=noisy(n, 4, rate=20.0)[0], acc=a, mag=m,
                                        dt=np.geomspace(DT_MIN, DT_MAX, n))
    yield "identical samples", dict(gyr=np.tile(g[0], (20000, 1)), acc=np.tile(a[0], (20000, 1)),
                                    mag=np.tile(m[0], (20000, 1)))
    yield "no rotation, no noise", dict(gyr=np.zeros((20000, 3)), acc=np.tile(G, (20000, 1)),
                                        mag=np.tile(FIELD, (20000, 1)))
    yield "near-zero acc", dict(gyr=g, acc=noisy(n, 5, acc_scale=1e-150)[1], mag=m)
    yield "near-zero acc and mag", dict(gyr=g, acc=a * 1e-150, mag=m * 1e-150)
    yield "huge acc and mag", dict(gyr=g, acc=a * 1e150, mag=m * 1e150)
    yield "mag along gravity", dict(gyr=g, acc=a, mag=np.tile(-G, (n, 1)))
    yield "upside down, freefall-like", dict(gyr=g, acc=-a * 1e-3, mag=m)


CASES = dict(cases())


def assert_healthy(est, q):
    assert np.isfinite(q).all()
    assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-12
    P = est.covariance
    assert np.isfinite(P).all()
    assert np.array_equal(P, P.T), np.abs(P - P.T).max()
    assert np.linalg.eigvalsh(P).min() > 0.0, np.linalg.eigvalsh(P)


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("name", FILTERS)
def test_covariance_stays_symmetric_positive_definite(name, case):
    kw = CASES[case]
    for nine in (True, False):
        est = fusion.make(name, 100.0)
        args = dict(kw) if nine else {k: v for k, v in kw.items() if k != "mag"}
        assert_healthy(est, est.run(**args))


@pytest.mark.parametrize("name", FILTERS)
def test_covariance_recovers_after_the_extremes(name):
    """After abuse, ordinary data brings the attitude uncertainty back to its usual size."""
    est, calm = fusion.make(name, 100.0), fusion.make(name, 100.0)
    g, a, m = noisy(10000, 9, rate=0.2)
    calm.run(g, a, m)
    for kw in CASES.values():
        est.run(**kw)
    assert_healthy(est, est.run(g, a, m))
    k = 4 if est.covariance.shape[0] == 7 else 3
    assert np.trace(est.covariance[:k, :k]) < 3 * np.trace(calm.covariance[:k, :k])
