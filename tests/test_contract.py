"""The contract every estimator of fusion.available() keeps (docs/estimators.md): its
interface (attributes, PARAMS, repr), run equal to repeated update, the state round trip and
pickling, and a clear ValueError for bad input. Estimator-specific behaviour is tested in the
estimator's own module; this one holds what all of them share, parametrised over the registry."""
import pickle

import numpy as np
import pytest
from _helpers import FS, inject_invalid

import fusion
from fusion.constants import GRAVITY as G

NAMES = fusion.available()
# settings beyond the defaults that change what run and update do (other branches, counters)
CASES = [(name, {}) for name in NAMES] + [
    ("mahony", {"kp": 2.0, "ki": 0.1}),
    ("ekf", {"gyro_noise": 0.003, "bias_noise": 1e-3, "acc_noise": 0.3, "mag_noise": 0.1,
             "q_init_std": 0.2, "bias_init_std": 0.05}),
    ("ekf", {"mag_update": "heading"}),
    ("ekf", {"acc_lowpass": 0.5}),
    ("aekf", {"measurement": "quest"}),
]
CASE_IDS = [name + ("-" + "-".join(f"{k}={v}" for k, v in p.items()) if p else "-defaults") for name, p in CASES]


def _close(x, y):
    """Equal, or arrays within 1e-15 of the larger magnitude (the order of float operations
    may differ between the batch loop and one call per sample)."""
    if isinstance(x, dict):
        return x.keys() == y.keys() and all(_close(x[k], y[k]) for k in x)
    x, y = np.asarray(x), np.asarray(y)
    if x.dtype.kind not in "fc" or x.size == 0:
        return x.shape == y.shape and np.array_equal(x, y)
    scale = np.abs(y).max()
    return x.shape == y.shape and np.abs(x - y).max() <= 1e-15 * scale if scale > 0 else np.array_equal(x, y)


# --- interface ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_interface(name, make_estimator):
    est = make_estimator(name)
    cls = type(est)
    assert isinstance(est, fusion.Estimator) and cls.name == est.name == name
    assert est.fs == FS and est.frame == "ENU" and est.on_invalid == "raise"
    assert isinstance(cls.PARAMS, dict)
    assert set(est.params) == set(cls.PARAMS)          # every parameter, defaults filled in
    assert est.quaternion.shape == (4,) and not est.initialised and est.skipped == {"gyr": 0, "acc": 0, "mag": 0}
    assert est.bias is None or est.bias.shape == (3,)
    assert est.covariance is None or est.covariance.shape[0] == est.covariance.shape[1]
    again = eval(repr(est), {"fusion": fusion})       # repr is the call that builds it
    assert type(again) is cls and again.params == est.params and again.fs == est.fs


REST_PROPERTIES = ("rest_time", "rest_gyro_tol", "rest_acc_tol", "rest_gyro_drift_tol", "rest_acc_drift_tol",
                   "rest_noise", "at_rest", "rest_samples")


@pytest.mark.parametrize("name", NAMES)
def test_rest_properties_exactly_where_rest_is_declared(name):
    """Rest detection is a component the filters that declare its parameters (fusion.params.REST)
    hold: they have the rest properties, reading what was given; the others have none."""
    cls = type(fusion.make(name, FS))
    if "rest_time" in cls.PARAMS:
        if "rest_noise" in cls.PARAMS:      # the filters with a zero-rate update
            est = fusion.make(name, FS, rest_time=0.25, rest_noise=0.002)
            assert est.rest_noise == 0.002
        else:                               # mahony: its own update at rest, no rest_noise
            est = fusion.make(name, FS, rest_time=0.25)
            assert not hasattr(est, "rest_noise")
        assert (est.rest_time, est.at_rest, est.rest_samples) == (0.25, False, 0)
        assert est.rest_gyro_tol == cls.PARAMS["rest_gyro_tol"].default
    else:
        est = fusion.make(name, FS)
        assert [p for p in REST_PROPERTIES + ("rest",) if hasattr(est, p)] == []


