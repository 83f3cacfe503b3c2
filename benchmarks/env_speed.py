"""Speed of the spherical-robot environment (targets in issue 5, numbers in docs/envs/).

    .venv/bin/python benchmarks/env_speed.py            # full run (10,000 resets: about a minute)
    .venv/bin/python benchmarks/env_speed.py --quick    # 1,000 resets
    .venv/bin/python benchmarks/env_speed.py --breakdown  # CPU time of the parts of a step
    .venv/bin/python benchmarks/env_speed.py --rates      # only the env against PyBullet's limit

Prints, in one run on one core:
  - the raw PyBullet step rate of the same world (stepSimulation only, and with the drive
    motor's per-step joint read and torque command), the floor under everything else;
  - environment steps per second at the defaults (50 Hz control, 200 Hz IMU, 400 Hz physics)
    with estimator="ekf" and with "truth", and the estimator's share of the step time;
  - the share of that limit the env reaches with "ekf" and "truth" (issue 16: >= 75 %),
    by CPU time and wall clock, each chunk of env steps against the limit measured around
    it, medians over the rounds with their range; the env is made as users make it
    (``gymnasium.make``), and a do-nothing env under the same wrappers says what they add;
  - robot steps per second of the batched vector env of 16 robots against one environment;
  - reset() time (mean, median, 99th percentile);
  - resident memory before and after N resets in one process, and whether physics clients
    leak (1,000 environments created and closed, 100 with --quick: the client slot must be
    reused and memory must not grow);
  - the physics-rate convergence check behind the 400 Hz default (``envs.convergence``: the
    hardest inputs of the action space at 400 and 1600 Hz; also ``tests/test_env_convergence.py``).
"""
import argparse
import gc
import os
import sys
import time

import numpy as np
import pybullet as p

from envs import convergence
from envs.robot import DCMotor, RobotParams, Servo, build_robot
from envs.sphere import SphereRobotEnv
from fusion.constants import GRAVITY


def rss_mb():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def pin_one_core():
    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        return True
    except (AttributeError, OSError):
        return False


class RawWorld:
    """The environment's world in PyBullet alone: stepSimulation only, and with the
    environment's per-step PyBullet calls: one joint read (both joints), one torque command
    (drive and servo), one external torque (the floor's spinning and rolling losses)."""

    def __init__(self):
        params = RobotParams()
        self.motor, self.servo = DCMotor(params), Servo(params)
        c = self.c = p.connect(p.DIRECT)
        p.resetSimulation(physicsClientId=c)
        p.setGravity(0, 0, -GRAVITY, physicsClientId=c)
        p.setPhysicsEngineParameter(fixedTimeStep=1 / 400.0, deterministicOverlappingPairs=1, physicsClientId=c)
        floor = p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c), physicsClientId=c)
        p.changeDynamics(floor, -1, lateralFriction=1.0, physicsClientId=c)
        self.b = build_robot(p, c, params, (0, 0), 0.0)

    def plain(self, steps):
        c = self.c
        t = time.perf_counter()
        for _ in range(steps):
            p.stepSimulation(c)
        return steps / (time.perf_counter() - t)

    def with_motor(self, steps, reads=False):
        """(wall-clock, CPU-time) physics steps/s; ``reads``: also the two base-state reads
        (pose, velocity) the true IMU signals need."""
        b, c, motor, servo = self.b, self.c, self.motor, self.servo
        joints, zero = (0, 1), (0.0, 0.0)
        cpu = time.thread_time()
        t = time.perf_counter()
        for _ in range(steps):
            js = p.getJointStates(b, joints, c)
            tau = motor.torque(3.0, js[0][1])
            ts = servo.torque(0.2, js[1][0], js[1][1])
            # the env loop's call form (envs/_signals.pyx): positional, torque mode reads the forces only
            p.setJointMotorControlArray(b, joints, p.TORQUE_CONTROL, zero, zero, (tau, ts), zero, zero, c)
            p.applyExternalTorque(b, 0, (0.0, 0.0, 0.0), p.WORLD_FRAME, physicsClientId=c)
            p.stepSimulation(c)
            if reads:
                p.getBasePositionAndOrientation(b, c)
                p.getBaseVelocity(b, c)
        return steps / (time.perf_counter() - t), steps / (time.thread_time() - cpu)

    def close(self):
        p.disconnect(self.c)


