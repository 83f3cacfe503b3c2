"""The default physics rate (400 Hz) against 4x (1600 Hz) under the hardest inputs of the
action space (envs/convergence.py; the measured table is in docs/envs/robot.md, "Rates"),
and the sideways rocking after a hard turn decaying."""
import math

import numpy as np
import pytest

from envs.convergence import SCENARIOS, bump_agreement, compare, mpu9250_16g
from envs.sphere import SphereRobotEnv


def _rel(p):
    return abs(p[0] - p[1]) / abs(p[1])


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_default_rate_matches_4x(name):
    c = compare(name, 400.0)
    bumps = name.startswith("bumps")
    # trajectory: 10 s at up to 1 m/s (bumps: four crossings cost speed, hence 0.2 m)
    assert c["dpos_m"] < (0.2 if bumps else 0.05), c
    assert c["dheading_deg"] < 1.0, c
    assert abs(c["roll_pp"][0] - c["roll_pp"][1]) < 3.0, c
    # IMU statistics (ideal IMU): 5 % smooth, 20 % through impacts
    assert _rel(c["acc_std"]) < (0.2 if bumps else 0.05), c
    assert _rel(c["gyr_std"]) < 0.05, c
    if bumps:
        assert c["acc_peak"][1] > 10.0, c           # the bumps were hit (flat runs: < 7)
        assert _rel(c["mpu_peak"]) < 0.2, c          # the chip's (DLPF) peak reading
        assert _rel(c["acc_peak"]) < 0.25, c         # point samples of the ideal IMU


@pytest.mark.parametrize("drive", [1.0, 0.6])
def test_each_bump_peak_matches_4x(drive):
    """Bump by bump, not only the largest peak of a run: every crossing's peak |acc| - g at
    the IMU within 20 % between 400 and 1600 Hz, for the ideal IMU (point samples of the step
    mean) and the MPU-9250 at +-16 g (its DLPF). The stiffer, more damped contact of v1's
    first version (3e4 N/m, zeta 0.5) failed this: worst bumps -31 % / -24 % at full drive,
    -35 % / -16 % at 0.6 (docs/envs/robot.md, "Contact")."""
    for imu in ("ideal", mpu9250_16g(16)):
        a, b = bump_agreement(drive, imu)           # 400 and 1600 Hz, the bumps both crossed
        assert len(a) >= (7 if drive == 1.0 else 4), (a, b)
        diff = a / b - 1.0
        assert np.abs(diff).max() < 0.2, (imu, diff)


def test_rocking_decay_rate_converges_and_400_hz_underdamps_it_by_a_fifth():
    """The sideways rocking's decay rate after a hard turn (envs.convergence.rocking_decay):
    PyBullet's multibody step adds energy to it in proportion to the step (with no losses the
    rocking grows, faster the longer the step), so the default 400 Hz damps it about 19 % less
    than the converged rate (0.147 against 0.181 /s at 3200 Hz; 800 Hz 0.167, 1600 Hz 0.176).
    Pinned here, and stated in docs/envs/robot.md: the rate converges as the step halves, and
    the default's error stays what the docs say (at most 22 %)."""
    from envs.convergence import rocking_decay
    r = {hz: rocking_decay(hz) for hz in (400.0, 800.0, 1600.0, 3200.0)}
    assert r[400.0] < r[800.0] < r[1600.0] < r[3200.0], r
    assert r[3200.0] - r[1600.0] < 0.6 * (r[1600.0] - r[800.0]), r       # halving the step halves the error
    assert 0.15 < 1.0 - r[400.0] / r[3200.0] < 0.22, r
    assert 1.0 - r[1600.0] / r[3200.0] < 0.05, r


def test_rocking_after_hard_turn_decays():
    env = SphereRobotEnv(estimator="truth", imu="ideal", arena_size=60.0, episode_s=20.0)
    env.reset(seed=1, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    roll = []
    for k in range(15 * 50):
        t = k / 50
        env.step((1.0, 1.0 if 1.0 < t < 4.0 else 0.0))
        R = env.true_state()["rotation"]
        roll.append(math.degrees(math.asin(max(-1.0, min(1.0, R[2, 1])))))
    env.close()
    r = np.array(roll)
    early, late = np.ptp(r[5 * 50:7 * 50]), np.ptp(r[13 * 50:15 * 50])
    assert early > 10.0                     # the turn did excite the rocking
    assert late < 0.5 * early, (early, late)


def test_ideal_robot_is_undamped():
    """realism='ideal' really switches the losses off: the same release rocks on."""
    out = []
    for realism in ("real", "ideal"):
        env = SphereRobotEnv(estimator="truth", imu="ideal", arena_size=60.0, episode_s=20.0, realism=realism)
        env.reset(seed=1, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
        roll = []
        for k in range(12 * 50):
            env.step((1.0, 1.0 if 1.0 < k / 50 < 4.0 else 0.0))
            R = env.true_state()["rotation"]
            roll.append(math.degrees(math.asin(max(-1.0, min(1.0, R[2, 1])))))
        env.close()
        out.append(np.ptp(np.array(roll)[10 * 50:]))
    assert out[1] > 2 * out[0], out
