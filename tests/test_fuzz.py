"""Property tests of every estimator's public interface (fusion.make, update, run, reset,
load_state): any input gives finite unit quaternions (and a finite, symmetric, positive
definite covariance) or a ValueError with a message; never a crash, a NaN, or a silent pass
of an input that on_invalid="raise" must refuse. Examples per estimator are printed by the
last test (pytest -s) and asserted there."""
import collections
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

import fusion
from fusion._core import DT_MIN, DT_MAX
from _helpers import SETTINGS, bad_message, check_output

NAMES = fusion.available()
EXAMPLES = collections.Counter()          # (test, estimator) -> examples run

SPECIAL = [0.0, -0.0, math.nan, math.inf, -math.inf, 1e150, -1e155, 1e-160, 5e-324, 1e200, 3e153]
values = st.one_of(st.floats(-30.0, 30.0), st.sampled_from(SPECIAL))


# --- construction ---------------------------------------------------------------------

def param_values(p):
    """Values at, inside and beyond the parameter's (a fusion.Param) range, and of wrong types."""
    default = p.default
    lo = p.low if p.low is not None and p.low > 0 else 1e-6     # a log-uniform draw: ends > 0
    hi = p.high if p.high is not None else 1e6
    edge = [lo, hi, lo * 0.999, hi * 1.001, 0.0, -lo, math.nan, math.inf]
    good = st.floats(math.log10(lo), math.log10(hi)).map(lambda e: 10.0 ** e)
    wrong = st.sampled_from(["1", None, True, 1 + 1j, [1.0]])
    extra = st.sampled_from([None, "quest", "vectors", "QUEST", "heading", "vector", 30.0, -95.0, 3, 0]) \
        if not isinstance(default, float) else st.nothing()
    return st.one_of(st.sampled_from(edge), good, wrong, extra)


@st.composite
def configs(draw, name):
    cls = type(fusion.make(name, 100.0))
    params = {k: draw(param_values(p)) for k, p in cls.PARAMS.items() if draw(st.booleans())}
    fs = draw(st.one_of(st.sampled_from([100.0, 1.0 / DT_MAX, 1.0 / DT_MIN, 1.01 / DT_MIN, 0.99 / DT_MAX,
                                         0.0, math.nan, 1000]),
                        st.floats(1.0, 2000.0)))
    return fs, params


def build(name, fs, params, **kw):
    try:
        return fusion.make(name, fs, **params, **kw)
    except ValueError as exc:
        bad_message(exc)
        return None


# --- samples ----------------------------------------------------------------------------

@st.composite
def sample_arrays(draw, n):
    """(N, 3) in a random dtype and memory layout; mostly plausible rows, some extreme."""
    base = draw(hnp.arrays(np.float64, (n, 3), elements=values))
    kind = draw(st.sampled_from(["f8", "f4", "i8", "F", "view", "obj", "list"]))
    plausible = draw(st.booleans())
    return base, kind, plausible


def layout(arr, kind):
    if kind == "f4":        # 1e150 becomes inf: an invalid row, as the kernels will see it
        with np.errstate(over="ignore"):
            return arr.astype(np.float32)
    if kind == "i8":
        return np.nan_to_num(arr, posinf=1e9, neginf=-1e9).clip(-1e9, 1e9).astype(np.int64)
    if kind == "F":
        return np.asfortranarray(arr)
    if kind == "view":
        big = np.zeros((arr.shape[0], 6))
        big[:, ::2] = arr
        return big[:, ::2]
    if kind == "obj":
        return arr.astype(object)
    if kind == "list":
        return arr.tolist()
    return arr


def as_f64(x):
    """What the kernels see, or None where a ValueError is due (dtype)."""
    a = np.asarray(x)
    if a.dtype.kind not in "fiu" or a.ndim != 2 or a.shape[1] != 3:
        return None
    return a.astype(np.float64)


