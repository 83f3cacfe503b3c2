"""fusion.datasets (skipped without the recorded data), fusion.scenarios and the comparison
loops of benchmarks.compare."""

import numpy as np
import pytest

import fusion
from fusion import datasets, metrics, quat, scenarios
from benchmarks import compare

DATA = datasets.default_data_dir()
needs_data = pytest.mark.skipif(DATA is None, reason=f"recorded data folder ({datasets.DATA_LOCATION}) not found")


# --- datasets ----------------------------------------------------------------------------

def test_default_data_dir_env_override(monkeypatch, tmp_path):
    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path))
    assert datasets.default_data_dir() == tmp_path
    monkeypatch.setenv(datasets.ENV_VAR, str(tmp_path / "missing"))
    assert datasets.default_data_dir() is None


def _write_trial(path, n=50, fs=100.0, mag=True, quality="ok", **extra):
    t = np.cumsum(np.full(n, 1 / fs)) - 1 / fs
    arrays = dict(t=t, gyr=np.zeros((n, 3)), acc=np.tile([0, 0, 9.81], (n, 1)),
                  quat=np.tile([1.0, 0, 0, 0], (n, 1)), fs=np.float64(fs),
                  quality=np.str_(quality), notes=np.str_("synthetic"), **extra)
    if mag:
        arrays["mag"] = np.tile([0, 0.4, -0.3], (n, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def test_load_trial_and_folder_from_files(tmp_path):
    _write_trial(tmp_path / "setA" / "b.npz", q_align=np.array([1.0, 0, 0, 0]))
    _write_trial(tmp_path / "setA" / "a.npz", mag=False, quality="exclude: broken")
    _write_trial(tmp_path / "setB" / "c.npz", n=10, fs=50.0)
    trials = datasets.load_folder(tmp_path)
    assert [tr.key for tr in trials] == ["setA/a", "setA/b", "setB/c"]
    a, b, c = trials
    assert not a.ok and a.mag is None and not a.has_mag
    assert b.ok and b.mag.shape == (50, 3) and "q_align" in b.extra
    assert c.fs == 50.0 and np.allclose(c.dt, 0.02) and c.dt.shape == (10,)
    assert [tr.key for tr in datasets.load_folder(tmp_path, only_ok=True)] == ["setA/b", "setB/c"]
    assert [tr.name for tr in datasets.load_folder(tmp_path / "setB")] == ["c"]
    with pytest.raises(ValueError, match="does not exist"):
        datasets.load_folder(tmp_path / "nope")


def test_load_trial_rejects_bad_files(tmp_path):
    (tmp_path / "s").mkdir()
    p = tmp_path / "s" / "bad.npz"
    np.savez(p, t=np.arange(5.0), gyr=np.zeros((5, 3)), acc=np.zeros((4, 3)),
             quat=np.zeros((5, 4)), fs=np.float64(1.0))
    with pytest.raises(ValueError, match="'acc' must have shape"):
        datasets.load_trial(p)
    np.savez(p, t=np.arange(5.0), gyr=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="missing key"):
        datasets.load_trial(p)
    np.savez(p, t=np.array([0, 1, 1, 2, 3.0]), gyr=np.zeros((5, 3)), acc=np.zeros((5, 3)),
             quat=np.zeros((5, 4)), fs=np.float64(1.0))
    with pytest.raises(ValueError, match="increase strictly"):
        datasets.load_trial(p)


@needs_data
def test_recorded_data_folder():
    trials = datasets.load_folder(DATA)
    assert trials, f"no .npz trials under {DATA}"
    sets = {tr.set for tr in trials}
    assert {"repoimu_tstick", "ese650"} <= sets
    for tr in trials:
        n = tr.n
        assert tr.t.shape == tr.dt.shape == (n,)
        assert tr.gyr.shape == tr.acc.shape == (n, 3) and tr.quat.shape == (n, 4)
        assert tr.mag is None or tr.mag.shape == (n, 3)
        assert tr.fs > 0 and (tr.dt > 0).all()
        assert np.allclose(np.cumsum(tr.dt[1:]), tr.t[1:] - tr.t[0])
        assert tr.ok == (tr.quality == "ok")
        assert tr.ok or tr.quality.startswith("exclude") or "no reference" in tr.quality
        finite = np.isfinite(tr.quat).all(axis=1)
        if tr.ok:
            assert finite.any()
            assert np.allclose(np.linalg.norm(tr.quat[finite], axis=1), 1, atol=1e-6)
    assert all(tr.has_mag for tr in trials if tr.set == "repoimu_tstick")
    assert not any(tr.has_mag for tr in trials if tr.set == "ese650")
    assert sum(not tr.ok for tr in trials) >= 1        # the excluded / reference-less trials


@needs_data
def test_recorded_trial_is_scoreable():
    tr = next(t for t in datasets.load_folder(DATA / "repoimu_tstick") if t.ok)
    q = fusion.make("mahony", tr.fs).run(tr.gyr, tr.acc, tr.mag, dt=tr.dt)
    s = metrics.score(q, tr.quat)
    assert all(np.isfinite(v) and 0 <= v < 20 for v in s.values())


# --- scenarios ---------------------------------------------------------------------------

def test_scenario_is_reproducible_by_seed():
    a = scenarios.make_scenario("mixed", duration=5.0, seed=3)
    b = scenarios.make_scenario("mixed", duration=5.0, seed=3)
    c = scenarios.make_scenario("mixed", duration=5.0, seed=4)
    for k in ("q_true", "gyr", "acc", "mag", "a_lin"):
        assert np.array_equal(getattr(a, k), getattr(b, k))
    assert not np.allclose(a.q_true, c.q_true)
    ideal = scenarios.make_scenario("mixed", duration=5.0, seed=3, ideal=True)
    assert np.array_equal(ideal.q_true, a.q_true)     # same motion, noise on its own stream
    assert np.array_equal(ideal.gyr, ideal.omega)


@pytest.mark.parametrize("name", list(scenarios.SCENARIOS))
def test_scenario_shapes_and_physics(name):
    fs, dur = 50.0, 4.0
    s = scenarios.make_scenario(name, fs=fs, duration=dur, ideal=True)
    n = int(dur * fs)
    assert s.n == n and s.t.shape == s.dt.shape == (n,) and np.allclose(s.dt, 1 / fs)
    for k in ("gyr", "acc", "mag", "omega", "a_lin"):
        assert getattr(s, k).shape == (n, 3)
    assert s.q_true.shape == (n, 4) and np.allclose(np.linalg.norm(s.q_true, axis=1), 1)
    # noise-free specific force and field, rotated back to the earth frame
    assert np.allclose(quat.rotate(s.q_true, s.acc), s.a_lin + [0, 0, scenarios.G])
    assert np.allclose(quat.rotate(s.q_true, s.mag), scenarios.FIELD)
    if name == "static":
        assert np.allclose(s.q_true, s.q_true[0]) and not s.a_lin.any()


def test_ideal_gyro_integrates_to_q_true():
    s = scenarios.make_scenario("mixed", fs=100.0, duration=30.0, seed=1, ideal=True)
    est = fusion.make("gyro", s.fs)
    est.reset(q0=s.q_true[0])
    q = est.run(s.gyr[1:], s.acc[1:], s.mag[1:], dt=s.dt[1:])      # sample i steps into t[i]
    assert quat.angle(q, s.q_true[1:]).max() < 1e-6
    est.reset(q0=s.q_start)                                         # or from before sample 0
    assert quat.angle(est.run(s.gyr, s.acc, s.mag, dt=s.dt), s.q_true).max() < 1e-6


def test_noisy_scenario_statistics():
    s = scenarios.make_scenario("static", fs=100.0, duration=60.0, seed=2)
    ideal = scenarios.make_scenario("static", fs=100.0, duration=60.0, seed=2, ideal=True)
    dg = s.gyr - ideal.gyr
    assert np.allclose(dg.mean(0), scenarios.DEFAULT_NOISE["gyro_bias"], atol=5e-4)
    assert np.allclose(dg.std(0), scenarios.DEFAULT_NOISE["gyro_noise"] * 10, rtol=0.05)
    assert np.allclose((s.acc - ideal.acc).std(0), scenarios.DEFAULT_NOISE["acc_noise"] * 10, rtol=0.05)


def test_scenario_bad_arguments():
    with pytest.raises(ValueError, match="unknown scenario"):
        scenarios.make_scenario("nope")
    with pytest.raises(ValueError, match="at least one sample"):
        scenarios.make_scenario("static", duration=0.001)
    with pytest.raises(ValueError, match="unknown scenario parameter"):
        scenarios.make_scenario("mixed", wobble=3)
    # each was NaN data, a bare numpy / int() error, or minutes of looping
    for kw, words in ((dict(duration=0.0), "duration"), (dict(duration=np.nan), "duration"),
                      (dict(duration=np.inf), "duration"), (dict(fs=np.nan), "fs"),
                      (dict(q_start=[0, 0, 0, 0]), "q_start"), (dict(q_start=[1, 0, 0]), "q_start"),
                      (dict(acc_noise=np.nan), "acc_noise"), (dict(gyro_noise=-1.0), "gyro_noise"),
                      (dict(g=np.nan), "g must"), (dict(gyro_bias=[0, np.inf, 0]), "gyro_bias"),
                      (dict(field=[0, 0, 0]), "field"), (dict(bursts_per_min=1e12), "bursts_per_min"),
                      (dict(freq=(0.5, 0.1)), "freq"), (dict(tilt="a"), "tilt")):
        with pytest.raises(ValueError, match=words):
            scenarios.make_scenario("mixed", **kw)
    sc = scenarios.failure_scenario("tapping", duration=0.05)     # was: numpy's "high - low < 0"
    assert sc.n == round(0.05 * 286.0) and np.isfinite(sc.acc).all()


@pytest.mark.parametrize("seed", [-1, "a", 1.5, True, None])
def test_scenario_bad_seed_names_seed(seed):
    # was numpy's SeedSequence error (or, for True, seed 1 without a word)
    with pytest.raises(ValueError, match=r"seed must be an integer >= 0, got"):
        scenarios.make_scenario("static", duration=1.0, seed=seed)
    with pytest.raises(ValueError, match=r"seed must be an integer >= 0, got"):
        scenarios.failure_scenario("tapping", duration=1.0, seed=seed)


# --- comparison loops --------------------------------------------------------------------

def test_filters_beat_gyro_on_the_mixed_scenario():
    s = scenarios.make_scenario("mixed", duration=20.0)
    rows, euler_rows, curves = compare.compare_scenario(fusion.available(), s)
    by = {(r["mode"], r["estimator"]): r for r in rows}
    for mode in compare.MODES:
        for name in fusion.available():
            if name != "gyro":
                assert by[mode, name]["inclination"] < by[mode, "gyro"]["inclination"]
    assert len(euler_rows) == 3 * len(rows) and curves["9-axis"]["gyro"].shape == (s.n,)


def test_aggregate_and_tables(tmp_path):
    rows = [dict(set="a", mode="9-axis", estimator="x", total=1.0, heading=2.0, inclination=3.0),
            dict(set="a", mode="9-axis", estimator="x", total=3.0, heading=2.0, inclination=1.0),
            dict(set="b", mode="6-axis", estimator="x", total=5.0, heading=float("nan"), inclination=1.0)]
    agg = compare.aggregate(rows)
    assert agg[0] == dict(set="a", mode="9-axis", estimator="x", n_trials=2, total=2.0, heading=2.0,
                          inclination=2.0)
    csv_path, md_path = compare.write_table(agg, tmp_path / "t", title="T")
    assert csv_path.read_text().splitlines()[0] == "set,mode,estimator,n_trials,total,heading,inclination"
    md = md_path.read_text()
    assert md.startswith("# T") and "| a | 9-axis | x | 2 | 2.000 |" in md
    assert "a \\| b" in compare.markdown_table([dict(x="a | b")])
