"""Every estimator returns finite unit quaternions on every seed scenario and every recorded
trial (issue: estimators on realistic inputs, 9- and 6-axis)."""
import numpy as np
import pytest

import fusion
from fusion import datasets
from fusion.scenarios import SEED_SCENARIOS, seed_scenario


def _check(name, fs, gyr, acc, mag, dt):
    est = fusion.make(name, fs, on_invalid="skip")
    q = est.run(gyr, acc, mag, dt=dt)
    assert np.all(np.isfinite(q)), f"{name}: non-finite quaternion"
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("scenario", list(SEED_SCENARIOS))
def test_seed_scenarios(scenario):
    sc = seed_scenario(scenario, seed=0)
    for name in fusion.available():
        for mag in (sc.mag, None):
            _check(name, sc.fs, sc.gyr, sc.acc, mag, sc.dt)


def test_recorded_trials(data_dir):
    trials = datasets.load_folder(data_dir)
    assert trials
    for tr in trials:           # every trial, the excluded (saturated) ones too
        for name in fusion.available():
            for mag in ((tr.mag, None) if tr.mag is not None else (None,)):
                _check(name, tr.fs, tr.gyr, tr.acc, mag, tr.dt)
