"""State round trip (docs/estimators.md, "State, pickling, copies"): est.state() /
est.load_state(), Estimator.from_state(), pickle and copy.deepcopy resume bit-identically."""
import copy
import json
import pickle

import numpy as np
import pytest

import fusion
from fusion._core import BIAS_MAX
from fusion.scenarios import make_scenario

NAMES = fusion.available()
# non-default settings that add state: a learned magnetic reference (aekf), a filtered
# magnetometer (iir-ekf), a sliding-mean window that is mid-lap at the cut (cf-ekf), a
# raised gain after saturated samples (gyro_range: the recording turns faster than 0.5 rad/s)
EXTRA = {"iir-ekf": dict(filter_mag=True, acc_lowpass=1.0), "ekf": dict(acc_lowpass=1.0),
         "cf-ekf": dict(window=7, gyro_range=0.5, bias_feedback=True),
         "madgwick": dict(zeta=0.01, gyro_range=0.5), "mahony": dict(gyro_range=0.5),
         "aekf": dict(measurement="quest")}


@pytest.fixture(scope="module")
def recording():
    sc = make_scenario("mixed", fs=100.0, duration=20.0, seed=3)
    gyr, acc, mag = sc.gyr.copy(), sc.acc.copy(), sc.mag.copy()
    # a few invalid rows so that the skip counters carry state as well
    gyr[[30, 1500]] = np.nan
    acc[[40, 1200]] = 0.0
    mag[[50, 1700]] = np.inf
    return gyr, acc, mag


def _restored(est, how):
    if how == "state":
        other = fusion.make(est.name, est.fs, frame=est.frame, on_invalid=est.on_invalid, **est.params)
        other.load_state(est.state())
        return other
    if how == "json":           # the state is plain data: it survives a text file
        return fusion.Estimator.from_state(json.loads(json.dumps(est.state())))
    if how == "pickle":
        return pickle.loads(pickle.dumps(est))
    return copy.deepcopy(est)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("nine_axis", [True, False])
@pytest.mark.parametrize("cut", [60, 1000])     # aekf: 60 is inside the 1 s learning period
def test_resume_is_bit_identical(recording, name, nine_axis, cut):
    gyr, acc, mag = recording
    mag = mag if nine_axis else None
    for params in ({}, EXTRA.get(name)):
        if params is None:
            continue
        est = fusion.make(name, 100.0, frame="NED", on_invalid="skip", **params)
        whole = fusion.make(name, 100.0, frame="NED", on_invalid="skip", **params).run(gyr, acc, mag)
        first = est.run(gyr[:cut], acc[:cut], None if mag is None else mag[:cut])
        copies = {how: _restored(est, how) for how in ("state", "json", "pickle", "deepcopy")}
        rest = slice(cut, None)
        tail = est.run(gyr[rest], acc[rest], None if mag is None else mag[rest])
        assert np.array_equal(np.vstack([first, tail]), whole)
        for how, other in copies.items():
            out = other.run(gyr[rest], acc[rest], None if mag is None else mag[rest])
            assert np.array_equal(out, tail), how
            assert other.state() == est.state(), how
            assert other.skipped == est.skipped and repr(other) == repr(est)
            for attr in ("bias", "covariance"):
                a, b = getattr(est, attr), getattr(other, attr)
                assert (a is None and b is None) or np.array_equal(a, b)


def test_copies_are_independent():
    est = fusion.make("ekf", 100.0)
    est.update([0.1, 0, 0], [0, 0, 9.81])
    twin = copy.deepcopy(est)
    before = twin.state()
    est.update([0.5, 0.2, 0], [0, 1, 9.81])
    assert twin.state() == before and est.state() != before


def test_state_is_plain_data():
    s = fusion.make("cf-ekf", 100.0).state()
    assert s["version"] == fusion._core.STATE_VERSION == 9 and s["estimator"] == "cf-ekf" and s["params"]["window"] == 1

    def plain(x):
        if isinstance(x, dict):
            return all(isinstance(k, str) and plain(v) for k, v in x.items())
        if isinstance(x, list):
            return all(plain(v) for v in x)
        return x is None or type(x) in (int, float, str, bool)
    assert plain(s)


def test_aekf_counters_and_reference_are_restored(recording):
    gyr, acc, mag = recording
    est = fusion.make("aekf", 100.0, on_invalid="skip")
    est.run(gyr[:500], acc[:500], mag[:500])
    other = copy.deepcopy(est)
    for attr in ("rejected", "tested", "quest_updates", "mag_reference", "last_decision"):
        assert getattr(other, attr) == getattr(est, attr)


# --- validation ---------------------------------------------------------------------

def _state(name="ekf", **params):
    est = fusion.make(name, 100.0, **params)
    est.update([0.1, 0.2, 0.3], [0.5, 0.1, 9.8])
    return est.state()


def _broken(change):
    s = copy.deepcopy(_state())
    change(s)
    return s


