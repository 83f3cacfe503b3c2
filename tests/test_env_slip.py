"""Wheel-floor slip (issue 15): low-friction patches on the floor (``slippery_patches``,
``patch_friction``). On a patch the drive slips, the encoder's dead reckoning drifts;
off the patches the episode is the flat floor's bit for bit; the slip converges with the
physics step; the flat floor's friction (0.6) is never exceeded by the drive."""
import math

import numpy as np
import pytest

from envs.sphere import SphereRobotEnv
from fusion.constants import GRAVITY


def _start_on_patch(env, seed):
    """Reset ``env`` (the first seed from ``seed`` on whose first patch has a radius of at
    least 1 m) with the shell's centre 0.8 radius west of the patch's centre, heading +x:
    1.6 m of patch ahead."""
    while True:
        env.reset(seed=seed)
        cx, cy, r2 = env._patches[0]
        if r2 >= 1.0:
            return env.reset(seed=seed, options={"start_xy": (cx - 0.8 * math.sqrt(r2), cy), "start_yaw": 0.0})
        seed += 1


def _slip_speed(env):
    """(m/s) the contact point's velocity along x: the true speed minus the shell's rolling
    speed (r times its absolute rate about the world y axis; the robot heads along +x)."""
    st = env.true_state()
    return st["velocity"][0] - env.robot.shell_radius * st["shell_rate"][1]


def _cm_velocity_x(env):
    """(m/s) the whole robot's centre-of-mass velocity along x (frame, shell, pendulum)."""
    p, c, b, rp = env._p, env._client, env._body, env.robot
    vf = p.getBaseVelocity(b, c)[0][0]
    vs = p.getLinkState(b, 0, computeLinkVelocity=1, physicsClientId=c)[6][0]
    vp = p.getLinkState(b, 1, computeLinkVelocity=1, physicsClientId=c)[6][0]
    return (rp.frame_mass * vf + rp.shell_mass * vs + rp.pendulum_mass * vp) / rp.total_mass