class _TimedUpdate:
    """Wraps an estimator and adds up the wall time spent inside its update calls."""

    def __init__(self, inner):
        self.inner, self.spent, self.calls = inner, 0.0, 0

    def update(self, *a):
        t0 = time.perf_counter()
        q = self.inner.update(*a)
        self.spent += time.perf_counter() - t0
        self.calls += 1
        return q

    def __getattr__(self, name):
        return getattr(self.inner, name)


def vector_rates(n=16, steps=200, repeats=3):
    """Best robot steps/s of one environment and of the batched vector env of ``n`` robots
    (envs/vector.py), runs interleaved, waypoints task with ekf (CPU time of this process)."""
    import gymnasium as gym
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, n, 2)).astype(np.float32)
    actions[..., 0] = np.abs(actions[..., 0]) * 0.8
    single = gym.make("SphereBotWaypoints-v1", estimator="ekf")
    batched = gym.make_vec("SphereBotWaypoints-v1", num_envs=n, vectorization_mode="vector_entry_point",
                           estimator="ekf")
    best = [0.0, 0.0]
    for r in range(repeats):
        single.reset(seed=r)
        t = time.process_time()
        for a in actions:
            if any(single.step(a[0])[2:4]):
                single.reset()
        best[0] = max(best[0], steps / (time.process_time() - t))
        batched.reset(seed=r)
        t = time.process_time()
        for a in actions:
            batched.step(a)
        best[1] = max(best[1], n * steps / (time.process_time() - t))
    single.close()
    batched.close()
    return best


def env_rates(estimators, steps, repeats=9):
    """Each contender's env steps/s against PyBullet's limit measured right around it: the raw
    world (physics steps with the env's per-step calls, ``8 * steps``) runs before and after
    every chunk of ``steps`` env steps, and the contenders take turns, ``repeats`` rounds
    (so that load changes on a shared machine hit the env and its limit alike). Contenders:
    each estimator's environment as users make it (``gymnasium.make``: with its wrappers).
    Episodes run on across the chunks (resets where they end, as in training). Returns per chunk and
    contender env steps/s, by wall clock and by CPU time (thread_time: less sensitive to the
    other jobs), each with the mean of its two limits (key (name, "limit"), env steps/s =
    physics steps/s / 8), and the measured time inside est.update per env step (us)."""
    import gymnasium as gym
    envs_ = {e: gym.make("SphereBotTrack-v1", estimator=e) for e in estimators}
    raw = RawWorld()
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps * repeats, 2)).astype(np.float32)
    actions[:, 0] = np.abs(actions[:, 0]) * 0.8          # mostly forward, changing steering
    wall = {k: [] for e in envs_ for k in (e, (e, "limit"))}
    cpu = {k: [] for k in wall}
    for env in envs_.values():
        env.reset(seed=0)
    last = raw.with_motor(8 * steps)
    for r in range(repeats):
        chunk = actions[r * steps:(r + 1) * steps]
        for e, env in envs_.items():
            c0 = time.thread_time()
            t = time.perf_counter()
            for a in chunk:
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    env.reset()
            wall[e].append(steps / (time.perf_counter() - t))
            cpu[e].append(steps / (time.thread_time() - c0))
            now = raw.with_motor(8 * steps)
            wall[e, "limit"].append((last[0] + now[0]) / 16)
            cpu[e, "limit"].append((last[1] + now[1]) / 16)
            last = now
    raw.close()
    update_us = {}
    for e, env in envs_.items():
        u = env.unwrapped
        est = u._est
        if est is not None:                                # the estimator's own cost per env step
            # (not an Estimator: the loop calls its Python update(), and the bias and skipped
            # counts through Python, the slower path; wall clock)
            timed = u._est = _TimedUpdate(est)
            env.reset(seed=0)
            n = min(2000, len(actions))
            for a in actions[:n]:
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    env.reset()
            u._est = est
            update_us[e] = timed.spent / n * 1e6
        env.close()
    return {k: np.array(v) for k, v in wall.items()}, {k: np.array(v) for k, v in cpu.items()}, update_us


