"""The reproducers of the defects adversarial testing found in the fusion library (docs/robustness.md,
"Adversarial inputs"), each run in a fresh interpreter so that a segfault or an abort fails its
test instead of killing the run. Each script asserts a clear ValueError / RuntimeError or the
right answer and prints OK last; the test checks the exit code and that line."""
import os
import subprocess
import sys
import textwrap

import pytest

import fusion

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(fusion.__file__)))    # this fusion's tree
KALMAN = ["ekf", "ekf-lp", "iir-ekf", "aekf", "ukf"]


# what every script starts with: the imports, the refusal message, noisy samples
PREAMBLE = """import threading
import numpy as np
import fusion
MSG = "estimator in use by another thread"
def noisy(n, seed, sd_gyr=0.3, sd_acc=0.2, sd_mag=0.5):
    rng = np.random.default_rng(seed)
    return (sd_gyr * rng.standard_normal((n, 3)), np.array([0.0, 0.0, 9.81]) + sd_acc * rng.standard_normal((n, 3)),
            np.array([0.0, 20.0, -40.0]) + sd_mag * rng.standard_normal((n, 3)))
"""


def run_script(body, timeout=120):
    code = PREAMBLE + textwrap.dedent(body) + "\nprint('OK')\n"
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                       cwd=ROOT, env=env)
    assert p.returncode == 0 and p.stdout.rstrip().endswith("OK"), (
        f"exit code {p.returncode}\nstdout: {p.stdout[-2000:]}\nstderr: {p.stderr[-3000:]}")
    return p.stdout


# --- 1. the sliding mean's window ---------------------------------------------------------

@pytest.mark.parametrize("window", [1431655766, 2 ** 31, 2 ** 63, 100_001, 0, -3])
def test_window_out_of_range_is_a_value_error(window):
    """3 * 1431655766 overflowed a C int in the buffer's size: accepted, then a heap overflow
    on run; 2**31 and more gave OverflowError. Now a ValueError naming window and its range,
    from make and from SlidingMean alike; the largest window accepted allocates and runs."""
    run_script(f"""
        import pytest
        for build in (lambda: fusion.make("cf-ekf", fs=100.0, window={window}),
                      lambda: fusion.SlidingMean({window})):
            with pytest.raises(ValueError, match=r"window must be an integer in \\[1, 100000\\]"):
                build()
        if {window} == 100_001:
            f = fusion.SlidingMean(100_000)
            x = np.arange(300_000, dtype=float)[:, None] * np.ones(3)
            y = f.run(x)
            assert np.allclose(y[-1], x[-100_000:].mean(axis=0), rtol=0, atol=1e-6), y[-1]
            est = fusion.make("cf-ekf", fs=100.0, window=100_000)
            assert np.isfinite(est.run(np.zeros((1000, 3)), np.tile([0.0, 0.0, 9.81], (1000, 1)))).all()
    """)


# --- 2. threads -------------------------------------------------------------------------------

THREAD_SCRIPT = """
    n = {n}
    gyr, acc, mag = noisy(n, 0)
    est = fusion.make("{name}", 100.0{params})
    serial = fusion.make("{name}", 100.0{params})
    s0 = est.state()
    refused, done, outs = [], [], []
    def worker():
        for _ in range({rounds}):
            try:
                outs.append(est.run(gyr, acc, mag))
                done.append(1)
            except RuntimeError as e:
                assert str(e) == MSG, e
                refused.append(1)
    threads = [threading.Thread(target=worker) for _ in range({threads})]
    for t in threads:
        t.start()
    # while the workers run, the other entry points are refused or succeed, never race
    for _ in range(200):
        for call in (lambda: est.update(gyr[0], acc[0], mag[0]), lambda: est.state(),
                     lambda: est.load_state(s0), lambda: est.reset()):
            try:
                call()
            except RuntimeError as e:
                assert str(e) == MSG, e
                refused.append(1)
    for t in threads:
        t.join()
    assert refused, "no call was ever refused: the test did not overlap"
    for q in outs:
        assert q.shape == (n, 4) and np.isfinite(q).all()
        assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-9
    # the final state is a valid one (load_state checks every field's range) and finite
    fusion.make("{name}", 100.0{params}).load_state(est.state())
    assert np.isfinite(est.quaternion).all()
    # and the estimator still works exactly: a run from a reset equals a fresh one's
    est.reset()
    assert np.array_equal(est.run(gyr, acc, mag), serial.run(gyr, acc, mag))
"""


