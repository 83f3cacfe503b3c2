"""Controllers: the PID, evaluation, training/loading of SB3 policies (tiny runs)."""
import io
import json
import math
import zipfile

import numpy as np
import pytest

pytest.importorskip("pybullet")
pytest.importorskip("stable_baselines3")

from controllers import PID, PIDGains
from controllers import rl
from controllers.evaluation import EPISODE_METRICS, _inclination_deg, aggregate, evaluate
from envs.sphere import SphereRobotEnv


def test_pid_bad_input():
    with pytest.raises(ValueError, match="task"):
        PID(task="dance")
    with pytest.raises(ValueError, match="heading_kp"):
        PIDGains(heading_kp=-1)
    with pytest.raises(ValueError, match="unknown PID gain"):
        PID(gains={"kp": 1})
    with pytest.raises(ValueError, match="control_hz"):
        PID(control_hz=0)
    with pytest.raises(ValueError, match="shape"):
        PID().act(np.zeros((2, 2, 14)))


def test_pid_batch_equals_rows():
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(5, 3, 14))
    obs[..., :4] /= np.linalg.norm(obs[..., :4], axis=-1, keepdims=True)
    batch, rows = PID(), [PID() for _ in range(3)]
    for t in range(5):
        a = batch.act(obs[t])
        assert a.shape == (3, 2) and np.all(np.abs(a) <= 1)
        for i in range(3):
            np.testing.assert_allclose(a[i], rows[i].act(obs[t, i]), atol=1e-7)
    batch.reset(index=[1])
    rows[1].reset()
    np.testing.assert_allclose(batch.act(obs[0])[1], rows[1].act(obs[0, 1]), atol=1e-7)


def test_pid_anti_windup_holds_integrator():
    pid = PID(task="track")
    o = np.zeros(14)
    o[0] = 1.0
    o[10] = 5.0                       # a speed the robot cannot reach: drive saturates
    o[12], o[13] = math.sin(3.0), math.cos(3.0)   # heading error near 180 deg: steer saturates
    for _ in range(500):
        a = pid.act(o)
    assert a[0] == pytest.approx(1.0) and a[1] == pytest.approx(1.0)
    # the integrators stopped when the outputs saturated instead of winding up to their limits
    assert pid._i_speed[0] < pid.gains.speed_i_limit and pid._i_head[0] < pid.gains.heading_i_limit


def test_pid_tracks_heading_under_truth():
    res = evaluate(PID(task="track"), dict(task="track", estimator="truth", imu="ideal", episode_s=12.0),
                   episodes=1, seed=3)
    ep = res["episodes"][0]
    assert ep["speed_rmse"] < 0.1
    assert ep["heading_rmse"] < 45.0          # command steps of up to 90 deg included
    assert ep["heading_ss"] < 10.0 and ep["speed_ss"] < 0.1 and 0.0 <= ep["settle_time"] < 5.0
    assert ep["attitude_error"] < 1e-3
    # the estimate's heading against the truth at its sample, as attitude_error (against the
    # physics step's heading, which an IMU slower than the physics lags, it was 0.06 deg under
    # truth: an offset in every estimator's row)
    ep = evaluate(PID(task="track"), dict(task="track", estimator="truth", episode_s=6.0), episodes=1,
                  seed=3)["episodes"][0]
    assert ep["attitude_error"] < 1e-3 and ep["heading_est_error"] < 1e-3


def test_pid_reaches_waypoints_under_truth():
    res = evaluate(PID(task="waypoints"), dict(task="waypoints", estimator="truth", n_waypoints=2), episodes=1,
                   seed=0, record_path=True)
    ep = res["episodes"][0]
    assert ep["success"] == 1.0 and ep["time_to_goal"] < 60
    assert ep["path"].shape[1] == 2 and ep["cross_track"] < 1.0