def wrapper_cost(steps=200_000):
    """CPU time (us) per step that ``gymnasium.make``'s wrappers (TimeLimit, OrderEnforcing,
    PassiveEnvChecker) add: a do-nothing environment with and without them, best of 5."""
    import gymnasium as gym

    class Null(gym.Env):
        observation_space = action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            return np.zeros(2, np.float32), {}

        def step(self, action):
            return np.zeros(2, np.float32), 0.0, False, False, {}

    gym.register("EnvSpeedNull-v0", entry_point=Null, max_episode_steps=10 * steps)
    a = np.zeros(2, np.float32)
    best = {}
    for name, env in (("bare", Null()), ("made", gym.make("EnvSpeedNull-v0"))):
        env.reset(seed=0)
        env.step(a)
        best[name] = float("inf")
        for _ in range(5):
            t = time.thread_time()
            for _ in range(steps):
                env.step(a)
            best[name] = min(best[name], (time.thread_time() - t) / steps * 1e6)
    gym.registry.pop("EnvSpeedNull-v0")
    return best["made"] - best["bare"]


def _share(rates, key):
    """(median, lowest, highest) over the rounds of the share of PyBullet's limit."""
    r = rates[key] / rates[key, "limit"]
    return float(np.median(r)), float(r.min()), float(r.max())


def breakdown(rounds=12, steps=250):
    """CPU time per env step (8 physics steps) of: PyBullet's limit (the raw world with the
    env's per-step calls), the same plus the two state reads the true signals need (base
    pose, base velocity), the env's physics loop alone (``_advance``), the whole ``step`` with
    ``ekf`` and ``truth``, and the Python reference of the loop (``compiled=False``). Medians of
    ``rounds`` interleaved rounds of ``steps`` env steps each."""
    raw = RawWorld()

    import gymnasium as gym
    envs_ = {"step, ekf": SphereRobotEnv(task="track", estimator="ekf"),
             "step, ekf, gymnasium.make (its wrappers)": gym.make("SphereBotTrack-v1", estimator="ekf"),
             "step, truth": SphereRobotEnv(task="track", estimator="truth"),
             "step, ekf, Python reference": SphereRobotEnv(task="track", estimator="ekf", compiled=False)}
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, 2)).astype(np.float32)
    actions[:, 0] = np.abs(actions[:, 0]) * 0.8
    res = {"PyBullet's limit": [], "+ base pose and velocity reads": [], "physics loop (_advance), ekf": []}
    res.update({k: [] for k in envs_})
    for env in envs_.values():
        env.reset(seed=0)
    for _ in range(rounds):
        res["PyBullet's limit"].append(8.0 / raw.with_motor(8 * steps)[1])
        res["+ base pose and velocity reads"].append(8.0 / raw.with_motor(8 * steps, reads=True)[1])
        for k, env in envs_.items():
            t = time.thread_time()
            for a in actions:
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    env.reset()
            res[k].append((time.thread_time() - t) / steps)
        env = envs_["step, ekf"]
        t = time.thread_time()
        for a in actions:
            env._advance(env._n_sub, float(a[0]) * env.robot.motor_voltage, float(a[1]) * env.robot.steer_max)
        res["physics loop (_advance), ekf"].append((time.thread_time() - t) / steps)
        env.reset()
    raw.close()
    for env in envs_.values():
        env.close()
    ref = float(np.median(res["PyBullet's limit"]))
    print(f"CPU time per env step, medians of {rounds} interleaved rounds of {steps} steps:")
    print("| | us | share of PyBullet's limit |\n|---|---|---|")
    for k, v in res.items():
        m = float(np.median(v))
        print(f"| {k} | {m * 1e6:.1f} | {ref / m:.1%} |")