@pytest.mark.parametrize("name, threads", [("cf-ekf", 2), ("iir-ekf", 4), ("ekf", 2), ("aekf", 2)])
def test_concurrent_calls_are_refused_not_raced(name, threads):
    """Two threads on one cf-ekf segfaulted (a race on the sliding mean's head index: run
    with the seed's window of 10, which moves it), four on an iir-ekf left NaN rows and a NaN
    state. Now a call that finds the estimator in use raises RuntimeError("estimator in use by
    another thread"); every completed run is finite and unit, and the estimator stays valid."""
    run_script(THREAD_SCRIPT.format(name=name, n=200_000 if name != "aekf" else 100_000,
                                    rounds=4, threads=threads,
                                    params=", window=10" if name == "cf-ekf" else ""), timeout=300)


def test_refused_calls_leave_no_trace():
    """While one run holds the estimator, update, run, reset, state and load_state from another
    thread are refused, and the run's result and final state are those of the run alone."""
    run_script("""
        n = 1_000_000
        gyr, acc, _ = noisy(n, 1)
        alone = fusion.make("cf-ekf", 100.0)
        q_alone = alone.run(gyr, acc)
        est = fusion.make("cf-ekf", 100.0)
        s0 = est.state()
        box = {}
        def worker():
            while True:         # until its run gets the estimator (state() below may hold it)
                try:
                    box["q"] = est.run(gyr, acc)
                    return
                except RuntimeError as e:
                    assert str(e) == MSG
        t = threading.Thread(target=worker)
        t.start()
        while True:             # until the run holds it: state() (which changes nothing) refused
            try:
                est.state()
            except RuntimeError as e:
                assert str(e) == MSG
                break
            assert t.is_alive()
        calls = {"update": lambda: est.update(gyr[0], acc[0]), "run": lambda: est.run(gyr[:5], acc[:5]),
                 "reset": lambda: est.reset(), "state": lambda: est.state(),
                 "load_state": lambda: est.load_state(s0)}
        seen = set()
        for k, call in calls.items():
            try:
                call()
            except RuntimeError as e:
                assert str(e) == MSG
                seen.add(k)
        still_running = t.is_alive()
        t.join()
        assert still_running and seen == set(calls), seen
        assert np.array_equal(box["q"], q_alone)
        assert est.state() == alone.state()
    """, timeout=300)


def test_aekf_decision_log_counts_every_sample_of_concurrent_runs():
    """aekf lost decision-log entries with two threads (the log grows by realloc in the
    loop). Now one run at a time: the log holds one code per sample of every run that
    completed, and reading it during a run is refused rather than racing the realloc."""
    run_script("""
        n = 60_000
        gyr, acc, _ = noisy(n, 2, sd_acc=0.5)
        est = fusion.make("aekf", 100.0)
        est.record_decisions()
        done = []
        def worker():
            for _ in range(4):
                try:
                    est.run(gyr, acc)
                    done.append(1)
                except RuntimeError as e:
                    assert str(e) == MSG
        threads = [threading.Thread(target=worker) for _ in range(2)]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            try:
                d = est.decisions
                assert d.size % n == 0, d.size
            except RuntimeError as e:
                assert str(e) == MSG
        for t in threads:
            t.join()
        assert est.decisions.size == len(done) * n, (est.decisions.size, len(done))
    """, timeout=300)


# --- 3. subclasses that skip __init__ ---------------------------------------------------------