def test_aggregate_intervals():
    eps = [{m: v for m in EPISODE_METRICS["track"]} for v in (1.0, 2.0, 3.0, 1.0, 2.0, 3.0, float("nan"))]
    s = aggregate(eps, "track")["return"]
    assert s["mean"] == pytest.approx(2.0) and s["n"] == 6 and s["std"] == pytest.approx(math.sqrt(0.8))
    assert 1.0 <= s["lo"] < 2.0 < s["hi"] <= 3.0 and s["iqm"] == pytest.approx(2.0)
    assert math.isnan(aggregate(eps[:3], "track")["return"]["lo"])        # fewer than MIN_BOOT: none


def test_evaluate_bad_input():
    with pytest.raises(ValueError, match="episodes"):
        evaluate(PID(), {"task": "track"}, episodes=0)


@pytest.fixture(scope="module")
def tiny_policy(tmp_path_factory):
    stem = tmp_path_factory.mktemp("pol") / "ppo-track-truth"
    rl.train("ppo", "track", "truth", timesteps=600, seed=1, out=stem, n_envs=1, progress=False,
             eval_freq=300, checkpoint_freq=300, eval_episodes=1, env_kwargs={"episode_s": 2.0}, log=lambda *a: None)
    return stem


def test_train_writes_policy_and_loads(tiny_policy):
    stem = tiny_policy
    for suffix in (".zip", ".vecnormalize.npz", ".json"):
        assert (stem.parent / (stem.name + suffix)).is_file()
    meta = json.loads((stem.parent / (stem.name + ".json")).read_text())
    assert meta["algo"] == "ppo" and meta["estimator"] == "truth" and meta["timesteps"] == 600
    env = SphereRobotEnv(task="track", estimator="truth", episode_s=1.0)
    ctrl = rl.load_policy(stem, env=env)
    obs, _ = env.reset(seed=0)
    a = ctrl.act(obs)
    assert a.shape == (2,) and np.all(np.abs(a) <= 1)
    assert ctrl.act(np.stack([obs, obs])).shape == (2, 2)
    env.close()


def test_resume_continues_from_checkpoint(tiny_policy):
    stem = tiny_policy
    ckpts = sorted((stem.parent / (stem.name + ".run") / "checkpoints").glob("ckpt_*_steps.zip"))
    assert ckpts, "checkpoints were written"
    log = stem.parent / (stem.name + ".run") / "evaluations.npz"
    with np.load(log) as d:
        before = d["timesteps"].tolist(), d["results"].tolist()
    # PPO rounds up to whole rollouts (1,024 steps): the first run ended at 1,024, this one trains on
    rl.train("ppo", "track", "truth", timesteps=2100, seed=1, out=stem, n_envs=1, progress=False, resume=True,
             eval_freq=300, checkpoint_freq=300, eval_episodes=1, env_kwargs={"episode_s": 2.0}, log=lambda *a: None)
    meta = json.loads((stem.parent / (stem.name + ".json")).read_text())
    assert meta["timesteps"] == 2100
    # the resumed run starts from the earlier best score: the shipped model is the best of both
    assert meta["best_eval"] is not None
    assert int(rl._latest_checkpoint(stem.parent / (stem.name + ".run") / "checkpoints").stem.split("_")[1]) >= 2100
    # the evaluation log (the learning curve) is continued, not started over
    with np.load(log) as d:
        assert before[0] == [300, 600, 900] and d["timesteps"].tolist()[:3] == before[0]
        assert d["results"].tolist()[:3] == before[1] and d["timesteps"][3] > 1024
        assert np.all(np.diff(d["timesteps"]) > 0)


