"""envs/vector.py: the batched vector environment equals N single environments."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pybullet")

import envs  # noqa: E402, F401


def _single_runs(env_id, n, seed, acts, extra=None, **kw):
    """Per robot i: observations and rewards of a single env reset with seed + i, reset
    again (no seed) whenever an episode ends, as the vector env's auto-reset does, and
    after the steps ``extra[i]``."""
    obs_all, rew_all = [], []
    for i in range(n):
        env = gym.make(env_id, **kw)
        o, _ = env.reset(seed=seed + i)
        obs, rew = [o], []
        for a in acts:
            o, r, term, trunc, _ = env.step(a[i])
            if term or trunc or len(rew) in (extra or {}).get(i, ()):
                o, _ = env.reset()
            obs.append(o), rew.append(r)
        env.close()
        obs_all.append(obs), rew_all.append(rew)
    return np.array(obs_all).transpose(1, 0, 2), np.array(rew_all).T


@pytest.mark.parametrize("env_id, kw", [
    ("SphereBotWaypoints-v1", {"estimator": "ekf"}),
    # slippery patches under the robots: each robot's own shell friction switched in the shared world
    ("SphereBotWaypoints-v1", {"estimator": "ekf", "slippery_patches": 10, "arena_size": 6.0}),
    # short episodes: auto-resets while the other robots sleep through the settling
    ("SphereBotTrack-v0", {"estimator": "mahony", "episode_s": 0.3, "bumps": 2}),
])
def test_same_seeds_give_the_episodes_of_single_environments_bit_for_bit(env_id, kw):
    n, steps = 3, 40
    acts = np.random.default_rng(0).uniform(-1, 1, size=(steps, n, 2)).astype(np.float32)
    venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    bank, calls = venv._bank, []

    class Counting:        # the bank's updates, counted: the robots' estimators run in it
        def update(self, *a):
            calls.append(1)
            return bank.update(*a)
    venv._bank = Counting()
    o, _ = venv.reset(seed=20)
    obs, rew, ends = [o], [], 0
    for a in acts:
        o, r, term, trunc, info = venv.step(a)
        obs.append(o), rew.append(r)
        ends += int(np.sum(term | trunc))
        if np.any(term | trunc):
            assert "final_obs" in info
    venv.close()
    assert calls           # the bank ran (when every robot had a sample in the same physics step)
    want_obs, want_rew = _single_runs(env_id, n, 20, acts, **kw)
    np.testing.assert_array_equal(np.array(obs), want_obs)
    np.testing.assert_array_equal(np.array(rew), want_rew)
    if "episode_s" in kw:
        assert ends >= n * 2


def test_one_robot_reset_alone():
    """A robot reset alone (an auto-reset of one robot) settles while the world steps every
    robot; the others get their positions, velocities and joints back afterwards. The reset
    robot's episode is its single environment's bit for bit; the others' are until that
    reset, not after it (PyBullet's contact caches moved on: envs/vector.py)."""
    env_id, n, kw = "SphereBotWaypoints-v1", 3, {"estimator": "ekf", "bumps": 2}
    acts = np.random.default_rng(1).uniform(-1, 1, size=(30, n, 2)).astype(np.float32)
    venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    o, _ = venv.reset(seed=5)
    obs = [o]
    for k, a in enumerate(acts):
        o = venv.step(a)[0]
        if k in (6, 17):
            (o1, _), = venv._reset_some([1], [None])
            o[1] = o1
        obs.append(o)
    venv.close()
    want, _ = _single_runs(env_id, n, 5, acts, extra={1: (6, 17)}, **kw)
    obs = np.array(obs)
    np.testing.assert_array_equal(obs[:, 1], want[:, 1])
    np.testing.assert_array_equal(obs[:8], want[:8])


@pytest.mark.parametrize("n", [0, -1, 1.5, True])
def test_num_envs_must_be_a_positive_integer(n):
    with pytest.raises(ValueError, match="num_envs"):
        gym.make_vec("SphereBotTrack-v1", num_envs=n, vectorization_mode="vector_entry_point")


def test_sb3_adapter_runs_and_reports_terminal_observations():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env  # noqa: F401  (SB3 importable)
    from envs.vector import SB3VecEnv, make_track_vec
    venv = SB3VecEnv(make_track_vec(2, estimator="truth", episode_s=0.1))
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (2, 14)
    done_seen = False
    for _ in range(6):
        obs, rew, dones, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
        if dones.any():
            done_seen = True
            i = int(np.flatnonzero(dones)[0])
            assert infos[i]["terminal_observation"].shape == (14,) and infos[i]["TimeLimit.truncated"]
    assert done_seen and rew.shape == (2,)
    venv.close()


def test_train_cli_trains_on_the_batched_vector_env(tmp_path):
    pytest.importorskip("stable_baselines3")
    from controllers import train_cli
    out = tmp_path / "ppo-track"
    rc = train_cli.main(["--algo", "ppo", "--env", "track", "--estimator", "truth", "-n", "128", "--n-envs", "2",
                         "--vec-env", "batched", "--out", str(out), "--eval-episodes", "0", "--n-eval-episodes", "1",
                         "--no-progress", "--hyperparams", "n_steps:64", "batch_size:64",
                         "--env-kwargs", "episode_s:1"])
    assert rc in (0, None) and out.with_suffix(".zip").is_file()
    assert (tmp_path / "ppo-track.run" / "monitor" / "0.monitor.csv").is_file()


def test_estimator_params_the_environment_owns_are_refused():
    # the bank takes the robots' estimator_params: NED would be read as ENU there too
    with pytest.raises(ValueError, match="frame"):
        gym.make_vec("SphereBotTrack-v1", num_envs=2, vectorization_mode="vector_entry_point",
                     estimator="ekf", estimator_params={"frame": "NED"})


def test_reset_takes_a_seed_per_robot():
    """gymnasium's VectorEnv.reset takes one integer seed; a list of num_envs seeds (as
    SyncVectorEnv takes them) and numpy integers were refused by it before the robots were
    reset ("Seed must be a python integer")."""
    venv = gym.make_vec("SphereBotTrack-v1", num_envs=2, vectorization_mode="vector_entry_point",
                        estimator="truth", episode_s=0.2)
    try:
        by_int = venv.reset(seed=3)[0]                  # robots: seeds 3, 4
        assert not np.array_equal(by_int[0], by_int[1])
        np.testing.assert_array_equal(venv.reset(seed=np.int64(3))[0], by_int)
        np.testing.assert_array_equal(venv.reset(seed=[4, np.int64(3)])[0], by_int[::-1])
        np.testing.assert_array_equal(venv.reset(seed=np.array([3, 4]))[0], by_int)
        assert venv.reset(seed=[None, 4])[0].shape == by_int.shape
        for seed, words in (([1, 2, 3], ["num_envs = 2", "3 seeds"]), ("abc", ["seed", "'abc'"]),
                            ([0, -1], ["seed[1]", ">= 0"]), (-5, ["seed", "-5"]), (True, ["seed", "True"])):
            with pytest.raises(ValueError) as e:
                venv.reset(seed=seed)
            for w in words:
                assert w in str(e.value)
    finally:
        venv.close()


def test_a_refused_row_leaves_every_robot_as_it_was():
    """Every row of the actions is checked before any robot begins its step: a NaN in the
    last row used to leave the robots before it with their step begun (a clipped action
    counted twice when the step was taken again)."""
    venv = gym.make_vec("SphereBotTrack-v1", num_envs=3, vectorization_mode="vector_entry_point",
                        estimator="truth", episode_s=0.5)
    try:
        venv.reset(seed=0)
        robots = venv.unwrapped.envs
        bad = np.array([[2.0, 0.0], [0.0, 0.0], [np.nan, 0.0]])
        with pytest.raises(ValueError, match=r"actions\[2\].*finite"):
            venv.step(bad)
        assert [r._clipped for r in robots] == [0, 0, 0]
        with pytest.raises(ValueError, match=r"actions\[0\].*real numbers"):
            venv.step(np.array([[0, 0], [1j, 0], [0, 0]]))
        bad[2, 0] = 0.0
        venv.step(bad)
        assert [r._clipped for r in robots] == [1, 0, 0]
    finally:
        venv.close()


def test_reset_mask_resets_those_robots_only():
    """options["reset_mask"], as gymnasium's SyncVectorEnv takes it (it was refused as an
    unknown option): the masked robots' new episodes are their single environments', the
    others' last observations come back as they were."""
    kw = dict(estimator="ekf", episode_s=2.0)
    venv = gym.make_vec("SphereBotTrack-v1", num_envs=3, vectorization_mode="vector_entry_point", **kw)
    try:
        with pytest.raises(ValueError, match="every robot first"):
            venv.reset(options={"reset_mask": np.array([True, False, False])})
        venv.reset(seed=0)
        for _ in range(3):
            last = venv.step(np.full((3, 2), 0.5, dtype=np.float32))[0]
        obs, info = venv.reset(seed=10, options={"reset_mask": np.array([False, True, False])})
        np.testing.assert_array_equal(obs[[0, 2]], last[[0, 2]])
        assert list(info["_position"]) == [False, True, False]      # infos of the reset robot only
        single = gym.make("SphereBotTrack-v1", **kw)
        np.testing.assert_array_equal(obs[1], single.reset(seed=11)[0])
        single.close()
        venv.step(np.zeros((3, 2), dtype=np.float32))
        for bad in ([True, False, False], np.array([0, 1, 0]), np.array([False] * 3), np.array([True, False])):
            with pytest.raises(ValueError, match="reset_mask"):
                venv.reset(options={"reset_mask": bad})
    finally:
        venv.close()


def test_close_reset_close_disconnects():
    """A reset after close reconnected but left gymnasium's closed flag set, so the next close
    (and __del__) did nothing and the physics client leaked."""
    import pybullet as p
    venv = gym.make_vec("SphereBotTrack-v1", num_envs=2, vectorization_mode="vector_entry_point",
                        estimator="truth")
    venv.reset(seed=0)
    venv.close()
    venv.reset(seed=0)
    client = venv.unwrapped._client
    venv.close()
    assert not p.isConnected(client)