def test_unconfigured_estimators_raise():
    """`class Mine(fusion.CFEKF): def __init__(self, fs): pass` segfaulted on update;
    cls.__new__(cls).run(...) returned NaN for the ekf family. Every estimator and prefilter
    now refuses use before its __init__ ran, with a RuntimeError saying so."""
    run_script("""
        import pytest
        classes = [type(fusion.make(n, 100.0)) for n in fusion.available()]
        assert len(classes) == 10     # with triad
        g, a, m = np.zeros(3), np.array([0.0, 0.0, 9.81]), np.array([0.0, 20.0, -40.0])
        for cls in classes:
            Mine = type("Mine", (cls,), {"__init__": lambda self, fs: None})
            for obj in (Mine(100.0), cls.__new__(cls)):
                for call in (lambda: obj.update(g, a, m), lambda: obj.run(np.zeros((5, 3)), np.tile(a, (5, 1))),
                             lambda: obj.reset(), lambda: obj.state(), lambda: obj.load_state({}),
                             lambda: __import__("pickle").dumps(obj)):
                    with pytest.raises(RuntimeError, match="was not configured: call the class's __init__"):
                        call()
                assert "not configured" in repr(obj)
            # a subclass that does call it works as the class
            Good = type("Good", (cls,), {"__init__": lambda self, fs: cls.__init__(self, fs)})
            assert np.array_equal(Good(100.0).update(g, a, m), cls(100.0).update(g, a, m))
        with pytest.raises(RuntimeError, match="cf_quaternion|not configured"):
            fusion.CFEKF.__new__(fusion.CFEKF).cf_quaternion
        # prefilters: the Butterworth's coefficients come from __init__; the sliding mean's
        # buffer is allocated in __cinit__, so it is configured whatever __init__ does
        with pytest.raises(RuntimeError, match="not configured"):
            fusion.Butterworth.__new__(fusion.Butterworth).run(np.ones((4, 3)))
        Lazy = type("Lazy", (fusion.SlidingMean,), {"__init__": lambda self, w: None})
        x = np.random.default_rng(0).standard_normal((50, 3))
        assert np.array_equal(Lazy(7).run(x), fusion.SlidingMean(7).run(x))
        with pytest.raises(TypeError):
            fusion.SlidingMean.__new__(fusion.SlidingMean)
    """)


# --- 4. byte order ----------------------------------------------------------------------------

def test_big_endian_samples_in_update():
    """update(g.astype(">f8"), ...) returned [1.0, -7.7e-183, ...] (the fast path read the
    bytes as native) while run converted; a big-endian mag was refused. Now every byte order
    and alignment gives the native numbers, and messages show the values given."""
    run_script("""
        import pytest
        rng = np.random.default_rng(3)
        g = 0.2 * rng.standard_normal(3)
        a = np.array([0.3, -0.2, 9.7])
        m = np.array([0.1, 20.0, -40.0])
        def unaligned(v):
            buf = np.zeros(3 * 8 + 1, dtype=np.uint8)
            out = np.frombuffer(buf.data, dtype=np.float64, count=3, offset=1)
            out[:] = v
            return out
        for name in fusion.available():
            ref = fusion.make(name, 100.0)
            q_ref = [ref.update(g, a, m) for _ in range(3)]
            for conv in (lambda v: v.astype(">f8"), lambda v: v.astype("<f8"), unaligned,
                         lambda v: np.repeat(v.astype(">f8"), 2)[::2]):
                est = fusion.make(name, 100.0)
                q = [est.update(conv(g), conv(a), conv(m)) for _ in range(3)]
                assert np.array_equal(np.array(q), np.array(q_ref)), (name, q[0], q_ref[0])
            # run converts as well
            est = fusion.make(name, 100.0)
            G, A, M = (np.tile(v, (3, 1)).astype(">f8") for v in (g, a, m))
            assert np.array_equal(est.run(G, A, M), np.array(q_ref))
        est = fusion.make("ekf", 100.0)
        with pytest.raises(ValueError,
                           match=r"mag must be finite and non-zero, .*, got array\\(\\[ *inf, +20\\., +-40\\.\\]"):
            est.update(g, a, np.array([np.inf, 20.0, -40.0], dtype=">f8"))
        with pytest.raises(ValueError,
                           match=r"acc must be finite and non-zero, .*, got array\\(\\[0\\., 0\\., 0\\.\\]"):
            est.update(g, np.zeros(3, dtype=">f8"), m)
    """)


