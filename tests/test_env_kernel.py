"""The environment's compiled step (envs/_signals.pyx, fusion/_imu.pyx: the physics steps,
and the base's part of each control step) against its Python reference (``compiled=False``):
same seed, same actions, the same observations, rewards, flags and infos, bit for bit."""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from envs.sphere import SphereRobotEnv
from envs.track import SphereBotTrackEnv


def rollout(env, actions, seed, log_from=None):
    """Every value reset() and step() return (and the reset()s after an episode's end)."""
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    for i, a in enumerate(actions):
        if log_from is not None and i == log_from:
            env.unwrapped.enable_signal_log()   # the Python path takes over ...
        if log_from is not None and i == log_from + 20:
            env.unwrapped.disable_signal_log()  # ... and hands back
        res = env.step(a)
        out.append(res)
        if res[2] or res[3]:
            out.append(env.reset())
    return out


def identical(a, b, where="step"):
    """a and b the same to the last bit: types, dict keys in order, arrays' dtype, shape and
    bytes, floats' bits (a NaN equals a NaN of the same bits)."""
    assert type(a) is type(b), f"{where}: {type(a)} against {type(b)}"
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), f"{where}: {a} against {b}"
    elif isinstance(a, dict):
        assert list(a) == list(b), f"{where}: keys {list(a)} against {list(b)}"
        for k in a:
            identical(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            identical(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert np.float64(a).tobytes() == np.float64(b).tobytes(), f"{where}: {a!r} against {b!r}"
    else:
        assert a == b, f"{where}: {a!r} against {b!r}"


def assert_same(a, b):
    assert len(a) == len(b)
    for i, (x, y) in enumerate(zip(a, b)):
        identical(x, y, f"record {i}")


CASES = {
    # the default robot with every realism effect, magnetic zones, bumps and ramps
    "real-ekf-zones": dict(task="track", estimator="ekf", mag_zones="random", n_mag_zones=6, arena_size=6.0,
                           bumps=3, ramps=2, episode_s=3.0),
    # slippery patches: the shell's friction switched as it enters and leaves them (4 times here)
    "real-ekf-patches": dict(task="track", estimator="ekf", slippery_patches=10, arena_size=6.0, episode_s=3.0),
    "real-mahony-waypoints": dict(task="waypoints", estimator="mahony", position_fix_hz=2.0, episode_s=3.0),
    "ideal-truth": dict(task="track", estimator="truth", realism="ideal", imu_offset=(0.0, 0.0, 0.0),
                        episode_s=2.0),
    "real-ekf-mti10-average": dict(task="track", estimator="ekf", imu="mti10", imu_hz=100.0, physics_hz=800.0,
                                   mag_zones=[(0.3, 0.2, 40.0)], episode_s=2.0),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_env_equals_python_reference(case):
    kw = CASES[case]
    rng = np.random.default_rng(7)
    actions = rng.uniform(-1, 1, (400, 2))
    actions[:, 0] = np.abs(actions[:, 0])                # mostly forward, with resets in between
    ref = SphereRobotEnv(compiled=False, **kw)
    ker = SphereRobotEnv(**kw)
    try:
        assert_same(rollout(ref, actions, 3), rollout(ker, actions, 3))
    finally:
        ref.close()
        ker.close()


def test_compiled_env_hands_over_to_python_while_logging():
    """A signal log runs the Python path; switching to it and back mid-episode changes nothing."""
    kw = CASES["real-ekf-zones"]
    actions = np.random.default_rng(1).uniform(0, 1, (200, 2))
    ref = SphereRobotEnv(compiled=False, **kw)
    ker = SphereRobotEnv(**kw)
    try:
        assert_same(rollout(ref, actions, 5), rollout(ker, actions, 5, log_from=30))
    finally:
        ref.close()
        ker.close()


def test_compiled_bad_input():
    with pytest.raises(ValueError, match="compiled"):
        SphereRobotEnv(compiled=1)


def mixed_actions(n, seed):
    """Actions in every form step() accepts: float32 and float64 arrays, strided and
    byte-swapped ones, float16, lists and tuples; some outside [-1, 1] (clipped, counted)."""
    rng = np.random.default_rng(seed)
    raw = rng.uniform(-1, 1, (n, 2))
    raw[:, 0] = 0.3 + 0.6 * raw[:, 0]
    raw[::13] *= 1.7
    out = []
    for i, a in enumerate(raw):
        k = i % 8
        out.append(a.astype(np.float32) if k < 4 else a if k == 4 else np.repeat(a, 2)[::2] if k == 5
                   else a.astype(">f4") if k == 6 else [float(a[0]), float(a[1])] if i % 16 == 7
                   else (a.astype(np.float16)[0], float(a[1])))
    return out


@pytest.mark.parametrize("env_id, kw, seed", [
    ("SphereBotTrack-v1", {"estimator": "ekf"}, 11),
    ("SphereBotWaypoints-v1", {"estimator": "ekf", "position_fix_hz": 2.0, "waypoint_radius": 1.5,
                               "mag_zones": "random"}, 12),
    ("SphereBotTrack-v1", {"estimator": "truth", "bumps": 3, "slippery_patches": 4, "arena_size": 6.0}, 13),
])
def test_long_rollout_as_users_make_it(env_id, kw, seed):
    """gymnasium.make's environment, 2,500 steps (the track's episode is 1,500: resets in
    between) of actions in every accepted form: the compiled step returns exactly what the
    Python reference returns."""
    acts = mixed_actions(2500, seed)
    ref, ker = gym.make(env_id, compiled=False, **kw), gym.make(env_id, **kw)
    try:
        assert ker.unwrapped._compiled_step and not ref.unwrapped._compiled_step
        assert_same(rollout(ref, acts, seed), rollout(ker, acts, seed))
    finally:
        ref.close()
        ker.close()


def test_compiled_step_errors_as_the_python_step():
    for compiled in (False, True):
        env = SphereRobotEnv(compiled=compiled)
        with pytest.raises(RuntimeError, match="call reset"):
            env.step(np.zeros(2, np.float32))
        env.reset(seed=0)
        for bad, match in ((np.array([np.nan, 0.0], np.float32), "finite"), (np.zeros(3), "shape"),
                           ("ab", "finite real numbers"), (np.array([0.0, np.inf]), "finite")):
            with pytest.raises(ValueError, match=match):
                env.step(bad)
        env.close()


def test_a_subclass_overriding_the_inlined_methods_keeps_them():
    """The compiled step inlines the base's end-of-step methods: a subclass that overrides one
    gets the Python step (with its override), the physics still compiled."""
    class Louder(SphereBotTrackEnv):
        def _observation(self, psi, bias):
            return 2.0 * super()._observation(psi, bias)

    env, plain = Louder(), SphereBotTrackEnv()
    try:
        assert plain._compiled_step and not env._compiled_step and env._loop is not None
        env.reset(seed=1)
        plain.reset(seed=1)
        a = np.array([0.5, 0.2], np.float32)
        np.testing.assert_array_equal(env.step(a)[0], 2.0 * plain.step(a)[0])
    finally:
        env.close()
        plain.close()


def test_the_track_task_inlined_unless_a_subclass_overrides_its_methods():
    """The compiled step runs the track task's reward, observation values and info in C
    (envs/_signals.pyx, TRACK_METHODS); a subclass overriding one of them gets its Python
    methods called (with the override), the rest of the step still compiled."""
    class Harsh(SphereBotTrackEnv):
        def _get_rew(self, a0, a1):
            terms, done = super()._get_rew(a0, a1)
            return {**terms, "extra": -1.0}, done

    env, plain = Harsh(), SphereBotTrackEnv()
    try:
        env.reset(seed=2)
        plain.reset(seed=2)
        assert plain._loop.track and not env._loop.track and env._compiled_step
        a = np.array([0.5, 0.2], np.float32)
        for _ in range(5):
            r1, r2 = env.step(a), plain.step(a)
            assert r1[1] == r2[1] - 1.0
            assert list(r1[4]["reward_terms"]) == ["speed", "heading", "effort", "extra"]
    finally:
        env.close()
        plain.close()


def test_every_estimator_same_through_the_compiled_update():
    """The loop calls each estimator's compiled step directly (no Python update call): the
    same estimates as update() for every estimator."""
    import fusion
    actions = np.random.default_rng(2).uniform(0, 1, (60, 2))
    for name in fusion.available():
        ref = SphereRobotEnv(estimator=name, compiled=False, episode_s=1.0)
        ker = SphereRobotEnv(estimator=name, episode_s=1.0)
        try:
            assert_same(rollout(ref, actions, 1), rollout(ker, actions, 1))
        finally:
            ref.close()
            ker.close()