@pytest.mark.parametrize("state, match", [
    (None, "must be a dict"),
    ([1, 2], "must be a dict"),
    ({"version": 2}, "lacks key"),
    (_broken(lambda s: s.update(version=1)), "version 1 was saved by an older build"),   # before rest detection
    (_broken(lambda s: s.update(version="2")), "version '2'"),
    (_broken(lambda s: s.update(estimator="ukf")), "estimator 'ukf', not 'ekf'"),
    (_broken(lambda s: s["fields"].pop("P")), r"missing \['P'\]"),
    (_broken(lambda s: s["fields"].update(extra=1.0)), r"unexpected \['extra'\]"),
    (_broken(lambda s: s["fields"].update(P=[0.0] * 36)), r"'P' must have shape \(49,\)"),
    (_broken(lambda s: s["fields"].update(b=[0.0, 0.0, float("nan")])), "'b' must be finite"),
    (_broken(lambda s: s["fields"].update(b="abc")), "'b' must hold real numbers"),
    (_broken(lambda s: s["fields"].update(q=[1.0, 1.0, 0.0, 0.0])), "'q' must be a unit quaternion"),
    (_broken(lambda s: s["fields"].update(is_init=2)), r"'is_init' must be in \[0, 1\]"),
    (_broken(lambda s: s["fields"].update(is_init=1.0)), "'is_init' must hold integers"),
    (_broken(lambda s: s["fields"].update(n_skip_acc=-1)), "'n_skip_acc' must be in"),
    (_broken(lambda s: s.update(fields=[])), "must be dicts"),
    # a negative variance beside a large one (the tolerance was relative to the largest entry)
    (_broken(lambda s: s["fields"].update(P=list(np.diag([1e5] + [1e-4] * 5 + [-5e-6]).ravel()))),
     "'P' must have variances >= 0"),
    # a correlation above 1 between a large and a small variance: indefinite, by 6e-7
    (_broken(lambda s: s["fields"].update(P=list((np.diag([1e5, 1e-6] + [1e-4] * 5)
                                                   + 0.4 * (np.eye(7, k=1) + np.eye(7, k=-1)) * (np.arange(7) < 2)
                                                   * (np.arange(7) < 2)[:, None]).ravel()))),
     "'P' must be positive semidefinite"),
])
def test_load_state_rejects_bad_input_and_changes_nothing(state, match):
    est = fusion.make("ekf", 100.0)
    est.update([0.0, 0.0, 0.1], [0.0, 0.3, 9.8])
    before = est.state()
    with pytest.raises(ValueError, match=match):
        est.load_state(state)
    assert est.state() == before


def test_mismatched_prefilters_and_memory_unsafe_indices_are_refused():
    est = fusion.make("iir-ekf", 100.0)
    with pytest.raises(ValueError, match=r"missing \[\].*unexpected \['pre_mag.primed'"):
        est.load_state(_state("iir-ekf", filter_mag=True))
    cf = fusion.make("cf-ekf", 100.0, window=4)
    with pytest.raises(ValueError, match=r"'pre_gyr.buf' must have shape \(12,\).*from_state"):
        cf.load_state(_state("cf-ekf", window=5))
    assert type(cf).from_state(_state("cf-ekf", window=5)).window == 5     # what the error offers
    s = _state("cf-ekf", window=4)
    s["fields"]["pre_acc.head"] = 4     # would index past the ring buffer
    with pytest.raises(ValueError, match=r"'pre_acc.head' must be in \[0, 3\]"):
        cf.load_state(s)
    s = _state("cf-ekf", window=4)
    s["fields"]["pre_acc.count"] = 5
    with pytest.raises(ValueError, match=r"'pre_acc.count' must be in \[0, 4\]"):
        cf.load_state(s)


def test_from_state_checks_the_class():
    s = _state("ekf")
    with pytest.raises(ValueError, match="estimator 'ekf', not 'ukf'"):
        fusion.UKF.from_state(s)
    assert type(fusion.EKF.from_state(s)) is fusion.EKF
    assert type(fusion.Estimator.from_state(s)) is fusion.EKF


@pytest.mark.parametrize("how", ["state", "json", "pickle"])
def test_mahony_resumes_mid_rest(how):
    """mahony's rest detector (its low-passes, the time at rest, the count) and the bias it
    pulled toward the rate are state: cut 3 s into a 6 s still spell (rest since rest_time), the
    resumed filter goes on bit-identically."""
    fs, n = 100.0, 900
    rng = np.random.default_rng(7)
    gyr = np.radians([0.5, -0.3, 0.8]) + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    gyr[600:] += np.radians([0.0, 0.0, 30.0])           # then a turn: the rest run ends
    whole = fusion.make("mahony", fs).run(gyr, acc)
    est = fusion.make("mahony", fs)
    est.run(gyr[:300], acc[:300])
    assert est.at_rest and est.rest_samples > 100
    assert {"rest_gyr", "rest_acc", "t_rest", "rest_samples"} <= set(est.state()["fields"])
    other = _restored(est, how)
    assert other.rest_samples == est.rest_samples and np.array_equal(other.bias, est.bias)
    assert np.array_equal(other.run(gyr[300:], acc[300:]), whole[300:])
    assert not other.at_rest and other.rest_samples == est.rest_samples + 300