# --- 5. tampered states -------------------------------------------------------------------

TAMPER = [  # estimator, field, how (a value, or an expression of the field's value v)
    ("ekf", "b", "[1e300, 0, 0]"), ("ekf", "b", "[101.0, 0, 0]"),
    ("ekf", "P", "(-np.array(v)).tolist()"),                            # negative definite
    ("ekf", "P", "(np.array(v) * 1e145).tolist()"),                     # overflows
    ("ekf", "P", "asym(v)"), ("ekf", "P", "indefinite(v)"), ("ekf", "t_unmeasured", "-1e300"),
    ("ekf", "t_rest", "1e300"), ("ekf", "acc_lp", "[1e300, 0, 0]"),
    ("iir-ekf", "pre_acc.z1", "[1e301, 0, 0]"), ("iir-ekf", "P", "indefinite(v)"),
    ("mahony", "eint", "[1e300, 0, 0]"), ("mahony", "t_recover", "1e300"),
    ("madgwick", "t_recover", "1e300"), ("madgwick", "bw", "[0, -1e300, 0]"),
    ("ukf", "P", "(-np.array(v)).tolist()"), ("ukf", "P", "indefinite(v)"), ("ukf", "b", "[0, 0, 1e300]"),
    ("ukf", "t_unmeasured", "-5.0"),
    ("cf-ekf", "cf.eint", "[1e300, 0, 0]"), ("cf-ekf", "sat_left", "2**31 - 1"),
    ("cf-ekf", "t_quiet", "1e300"), ("cf-ekf", "cf.t_recover", "-1e300"), ("cf-ekf", "P", "asym(v)"),
    ("aekf", "t_dir", "-1e300"), ("aekf", "dip_ref", "1e300"), ("aekf", "ref_field", "[0, 2, 0]"),
    ("aekf", "P", "(np.array(v) * 1e145).tolist()"),
]


@pytest.mark.parametrize("name", sorted({t[0] for t in TAMPER}))
def test_tampered_state_is_refused_naming_the_field(name):
    """load_state checked finiteness and a unit quaternion only: a bias of 1e300, a negative,
    asymmetric or 1e145-scaled P, mahony's eint = 1e300, madgwick's t_recover = 1e300 were
    accepted and gave NaN or an indefinite P. Now a ValueError names the field, and the
    estimator is unchanged (every case of TAMPER for this estimator, one interpreter)."""
    cases = [(f, h) for n, f, h in TAMPER if n == name]
    run_script(f"""
        import pytest
        def asym(v):
            P = np.array(v, dtype=float); k = int(round(len(P) ** 0.5)); P = P.reshape(k, k)
            P[0, 1] += 1e-3
            return P.ravel().tolist()
        def indefinite(v):   # symmetric, positive diagonal, one negative eigenvalue
            P = np.array(v, dtype=float); k = int(round(len(P) ** 0.5)); P = P.reshape(k, k)
            P[0, 1] = P[1, 0] = 2 * np.sqrt(P[0, 0] * P[1, 1])
            return P.ravel().tolist()
        gyr, acc, mag = noisy(300, 0, 0.1, 0.1, 0.1)
        est = fusion.make("{name}", 100.0, gyro_range=5.0)
        est.run(gyr, acc, mag)
        for field, how in {cases!r}:
            s = est.state()
            v = s["fields"][field]
            s["fields"][field] = eval(how)
            before = est.state()
            with pytest.raises(ValueError, match=f"state field '{{field}}' must"):
                est.load_state(s)
            assert est.state() == before, field
            with pytest.raises(ValueError, match=f"state field '{{field}}' must"):
                type(est).from_state(s)
    """)


# --- 6. one out-of-range gyro sample in the Kalman family -----------------------------------

