"""fusion.make_bank (docs/estimators.md, "Banks"): count estimators in one object give the
numbers of count separate estimators, bit for bit; bad input is refused naming the argument;
states round trip; one filter resets alone; a second thread is refused while one steps."""
import copy
import json
import pickle
import threading
import time

import numpy as np
import pytest

import fusion
from fusion.scenarios import make_scenario

NAMES = fusion.available()
COUNT, T = 4, 500
# one parameter per estimator given per filter (each filter its own value)
PER_FILTER = {"mahony": ("kp", [0.5, 1.0, 0.25, 2.0]), "madgwick": ("beta", [0.041, 0.1, 0.02, 0.3]),
              "cf-ekf": ("cf_noise", [0.005, 0.01, 0.002, 0.05])}
for _n in ("ekf", "iir-ekf", "aekf", "ukf"):
    PER_FILTER[_n] = ("acc_noise", [1.0, 2.0, 0.5, 4.0])


@pytest.fixture(scope="module")
def data():
    """(T, COUNT, 3) gyr, acc, mag: filter i gets the i-th piece of one recording, with a few
    invalid rows (for on_invalid='skip') in some filters only."""
    sc = make_scenario("mixed", fs=100.0, duration=COUNT * T / 100.0, seed=5)

    def pieces(x):
        return np.ascontiguousarray(x[:COUNT * T].reshape(COUNT, T, 3).transpose(1, 0, 2))

    return pieces(sc.gyr), pieces(sc.acc), pieces(sc.mag)


def _with_glitches(data):
    G, A, M = (x.copy() for x in data)
    G[30, 1] = np.nan
    A[40, 2] = 0.0
    M[50, 3] = np.inf
    A[0, 0] = np.nan            # filter 0 starts without an attitude
    return G, A, M


def _params(name):
    if name not in PER_FILTER:
        return {}, [{}] * COUNT
    k, vals = PER_FILTER[name]
    return {k: vals}, [{k: v} for v in vals]


def _separate(name, per, **kw):
    return [fusion.make(name, 100.0, **kw, **p) for p in per]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("nine_axis", [True, False])
def test_bank_equals_separate_estimators(data, name, nine_axis):
    G, A, M = _with_glitches(data)
    M = M if nine_axis else None
    shared, per = _params(name)
    kw = dict(frame="NED", on_invalid="skip")
    # run: each filter's batch over its column
    bank = fusion.make_bank(name, 100.0, COUNT, **kw, **shared)
    ests = _separate(name, per, **kw)
    Q = bank.run(G, A, M)
    assert Q.shape == (T, COUNT, 4)
    ref = np.stack([e.run(G[:, i], A[:, i], None if M is None else M[:, i]) for i, e in enumerate(ests)], 1)
    assert np.array_equal(Q, ref)
    # update: one sample for every filter per call, against the single estimators' update
    bank = fusion.make_bank(name, 100.0, COUNT, **kw, **shared)
    ests = _separate(name, per, **kw)
    for t in range(T):
        q = bank.update(G[t], A[t], None if M is None else M[t])
        r = [e.update(G[t, i], A[t, i], None if M is None else M[t, i]) for i, e in enumerate(ests)]
        assert np.array_equal(q, np.array(r)), f"sample {t}"
    assert np.array_equal(Q, ref)
    assert [s for s in bank.state()["filters"]] == [e.state() for e in ests]
    assert np.array_equal(bank.quaternion, [e.quaternion for e in ests])
    if ests[0].bias is None:
        assert bank.bias is None
    else:
        assert np.array_equal(bank.bias, [e.bias for e in ests])
    if ests[0].covariance is None:
        assert bank.covariance is None
    else:
        assert np.array_equal(bank.covariance, [e.covariance for e in ests])
    assert np.array_equal(bank.euler, [e.euler for e in ests])
    if "rest_time" in ests[0].PARAMS:
        assert np.array_equal(bank.at_rest, [e.at_rest for e in ests])
    else:
        assert bank.at_rest is None         # no rest detector (test_contract: no at_rest either)
    sk = bank.skipped
    for s in ("gyr", "acc", "mag"):
        assert list(sk[s]) == [e.skipped[s] for e in ests]
    assert bank.params == [e.params for e in ests]


