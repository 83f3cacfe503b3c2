"""Fixtures shared by the test modules: the synthetic run the kernels are compared on, the
recorded-data folder (or a skip), and estimator construction. Plain helpers (no fixtures)
are in _helpers.py."""
import pytest
from _helpers import FS, synthetic

import fusion
from fusion import datasets


@pytest.fixture(scope="session")
def synthetic_data():
    """(q_true, gyr, acc, mag): 10 000 samples at 100 Hz of a strongly moving, noisy body
    (_helpers.synthetic with its defaults). Read-only: copy before changing it."""
    arrays = synthetic()
    for a in arrays:
        a.setflags(write=False)
    return arrays


@pytest.fixture(scope="session")
def data_dir():
    """The recorded IMU data folder, or a skip when it is not there."""
    root = datasets.default_data_dir()
    if root is None:
        pytest.skip(f"recorded data folder not found ({datasets.DATA_LOCATION})")
    return root


@pytest.fixture
def make_estimator():
    """fusion.make with the tests' default sample rate: make_estimator(name, **kw)."""
    def build(name, fs=FS, **kw):
        return fusion.make(name, fs, **kw)
    return build
