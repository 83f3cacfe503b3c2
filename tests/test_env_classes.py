"""envs: one class per task (issue 14): the same episodes as the single class before, bit for
bit; the observation layout by name; the env checker for each class."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pybullet")

import envs  # noqa: E402
from envs.sphere import SphereRobotEnv  # noqa: E402
from envs.track import SphereBotTrackEnv  # noqa: E402
from envs.waypoints import SphereBotWaypointsEnv  # noqa: E402

from env_golden import CASES, PATH, PID_CASES, record  # noqa: E402


@pytest.fixture(scope="module")
def golden():
    return np.load(PATH)


@pytest.mark.parametrize("i", range(len(CASES) + len(PID_CASES)))
def test_episodes_equal_the_single_class_ones_bit_for_bit(golden, i):
    env_id, kw, seed = (CASES + PID_CASES)[i]
    got = record(env_id, kw, seed, pid=i >= len(CASES))
    for name, arr in zip(("obs", "rew", "flags", "pos"), got, strict=True):
        np.testing.assert_array_equal(arr, golden[f"{i}_{name}"], err_msg=f"{env_id} {kw} {name}")


def test_ids_build_the_task_classes():
    for env_id, cls in (("SphereBotTrack-v1", SphereBotTrackEnv), ("SphereBotWaypoints-v0", SphereBotWaypointsEnv)):
        env = gym.make(env_id, estimator="truth")
        assert type(env.unwrapped) is cls
        env.close()
    assert gym.make("SphereBotTrack-v0").unwrapped.realism == "ideal"
    assert type(SphereRobotEnv(task="waypoints", estimator="truth")) is SphereBotWaypointsEnv
    with pytest.raises(ValueError, match="task"):
        SphereRobotEnv(task="race")


@pytest.mark.parametrize("cls", [SphereBotTrackEnv, SphereBotWaypointsEnv])
def test_observation_layout_by_name(cls):
    env = cls(estimator="ekf")
    assert list(cls.OBS) == list(env.obs_names) and len(cls.OBS) == env.observation_space.shape[0]
    assert [cls.OBS[n] for n in env.obs_names] == list(range(14))
    obs, info = env.reset(seed=1)
    for _ in range(5):
        obs, *_rest, info = env.step(np.array([0.5, 0.2], dtype=np.float32))
    assert obs[cls.OBS["encoder_speed"]] == np.float32(info["encoder_speed"])
    assert obs[cls.OBS["last_drive"]] == np.float32(0.5)
    if cls is SphereBotTrackEnv:
        assert obs[cls.OBS["speed_cmd"]] == np.float32(info["command"][0])
    else:
        fwd, left = obs[cls.OBS["target_forward"]], obs[cls.OBS["target_left"]]
        assert np.hypot(fwd, left) == pytest.approx(np.hypot(*(info["waypoint"] - info["position_est"])), rel=1e-5)
    env.close()


@pytest.mark.parametrize("cls", [SphereBotTrackEnv, SphereBotWaypointsEnv])
def test_env_checker_passes_for_each_class(cls):
    from gymnasium.utils.env_checker import check_env
    env = cls(estimator="ekf")
    check_env(env, skip_render_check=True)
    env.close()


def test_waypoint_arguments_belong_to_the_waypoints_task():
    with pytest.raises(TypeError, match="n_waypoints"):
        SphereBotTrackEnv(n_waypoints=3)
    with pytest.raises(ValueError, match="n_waypoints"):
        SphereBotWaypointsEnv(n_waypoints=0)


def test_waypoints_are_apart_and_within_the_square():
    """Each waypoint 1.5-3.5 m from the previous and within 40 % of the arena of the centre.
    A clamp to that square used to put consecutive waypoints on one corner (a second reward
    for the same point): 143 of 300 episodes in an 8 m arena had a pair closer than 1.5 m."""
    from envs.waypoints import _step_within
    rng = np.random.default_rng(0)
    for arena, n in ((8.0, 4), (20.0, 8), (6.3, 6)):
        lim = 0.4 * arena
        for _ in range(300):
            x, y = rng.uniform(-lim, lim, 2)
            for a, d in zip(rng.uniform(-np.pi, np.pi, n), rng.uniform(1.5, 3.5, n), strict=True):
                nx, ny = _step_within(x, y, a, d, lim)
                assert abs(nx) <= lim + 1e-12 and abs(ny) <= lim + 1e-12
                assert np.hypot(nx - x, ny - y) == pytest.approx(d)
                x, y = nx, ny
    # an arena too small for the step: toward the farthest corner, as far as fits
    x, y = _step_within(0.5, 0.5, 0.3, 3.0, 0.8)
    assert (x, y) == pytest.approx((-0.8, -0.8))
    env = SphereBotWaypointsEnv(estimator="truth", imu="ideal", arena_size=8.0)
    try:
        env.reset(seed=74)                    # a seed whose last two waypoints the clamp merged
        wp = np.vstack([env._xy0, env._waypoints])
        assert np.all(np.hypot(*np.diff(wp, axis=0).T) >= 1.5)
    finally:
        env.close()


@pytest.mark.parametrize("page, cls", [("sphere_bot_track.md", SphereBotTrackEnv),
                                       ("sphere_bot_waypoints.md", SphereBotWaypointsEnv)])
def test_docs_observation_tables_follow_the_layout(page, cls):
    """Every index row of the page's observation table names the layout's names at it."""
    import os
    import re
    text = open(os.path.join(os.path.dirname(__file__), "..", "docs", "envs", page), encoding="utf-8").read()
    rows = re.findall(r"^\| (\d+)(?:-(\d+))? \| ((?:`[a-z_0-9]+`(?:, )?)+) \|", text, re.M)
    assert rows
    for lo, hi, names in rows:
        idx = list(range(int(lo), int(hi or lo) + 1))
        assert [cls.OBS[n] for n in re.findall(r"`([a-z_0-9]+)`", names)] == idx, (page, lo, names)
    assert envs.SphereBotTrackEnv is SphereBotTrackEnv
