"""Property tests of the input classes that found the defects of tests/test_adversarial.py
(docs/robustness.md, "Adversarial inputs"): threads sharing one estimator, subclasses that skip
or botch __init__, samples in any byte order and alignment, tampered states, and single gyro
samples beyond the range. Any of them gives the right answer, or a ValueError / RuntimeError
with a message; never a crash, a NaN or an indefinite covariance."""
import math
import re
import threading

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import fusion
from fusion.constants import GRAVITY
from _helpers import SETTINGS, bad_message, check_output

# a numpy warning here is arithmetic gone out of range on bad input: it must be refused first
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

NAMES = fusion.available()
KALMAN = ["ekf", "iir-ekf", "aekf", "ukf"]
MSG = "estimator in use by another thread"
UP = np.array([0.0, 0.0, GRAVITY])
FIELD = np.array([0.0, 20.0, -40.0])
# max_examples of each property below (docs/robustness.md counts the inputs from these)
EXAMPLES = {"threads": 40, "subclasses": 150, "byte_order": 300, "tampered": 400, "out_of_range": 150}


def motion(n, seed, scale=0.3):
    rng = np.random.default_rng(seed)
    return (scale * rng.standard_normal((n, 3)), UP + 0.3 * rng.standard_normal((n, 3)),
            FIELD + 0.5 * rng.standard_normal((n, 3)))


def check_state_valid(est):
    """The state loads into a fresh estimator (every field within its range) and the
    attitude and covariance are sound."""
    fusion.make(est.name, est.fs, **est.params).load_state(est.state())
    check_output(est, est.quaternion[None, :], 1)


# --- threads ------------------------------------------------------------------------------

@settings(max_examples=EXAMPLES["threads"], **SETTINGS)
@given(name=st.sampled_from(NAMES), n_threads=st.integers(2, 4),
       plans=st.lists(st.lists(st.sampled_from(["run", "update", "reset", "state", "load_state"]),
                               min_size=1, max_size=6), min_size=4, max_size=4),
       n=st.sampled_from([1, 2_000, 100_000]), nine=st.booleans())