def test_the_drive_cannot_exceed_the_floor_friction():
    """Hand calculation: the largest traction the drive can ask for is its torque limit over
    r, shared between the robot's mass and the shell's inertia, tau/r * m/(m + I/r^2) = 0.97 N,
    against mu N = 0.6 * 11.3 N = 6.8 N. Measured: full drive, full steering and reversals on
    the flat floor never slip by more than 5 mm/s."""
    env = SphereRobotEnv(task="track", estimator="truth")
    rp = env.robot
    m, r = rp.total_mass, rp.shell_radius
    demand = rp.motor_torque_limit / r * m / (m + rp.shell_inertia / r ** 2)
    assert demand < 0.2 * rp.lateral_friction * m * GRAVITY
    env.reset(seed=0, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
    worst = 0.0
    for k in range(200):
        a = np.array([1.0 if (k // 50) % 2 == 0 else -1.0, 1.0 if k < 100 else 0.0], np.float32)
        env.step(a)
        st = env.true_state()
        v, w = st["velocity"], st["shell_rate"]
        slip = math.hypot(v[0] - r * w[1], v[1] + r * w[0])       # contact point: v + w x (0, 0, -r)
        worst = max(worst, slip)
    env.close()
    assert worst < 5e-3, worst


def test_on_a_patch_the_drive_slips_at_mu_g():
    """Full drive from rest on a patch (mu 0.05): the shell spins faster than the robot
    moves (rolling speed - true speed up to 0.35 m/s), and while it slips the centre of mass
    accelerates at mu g (hand calculation: the floor's only horizontal force is mu N, N = m g)."""
    mu = 0.05
    env = SphereRobotEnv(task="track", estimator="truth", slippery_patches=1, patch_friction=mu)
    _start_on_patch(env, seed=0)
    slips, vcm = [], []
    for _ in range(100):
        env.step(np.array([1.0, 0.0], np.float32))
        assert env._patch_on
        slips.append(-_slip_speed(env))
        vcm.append(_cm_velocity_x(env))
    env.close()
    slips = np.array(slips)
    assert slips.max() > 0.3, slips.max()
    # the slip phase (rolling speed ahead of the true speed by more than 5 cm/s): its mean
    # acceleration of the centre of mass
    k = np.flatnonzero(slips > 0.05)
    assert len(k) >= 40                   # about a second of slip
    a = (vcm[k[-1]] - vcm[k[0]]) / ((k[-1] - k[0]) / 50.0)
    assert a == pytest.approx(mu * GRAVITY, rel=0.05), a
    assert slips[-10:].max() < 5e-3       # caught up: rolling again


def test_dead_reckoning_drifts_on_a_patch_not_on_the_floor():
    """The encoder's dead reckoning (waypoints task, true attitude) after 3 s of full drive:
    on the flat floor within 1 cm of the truth, from a patch more than 20 cm behind."""
    errs = {}
    for patches in (0, 1):
        env = SphereRobotEnv(task="waypoints", estimator="truth", slippery_patches=patches)
        if patches:
            _start_on_patch(env, seed=1)
        else:
            env.reset(seed=1, options={"start_xy": (0.0, 0.0), "start_yaw": 0.0})
        for _ in range(150):
            _, _, _, _, info = env.step(np.array([1.0, 0.0], np.float32))
        errs[patches] = float(np.linalg.norm(info["position_est"] - info["position"][:2]))
        env.close()
    assert errs[0] < 0.01, errs
    assert errs[1] > 0.2, errs


def test_off_the_patches_the_episode_is_the_flat_floors():
    """Patches are drawn after every other draw of the reset and act only under the shell:
    an episode that never reaches one is the flat floor's, bit for bit."""
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1, 1, (100, 2)).astype(np.float32)
    for seed in range(20):
        env = SphereRobotEnv(task="waypoints", estimator="ekf", slippery_patches=2)
        env.reset(seed=seed)
        if min(math.hypot(x, y) - math.sqrt(r2) for x, y, r2 in env._patches) > 3.0:
            break
        env.close()
    runs = []
    for e in (SphereRobotEnv(task="waypoints", estimator="ekf"), env):
        obs, _ = e.reset(seed=seed)
        out = [obs]
        for a in actions:
            out.append(e.step(a)[0])
            assert not e._patch_on
        runs.append(np.array(out))
        e.close()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_slip_event_converges_with_the_physics_step():
    """A slip event (full drive from rest on a patch, 2 s) at 400 Hz and at 800 Hz (half the
    step): distance travelled within 1 cm, slip distance (rolled minus travelled) within 2 %
    (measured: 0.943 / 0.942 m and 0.2605 / 0.2604 m)."""
    res = []
    for hz in (400.0, 800.0):
        env = SphereRobotEnv(task="track", estimator="truth", slippery_patches=1, physics_hz=hz)
        _start_on_patch(env, seed=0)
        st = env.true_state()
        x0, q0 = st["position"][0], st["drive_angle"]
        for _ in range(100):
            env.step(np.array([1.0, 0.0], np.float32))
        st = env.true_state()
        R = st["rotation"]
        pitch = math.atan2(-R[2, 0], R[0, 0])               # the frame's, about the axle (started level)
        travel = st["position"][0] - x0
        rolled = env.robot.shell_radius * (st["drive_angle"] - q0 + pitch)
        res.append((travel, rolled - travel))
        env.close()
    (t1, s1), (t2, s2) = res
    assert s1 > 0.2
    assert abs(t1 - t2) < 0.01, res
    assert abs(s1 - s2) < 0.02 * s2, res


def test_patches_in_the_scenario_and_their_draws():
    from controllers.compare import SCENARIOS
    env = SphereRobotEnv(task="track", estimator="truth", **SCENARIOS["disturbed"])
    env.reset(seed=0)
    assert len(env._patches) == SCENARIOS["disturbed"]["slippery_patches"] > 0
    half = 0.5 * env.arena_size - 1.0
    for x, y, r2 in env._patches:
        assert abs(x) <= half and abs(y) <= half and 0.5 <= math.sqrt(r2) <= 1.5
    env.close()


@pytest.mark.parametrize("name, value", [("slippery_patches", -1), ("slippery_patches", 1.5),
                                         ("slippery_patches", True), ("slippery_patches", 1001),
                                         ("patch_friction", -0.1), ("patch_friction", 1.5),
                                         ("patch_friction", float("nan")), ("patch_friction", "low")])
def test_patch_arguments_are_range_checked(name, value):
    with pytest.raises(ValueError, match=name):
        SphereRobotEnv(task="track", **{name: value})