def step_scaling(counts=(1, 2, 4, 8, 16), steps=2000, rounds=3):
    """CPU time of one ``stepSimulation`` per robot with N robots in one client, rolling
    (constant drive torque): side by side as envs/vector.py places them (every robot at the
    same place, collisions between robots filtered out, one floor), and spread 3 m apart on
    a grid (no filter needed: their shapes never overlap in the broadphase). Best of
    ``rounds``; what bounds the batched vector env's speed per core."""
    params = RobotParams()
    print(f"stepSimulation CPU time per robot (us), N robots in one client, 400 Hz, best of {rounds} x {steps} steps:")
    print("| N | same place, pairs filtered | 3 m apart | step per robot / one robot's (same place, apart) |")
    print("|---|---|---|---|")
    one = None
    for n in counts:
        res = []
        for spread in (False, True):
            c = p.connect(p.DIRECT)
            p.setGravity(0, 0, -GRAVITY, physicsClientId=c)
            p.setPhysicsEngineParameter(fixedTimeStep=1 / 400.0, deterministicOverlappingPairs=1, physicsClientId=c)
            floor = p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c), physicsClientId=c)
            p.changeDynamics(floor, -1, lateralFriction=1.0, physicsClientId=c)
            side = int(np.ceil(np.sqrt(n)))
            bodies = [build_robot(p, c, params, ((i % side) * 3.0, (i // side) * 3.0) if spread else (0, 0), 0.0)
                      for i in range(n)]
            if not spread:
                for i, a in enumerate(bodies):
                    for bb in bodies[i + 1:]:
                        for la in (-1, 0, 1):
                            for lb in (-1, 0, 1):
                                p.setCollisionFilterPair(a, bb, la, lb, 0, physicsClientId=c)
            for b in bodies:
                p.setJointMotorControlArray(b, (0, 1), p.TORQUE_CONTROL, forces=(0.05, 0.0), physicsClientId=c)
            for _ in range(200):
                p.stepSimulation(c)
            best = float("inf")
            for _ in range(rounds):
                t = time.thread_time()
                for _ in range(steps):
                    p.stepSimulation(c)
                best = min(best, (time.thread_time() - t) / steps / n)
            p.disconnect(c)
            res.append(best * 1e6)
        if one is None:
            one = res
        print(f"| {n} | {res[0]:.2f} | {res[1]:.2f} | {res[0] / one[0]:.2f}, {res[1] / one[1]:.2f} |", flush=True)


def reset_times(n=300):
    env = SphereRobotEnv(estimator="ekf")
    env.reset(seed=0)
    ts = []
    for i in range(n):
        t = time.perf_counter()
        env.reset(seed=i)
        ts.append(time.perf_counter() - t)
    env.close()
    ts = np.array(ts) * 1e3
    return ts.mean(), np.median(ts), np.percentile(ts, 99)


def reset_memory(n, n_cycles):
    env = SphereRobotEnv(estimator="ekf", bumps=5, mag_zones="random")
    for i in range(100):                                   # warm-up: caches, allocator
        env.reset(seed=i)
        env.step([0.5, 0.1])
    gc.collect()
    before = rss_mb()
    t = time.perf_counter()
    for i in range(n):
        env.reset(seed=i)
        if i % 10 == 0:
            env.step([0.5, 0.1])
    el = time.perf_counter() - t
    gc.collect()
    after = rss_mb()
    env.close()
    # client leak: create and close environments (with an estimator, as users do);
    # PyBullet reuses a freed client slot, and memory must not grow per cycle
    ids = []
    gc.collect()
    cyc_before = rss_mb()
    for i in range(n_cycles):
        e = SphereRobotEnv(estimator="ekf")
        e.reset(seed=i)
        ids.append(e._client)
        e.close()
    gc.collect()
    cyc_after = rss_mb()
    return before, after, el / n * 1e3, max(ids), len(set(ids)), cyc_before, cyc_after


def print_rates(steps, repeats):
    """The env's steps/s against PyBullet's limit (env_rates), as a table."""
    raw = RawWorld()
    plain = raw.plain(20000)
    raw.close()
    wall, cpu, update_us = env_rates(["ekf", "truth"], steps, repeats)
    med = {k: float(np.median(v)) for k, v in cpu.items()}
    lim = float(np.median(np.concatenate([v for k, v in cpu.items() if isinstance(k, tuple)])))
    print(f"raw PyBullet, 400 Hz world: {plain:,.0f} stepSimulation/s (wall clock); with the env's joint read, "
          f"torque command and floor-loss torque (PyBullet's limit): {8 * lim:,.0f}/s by CPU time = {lim:,.0f} "
          "env steps/s at 8 physics steps each (median of the runs)")
    print(f"{repeats} rounds, chunks of {steps:,} env steps (gymnasium.make('SphereBotTrack-v1'), 50 Hz "
          "control, 200 Hz IMU mpu9250, 400 Hz physics), each against the limit measured before and after it; "
          "medians [lowest, highest] over the rounds:")
    print("| | env steps/s, CPU time | share of PyBullet's limit, CPU time | share, wall clock |\n|---|---|---|---|")
    for k, name in (("ekf", "ekf"), ("truth", "truth")):
        c, w = _share(cpu, k), _share(wall, k)
        print(f"| {name} | {med[k]:,.0f} | {c[0]:.1%} [{c[1]:.1%}, {c[2]:.1%}] | {w[0]:.1%} [{w[1]:.1%}, {w[2]:.1%}] |")
    c = _share(cpu, "ekf")
    verdict = "met" if c[0] >= 0.75 else "NOT met"
    print(f"  target (issue 16) >= 75 % of the limit with ekf (CPU time, median): {verdict}")
    print(f"  of which gymnasium.make's wrappers (TimeLimit, OrderEnforcing, PassiveEnvChecker): "
          f"{wrapper_cost():.2f} us per step (measured on a do-nothing env with and without them)")
    share_diff = 1.0 - med["ekf"] / med["truth"]
    share_direct = update_us["ekf"] * 1e-6 * med["ekf"]
    print(f"  estimator share of the ekf step time: {100 * share_diff:.1f} % from the two rates, "
          f"{100 * share_direct:.1f} % timed around a wrapped est.update ({update_us['ekf']:.1f} us per env step, "
          f"the Python update path, wall clock); "
          f"target >= 2,000 steps/s with ekf: {'met' if med['ekf'] >= 2000 else 'NOT met'}; "
          f"estimator share < 10 %: {'met' if max(share_diff, share_direct) < 0.10 else 'NOT met'}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="1,000 resets instead of 10,000")
    ap.add_argument("--steps", type=int, default=2000, help="env steps per timing round")
    ap.add_argument("--repeats", type=int, default=9, help="interleaved timing rounds")
    ap.add_argument("--scaling", action="store_true",
                    help="only stepSimulation's time per robot with N robots in one client (the vector env's floor)")
    ap.add_argument("--rates", action="store_true",
                    help="only the env's steps/s against PyBullet's limit (the interleaved rounds)")
    ap.add_argument("--breakdown", action="store_true",
                    help="only the CPU-time breakdown of an env step (PyBullet, physics loop, the rest)")
    args = ap.parse_args()
    pinned = pin_one_core()
    print(f"one core: {'pinned' if pinned else 'not pinned'}; python {sys.version.split()[0]}")
    if args.breakdown:
        breakdown()
        return
    if args.scaling:
        step_scaling()
        return

    print_rates(args.steps, args.repeats)
    if args.rates:
        return

    one, many = vector_rates(16, 100 if args.quick else 300)
    print(f"batched vector env (envs/vector.py), 16 robots in one client, waypoints, ekf: {many:,.0f} robot steps/s "
          f"against {one:,.0f} for one environment: {many / one:.2f}x per core (target >= 3x: "
          f"{'met' if many / one >= 3 else 'NOT met'})")

    mean, med, p99 = reset_times()
    print(f"reset(): mean {mean:.2f} ms, median {med:.2f} ms, p99 {p99:.2f} ms  "
          f"(target < 10 ms: {'met' if mean < 10 else 'NOT met'})")

    n = 1000 if args.quick else 10000
    n_cycles = 100 if args.quick else 1000
    before, after, per, max_id, distinct, cb, ca = reset_memory(n, n_cycles)
    print(f"{n:,} resets in one process: RSS {before:.1f} MB -> {after:.1f} MB "
          f"(growth {after - before:+.1f} MB; target < 50 MB: {'met' if after - before < 50 else 'NOT met'}), "
          f"{per:.2f} ms per reset")
    print(f"{n_cycles:,} environments created, reset and closed: {distinct} client slot(s) used "
          f"(highest id {max_id}); RSS {cb:.1f} MB -> {ca:.1f} MB (growth {ca - cb:+.1f} MB)")

    convergence.main(400.0)


if __name__ == "__main__":
    main()