def row_ok(a, allow_zero):
    """The kernels' rule (docs/estimators.md, "Invalid samples"): |v|^2 finite, and for acc
    and mag a normal double (denormal or zero is invalid)."""
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        n2 = (a * a).sum(axis=1)
    return np.isfinite(n2) & (allow_zero | (n2 >= np.finfo(np.float64).tiny))


@st.composite
def dts(draw, n):
    return draw(st.one_of(
        st.none(),
        st.sampled_from([0.01, DT_MIN, DT_MAX, 0.0, -0.01, math.nan, math.inf, DT_MAX * 2, DT_MIN / 2]),
        hnp.arrays(np.float64, (n,), elements=st.one_of(
            st.floats(DT_MIN, 1.0), st.sampled_from([0.0, -0.01, DT_MAX, DT_MIN, math.nan, 50.0]))),
    ))


def dt_ok(dt):
    if dt is None:
        return True
    d = np.asarray(dt, dtype=np.float64)
    return bool(np.all((d >= DT_MIN) & (d <= DT_MAX)))


# --- the properties -----------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=60, **SETTINGS)
@given(data=st.data())
def test_make_accepts_its_ranges_or_says_why(name, data):
    EXAMPLES["make", name] += 1
    fs, params = data.draw(configs(name))
    est = build(name, fs, params)
    if est is None:
        return
    # documented ranges hold; repr round-trips the accepted configuration
    assert 1.0 / DT_MAX <= est.fs <= 1.0 / DT_MIN
    again = eval(repr(est), {"fusion": fusion})
    assert again.params == est.params
    # a short noisy run at the extremes of the accepted configuration stays healthy
    rng = np.random.default_rng(0)
    gyr = rng.normal(0, 3.0, (30, 3))
    acc = np.array([0, 0, 9.81]) + rng.normal(0, 3.0, (30, 3))
    mag = np.array([0, 0.4, -0.3]) + rng.normal(0, 0.05, (30, 3))
    check_output(est, est.run(gyr, acc, mag), 30)
    check_output(est, est.run(gyr, acc, mag, dt=DT_MAX), 30)
    check_output(est, est.run(gyr, acc, None, dt=DT_MIN), 30)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=150, **SETTINGS)