def test_a_run_without_evaluations_ships_its_last_model_after_a_resume(tmp_path):
    """With no evaluation in either part (a run shorter than eval_freq, resumed), the shipped
    model is the last one. Before, the resume kept shipping the first part's model."""
    stem = tmp_path / "ppo-track-truth"
    kw = dict(seed=1, out=stem, n_envs=1, progress=False, eval_freq=10_000, checkpoint_freq=10_000,
              eval_episodes=1, env_kwargs={"episode_s": 2.0}, log=lambda *a: None)
    rl.train("ppo", "track", "truth", timesteps=300, **kw)
    first = (stem.parent / (stem.name + ".zip")).read_bytes()
    rl.train("ppo", "track", "truth", timesteps=1500, resume=True, **kw)
    last = rl._latest_checkpoint(stem.parent / (stem.name + ".run") / "checkpoints")
    assert int(last.stem.split("_")[1]) > 1024          # the second part trained
    shipped = (stem.parent / (stem.name + ".zip")).read_bytes()

    def entries(b):         # (a zip's bytes hold its save time: compare what it holds)
        with zipfile.ZipFile(io.BytesIO(b)) as z:
            return {n: z.read(n) for n in z.namelist()}
    assert entries(shipped) != entries(first) and entries(shipped) == entries(last.read_bytes())
    assert json.loads((stem.parent / (stem.name + ".json")).read_text())["best_eval"] is None
    # an evaluation's score whose model is gone (a crash between them): the last model too
    run = stem.parent / (stem.name + ".run")
    (run / "best.json").write_text(json.dumps({"mean_reward": 0.0, "timesteps": 0}))
    (run / "best_model.zip").unlink()
    rl.train("ppo", "track", "truth", timesteps=2600, resume=True, **kw)
    last = rl._latest_checkpoint(run / "checkpoints")
    assert entries((stem.parent / (stem.name + ".zip")).read_bytes()) == entries(last.read_bytes())
    # a whole best set (its score names its files' digests) is kept by a resume...
    saver = rl._RunFiles(None, run, run / "checkpoints", True)
    (run / "best_model.zip").write_bytes(first)
    (run / "best.json").write_text(json.dumps({"mean_reward": 1e9, "timesteps": 300, "sha256": saver._digests()}))
    rl.train("ppo", "track", "truth", timesteps=3700, resume=True, **kw)
    assert entries((stem.parent / (stem.name + ".zip")).read_bytes()) == entries(first)
    assert json.loads((stem.parent / (stem.name + ".json")).read_text())["best_eval"] == {
        "mean_reward": 1e9, "timesteps": 300}
    # ...but a kill between a new best's model and its statistics and score left a model the
    # score does not name (before: shipped with the other moment's statistics): the last model
    (run / "best_model.zip").write_bytes(last.read_bytes())
    rl.train("ppo", "track", "truth", timesteps=4800, resume=True, **kw)
    last = rl._latest_checkpoint(run / "checkpoints")
    assert entries((stem.parent / (stem.name + ".zip")).read_bytes()) == entries(last.read_bytes())
    assert json.loads((stem.parent / (stem.name + ".json")).read_text())["best_eval"] is None


def test_init_from_fine_tunes(tmp_path, tiny_policy, monkeypatch):
    stem = tmp_path / "ppo-track-gyro"
    # training leaves nothing in the temp directory (SB3's default logger makes a folder there)
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    rl.train("ppo", "track", "gyro", timesteps=300, seed=2, out=stem, n_envs=1, progress=False, init_from=tiny_policy,
             trusted=True, eval_freq=300, checkpoint_freq=300, eval_episodes=1, env_kwargs={"episode_s": 2.0},
             log=lambda *a: None)
    meta = json.loads((tmp_path / "ppo-track-gyro.json").read_text())
    assert not any((tmp_path / "tmp").iterdir())
    assert meta["init_from"] == "ppo-track-truth.zip" and meta["estimator"] == "gyro"
    # the starting policy's evaluation is the first point of the learning curve
    with np.load(tmp_path / "ppo-track-gyro.run" / "evaluations.npz") as d:
        assert d["timesteps"].tolist()[:2] == [0, 300] and d["results"].shape[1] == 1
        # the best model is the best of the log, the start included
        assert meta["best_eval"]["mean_reward"] == pytest.approx(d["results"].mean(axis=1).max())
    with pytest.raises(ValueError, match="ppo policy"):
        rl.train("sac", "track", "gyro", timesteps=10, out=tmp_path / "w", init_from=tiny_policy, progress=False)


def test_fresh_start_does_not_clobber_checkpoints(tiny_policy):
    with pytest.raises(FileExistsError, match="--resume"):
        rl.train("ppo", "track", "truth", timesteps=10, out=tiny_policy, n_envs=1, progress=False)