@pytest.mark.parametrize("name", ["mahony", "cf-ekf", "ekf"])
def test_a_state_of_the_previous_version_is_refused_by_its_version(name):
    """Version 3 states of mahony and cf-ekf lack fields this build's have (mahony's rest
    detector, cf-ekf's composed core), and every version-3 state has the disturbance
    detector's old field names: such a state was refused as "state fields do not match",
    which did not say that the format had changed. The version is checked first, and the
    message says which version this build reads. Version 5 states hold the accelerometer
    low-pass in the frame acc_qg, which version 6 dropped (the low-pass in the body frame);
    version 6 states lack the disturbance detector's field-direction test (version 7), version
    7 states the rest detector's drift test and running-mean start (version 8), version 8
    states the still run's sum that the first zero-rate update takes (version 9)."""
    for version in (3, 5, 6, 7, 8):
        s = _state(name)
        s["version"] = version
        for load in (fusion.make(name, 100.0).load_state, fusion.Estimator.from_state):
            with pytest.raises(ValueError, match=rf"state version {version} was saved by an older build: "
                                                 r"this build reads version 9 only .*est\.state\(\)"):
                load(s)


@pytest.mark.parametrize("name, params, six_axis", [
    # a zero bias_init_std (accepted): the fresh filter's bias block is zero, semidefinite
    ("ekf", dict(bias_init_std=0.0), False), ("iir-ekf", dict(bias_init_std=0.0), False),
    ("aekf", dict(bias_init_std=0.0), False), ("cf-ekf", dict(bias_init_std=0.0), False),
    ("ekf", dict(bias_init_std=0.0, bias_noise=0.0), False),
    # the ukf's covariance indefinite by rounding (min eigenvalue -1e-16), which its sigma
    # points take: 1 Hz, the gyro nearly always saturated
    ("ukf", dict(gyro_range=0.01), True),
    # gains that make the loop unstable: the bias wound up to 200-450 rad/s, beyond the load's
    # BIAS_MAX; now held at it
    ("mahony", dict(ki=100.0), False), ("madgwick", dict(zeta=10.0), False), ("cf-ekf", dict(ki=100.0), False),
])
def test_every_state_a_filter_makes_loads(name, params, six_axis):
    """est.state() of a filter that ran on valid samples at accepted parameters always loads:
    each case was refused ('P must be positive definite', 'eint must be in ...'), and with it
    pickle, deepcopy and the bank of the filter."""
    fs = 1.0 if name == "ukf" else 100.0
    sc = make_scenario("mixed", fs=100.0, duration=60.0 if fs == 100.0 else 30.0, seed=3 if six_axis else 0)
    est = fusion.make(name, fs, **params)
    for k in range(3):
        if k:
            est.run(sc.gyr[:3000 // k], sc.acc[:3000 // k], None if six_axis else sc.mag[:3000 // k])
        twin = pickle.loads(pickle.dumps(est))
        assert twin.state() == est.state()
        copy.deepcopy(est)
        fusion.Bank([est])
    if name in ("mahony", "madgwick", "cf-ekf"):
        assert np.abs(est.bias).max() <= 100.0 + 1e-9
    # and continues bit for bit
    q1 = est.run(sc.gyr[:200], sc.acc[:200], None if six_axis else sc.mag[:200])
    q2 = twin.run(sc.gyr[:200], sc.acc[:200], None if six_axis else sc.mag[:200])
    np.testing.assert_array_equal(q1, q2)


@pytest.mark.parametrize("name", ["ekf", "iir-ekf", "aekf", "ukf", "cf-ekf", "mahony", "madgwick", "bank"])
def test_a_crafted_rest_sum_cannot_pull_the_bias_beyond_bias_max(name):
    """The still run's gyro sum and its time are loaded one by one, each within its range; a
    pair whose mean is 1e6 rad/s pulled the Kalman filters' bias to 7e5 rad/s on the next
    sample at rest, and their state could no longer be loaded. The mean is held within
    BIAS_MAX (in the scalar kernels and the ekf bank): after a second at rest the bias is
    within it and the state loads again."""
    fs, n = 100.0, 20
    still = (np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)))
    est = fusion.make_bank("ekf", fs, 4) if name == "bank" else fusion.make(name, fs)
    est.run(*(np.repeat(x[:, None], 4, axis=1) if name == "bank" else x for x in still))
    s = est.state()
    for f in ([x["fields"] for x in s["filters"]] if name == "bank" else [s["fields"]]):
        f.update(rest_gsum=[1e6, -1e6, 1e6], rest_gsum_t=1.0, rest_taken=0)
    est.load_state(s)
    still = (np.zeros((100, 3)), np.tile([0.0, 0.0, 9.81], (100, 1)))
    est.run(*(np.repeat(x[:, None], 4, axis=1) if name == "bank" else x for x in still))
    b = np.asarray(est.bias)
    assert np.all(np.abs(b) <= BIAS_MAX), b
    est.load_state(est.state())