@pytest.mark.parametrize("name", [n for n in NAMES if "rest_time" in type(fusion.make(n, FS)).PARAMS])
def test_rest_time_reached_whatever_the_steps_rounding(name):
    """A still start of exactly rest_time (the 50 steps of 1/125 s after the detector's first
    sample = 0.4 s): steps from time stamps
    that equal 1/fs to 1e-13 sum just short of 0.4 and made the first zero-rate update one
    sample late, after the motion had begun (a recorded trial's error 0.82 -> 1.83 deg); now a
    summed duration counts within its rounding, and the stamps give the nominal steps' result."""
    fs, n = 125.0, 400
    rng = np.random.default_rng(3)
    gyr = 0.01 + 1e-4 * rng.standard_normal((n, 3))
    gyr[51:] += 1.0                         # motion from the 52nd sample on
    acc = np.tile([0.0, 0.0, G], (n, 1)) + 1e-3 * rng.standard_normal((n, 3))
    a, b, c = (fusion.make(name, fs) for _ in range(3))
    qa = a.run(gyr, acc)
    qb = b.run(gyr, acc, dt=np.full(n, (1.0 / fs) * (1.0 - 1e-13)))
    c.run(gyr[:51], acc[:51])
    assert c.at_rest and a.rest_samples == b.rest_samples >= 1
    np.testing.assert_allclose(qb, qa, atol=1e-9)
    for t in (a, b, c):
        t.reset()
    c.run(gyr[:50], acc[:50])
    assert not c.at_rest                    # one step short of rest_time is not rest


@pytest.mark.parametrize("name", NAMES)
def test_stamps_equal_to_1_over_fs_give_the_nominal_result(name):
    """Every duration summed from steps that decides something (rest, the low-passes' starts,
    magnetic disturbance times, aekf's timeout, cf-ekf's quiet time, the recovery after a
    saturated gyro) decides on the same sample whether the steps are 1/fs or time stamps
    within 1e-13 of it (a review found cf-ekf's quiet time and the recovery still off by a
    sample: 7 % of cf-ekf's learned bias, 1.8e-4 in madgwick's quaternion)."""
    fs, n = 100.0, 1200
    rng = np.random.default_rng(8)
    gyr = np.tile([0.015, -0.01, 0.02], (n, 1)) + 1e-4 * rng.standard_normal((n, 3))
    acc = np.tile([0.0, 0.0, G], (n, 1)) + 1e-3 * rng.standard_normal((n, 3))
    mag = np.tile([0.25, 0.0, -0.4], (n, 1)) + 1e-3 * rng.standard_normal((n, 3))
    gyr[100:200, 2] += 1.0          # a turn after exactly 1 s still
    acc[300:500, 0] += 1.5          # 2 s of linear acceleration
    mag[500:700] *= 1.5             # 2 s of a disturbed field
    gyr[800] = [50.0, 0.0, 0.0]     # a saturated sample
    params = {"gyro_range": 35.0} if "gyro_range" in type(fusion.make(name, fs)).PARAMS else {}
    nominal = fusion.make(name, fs, **params).run(gyr, acc, mag)
    for rel in (1e-13, -1e-13):
        q = fusion.make(name, fs, **params).run(gyr, acc, mag, dt=np.full(n, (1.0 / fs) * (1.0 + rel)))
        np.testing.assert_allclose(q, nominal, atol=1e-9, err_msg=f"steps (1 {rel:+g}) / fs")


EVERY_PARAM = sorted({p for n in NAMES for p in type(fusion.make(n, FS)).PARAMS})


@pytest.mark.parametrize("name", NAMES)
def test_an_attribute_named_after_a_parameter_only_where_it_is_declared(name):
    """Each parameter an estimator declares reads back as an attribute of that value; a
    parameter another estimator declares is no attribute of this one (gyro_range, every
    estimator's, aside): aekf had acc_lowpass (0.0), the base class the magdist_* of its
    disturbance detector, so gyro.magdist_time read 60."""
    est = fusion.make(name, FS)
    declared = type(est).PARAMS
    given = {p: d.default for p, d in declared.items() if d.default is not None}   # None: resolved
    assert all(hasattr(est, p) for p in declared) and {p: getattr(est, p) for p in given} == given
    extra = [p for p in EVERY_PARAM if p not in declared and p != "gyro_range" and hasattr(est, p)]
    assert extra == []
    if "magdist_time" not in declared:
        assert not hasattr(est, "mag_rejected") and not hasattr(est, "magd")


# --- run is N updates -----------------------------------------------------------------------