def test_resume_without_checkpoint(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        rl.train("ppo", "track", "truth", timesteps=10, out=tmp_path / "none", resume=True, progress=False)


def test_train_bad_names(tmp_path):
    with pytest.raises(ValueError, match="algorithm"):
        rl.train("dqn", "track", "truth", out=tmp_path / "x")
    with pytest.raises(ValueError, match="estimator"):
        rl.train("ppo", "track", "kalman", out=tmp_path / "x")
    with pytest.raises(ValueError, match="task"):
        rl.train("ppo", "fly", "truth", out=tmp_path / "x")
    for bad in (0, 2.5, True, "100", float("nan")):
        with pytest.raises(ValueError, match="timesteps must be an integer >= 1"):
            rl.train("ppo", "track", "truth", timesteps=bad, out=tmp_path / "x")
    with pytest.raises(ValueError, match="vec_env must be one of"):
        rl.train("ppo", "track", "truth", timesteps=10, vec_env="gpu", out=tmp_path / "x")


def test_load_policy_errors(tmp_path, tiny_policy):
    with pytest.raises(rl.PolicyError, match="does not exist"):
        rl.load_policy(tmp_path / "missing")
    bad = tmp_path / "bad.zip"
    bad.write_bytes(b"not a zip")
    with pytest.raises(rl.PolicyError, match="corrupt"):
        rl.load_policy(bad)
    env = SphereRobotEnv(task="waypoints", estimator="truth")
    with pytest.raises(rl.PolicyError, match="task"):
        rl.load_policy(tiny_policy, env=env)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_init_from_pid_clones_the_teacher(tmp_path, algo):
    """Behaviour cloning: the shipped clone acts like the PID on the states the PID visits
    (not like an untrained policy), and is kept as the best model until training beats it."""
    stem = tmp_path / f"{algo}-waypoints-truth"
    kw = {"episode_s": 10.0}
    rl.train(algo, "waypoints", "truth", timesteps=64, seed=0, out=stem, n_envs=1, progress=False,
             init_from="pid", bc_steps=4000, eval_freq=10**6, eval_episodes=1, env_kwargs=kw, log=lambda *a: None)
    meta = json.loads((tmp_path / f"{algo}-waypoints-truth.json").read_text())
    assert meta["init_from"] == "pid (behaviour cloning, 4000 steps)"
    assert meta["best_eval"]["timesteps"] == 0
    clone = rl.load_policy(stem)
    env = SphereRobotEnv(task="waypoints", estimator="truth", **kw)
    pid = PID("waypoints")
    obs, _ = env.reset(seed=5)
    diff = []
    for _ in range(300):
        a = pid.act(obs)
        diff.append(np.abs(clone.act(obs) - a).mean())
        obs, _, term, trunc, _ = env.step(a)
        if term or trunc:
            break
    env.close()
    assert np.mean(diff) < 0.1, np.mean(diff)     # an untrained policy: 0.54


def test_sac_resumes_with_its_replay_buffer(tmp_path):
    """A resumed SAC run continues with the transitions it had (before: an empty buffer, past
    learning_starts, so gradient steps began on a handful of samples; a PID clone's 60,000
    transitions were lost). The buffer is plain arrays beside the newest checkpoint only; a
    tampered one is refused and leaves the buffer as it was."""
    from controllers import policy_io
    stem = tmp_path / "sac-track-truth"
    kw = dict(seed=0, out=stem, n_envs=1, progress=False, eval_freq=10**6, eval_episodes=1,
              checkpoint_freq=200, env_kwargs={"episode_s": 1.0},
              hyperparams_override={"learning_starts": 100, "batch_size": 32, "gradient_steps": 1,
                                    "buffer_size": 5000})
    rl.train("sac", "track", "truth", timesteps=400, log=lambda *a: None, **kw)
    # the record holds the YAML file's policy_kwargs, not what SB3 wrote into the dict it got
    # (use_sde: a grid's --resume took it for another setting)
    meta = json.loads((tmp_path / "sac-track-truth.json").read_text())
    assert meta["hyperparams"]["policy_kwargs"] == rl.hyperparams("sac", "track")["policy_kwargs"]
    ckpts = rl._checkpoints(stem.parent / (stem.name + ".run") / "checkpoints")
    replays = sorted(ckpts[0].parent.glob("ckpt_replay_*"))
    assert replays == [rl._checkpoint_replay(ckpts[0])]            # the newest checkpoint's only
    said = []
    rl.train("sac", "track", "truth", timesteps=800, resume=True, log=said.append, **kw)
    assert "replay buffer: 400 transitions" in said, said
    replays = sorted(ckpts[0].parent.glob("ckpt_replay_*"))
    assert [r.name for r in replays] == ["ckpt_replay_800_steps.npz"]
    # a buffer that does not fit this run's is refused, the buffer untouched
    from stable_baselines3.common.buffers import ReplayBuffer
    from gymnasium import spaces
    buf = ReplayBuffer(5000, spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (2,)))
    with pytest.raises(policy_io.PolicyError, match="observations has shape"):
        policy_io.load_replay(buf, replays[0])
    assert buf.pos == 0 and not buf.full and not buf.observations.any()
    with pytest.raises(policy_io.PolicyError, match="lacks observations"):
        policy_io.load_replay(buf, ckpts[0])                        # (a model's zip, not the arrays)
    with pytest.raises(policy_io.PolicyError, match="missing, corrupt"):
        policy_io.load_replay(buf, tmp_path / "none.npz")