def test_threads_on_one_estimator(name, n_threads, plans, n, nine):
    """Threads calling any mix of the entry points on one estimator: each call succeeds or
    raises RuntimeError(MSG); every result is finite and unit, the state stays valid."""
    gyr, acc, mag = motion(n, n)
    m = mag if nine else None
    est = fusion.make(name, 100.0)
    s0 = est.state()
    errors, outs = [], []

    def worker(plan):
        for op in plan:
            try:
                if op == "run":
                    outs.append(est.run(gyr, acc, m))
                elif op == "update":
                    outs.append(est.update(gyr[0], acc[0], None if m is None else m[0])[None, :])
                elif op == "reset":
                    est.reset()
                elif op == "state":
                    est.state()
                else:
                    est.load_state(s0)
            except RuntimeError as exc:
                if str(exc) != MSG:
                    errors.append(exc)
            except Exception as exc:        # noqa: BLE001 - any other error fails the test
                errors.append(exc)

    threads = [threading.Thread(target=worker, args=(plans[i],)) for i in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not any(t.is_alive() for t in threads)
    assert not errors, errors
    for q in outs:
        assert np.isfinite(q).all() and np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-9
    check_state_valid(est)


# --- subclasses ---------------------------------------------------------------------------

CLASSES = [type(fusion.make(n, 100.0)) for n in NAMES]
CALLS = ["update", "run", "reset", "state", "load_state", "pickle", "repr"]


def call(obj, what, state):
    g, a, m = motion(5, 0)
    if what == "update":
        return obj.update(g[0], a[0], m[0])
    if what == "run":
        return obj.run(g, a, m)
    if what == "reset":
        return obj.reset()
    if what == "state":
        return obj.state()
    if what == "load_state":
        return obj.load_state(state)
    if what == "pickle":
        import pickle
        return pickle.loads(pickle.dumps(obj))
    return repr(obj)


@settings(max_examples=EXAMPLES["subclasses"], **SETTINGS)
@given(cls=st.sampled_from(CLASSES), how=st.sampled_from(["skip", "new", "super", "super-bad", "re-init-bad"]),
       what=st.sampled_from(CALLS), param=st.sampled_from([("kp", -1.0), ("gyro_noise", math.nan),
                                                          ("window", 2 ** 40), ("cutoff_hz", 1e9),
                                                          ("nope", 1), ("acc_norm_tol", 0.0)]))
def test_subclasses(cls, how, what, param):
    """A subclass that skips __init__ (or an object from __new__, or one whose __init__
    raised) is refused with RuntimeError; one that calls it works as the class; a configured
    object whose __init__ is called again with a bad parameter raises ValueError and stays
    usable."""
    state = fusion.make(cls.name, 100.0).state()
    k, v = param

    def init(self, fs):
        if how == "super":
            cls.__init__(self, fs)
        elif how == "super-bad":
            try:
                cls.__init__(self, fs, **{k: v})
            except ValueError:
                pass

    Mine = type("Mine", (cls,), {"__init__": init})
    obj = cls.__new__(cls) if how == "new" else Mine(100.0)
    if how == "re-init-bad":
        obj = cls(100.0)
        try:
            cls.__init__(obj, 100.0, **{k: v})
        except ValueError as exc:
            bad_message(exc)
    configured = how in ("super", "re-init-bad")     # every param drawn is unknown or invalid
    if not configured and what != "repr":
        with pytest.raises(RuntimeError, match="was not configured"):
            call(obj, what, state)
        return
    if what == "pickle" and how == "super":
        return              # pickle cannot find a class defined in a function, by design
    out = call(obj, what, state)
    if what in ("update", "run"):
        check_output(obj, np.atleast_2d(out), np.atleast_2d(out).shape[0])
    if configured:
        check_state_valid(obj)


# --- byte order and alignment -----------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_a_refused_reinit_changes_nothing(name):
    """A second __init__ that is refused leaves the estimator as it was, whatever it would have
    changed: every argument is checked before any is taken. Refused here: a bad frame or
    on_invalid, an unknown parameter, and a bad value beside good new ones (a new fs and
    saturation range, which a bad frame or value once let through)."""
    gyr, acc, mag = motion(300, 7)
    est, same = fusion.make(name, 100.0), fusion.make(name, 100.0)
    cls = type(est)
    new = {"gyro_range": 1.0} if "gyro_range" in cls.PARAMS else {}
    bad = [dict(frame="bogus"), dict(on_invalid="bogus"), dict(no_such_parameter=1.0)]
    bad += [{k: -1e30} for k, p in cls.PARAMS.items()
            if p.low is not None and p.choices is None and not isinstance(p.default, bool)][:2]
    if name == "iir-ekf":
        bad.append(dict(cutoff_hz=40.0))        # above fs / 2 at the new fs: refused by its design
    for b in bad:
        with pytest.raises(ValueError):
            cls.__init__(est, 50.0, **dict(new, **b))
    assert est.fs == 100.0
    np.testing.assert_array_equal(est.run(gyr, acc, mag), same.run(gyr, acc, mag))


@pytest.mark.parametrize("name", NAMES)
def test_a_reinit_holds_the_estimator_throughout(name):
    """While __init__ re-configures an estimator, a call from another thread is refused, so
    that no run steps through prefilters (or other parts) that __init__ is replacing, and so
    is a run of the new prefilters; once it returns the estimator runs with its new
    configuration. Before, __init__ tested the in-use flag only at its start."""
    gyr, acc, mag = motion(300, 8)
    inside, go_on = threading.Event(), threading.Event()
    base = type(fusion.make(name, 100.0))

    class Paused(base):
        def _configure(self, *args):
            super()._configure(*args)
            if go_on.is_set():
                return
            inside.set()
            go_on.wait(60)

    go_on.set()
    est = Paused(100.0)         # the first configuration passes straight through
    go_on.clear()
    old = [p for p in est.prefilters.values() if p is not None]
    t = threading.Thread(target=lambda: est.__init__(50.0))
    t.start()
    assert inside.wait(10)
    calls = {"run": lambda: est.run(gyr, acc, mag), "update": lambda: est.update(gyr[0], acc[0]),
             "reset": est.reset, "state": est.state, "init": lambda: est.__init__(100.0)}
    for what, call in calls.items():
        with pytest.raises(RuntimeError, match=MSG):
            call()
            pytest.fail(f"{what} ran while __init__ held the estimator")
    for k, p in est.prefilters.items():     # the new ones, which __init__ put in
        if p is not None:
            with pytest.raises(RuntimeError, match="prefilter in use"):
                p.run(np.ones((2, 3)))
                pytest.fail(f"the {k} prefilter ran while __init__ held its estimator")
    go_on.set()
    t.join(60)
    assert not t.is_alive() and est.fs == 50.0
    for p in old + [p for p in est.prefilters.values() if p is not None]:     # all released
        p.reset()           # (refused while in use; the new ones were just cleared: no change)
    # a subclass steps through the generic loop, not a kernel's inlined one: equal to round-off
    np.testing.assert_allclose(est.run(gyr, acc, mag), fusion.make(name, 50.0).run(gyr, acc, mag),
                               rtol=0, atol=1e-12)


def converted(v, kind):
    """v (3,) float64 in another byte order / type / alignment / stride."""
    if kind == "unaligned":
        buf = np.zeros(3 * 8 + 1, dtype=np.uint8)
        out = np.frombuffer(buf.data, dtype=np.float64, count=3, offset=1)
        out[:] = v
        return out
    if kind == "strided-be":
        return np.repeat(v.astype(">f8"), 3)[::3]
    if kind == "list":
        return v.tolist()
    return v.astype(kind)


KINDS = [">f8", "<f8", ">f4", "<f4", ">i4", "<i2", "unaligned", "strided-be", "list"]
vec = st.lists(st.floats(-30.0, 30.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=EXAMPLES["byte_order"], **SETTINGS)
@given(name=st.sampled_from(NAMES), g=vec, a=vec, m=vec, kinds=st.lists(st.sampled_from(KINDS), min_size=3, max_size=3))
def test_any_byte_order_gives_the_native_numbers(name, g, a, m, kinds):
    """update() of samples in any byte order, type, alignment and stride returns what it
    returns for the same numbers as native float64 (or the same ValueError)."""
    given_ = [converted(v, k) for v, k in zip((g, a, m), kinds)]
    native = [np.asarray(x).astype(np.float64) for x in given_]
    est, ref = fusion.make(name, 100.0), fusion.make(name, 100.0)
    try:
        q_ref = ref.update(*native)
    except ValueError as exc:
        with pytest.raises(ValueError, match=re.escape(str(exc).split(",")[0])):
            est.update(*given_)
        return
    assert np.array_equal(est.update(*given_), q_ref)


# --- tampered states ----------------------------------------------------------------------

TAMPERS = ["scale", "add", "set", "negate", "asym", "swap"]


@settings(max_examples=EXAMPLES["tampered"], **SETTINGS)
@given(name=st.sampled_from(NAMES), data=st.data())
def test_tampered_state_is_refused_or_harmless(name, data):
    """A state from a real run with one field tampered (scaled, shifted, set, negated, made
    asymmetric, two entries swapped): load_state refuses it naming the field, or runs on it
    to finite unit quaternions, a symmetric positive-definite covariance and a state that
    is itself valid."""
    cls = type(fusion.make(name, 100.0))
    est = cls(100.0, **({"gyro_range": 5.0} if "gyro_range" in cls.PARAMS else {}))
    g, a, m = motion(300, 5)
    est.run(g, a, m)
    s = est.state()
    key = data.draw(st.sampled_from(sorted(k for k, v in s["fields"].items() if isinstance(v, (float, list)))))
    v = np.atleast_1d(np.array(s["fields"][key], dtype=float))
    i = data.draw(st.integers(0, v.size - 1))
    how = data.draw(st.sampled_from(TAMPERS))
    x = data.draw(st.sampled_from([1e300, -1e300, 1e145, 1e6, 1e3, -1.0, 1e-3, 0.5, 5.0, 101.0, 1e-300, 0.0]))
    if how == "scale":
        v = v * x
    elif how == "add":
        v[i] += x
    elif how == "set":
        v[i] = x
    elif how == "negate":
        v = -v
    elif how == "asym" and v.size in (36, 49):
        k = int(round(math.sqrt(v.size)))
        v[(i // k) * k + (i % k + 1) % k] += 1e-3
    elif v.size > 1:
        j = (i + 1) % v.size
        v[i], v[j] = v[j], v[i]
    with np.errstate(over="ignore", invalid="ignore"):
        s["fields"][key] = v.tolist() if v.size > 1 else float(v[0])
    try:
        est.load_state(s)
    except ValueError as exc:
        assert f"state field {key!r}" in str(exc), exc
        return
    q = est.run(*motion(200, 6))
    check_output(est, q, 200)
    check_state_valid(est)


# --- single out-of-range gyro samples -----------------------------------------------------

@settings(max_examples=EXAMPLES["out_of_range"], **SETTINGS)
@given(name=st.sampled_from(KALMAN), k=st.integers(0, 399), axis=st.integers(0, 2),
       sign=st.sampled_from([-1.0, 1.0]), factor=st.floats(1.021, 1e6), gyro_range=st.floats(0.5, 50.0),
       nine=st.booleans())
def test_single_out_of_range_sample_is_dropped(name, k, axis, sign, factor, gyro_range, nine):
    """One gyro sample beyond 1.02 gyro_range on one axis is not a measurement: the Kalman
    filters run as if it had been dropped (to the rounding of the ekf's inlined batch step),
    by run and by update."""
    g, a, m = motion(400, k)
    m = m if nine else None
    bad = g.copy()
    bad[k, axis] = sign * factor * gyro_range
    dropped = g.copy()
    dropped[k] = np.nan
    est = fusion.make(name, 100.0, gyro_range=gyro_range, on_invalid="skip")
    q = est.run(bad, a, m)
    ref = fusion.make(name, 100.0, gyro_range=gyro_range, on_invalid="skip")
    assert np.abs(ref.run(dropped, a, m) - q).max() < 1e-12
    check_output(est, q, 400)
    one = fusion.make(name, 100.0, gyro_range=gyro_range, on_invalid="skip")
    last = min(k + 1, 399)
    for j in range(last + 1):
        qj = one.update(bad[j], a[j], None if m is None else m[j])
    assert np.abs(qj - q[last]).max() < 1e-12