@pytest.mark.parametrize("name", ["ekf", "mahony"])
def test_time_steps(data, name):
    """dt: scalar, (T,) shared, (T, count) per filter in run; (count,) in update."""
    G, A, M = data
    rng = np.random.default_rng(0)
    D = rng.uniform(0.005, 0.02, (T, COUNT))
    bank = fusion.make_bank(name, 100.0, COUNT)
    ests = _separate(name, [{}] * COUNT)
    Q = bank.run(G, A, M, dt=D)
    assert np.array_equal(Q, np.stack([e.run(G[:, i], A[:, i], M[:, i], dt=D[:, i]) for i, e in enumerate(ests)], 1))
    for dt in (0.02, D[:, 0]):
        bank = fusion.make_bank(name, 100.0, COUNT)
        ests = _separate(name, [{}] * COUNT)
        Q = bank.run(G, A, M, dt=dt)
        assert np.array_equal(Q, np.stack([e.run(G[:, i], A[:, i], M[:, i], dt=dt) for i, e in enumerate(ests)], 1))
    bank = fusion.make_bank(name, 100.0, COUNT)
    ests = _separate(name, [{}] * COUNT)
    for t in range(20):
        q = bank.update(G[t], A[t], M[t], dt=D[t])
        assert np.array_equal(q, [e.update(G[t, i], A[t, i], M[t, i], dt=D[t, i]) for i, e in enumerate(ests)])


def test_bad_construction():
    for count in (0, -1, 1.5, True, "4", None):
        with pytest.raises(ValueError, match="count"):
            fusion.make_bank("ekf", 100.0, count)
    with pytest.raises(ValueError, match="acc_noise.*3 values.*count is 4"):
        fusion.make_bank("ekf", 100.0, 4, acc_noise=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="acc_noise.*filter 2"):
        fusion.make_bank("ekf", 100.0, 4, acc_noise=[1.0, 2.0, -3.0, 1.0])
    with pytest.raises(ValueError, match="kp"):
        fusion.make_bank("mahony", 100.0, 3, kp=-1.0)
    with pytest.raises(ValueError, match="unknown estimator"):
        fusion.make_bank("kalman", 100.0, 3)
    with pytest.raises(ValueError, match="fs"):
        fusion.make_bank("ekf", -1.0, 3)
    # a string is one value for all filters, not a sequence of characters
    b = fusion.make_bank("ekf", 100.0, 2, mag_update="heading", acc_noise=np.array([1.0, 2.0]))
    assert [p["mag_update"] for p in b.params] == ["heading"] * 2
    assert [p["acc_noise"] for p in b.params] == [1.0, 2.0]


def test_bad_arrays(data):
    G, A, M = data
    bank = fusion.make_bank("ekf", 100.0, COUNT)
    before = bank.state()
    g, a, m = G[0], A[0], M[0]
    with pytest.raises(ValueError, match=r"gyr has 5 filters.*count 4"):
        bank.update(np.zeros((5, 3)), a, m)
    with pytest.raises(ValueError, match=r"acc has 3 filters.*count 4"):
        bank.update(g, a[:3], m)
    with pytest.raises(ValueError, match=r"mag must have shape \(4, 3\)"):
        bank.update(g, a, m[:, :2])
    with pytest.raises(ValueError, match="gyr must be a real numeric array"):
        bank.update(np.full((4, 3), "x"), a, m)
    with pytest.raises(ValueError, match="dt"):
        bank.update(g, a, m, dt=-0.01)
    with pytest.raises(ValueError, match=r"dt.*shape \(4,\)"):
        bank.update(g, a, m, dt=np.full(3, 0.01))
    with pytest.raises(ValueError, match=r"dt\[2\]"):
        bank.update(g, a, m, dt=[0.01, 0.01, np.nan, 0.01])
    with pytest.raises(ValueError, match=r"gyr has 3 filters.*count 4"):
        bank.run(G[:, :3], A, M)
    with pytest.raises(ValueError, match=r"gyr must have shape \(T, 4, 3\)"):
        bank.run(G[0], A, M)
    with pytest.raises(ValueError, match=r"acc must have shape \(499, 4, 3\)"):
        bank.run(G[:499], A, M)
    with pytest.raises(ValueError, match=r"mag has 2 filters"):
        bank.run(G, A, M[:, :2])
    with pytest.raises(ValueError, match=r"dt.*shape \(500,\) or \(500, 4\)"):
        bank.run(G, A, M, dt=np.full((4, 500), 0.01))
    with pytest.raises(ValueError, match=r"dt\[3, 1\]"):
        D = np.full((T, COUNT), 0.01)
        D[3, 1] = 0.0
        bank.run(G, A, M, dt=D)
    assert bank.state() == before
    assert bank.run(G[:0], A[:0], M[:0]).shape == (0, COUNT, 4)


