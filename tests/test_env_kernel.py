"""The environment's compiled per-physics-step path (envs/_signals.pyx, fusion/_imu.pyx)
against its Python reference (``compiled=False``): same seed, same actions, the same
trajectories and observations."""
import numpy as np
import pytest

from envs.sphere import SphereRobotEnv


def rollout(env, actions, seed, log_from=None):
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    for i, a in enumerate(actions):
        if log_from is not None and i == log_from:
            env.enable_signal_log()             # the Python path takes over ...
        if log_from is not None and i == log_from + 20:
            env.disable_signal_log()            # ... and hands back
        obs, r, term, trunc, info = env.step(a)
        out.append((obs, r, info))
        if term or trunc:
            obs, info = env.reset()
            out.append((obs, 0.0, info))
    return out


def assert_same(a, b):
    assert len(a) == len(b)
    for (oa, ra, ia), (ob, rb, ib) in zip(a, b):
        np.testing.assert_allclose(oa, ob, rtol=0, atol=1e-12)
        assert abs(ra - rb) <= 1e-12
        for k in ("q_est", "q_true", "position", "velocity"):
            np.testing.assert_allclose(ia[k], ib[k], rtol=0, atol=1e-12)
        for k in ("attitude_error_deg", "heading_est", "motor_torque", "encoder_speed"):
            assert abs(ia[k] - ib[k]) <= 1e-12, k
        assert ia["imu_samples"] == ib["imu_samples"]
        assert ia["estimator_skipped"] == ib["estimator_skipped"]


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
