"""The real robot's imperfections (v1 defaults): each on by default, each measurable, each
switched off by realism="ideal" or its RobotParams field = 0. docs/envs/robot.md, "Realism"."""
import math

import numpy as np
import pytest

from envs.robot import RobotParams
from envs.sphere import SphereRobotEnv


def _steady_acc(robot=None, realism="real", drive=0.6, seconds=4.0):
    env = SphereRobotEnv(estimator="truth", imu="ideal", arena_size=60.0, robot=robot, realism=realism)
    env.reset(seed=0, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    for _ in range(150):
        env.step((drive, 0.0))
    log = env.enable_signal_log()
    for _ in range(int(seconds * 50)):
        env.step((drive, 0.0))
    env.close()
    return np.array([s.acc for *_, s in log if s is not None]), log


def test_drive_vibration_at_0_6_voltage():
    acc, _ = _steady_acc()
    assert np.linalg.norm(acc, axis=1).std() >= 0.1          # issue 15's target
    acc0, _ = _steady_acc(realism="ideal")
    assert np.linalg.norm(acc0, axis=1).std() < 0.01
    # the tones scale with speed: slower rolling, less vibration
    slow, _ = _steady_acc(drive=0.3)
    assert np.linalg.norm(slow, axis=1).std() < np.linalg.norm(acc, axis=1).std()


def test_vibration_is_the_same_at_4x_the_physics_rate():
    def std(hz):
        env = SphereRobotEnv(estimator="truth", imu="ideal", arena_size=60.0, physics_hz=hz)
        env.reset(seed=0, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
        log = env.enable_signal_log()
        for _ in range(250):
            env.step((0.6, 0.0))
        env.close()
        return np.linalg.norm([s.acc for *_, s in log[len(log) // 2:] if s is not None], axis=1).std()
    a, b = std(400.0), std(1600.0)
    assert abs(a - b) < 0.05 * b, (a, b)


def test_deadband_and_stiction_hold_the_robot_at_small_voltage():
    # 1.9 % of full voltage: inside the real driver's 2 % deadband; 3.5 % with no deadband:
    # the gearbox's 0.03 N m stiction needs 5.3 % to break away (0.03 N m x 12 ohm / 0.925)
    for realism, robot, u, moves in (("real", None, 0.019, False), ("ideal", None, 0.019, True),
                                     ("real", {"motor_deadband": 0.0}, 0.035, False),
                                     ("real", {"motor_deadband": 0.0}, 0.08, True)):
        env = SphereRobotEnv(estimator="truth", imu="ideal", realism=realism, robot=robot)
        env.reset(seed=0)
        p0 = env.true_state()["position"].copy()
        for _ in range(200):
            env.step((u, 0.0))
        moved = np.linalg.norm(env.true_state()["position"] - p0)
        env.close()
        assert (moved > 0.01) == moves, (realism, robot, u, moved)


def test_steering_moves_the_magnetometer_offset():
    """The pendulum's field turns with the steering: the field at the IMU minus the earth
    field in the body frame follows R_x(q) (0, 0, -mag_steer) + (0, 0, mag_steer)."""
    rp = RobotParams(mag_current=0.0)
    env = SphereRobotEnv(estimator="truth", imu="ideal", robot=rp)
    env.reset(seed=0)
    for _ in range(40):
        env.step((0.0, 1.0))
    st = env.true_state()
    mag = np.array(env._true[5])
    earth = st["rotation"].T @ np.array(env.earth_field)
    q = st["steer_angle"]
    assert q > math.radians(25)
    expect = rp.mag_steer * np.array([0.0, math.sin(q), 1.0 - math.cos(q)])
    np.testing.assert_allclose(mag - earth, expect, atol=0.01)      # angle read one physics step earlier
    env.close()


def test_latency_delays_the_command():
    def first_motion(latency):
        env = SphereRobotEnv(estimator="truth", imu="ideal", robot={"latency_s": latency})
        env.reset(seed=0)
        log = env.enable_signal_log()
        env.step((0.0, 1.0))
        env.close()
        ang = np.array([np.linalg.norm(row[3]) for row in log])
        return int(np.argmax(ang > 1e-3))
    assert first_motion(0.01) - first_motion(0.0) == 4        # 10 ms = 4 steps at 400 Hz


@pytest.mark.parametrize("field, value", [("latency_s", 0.5), ("motor_deadband", -0.1), ("steer_band", 2.0),
                                          ("contact_stiffness", -1.0), ("vib_motor", math.nan),
                                          ("mag_steer", 1e6), ("battery_resistance", "x")])
def test_realism_parameters_are_range_checked(field, value):
    with pytest.raises(ValueError, match=f"robot.{field}"):
        SphereRobotEnv(robot={field: value})


def test_latency_longer_than_the_control_period_is_refused():
    with pytest.raises(ValueError, match="robot.latency_s"):
        SphereRobotEnv(robot={"latency_s": 0.05}, control_hz=50.0)
    with pytest.raises(ValueError, match="realism"):
        SphereRobotEnv(realism="perfect")


def test_ideal_params_are_all_zero_and_v0_ids_use_them():
    import gymnasium as gym
    import envs  # noqa: F401
    assert RobotParams.ideal().is_ideal and not RobotParams().is_ideal
    env = gym.make("SphereBotTrack-v0", estimator="truth")
    assert env.unwrapped.robot.is_ideal
    env.close()
    env = gym.make("SphereBotTrack-v1", estimator="truth")
    assert env.unwrapped.robot == RobotParams()
    env.close()


def test_top_speed_matches_the_hand_calculation():
    """Steady rolling at full voltage: the drive's torque (current-limited motor line minus
    viscous and Coulomb gearbox friction, the pack sagging under the motor's and the
    electronics' current) equals the floor's loss on the shell (rolling damping c w plus the
    rolling resistance Crr N r). Solved by hand for w; the env must roll at w r within 1 %."""
    from envs.robot import IDLE_CURRENT
    for realism in ("real", "ideal"):
        rp = RobotParams() if realism == "real" else RobotParams.ideal()
        k, R, b = rp.motor_k, rp.motor_resistance, rp.motor_friction
        t_rr = rp.rolling_resistance * rp.total_mass * 9.81 * rp.shell_radius
        w = 0.0
        for _ in range(50):                                   # fixed point in the sag
            i = (0.0 if w == 0 else (t_rr + rp.rolling_damping * w + b * w + rp.drive_coulomb) / k)
            v = rp.motor_voltage * (1 - rp.battery_resistance * (i + IDLE_CURRENT) / rp.motor_voltage)
            w = (k / R * v - rp.drive_coulomb - t_rr) / (k * k / R + b + rp.rolling_damping)
        env = SphereRobotEnv(estimator="truth", imu="ideal", arena_size=60.0, realism=realism)
        env.reset(seed=0, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
        for _ in range(400):
            env.step((1.0, 0.0))
        v_env = float(np.hypot(*env.true_state()["velocity"][:2]))
        env.close()
        assert v_env == pytest.approx(w * rp.shell_radius, rel=0.01), (realism, v_env, w * rp.shell_radius)


def test_contact_too_soft_to_carry_the_robot_is_refused():
    """A compliant contact must carry the robot's weight: contact_stiffness 1e-6 N/m was
    accepted and the robot started 1.1e7 m below the floor and fell through it (a finite,
    silently wrong episode). The static sink m g / k is bounded by a tenth of the radius."""
    with pytest.raises(ValueError, match="robot.contact_stiffness"):
        SphereRobotEnv(robot={"contact_stiffness": 1e-6, "contact_damping": 1e-6})
    p = RobotParams(contact_stiffness=1000.0)          # 11 mm sink under 1.15 kg: accepted
    assert p.total_mass * 9.81 / p.contact_stiffness <= 0.1 * p.shell_radius
