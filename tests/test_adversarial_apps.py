"""Issue 13, items 7-9: the environment's rates, training runs, the scripts and readers.

Each test is a reproducer that failed before the fix (a hang, a traceback, a silent wrong
answer); where a hang or a crash is possible it runs in a subprocess with a timeout.
"""
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import fusion
from fusion import datasets

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def run(code_or_args, timeout=120, cwd=None):
    args = [PY, "-c", code_or_args] if isinstance(code_or_args, str) else [PY] + list(code_or_args)
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, env=ENV, cwd=cwd or ROOT)


# --- item 7: rates ---------------------------------------------------------------------------

MAKE_AND_STEP = """
import gymnasium as gym, envs
try:
    env = gym.make("SphereBotTrack-v0", {kw})
except ValueError as e:
    print("ValueError:", e)
else:
    env.reset(seed=0)
    env.step([0.0, 0.0])
    print("stepped")
"""


@pytest.mark.parametrize("kw, name", [
    ("control_hz=1e-9", "control_hz"),          # was: 400 billion substeps, step() never returned
    ("imu_hz=0.005", "imu_hz"),                  # was: a message about fusion's fs
    ("control_hz=400.0, imu_hz=200.0, physics_hz=400.0", "control_hz"),   # control above the IMU rate
    ("control_hz=1.0, imu_hz=1000.0, physics_hz=20000.0", "control_hz"),  # 20,000 substeps per step
])
def test_env_rates_refused_with_their_name(kw, name):
    r = run(MAKE_AND_STEP.format(kw=kw), timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1].startswith(f"ValueError: {name} "), r.stdout