def test_invalid_samples_raise_before_any_work(data):
    G, A, M = (x.copy() for x in data)
    bank = fusion.make_bank("ekf", 100.0, COUNT)
    bank.run(G[:10], A[:10], M[:10])
    before = bank.state()
    A[0, 2] = 0.0
    with pytest.raises(ValueError, match=r"acc must be finite and non-zero; acc\[2\] .*filter 2"):
        bank.update(G[0], A[0], M[0])
    G[7, 3] = np.nan
    M[5, 1] = np.inf
    with pytest.raises(ValueError, match=r"acc\[0, 2\].*filter 2, sample 0"):
        bank.run(G, A, M)
    A[0, 2] = 1.0
    with pytest.raises(ValueError, match=r"mag\[5, 1\].*filter 1, sample 5"):
        bank.run(G, A, M)
    with pytest.raises(ValueError, match=r"gyr\[7, 3\].*filter 3, sample 7"):
        bank.run(G, A, None)
    assert bank.state() == before       # nothing stepped


def test_reset_one_index(data):
    G, A, M = data
    bank = fusion.make_bank("ekf", 100.0, COUNT, q_init_std=[0.05, 0.1, 0.2, 0.3])
    ests = [fusion.make("ekf", 100.0, q_init_std=v) for v in (0.05, 0.1, 0.2, 0.3)]
    bank.run(G[:200], A[:200], M[:200])
    for i, e in enumerate(ests):
        e.run(G[:200, i], A[:200, i], M[:200, i])
    q0 = [0.9, 0.1, 0.0, 0.1]
    bank.reset(2, q0=q0)
    ests[2].reset(q0)
    bank.reset(-1)
    ests[3].reset()
    assert bank.state()["filters"] == [e.state() for e in ests]
    Q = bank.run(G[200:], A[200:], M[200:])
    ref = np.stack([e.run(G[200:, i], A[200:, i], M[200:, i]) for i, e in enumerate(ests)], 1)
    assert np.array_equal(Q, ref)
    # all at once, one start attitude per filter; a bad row changes nothing
    q0s = np.tile(q0, (COUNT, 1))
    q0s[1] = 0.0
    before = bank.state()
    with pytest.raises(ValueError, match=r"q0\[1\]"):
        bank.reset(q0=q0s)
    assert bank.state() == before
    with pytest.raises(ValueError, match=r"q0.*shape \(4, 4\)"):
        bank.reset(q0=np.ones((3, 4)))
    for bad in (4, -5, 1.0, True):
        with pytest.raises(ValueError, match="index"):
            bank.reset(bad)
    bank.reset()
    fresh = fusion.make_bank("ekf", 100.0, COUNT, q_init_std=[0.05, 0.1, 0.2, 0.3])
    assert bank.state() == fresh.state()