@pytest.mark.parametrize("variant", ["6axis", "9axis", "dt", "skip", "ned"])
@pytest.mark.parametrize("name, params", CASES, ids=CASE_IDS)
def test_run_equals_repeated_update(synthetic_data, name, params, variant):
    _, gyr, acc, mag = synthetic_data
    n = 2000
    gyr, acc, mag = gyr[:n], acc[:n], mag[:n]
    kw = dict(params)
    dt = None
    if variant == "6axis":
        mag = None
    elif variant == "dt":
        dt = np.random.default_rng(6).uniform(0.002, 0.03, n)
    elif variant == "skip":
        gyr, acc, mag = inject_invalid(gyr, acc, mag)
        kw["on_invalid"] = "skip"
    elif variant == "ned":
        kw["frame"] = "NED"
    a, b = fusion.make(name, FS, **kw), fusion.make(name, FS, **kw)
    decisions = hasattr(a, "record_decisions")
    if decisions:
        a.record_decisions()
        b.record_decisions()
    q = a.run(gyr, acc, mag, dt=dt)
    qu, codes = [], []
    for i in range(n):
        qu.append(b.update(gyr[i], acc[i], None if mag is None else mag[i], dt=None if dt is None else dt[i]))
        if decisions:
            codes.append(b.last_decision)
    assert np.abs(q - np.array(qu)).max() <= 1e-15
    assert np.array_equal(a.quaternion, b.quaternion)
    assert a.skipped == b.skipped
    if decisions:
        assert np.array_equal(a.decisions, codes) and np.array_equal(b.decisions, codes)
    # the whole state (bias, covariance, counters, filters' memories) agrees, not only q
    sa, sb = a.state()["fields"], b.state()["fields"]
    assert sa.keys() == sb.keys()
    bad = [k for k in sa if not _close(sa[k], sb[k])]
    assert not bad, f"state fields differ between run and update: {bad}"


# --- state round trip and pickling ------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_state_round_trip_and_pickle_resume_identically(synthetic_data, name):
    _, gyr, acc, mag = synthetic_data
    est = fusion.make(name, FS, on_invalid="skip")
    est.run(gyr[:700], acc[:700], mag[:700])
    loaded = fusion.make(name, FS, on_invalid="skip")
    loaded.load_state(est.state())
    copies = [loaded, fusion.Estimator.from_state(est.state()), pickle.loads(pickle.dumps(est))]
    tail = slice(700, 1400)
    expected = est.run(gyr[tail], acc[tail], mag[tail])
    for other in copies:
        assert type(other) is type(est)
        assert np.array_equal(other.run(gyr[tail], acc[tail], mag[tail]), expected)
        assert other.state() == est.state() or _close(other.state()["fields"], est.state()["fields"])


# --- bad input ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_bad_shapes_dtypes_lengths_and_dt(name):
    est = fusion.make(name, 100.0)
    ok = np.zeros((10, 3)) + [0, 0, G]
    cases = [
        (dict(gyr=np.zeros((10, 2)), acc=ok), "gyr must have shape"),
        (dict(gyr=np.zeros(30), acc=ok), "gyr must have shape"),
        (dict(gyr=ok, acc=ok[:9]), "acc has 9 samples"),
        (dict(gyr=ok, acc=ok, mag=ok[:, :2]), "mag must have shape"),
        (dict(gyr=ok.astype(object), acc=ok), "gyr must be a real numeric"),
        (dict(gyr=ok + 0j, acc=ok), "gyr must be a real numeric"),
        (dict(gyr=ok, acc=ok, dt=0.0), "dt must be"),
        (dict(gyr=ok, acc=ok, dt=-0.01), "dt must be"),
        (dict(gyr=ok, acc=ok, dt=np.full(9, 0.01)), "dt must be"),
        (dict(gyr=ok, acc=ok, dt=np.r_[np.full(9, 0.01), 0.0]), r"dt\[9\]"),
    ]
    for kwargs, msg in cases:
        with pytest.raises(ValueError, match=msg):
            est.run(**kwargs)
        assert not est.initialised      # nothing was processed
    with pytest.raises(ValueError, match="acc must have shape"):
        est.update([0, 0, 0], [0, 0])
    with pytest.raises(ValueError, match="dt must be"):
        est.update([0, 0, 0], [0, 0, G], dt=0)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("which", ["gyr", "acc", "mag"])
def test_non_finite_input_is_named(name, which, make_estimator):
    est = make_estimator(name)
    rows = {"gyr": np.zeros((5, 3)), "acc": np.tile([0.0, 0.0, G], (5, 1)), "mag": np.tile([0.0, 20.0, -40.0], (5, 1))}
    rows[which][3, 1] = np.nan
    with pytest.raises(ValueError, match=which):
        est.run(rows["gyr"], rows["acc"], rows["mag"])
    assert not est.initialised
    assert np.isfinite(est.quaternion).all()


@pytest.mark.parametrize("name", NAMES)
def test_unknown_parameter_is_named_with_the_accepted_ones(name):
    accepted = sorted(type(fusion.make(name, FS)).PARAMS)
    with pytest.raises(ValueError, match="no_such_param") as info:
        fusion.make(name, FS, no_such_param=1.0)
    msg = str(info.value)
    assert all(p in msg for p in accepted) if accepted else "accepted" in msg or "no parameters" in msg