def test_slowest_accepted_step_is_bounded():
    """The most physics steps one step() may take (MAX_SUBSTEPS) run in about a second."""
    code = """
import time, gymnasium as gym, envs
from envs.sphere import MAX_SUBSTEPS
env = gym.make("SphereBotTrack-v0", physics_hz=20000.0, imu_hz=2.0, control_hz=2.0)
assert env.unwrapped._n_sub == MAX_SUBSTEPS
env.reset(seed=0)
t = time.perf_counter(); env.step([0.0, 0.0]); print(time.perf_counter() - t)
"""
    r = run(code, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert float(r.stdout.split()[-1]) < 5.0       # ~0.4 s idle; generous for a loaded machine


def test_imu_calibrated_must_be_bool():
    from envs.sphere import SphereRobotEnv
    with pytest.raises(ValueError, match="imu_calibrated"):
        SphereRobotEnv(imu_calibrated="no")       # was: truthy, so calibrated


# --- item 9: readers and numbers ---------------------------------------------------------------

def test_zero_d_arrays_are_numbers():
    est = fusion.make("ekf", fs=np.array(100.0))
    q = est.update(np.zeros(3), np.array([0.0, 0.0, 9.81]), dt=np.array(0.01))
    assert np.isfinite(q).all()
    g, a = np.zeros((5, 3)), np.tile([0.0, 0.0, 9.81], (5, 1))
    ref = fusion.make("ekf", fs=100.0).run(g, a, dt=0.01)
    np.testing.assert_array_equal(fusion.make("ekf", fs=np.array(100.0)).run(g, a, dt=np.array(0.01)), ref)
    fusion.Butterworth(np.array(100.0), np.array(10.0))
    from envs.sphere import SphereRobotEnv
    env = SphereRobotEnv(imu_hz=np.array(200.0), estimator="truth")
    assert env.imu_hz == 200.0
    env.close()
    with pytest.raises(ValueError, match="fs"):
        fusion.make("ekf", fs=np.array(True))
    with pytest.raises(ValueError, match="fs"):
        fusion.make("ekf", fs=np.array([100.0]))


def _trial(path, **over):
    n = 20
    d = dict(t=np.arange(n) / 100.0, gyr=np.zeros((n, 3)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
             quat=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), fs=np.array(100.0), quality=np.array("ok"),
             notes=np.array(""))
    d.update(over)
    np.savez(path, **d)
    return path


def test_datasets_refuse_complex(tmp_path):
    n = 20
    p = _trial(tmp_path / "c.npz", gyr=np.zeros((n, 3)) + 1j)
    with pytest.raises(ValueError, match="'gyr' must be real"):
        datasets.load_trial(p)                   # was: the imaginary part dropped silently


def test_datasets_bytes_quality(tmp_path):
    p = _trial(tmp_path / "b.npz", quality=np.array(b"ok"), notes=np.array(b"n\xc3\xa9"))
    tr = datasets.load_trial(p)
    assert tr.ok and tr.quality == "ok" and tr.notes == "n\u00e9"   # was: "b'ok'", not ok


def test_load_folder_reports_bad_files(tmp_path):
    (tmp_path / "s").mkdir()
    _trial(tmp_path / "s" / "good.npz")
    (tmp_path / "s" / "bad.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="bad.npz"):
        datasets.load_folder(tmp_path)
    bad = []
    trials = datasets.load_folder(tmp_path, unreadable=bad)
    assert [t.key for t in trials] == ["s/good"] and bad[0][0] == "s/bad"


def test_load_policy_none():
    from controllers import rl
    with pytest.raises(rl.PolicyError, match="policy must be a name"):
        rl.load_policy(None)                     # was: TypeError


# --- item 9: compare_estimators --------------------------------------------------------------

SCRIPT = str(ROOT / "scripts" / "compare_estimators.py")


def test_estimators_unwritable_out(tmp_path):
    (tmp_path / "file").write_text("x")
    r = run([SCRIPT, "--out", str(tmp_path / "file" / "sub"), "--quick"], timeout=60)
    assert r.returncode != 0 and "--out" in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("args, word", [(["--seed", "-1"], "--seed"), (["--estimators", ""], "--estimators"),
                                        (["--estimators", ",,"], "--estimators")])
def test_estimators_bad_options(tmp_path, args, word):
    r = run([SCRIPT, "--out", str(tmp_path), "--quick"] + args, timeout=60)
    assert r.returncode != 0 and word in r.stderr and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    assert not (tmp_path / "report.md").exists()


@pytest.mark.parametrize("name", ["missing", "file"])
def test_estimators_data_must_be_a_folder(tmp_path, name):
    (tmp_path / "file").write_text("x")
    r = run([SCRIPT, "--out", str(tmp_path / "out"), "--quick", "--data", str(tmp_path / name)], timeout=60)
    assert r.returncode != 0 and "--data" in r.stderr and str(tmp_path / name) in r.stderr, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()     # was: a note, exit 0


def test_estimators_unknown_plot_trial_is_refused(tmp_path):
    """An unknown --plot-trial was ignored (no figure, no word, exit 0)."""
    data = tmp_path / "data" / "s"
    data.mkdir(parents=True)
    _trial(data / "good.npz", gyr=np.random.default_rng(0).normal(0, 0.01, (20, 3)))
    r = run([SCRIPT, "--out", str(tmp_path / "out"), "--quick", "--estimators", "gyro", "--data",
             str(tmp_path / "data"), "--plot-trial", "s/nope"], timeout=300)
    assert r.returncode != 0 and "--plot-trial 's/nope'" in r.stderr and "s/good" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()        # refused before the synthetic tables were written


def test_estimators_a_trial_without_reference_does_not_blank_its_set(tmp_path):
    """A trial whose reference is all zero was skipped in 6-axis but scored NaN in 9-axis,
    which made the set's 9-axis mean NaN."""
    data = tmp_path / "data" / "s"
    data.mkdir(parents=True)
    mag = np.tile([0.2, 0.0, -0.4], (20, 1))
    _trial(data / "good.npz", gyr=np.random.default_rng(0).normal(0, 0.01, (20, 3)), mag=mag)
    _trial(data / "zero.npz", quat=np.zeros((20, 4)), mag=mag)
    r = run([SCRIPT, "--out", str(tmp_path / "out"), "--estimators", "gyro", "--data",
             str(tmp_path / "data")], timeout=300)
    assert r.returncode == 0, r.stderr
    agg = (tmp_path / "out" / "trials_aggregate.csv").read_text()
    assert "nan" not in agg.lower() and "s/zero" in (tmp_path / "out" / "report.md").read_text()


def test_estimators_bad_npz_is_skipped(tmp_path):
    data = tmp_path / "data" / "s"
    data.mkdir(parents=True)
    rng = np.random.default_rng(0)
    _trial(data / "good.npz", gyr=rng.normal(0, 0.01, (20, 3)))
    (data / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with zipfile.ZipFile(_trial(tmp_path / "whole.npz")) as src, zipfile.ZipFile(data / "raw.npz", "w") as z:
        for m in src.namelist():                 # 't' without .npy: was an AttributeError
            if m == "t.npy":
                z.writestr("t", b"no npy header")
            else:
                z.writestr(m, src.read(m))
    r = run([SCRIPT, "--out", str(tmp_path / "out"), "--quick", "--estimators", "gyro",
             "--data", str(tmp_path / "data")], timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "s/bad" in r.stdout and "s/raw" in r.stdout
    assert "s,good," in (tmp_path / "out" / "trials.csv").read_text()
    assert "s/bad" in (tmp_path / "out" / "report.md").read_text()


# --- item 8: training runs ----------------------------------------------------------------------

def test_atomic_write_keeps_the_old_file(tmp_path):
    from controllers.policy_io import atomic_write
    target = tmp_path / "ckpt.zip"
    target.write_bytes(b"old, whole")

    def interrupted(f):
        f.write(b"half of the new")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(target, interrupted)
    assert target.read_bytes() == b"old, whole" and os.listdir(tmp_path) == ["ckpt.zip"]


@pytest.mark.parametrize("kw, name", [({"n_envs": 0}, "n_envs"), ({"n_envs": -1}, "n_envs"),
                                      ({"env_kwargs": {"control_hz": "x"}}, "control_hz"),
                                      ({"env_kwargs": {"bogus": 1}}, "bogus"),
                                      ({"hyperparams_override": {"learning_rate": "abc"}}, "learning_rate"),
                                      ({"hyperparams_override": {"n_steps": 0}}, "n_steps"),
                                      ({"hyperparams_override": {"gamma": 2.0}}, "gamma"),
                                      # SB3 refused these with a TypeError once the environments ran
                                      ({"hyperparams_override": {"policy_kwargs": {"foo": 1}}}, "'foo'"),
                                      ({"hyperparams_override": {"policy_kwargs": {"log_std_init": "abc"}}},
                                       "log_std_init must be a finite number"),
                                      ({"hyperparams_override": {"policy_kwargs": {"net_arch": [64, 0]}}},
                                       "net_arch"),
                                      ({"hyperparams_override": {"policy_kwargs": {"activation_fn": "nn.ReLU"}}},
                                       "activation_fn"),
                                      # (found by a review: refused by SB3 after the start too)
                                      ({"hyperparams_override": {"policy_kwargs": {"use_sde": True}}}, "use_sde"),
                                      ({"hyperparams_override": {"policy_kwargs": {"squash_output": True}}},
                                       "squash_output"),
                                      ({"hyperparams_override": {"policy_kwargs": {
                                          "net_arch": {"pi": [8], "qf": [8]}}}}, "net_arch")])
def test_train_bad_options_before_work(tmp_path, kw, name):
    from controllers import rl
    with pytest.raises(ValueError, match=name):
        rl.train("ppo", "track", "truth", timesteps=64, out=tmp_path / "p", progress=False, **kw)
    assert not (tmp_path / "p.run").exists()     # nothing started


@pytest.mark.parametrize("args, word", [(["--n-envs", "0"], "--n-envs"), (["--n-envs", "-1"], "--n-envs"),
                                        (["--env-kwargs", '{"imu_hz": 0.005}'], "imu_hz"),
                                        (["--env-kwargs", '{"bogus": 1}'], "bogus"),
                                        (["--hyperparams", "learning_rate=abc"], "learning_rate"),
                                        (["--seed", "4294967296"], "--seed"),
                                        (["--workers", "2"], "--workers"),
                                        (["--backend", "local", "--address", "auto"], "--address")])
def test_train_cli_bad_options(tmp_path, args, word):
    # the flags the script had before (--task, --out), so that the old script parses them too
    r = run([str(ROOT / "scripts" / "train.py"), "--algo", "ppo", "--task", "track", "--estimator", "truth",
             "--out", str(tmp_path / "p"), "--timesteps", "64", "--eval-episodes", "0", "--no-progress"] + args,
            timeout=300)
    assert r.returncode == 2 and word in r.stderr, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "unrecognized" not in r.stderr, r.stderr[-2000:]
    assert not any(tmp_path.iterdir())


TINY = dict(seed=1, n_envs=1, progress=False, eval_freq=200, checkpoint_freq=200, eval_episodes=1,
            env_kwargs={"episode_s": 1.0}, hyperparams_override={"n_steps": 64, "batch_size": 32, "n_epochs": 1})


def test_resume_refuses_another_run(tmp_path):
    """--resume continued a run trained with another estimator (or environment, algorithm,
    seed, hyperparameters) and labelled the mix with the new settings; now each difference is
    named before any work, and resume with overwrite is refused."""
    from controllers import rl
    stem = tmp_path / "ppo-track-gyro"
    rl.train("ppo", "track", "gyro", timesteps=200, out=stem, log=lambda *a: None, **TINY)
    for change, word in ((dict(estimator="ekf"), "estimator: 'gyro' before, 'ekf' now"),
                         (dict(env_kwargs={"episode_s": 2.0}), "env_kwargs"),
                         (dict(seed=2), "seed: 1 before, 2 now"),
                         (dict(init_from="pid"), "init_from: None before, 'pid' now")):
        kw = {**TINY, "estimator": "gyro", **change}
        est = kw.pop("estimator")
        with pytest.raises(ValueError, match=word):
            rl.train("ppo", "track", est, timesteps=400, out=stem, resume=True, log=lambda *a: None, **kw)
    with pytest.raises(ValueError, match="give one"):
        rl.train("ppo", "track", "gyro", timesteps=400, out=stem, resume=True, overwrite=True,
                 log=lambda *a: None, **TINY)
    meta = json.loads((tmp_path / "ppo-track-gyro.json").read_text())
    assert meta["estimator"] == "gyro" and meta["timesteps"] == 200      # untouched by the refusals


def test_resume_falls_back_and_appends_monitor(tmp_path):
    from controllers import rl
    stem = tmp_path / "ppo-track-truth"
    rl.train("ppo", "track", "truth", timesteps=400, out=stem, log=lambda *a: None, **TINY)
    ckpts = rl._checkpoints(tmp_path / "ppo-track-truth.run" / "checkpoints")
    assert len(ckpts) >= 2
    monitor = tmp_path / "ppo-track-truth.run" / "monitor" / "0.monitor.csv"
    rows_before = monitor.read_text().splitlines()
    assert len(rows_before) > 3
    newest = ckpts[0]
    newest.write_bytes(newest.read_bytes()[:1000])          # a truncated newest checkpoint
    with open(monitor, "a") as f:
        f.write("1.5,50,0.")                               # killed in the middle of a row
    with pytest.warns(RuntimeWarning, match=newest.name):
        rl.train("ppo", "track", "truth", timesteps=800, out=stem, resume=True, log=lambda *a: None, **TINY)
    meta = json.loads((tmp_path / "ppo-track-truth.json").read_text())
    assert meta["timesteps"] == 800
    rows_after = monitor.read_text().splitlines()
    assert rows_after[:len(rows_before)] == rows_before     # the episodes before the interrupt stay
    assert len(rows_after) > len(rows_before) and all(len(r.split(",")) == 3 for r in rows_after[2:])


@pytest.mark.parametrize("module, argv, word", [
    ("benchmarks.accuracy", ["--trial-seconds", "-1"], "--trial-seconds"),
    ("benchmarks.accuracy", ["--max-trials", "0"], "--max-trials"),
    ("benchmarks.accuracy", ["--duration", "nan"], "--duration"),
    ("benchmarks.accuracy", ["--seed", "-3"], "--seed"),
    ("benchmarks.accuracy", ["--scenarios", "bogus"], "bogus"),
    ("benchmarks.accuracy", ["--data", "/nonexistent"], "--data"),
    ("benchmarks.loso", ["ekf", "--seconds", "0"], "--seconds"),
    ("benchmarks.loso", ["bogus"], "bogus"),
    ("benchmarks.loso", ["ekf", "--grid", "acc_lowpass=1,2", "--png", "x.png"], "--png"),
    ("benchmarks.throughput", ["--target", "-1"], "--target"),
    ("benchmarks.throughput", ["--bank-only", "--no-bank"], "--no-bank"),
])
def test_benchmark_options_are_checked_before_any_work(module, argv, word, capsys):
    """Out-of-range, unknown and contradicting options ran (scoring every trial minus its last
    second for --trial-seconds -1, empty tables for an unknown scenario, the bank for
    --bank-only --no-bank) or failed with a traceback after the work; each is argparse's error."""
    import importlib
    mod = importlib.import_module(module)
    with pytest.raises(SystemExit) as e:
        mod.main(argv)
    assert e.value.code == 2 and word in capsys.readouterr().err


@pytest.mark.parametrize("module, argv, word", [
    ("benchmarks.throughput", ["--quick", "--only", "bogus"], "--only"),
    ("benchmarks.papers_cli", ["--sections", "000", "000"], "more than once"),
    ("benchmarks.estimators_cli", ["--quick", "--estimators", "ekf,ekf"], "more than once"),
])
def test_command_errors_name_the_option_without_a_traceback(module, argv, word, tmp_path):
    import importlib
    mod = importlib.import_module(module)
    with pytest.raises(SystemExit) as e:
        mod.main(argv + ["--out", str(tmp_path / "out")])
    assert e.value.code not in (0, None) and word in str(e.value.code)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_arg_type_keeps_large_integers_exact():
    import argparse
    from fusion.checks import arg_type, integer
    parse = arg_type(integer, low=0)
    assert parse("12345678901234567891") == 12345678901234567891 and parse("1e3") == 1000
    with pytest.raises(argparse.ArgumentTypeError, match="integer"):
        parse("1.5")


def test_commands_check_out_before_the_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    import importlib
    for module in ("benchmarks.throughput", "benchmarks.papers_cli"):
        with pytest.raises(SystemExit) as e:
            importlib.import_module(module).main(["--quick", "--out", str(blocker)])
        assert "cannot be written" in str(e.value.code), module


def test_new_run_moves_aside_a_run_without_checkpoints(tmp_path):
    """A run killed after its start's evaluation but before its first checkpoint left
    best.json and best_model.zip; a new run (no evaluation of its own) shipped that stale
    model as its own. Now any earlier run directory is moved aside, twice in a second too."""
    from controllers import rl
    stem = tmp_path / "ppo-track-gyro"
    run_dir = tmp_path / "ppo-track-gyro.run"
    for k in range(2):
        run_dir.mkdir()
        (run_dir / "best_model.zip").write_bytes(b"stale")
        (run_dir / "best.json").write_text('{"mean_reward": 1e9, "timesteps": 1}')
        rl.train("ppo", "track", "gyro", timesteps=64, out=stem, log=lambda *a: None,
                 **{**TINY, "eval_freq": 10_000, "checkpoint_freq": 10_000})
        assert zipfile.is_zipfile(str(stem) + ".zip")
        assert json.loads((tmp_path / "ppo-track-gyro.json").read_text())["best_eval"] is None
        asides = sorted(tmp_path.glob("ppo-track-gyro.run.old-*"))
        assert len(asides) == k + 1 and all((a / "best_model.zip").read_bytes() == b"stale" for a in asides)
        shutil.rmtree(run_dir)