@pytest.mark.parametrize("how", ["load_state", "from_state", "json", "pickle", "deepcopy"])
def test_state_round_trip(data, how):
    G, A, M = _with_glitches(data)
    kw = dict(on_invalid="skip", acc_noise=[1.0, 2.0, 0.5, 4.0])
    bank = fusion.make_bank("aekf", 100.0, COUNT, **kw)
    whole = fusion.make_bank("aekf", 100.0, COUNT, **kw).run(G, A, M)
    first = bank.run(G[:150], A[:150], M[:150])
    s = bank.state()
    if how == "load_state":
        other = fusion.make_bank("aekf", 100.0, COUNT, **kw)
        other.load_state(s)
    elif how == "from_state":
        other = fusion.Bank.from_state(s)
    elif how == "json":
        other = fusion.Bank.from_state(json.loads(json.dumps(s)))
    elif how == "pickle":
        other = pickle.loads(pickle.dumps(bank))
    else:
        other = copy.deepcopy(bank)
    assert other.state() == s
    tail = other.run(G[150:], A[150:], M[150:])
    assert np.array_equal(np.concatenate([first, tail]), whole)
    assert np.array_equal(bank.run(G[150:], A[150:], M[150:]), tail)    # the original unchanged by the copy


def test_load_state_refused_whole(data):
    G, A, M = data
    bank = fusion.make_bank("ekf", 100.0, COUNT)
    bank.run(G[:50], A[:50], M[:50])
    s = bank.state()
    other = fusion.make_bank("ekf", 100.0, COUNT)
    before = other.state()
    bad = copy.deepcopy(s)
    bad["filters"][3]["fields"]["q"] = [float("nan")] * 4
    with pytest.raises(ValueError, match=r"filters'\]\[3\]"):
        other.load_state(bad)
    assert other.state() == before                   # filters 0-2 untouched too
    with pytest.raises(ValueError, match="count 4 but this bank has count 3"):
        fusion.make_bank("ekf", 100.0, 3).load_state(s)
    with pytest.raises(ValueError, match="'ekf', not 'mahony'"):
        fusion.make_bank("mahony", 100.0, COUNT).load_state(s)
    with pytest.raises(ValueError, match="version"):
        other.load_state(dict(s, version=99))
    with pytest.raises(ValueError, match="must be a dict"):
        other.load_state([1, 2])
    with pytest.raises(ValueError, match="lacks"):
        other.load_state({"version": 1})


def test_index_gives_a_copy(data):
    G, A, M = data
    bank = fusion.make_bank("mahony", 100.0, COUNT, kp=[0.5, 1.0, 0.25, 2.0])
    bank.run(G[:100], A[:100], M[:100])
    assert len(bank) == COUNT
    e = bank[1]
    assert isinstance(e, fusion.Mahony) and e.kp == 1.0
    assert e.state() == bank.state()["filters"][1]
    assert bank[-1].kp == 2.0
    e.run(G[100:, 1], A[100:, 1], M[100:, 1])
    assert not np.array_equal(e.quaternion, bank.quaternion[1])   # the bank did not move
    for bad in (4, -5, 1.0, slice(0, 2)):
        with pytest.raises(IndexError):
            bank[bad]


def test_in_use_guard_and_threads(data):
    """While one thread steps a bank (the GIL released), another thread's call on the same
    bank is refused; separate banks in separate threads give the sequential numbers."""
    G, A, M = data
    reps = 40
    GG, AA, MM = (np.concatenate([x] * reps) for x in (G, A, M))     # long enough to overlap
    bank = fusion.make_bank("ekf", 100.0, COUNT)
    s0 = bank.state()
    errors, calls = [], []
    worker = threading.Thread(target=lambda: bank.run(GG, AA, MM))
    worker.start()
    deadline = time.monotonic() + 30.0
    while worker.is_alive() and time.monotonic() < deadline:
        if bank._in_use:
            for call in (lambda: bank.update(G[0], A[0], M[0]), lambda: bank.reset(),
                         lambda: bank.state(), lambda: bank.quaternion, lambda: bank.load_state(s0), lambda: bank[0]):
                calls.append(1)
                try:
                    call()
                except RuntimeError as e:
                    errors.append(str(e))
            break
    worker.join()
    assert calls, "the run finished before the main thread saw it running"
    assert len(errors) == len(calls) == 6 and all("in use by another thread" in e for e in errors)
    # after the run the bank works again; parallel banks agree with sequential ones
    seq = [fusion.make_bank("ekf", 100.0, COUNT).run(G, A, M) for _ in range(2)]
    out = [None, None]
    banks = [fusion.make_bank("ekf", 100.0, COUNT) for _ in range(2)]
    ths = [threading.Thread(target=lambda k=k: out.__setitem__(k, banks[k].run(G, A, M))) for k in range(2)]
    for th in ths:
        th.start()
    for th in ths:
        th.join()
    assert np.array_equal(out[0], seq[0]) and np.array_equal(out[1], seq[1])
    bank.update(G[0], A[0], M[0])