def test_init_from_pid_bad_input(tmp_path):
    with pytest.raises(ValueError, match="bc_steps"):
        rl.train("ppo", "track", "truth", timesteps=10, out=tmp_path / "p", init_from="pid", bc_steps=0,
                 progress=False)


def test_hyperparams_override(tmp_path):
    stem = tmp_path / "ppo-track-truth"
    rl.train("ppo", "track", "truth", timesteps=64, seed=0, out=stem, n_envs=1, progress=False,
             hyperparams_override={"learning_rate": 1e-4, "n_steps": 64, "batch_size": 32},
             eval_freq=10**6, eval_episodes=1, env_kwargs={"episode_s": 2.0}, log=lambda *a: None)
    meta = json.loads((tmp_path / "ppo-track-truth.json").read_text())
    assert meta["hyperparams"]["learning_rate"] == 1e-4 and meta["hyperparams"]["n_steps"] == 64
    assert rl.load_policy(stem).model.learning_rate == 1e-4
    with pytest.raises(ValueError, match="unknown hyperparameter.*learning_rat"):
        rl.train("ppo", "track", "truth", timesteps=10, out=tmp_path / "x", progress=False,
                 hyperparams_override={"learning_rat": 1e-4})


def test_tilt_error_is_the_inclination_error():
    from fusion.metrics import attitude_errors
    rng = np.random.default_rng(3)
    qe, qt = rng.normal(size=(2, 200, 4))
    qe /= np.linalg.norm(qe, axis=1, keepdims=True)
    qt /= np.linalg.norm(qt, axis=1, keepdims=True)
    ref = attitude_errors(qe, qt)["inclination"]
    got = np.array([_inclination_deg(a, b) for a, b in zip(qe, qt)])
    assert np.allclose(got, ref, atol=1e-9)
    # a pure heading error has no tilt, a 5 deg roll error is 5 deg of tilt
    h = np.radians(30.0) / 2
    assert _inclination_deg((math.cos(h), 0, 0, math.sin(h)), (1, 0, 0, 0)) == pytest.approx(0.0, abs=1e-12)
    r = np.radians(5.0) / 2
    assert _inclination_deg((math.cos(r), math.sin(r), 0, 0), (1, 0, 0, 0)) == pytest.approx(5.0)


def test_tilt_error_in_the_loop():
    kw = {"task": "track", "episode_s": 4.0}
    truth = evaluate(PID(), dict(kw, estimator="truth"), episodes=1)["episodes"][0]
    gyro = evaluate(PID(), dict(kw, estimator="gyro"), episodes=1)["episodes"][0]
    assert truth["tilt_error"] < 1e-3 and gyro["tilt_error"] > 10 * truth["tilt_error"]
    assert gyro["tilt_error"] <= gyro["attitude_error"] + 1e-9