@given(data=st.data())
def test_run_gives_unit_quaternions_or_a_value_error(name, data):
    EXAMPLES["run", name] += 1
    n = data.draw(st.sampled_from([0, 1, 2, 3, 7, 25]))
    on_invalid = data.draw(st.sampled_from(["raise", "skip"]))
    frame = data.draw(st.sampled_from(["ENU", "NED"]))
    est = fusion.make(name, data.draw(st.sampled_from([100.0, 1000.0, 1.0 / DT_MAX, 1.0 / DT_MIN])),
                      frame=frame, on_invalid=on_invalid)
    g, gk, _ = data.draw(sample_arrays(n))
    a, ak, a_plausible = data.draw(sample_arrays(n))
    if a_plausible:          # keep most accelerometer rows near gravity
        a = np.where(np.isfinite(a), np.array([0.0, 0.0, 9.81]) + np.clip(a, -5, 5) * 0.3, a)
    nine = data.draw(st.booleans())
    m, mk, _ = data.draw(sample_arrays(n))
    dt = data.draw(dts(n))
    args = (layout(g, gk), layout(a, ak), layout(m, mk) if nine else None)
    G, A, M = as_f64(args[0]), as_f64(args[1]), (as_f64(args[2]) if nine else np.zeros((n, 3)))
    typed = G is not None and A is not None and M is not None
    valid = typed and row_ok(G, True).all() and row_ok(A, False).all() and (not nine or row_ok(M, False).all())
    must_work = typed and dt_ok(dt) and (valid or on_invalid == "skip")
    before = est.state()
    try:
        q = est.run(*args, dt=dt)
    except ValueError as exc:
        bad_message(exc)
        assert not must_work, f"refused a valid input: {exc}"
        assert est.state() == before, "a refused input changed the state"
        return
    assert must_work, "accepted an input it must refuse"
    check_output(est, q, n)
    # run is N calls of update: the same numbers
    if 0 < n <= 7:
        other = fusion.make(est.name, est.fs, frame=frame, on_invalid=on_invalid)
        d = np.broadcast_to(np.asarray(0.01 if dt is None else dt, dtype=np.float64), (n,))
        dt_given = dt is not None
        ups = [other.update(G[i], A[i], M[i] if nine else None, dt=d[i] if dt_given else None)
               for i in range(n)]
        assert np.array_equal(np.array(ups), q) if est.fs == 100.0 or dt_given else True


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=80, **SETTINGS)
@given(data=st.data())
def test_update_and_reset_refuse_or_stay_unit(name, data):
    EXAMPLES["update", name] += 1
    est = fusion.make(name, 100.0, on_invalid=data.draw(st.sampled_from(["raise", "skip"])))
    q0 = data.draw(st.one_of(st.none(), hnp.arrays(np.float64, data.draw(st.sampled_from([(4,), (3,), (2, 2)])),
                                                   elements=values),
                             st.sampled_from(["abcd", [1, 0, 0, 0], (0, 0, 0, 1)])))
    try:
        est.reset(q0)
    except ValueError as exc:
        bad_message(exc)
    for _ in range(data.draw(st.integers(1, 12))):
        g = data.draw(st.one_of(hnp.arrays(np.float64, (3,), elements=values),
                                st.lists(values, min_size=2, max_size=4), st.sampled_from(["xyz", None])))
        a = data.draw(st.one_of(st.just(np.array([0.1, -0.2, 9.8])),
                                hnp.arrays(np.float64, (3,), elements=values)))
        m = data.draw(st.one_of(st.none(), hnp.arrays(np.float64, (3,), elements=values)))
        dt = data.draw(st.one_of(st.none(), st.sampled_from([0.01, DT_MAX, DT_MIN, 0.0, -1.0, math.nan]),
                                 st.floats(DT_MIN, 10.0)))
        try:
            q = est.update(g, a, m, dt=dt)
        except (ValueError, TypeError) as exc:
            # TypeError only from numpy for objects that are not arrays at all (None)
            if isinstance(exc, TypeError):
                assert g is None, repr(exc)
                continue
            bad_message(exc)
            continue
        check_output(est, q[None, :], 1)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=40, **SETTINGS)
@given(data=st.data())
def test_load_state_refuses_garbage(name, data):
    EXAMPLES["load_state", name] += 1
    est = fusion.make(name, 100.0)
    est.update([0.1, 0.0, 0.0], [0.0, 0.2, 9.8], [0.0, 0.4, -0.3])
    s = est.state()
    key = data.draw(st.sampled_from(sorted(s["fields"])))
    s["fields"][key] = data.draw(st.one_of(values, st.lists(values, max_size=60), st.text(max_size=3),
                                           st.integers(-3, 10 ** 20)))
    other = fusion.make(name, 100.0)
    try:
        other.load_state(s)
    except ValueError as exc:
        bad_message(exc)
        return
    rng = np.random.default_rng(1)
    check_output(other, other.run(rng.normal(0, 1, (20, 3)), [0, 0, 9.81] + rng.normal(0, 1, (20, 3)),
                                  [0, 0.4, -0.3] + rng.normal(0, 0.01, (20, 3))), 20)


def test_zz_report_examples():
    """Runs last (file order): the number of Hypothesis examples per estimator and test."""
    tests = sorted({t for t, _ in EXAMPLES})
    if not tests:
        pytest.skip("run with the property tests above")
    print("\nHypothesis examples per estimator:")
    for name in NAMES:
        counts = {t: EXAMPLES[t, name] for t in tests}
        print(f"  {name:9s} " + "  ".join(f"{t}={c}" for t, c in counts.items())
              + f"  total={sum(counts.values())}")
    assert all(EXAMPLES[t, n] >= 20 for t in tests for n in NAMES)