@pytest.mark.parametrize("name", KALMAN)
def test_one_out_of_range_gyro_sample_does_not_derail(name):
    """The `mixed` scenario at 100 Hz for 90 s (seed 0), gyro_range=34.9 rad/s, one gyro sample
    of 100 rad/s at 30 s. Before: ekf 7.4-8.5 deg off after 90 s with a wrong bias (ukf 7.5,
    iir-ekf 8.5, aekf 24.5). The sample is now not a measurement, held as a dropped one:
    mean error over the last 30 s 0.13 deg (ekf; undisturbed 0.067), 0.10 (aekf; 0.068),
    final 0.12 deg, bias within 0.01 deg/s of the truth, and the same as dropping it.
    The 0.05 deg left is the heading's slow return from the 0.9 deg turn the sample missed.
    Since issue 19's bias_init_std 0.0087 rad/s the bias is learned more slowly (undisturbed:
    0.023 deg/s off after 90 s, was within 0.01): the glitch is held to add at most 0.005."""
    run_script(f"""
        from fusion import quat
        from fusion.scenarios import make_scenario
        sc = make_scenario("mixed", fs=100.0, duration=90.0, seed=0)
        res = {{}}
        for kind in ("undisturbed", "glitch", "dropped"):
            g = sc.gyr.copy()
            if kind == "glitch":
                g[3000] = [100.0, 0.0, 0.0]
            elif kind == "dropped":
                g[3000] = np.nan
            est = fusion.make("{name}", 100.0, gyro_range=34.9, on_invalid="skip")
            est.reset(sc.q_true[0])
            q = est.run(g, sc.acc, sc.mag)
            e = np.degrees(quat.angle(q, sc.q_true))
            res[kind] = (q, e[6000:].mean(), e[-1], np.degrees(np.abs(est.bias - sc.gyro_bias).max()))
        (q0, m0, f0, b0), (q1, m1, f1, b1), (q2, _, _, _) = res.values()
        print(res["undisturbed"][1:], res["glitch"][1:])
        assert np.abs(q1 - q2).max() < 1e-12     # as a dropped sample (to the rounding of the
                                                 # ekf's inlined batch step)
        assert m1 < m0 + 0.1 and f1 < 0.25, (m0, m1, f1)
        assert b1 < b0 + 0.005, (b0, b1)
    """)


@pytest.mark.parametrize("scale", [1e-160, 1e-300, 1e200, 1e300])
def test_reset_q0_of_any_finite_scale_is_normalised(scale):
    """reset(q0) with components whose squares under- or overflow (1e-160, 1e300) gives the
    unit quaternion of their direction, not NaN (Hypothesis found 1e-160)."""
    run_script(f"""
        for name in fusion.available():
            est = fusion.make(name, 100.0)
            est.reset(np.array([1.0, 2.0, -2.0, 4.0]) * {scale!r})
            q = est.update([0.01, 0.0, 0.0], [0.0, 0.0, 9.81])
            assert np.all(np.isfinite(q)), (name, q)
            assert abs(np.linalg.norm(est.quaternion) - 1.0) < 1e-12, name
    """)


def test_denormal_acc_or_mag_is_invalid_not_nan():
    """A magnetometer sample of 1e-160 per axis (its squared norm denormal) gave cf-ekf a NaN
    quaternion (Hypothesis found it): such a sample is invalid, refused with its name, or
    skipped and counted with on_invalid='skip'."""
    run_script("""
        import pytest
        tiny = np.array([1e-160, 1e-160, 1e-160])
        for name in fusion.available():
            est = fusion.make(name, 100.0)
            with pytest.raises(ValueError, match="mag must be finite"):
                est.update(np.zeros(3), np.array([0.1, -0.2, 9.8]), tiny)
            with pytest.raises(ValueError, match="acc must be finite"):
                est.update(np.zeros(3), tiny)
            est = fusion.make(name, 100.0, on_invalid="skip")
            q = est.update(np.zeros(3), np.array([0.1, -0.2, 9.8]), tiny)
            assert np.isfinite(q).all() and np.isfinite(est.update(np.zeros(3), [0.1, -0.2, 9.8])).all(), name
    """)