def test_bank_of_given_estimators(data):
    """fusion.Bank(estimators) steps copies: the caller's estimators do not move."""
    G, A, M = data
    es = [fusion.make("ekf", 100.0, acc_noise=v) for v in (1.0, 2.0)]
    es[0].run(G[:50, 0], A[:50, 0], M[:50, 0])
    before = [e.state() for e in es]
    bank = fusion.Bank(es)
    assert bank.state()["filters"] == before
    bank.run(G[:, :2], A[:, :2], M[:, :2])
    assert [e.state() for e in es] == before
    with pytest.raises(ValueError, match="share those of filters"):
        fusion.Bank([fusion.make("ekf", 100.0), fusion.make("ekf", 200.0)])
    with pytest.raises(ValueError, match="share those of filters"):
        fusion.Bank([fusion.make("ekf", 100.0), fusion.make("aekf", 100.0)])
    with pytest.raises(ValueError, match="not a fusion estimator"):
        fusion.Bank([fusion.make("ekf", 100.0), 3])
    with pytest.raises(ValueError, match="count"):
        fusion.Bank([])


def test_any_real_array_layout(data):
    """Lists, float32, Fortran order and strided views give the float64 numbers."""
    G, A, M = data
    ref = fusion.make_bank("mahony", 100.0, COUNT)
    q = ref.update(G[0], A[0], M[0])
    Q = ref.run(G[1:20], A[1:20], M[1:20])
    bank = fusion.make_bank("mahony", 100.0, COUNT)
    assert np.array_equal(bank.update(G[0].tolist(), np.asfortranarray(A[0]), np.stack([M[0], M[0]], 2)[:, :, 0]), q)
    Gs = np.repeat(G, 2, axis=1)[:, ::2]               # strided view, same values
    assert np.array_equal(bank.run(Gs[1:20], A[1:20], M[1:20].tolist()), Q)
    a32 = fusion.make_bank("mahony", 100.0, COUNT).update(G[0], A[0].astype(np.float32), M[0])
    e = fusion.make("mahony", 100.0)
    assert np.array_equal(a32[2], e.update(G[0, 2], A[0, 2].astype(np.float32).astype(float), M[0, 2]))


@pytest.mark.parametrize("name", ["ekf", "mahony"])
def test_big_endian_and_unaligned_input(data, name):
    """Big-endian float64 is read by value, not as native bytes (the fast path checked the
    type number only: update and run stepped on byte-swapped garbage, and a valid mag was
    refused with a message showing the right numbers); an unaligned buffer likewise."""
    G, A, M = data
    ref = fusion.make_bank(name, 100.0, COUNT)
    q = ref.update(G[0], A[0], M[0])
    Q = ref.run(G[1:20], A[1:20], M[1:20])
    be = fusion.make_bank(name, 100.0, COUNT)
    assert np.array_equal(be.update(G[0].astype(">f8"), A[0].astype(">f8"), M[0].astype(">f8")), q)
    assert np.array_equal(be.run(G[1:20].astype(">f8"), A[1:20].astype(">f8"), M[1:20].astype(">f8")), Q)

    def unaligned(x):
        buf = np.zeros(x.nbytes + 1, np.uint8)
        u = buf[1:].view(np.float64).reshape(x.shape)
        u[...] = x
        return u
    ua = fusion.make_bank(name, 100.0, COUNT)
    assert not unaligned(G[0]).flags.aligned
    assert np.array_equal(ua.update(unaligned(G[0]), unaligned(A[0]), unaligned(M[0])), q)
    assert np.array_equal(ua.run(unaligned(G[1:20]), unaligned(A[1:20]), unaligned(M[1:20])), Q)
