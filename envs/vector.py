"""N robots of one task in one process and one PyBullet client: a Gymnasium ``VectorEnv``
(``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``) and an
SB3 ``VecEnv`` adapter (``SB3VecEnv``).

Every robot has its own floor and obstacles at the same place in the one world, and the
collisions between one robot's bodies and every other robot's are filtered out, so the
robots never meet; positions keep the single environment's coordinates (no far-away
arenas, whose large coordinates would round differently). Each physics step commands every
robot, steps the world once and senses every robot.

Resets: ``reset()`` resets every robot, their settling (``_reset_some``) interleaved as a
step is, so each robot's episode is its single environment's bit for bit (test, also with
ekf and obstacles). An auto-reset of some robots settles them while PyBullet (which cannot
step a subset of its bodies) also moves the others; their positions, velocities and joints
are put back afterwards, but not PyBullet's contact caches: the reset robot's new episode is
bit for bit its single environment's, the others' episodes from then on are not (they
differ at rounding level at first, then drift apart as any chaotic system does).

Estimators: one bank (``fusion.make_bank``) holds every robot's filter; it steps them all
in one call when every robot has an IMU sample in the same physics step, otherwise each
robot's filter is updated alone (the same numbers: tested). The IMU model's sample clocks
have per-device jitter and error, so the robots' samples seldom coincide (3 robots, 40
steps: 51 bank calls against about 160 samples each). Not done: one IMU-model kernel for
all robots (each still has its own ``fusion.imu.IMU``). Speed: 16 robots ran
0.5-0.9x the robot steps/s per core of one environment, same run (target 3x; measured by
benchmarks/env_speed.py). The limit is PyBullet's: its world step costs each robot at least
one robot's step (5.4 us at 400 Hz; 9.5 us per robot with 16 robots at the same place, whose
shapes overlap in the broadphase before the filter drops the pairs; 6.0 us with 16 robots
3 m apart: ``env_speed.py --scaling``), and the per-robot PyBullet calls (about 3.3 us per
physics step) have no batched form, so a robot step costs at least about 100 us (one
place) or 75 us (apart) against about 90-100 us for a whole step of one environment: about
1x per core is the ceiling here, 1.3x spread apart (docs/envs/vector.md). The per-robot
Python of each physics step (the IMU model's ``step``, the true signals, sensing, actuation:
about half of the time, profiled) is not shared by batching.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.base import NEEDS_RESET, SphereRobotBase, parse_action
from fusion.checks import integer

__all__ = ["SphereBotVectorEnv", "SB3VecEnv", "make_track_vec", "make_waypoints_vec"]


class SphereBotVectorEnv(VectorEnv):
    """``num_envs`` robots of the task class ``env_cls`` built with ``kwargs`` (the single
    environment's arguments; ``render_mode`` is not supported here)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, env_cls: type[SphereRobotBase], num_envs: int, **kwargs: Any) -> None:
        num_envs = integer("num_envs", num_envs, 1, 1024)
        if kwargs.get("render_mode") is not None:
            raise ValueError("render_mode must be None for the batched vector environment")
        if kwargs.pop("max_episode_steps", None) is not None:
            raise ValueError("max_episode_steps is not taken by the batched vector environment: "
                             "the robots' episodes end after episode_s (s)")
        self.num_envs = num_envs
        self.envs = [env_cls(**kwargs) for _ in range(self.num_envs)]
        e0 = self.envs[0]
        self.single_observation_space = e0.observation_space
        self.single_action_space = e0.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.OBS, self.task, self.control_hz, self.robot = e0.OBS, e0.task, e0.control_hz, e0.robot
        self._bank = None
        self._last_obs = None           # the observations last returned (reset_mask)
        if e0._est is not None:
            # one bank steps every robot's estimator when all have a sample (the usual case);
            # each robot holds its bank filter, for its bias, counters, reset and lone updates
            import fusion
            self._bank = fusion.make_bank(e0.estimator_name, e0.imu_hz, self.num_envs, on_invalid="skip",
                                          **e0._est_params)
            # the robots use their filter objects between the bank's steps (reset, bias, lone
            # updates): the bank steps those objects, not its structure-of-arrays copy
            self._bank._objects_only()
            for e, f in zip(self.envs, self._bank._filters, strict=True):
                e._est = f
        self._p = self._client = None

    def _connect(self):
        import pybullet as p
        self._p = p
        self._client = p.connect(p.DIRECT)
        if self._client < 0:
            raise RuntimeError("could not connect to PyBullet")
        for e in self.envs:
            e._shared = self._client
            e._connect()
        self.envs[0]._world_settings()
        self._floor = self.envs[0]._make_floor()        # one floor for every robot
        self.closed = False         # (a reset after close reconnects: a later close must disconnect)

    def _filter(self, i):
        """No collisions between robot ``i``'s bodies and the other robots' bodies."""
        p, c = self._p, self._client
        mine = [(b, link) for b in self.envs[i]._bodies for link in range(-1, p.getNumJoints(b, physicsClientId=c))]
        for j, e in enumerate(self.envs):
            if j == i:
                continue
            for b in e._bodies:
                for link in range(-1, p.getNumJoints(b, physicsClientId=c)):
                    for (a, la) in mine:
                        p.setCollisionFilterPair(a, b, la, link, 0, physicsClientId=c)

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every robot. ``seed``: None (each robot draws its own), an integer s >= 0
        (robot i: s + i) or a list of ``num_envs`` seeds, each an integer >= 0 or None (as
        gymnasium's SyncVectorEnv takes them). ``options["reset_mask"]`` (a bool array of
        ``num_envs``, as SyncVectorEnv takes it): only those robots, the others' last
        observations returned as they were; the other options go to every robot reset."""
        mask = None
        if options is not None and "reset_mask" in options:
            options = dict(options)
            mask = options.pop("reset_mask")
            if (not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,)
                    or not mask.any()):
                raise ValueError(f"options['reset_mask'] must be a numpy bool array of shape ({self.num_envs},) "
                                 f"with at least one True, got {mask!r}")
            if self._last_obs is None:
                raise ValueError("options['reset_mask'] needs a reset of every robot first")
            options = options or None
        if isinstance(seed, (list, tuple)) or (isinstance(seed, np.ndarray) and seed.ndim == 1):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must be None, an integer >= 0 or a list of num_envs = {self.num_envs} "
                                 f"seeds, got {len(seed)} seeds")
            seeds = [integer(f"seed[{i}]", s, 0, allow_none=True) for i, s in enumerate(seed)]
            first = None        # gymnasium's VectorEnv.reset takes one integer: its own generator is left as it is
        else:
            try:
                first = integer("seed", seed, 0, allow_none=True)
            except ValueError:
                raise ValueError(f"seed must be None, an integer >= 0 or a list of num_envs = {self.num_envs} "
                                 f"seeds (each an integer >= 0 or None), got {seed!r}") from None
            seeds = [None if first is None else first + i for i in range(self.num_envs)]
        super().reset(seed=first)
        if self._client is None:
            self._connect()
        index = list(range(self.num_envs)) if mask is None else [int(i) for i in np.flatnonzero(mask)]
        out = self._reset_some(index, [seeds[i] for i in index], options)
        if mask is None:
            obs = np.empty((self.num_envs,) + self.single_observation_space.shape, dtype=np.float32)
        else:
            obs = self._last_obs.copy()
        infos = {}
        for i, (o, info) in zip(index, out, strict=True):
            obs[i] = o
            infos = self._add_info(infos, info, i)
        self._last_obs = obs.copy()
        return obs, infos

    def _reset_some(self, index, seeds, options=None):
        """Reset the robots ``index`` (with ``seeds``): their settling runs together, and the
        other robots' positions, velocities and joints are put back after it (the module
        docstring says what that does not restore). Returns [(obs, info), ...]."""
        resetting = [self.envs[i] for i in index]
        for i, s in zip(index, seeds, strict=True):
            self.envs[i]._reset_begin(s, options)
            self._filter(i)
        others = [e for j, e in enumerate(self.envs) if j not in set(index)]
        saved = [self._kinematic_state(e._body) for e in others]
        self._physics(resetting, [(0.0, 0.0)] * len(resetting), resetting[0]._settle_steps)
        for e, st in zip(others, saved, strict=True):
            self._restore_kinematic_state(e._body, st)
        return [e._reset_end() for e in resetting]

    def _kinematic_state(self, b):
        p, c = self._p, self._client
        joints = range(p.getNumJoints(b, physicsClientId=c))
        return (p.getBasePositionAndOrientation(b, c), p.getBaseVelocity(b, c),
                [p.getJointState(b, j, c)[:2] for j in joints])

    def _restore_kinematic_state(self, b, st):
        p, c = self._p, self._client
        (pos, orn), (lin, ang), js = st
        p.resetBasePositionAndOrientation(b, pos, orn, physicsClientId=c)
        p.resetBaseVelocity(b, lin, ang, physicsClientId=c)
        for j, (q, w) in enumerate(js):
            p.resetJointState(b, j, q, w, physicsClientId=c)

    def _physics(self, envs, commands, n):
        """n physics steps of ``envs`` with the commands (voltage, steering target): each
        robot's ``_advance`` interleaved with the others' around one world step."""
        step, c = self._p.stepSimulation, self._client
        pairs = [(e._actuate, v, t) for e, (v, t) in zip(envs, commands, strict=True)]
        bank = self._bank if len(envs) == self.num_envs else None
        for k in range(n):
            for actuate, v, t in pairs:
                actuate(k, v, t)
            step(c)
            self._sense(envs, bank)
        for e, cmd in zip(envs, commands, strict=True):
            e._cmd_prev = cmd

    @staticmethod
    def _sense(envs, bank):
        """Every robot's sensing after a world step; one bank update when all have a sample."""
        samples = [e._measure() for e in envs]
        if bank is not None and all(s is not None for s in samples):
            mag = None if samples[0].mag is None else np.array([s.mag for s in samples])
            q = bank.update(np.array([s.gyr for s in samples]), np.array([s.acc for s in samples]), mag)
            for i, (e, s) in enumerate(zip(envs, samples, strict=True)):
                e._on_sample(s, q[i].copy())
            return
        for e, s in zip(envs, samples, strict=True):
            if s is not None:
                e._on_sample(s, e._est.update(s.gyr, s.acc, s.mag) if e._est is not None else None)

    def step(self, actions: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {actions.shape}")
        envs = self.envs
        # every row is checked before any robot begins its step, so that a refused row leaves
        # the others as they were (their clip counts, their step's sums)
        for i, (e, a) in enumerate(zip(envs, actions, strict=True)):
            if e._needs_reset:
                raise RuntimeError(NEEDS_RESET)
            try:
                parse_action(a)
            except ValueError as err:
                raise ValueError(f"actions[{i}]: {err}") from None
        cmd = []
        for e, a in zip(envs, actions, strict=True):
            a0, a1 = e._begin_step(a)
            cmd.append((a0, a1, a0 * e.robot.motor_voltage, a1 * e.robot.steer_max))
        self._physics(envs, [(v, t) for _, _, v, t in cmd], envs[0]._n_sub)
        return self._finish(cmd)

    def _finish(self, cmd):
        n = self.num_envs
        obs = np.empty((n,) + self.single_observation_space.shape, dtype=np.float32)
        rew, term, trunc = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        infos = {}
        ends = []
        for i, (e, (a0, a1, _, _)) in enumerate(zip(self.envs, cmd, strict=True)):
            obs[i], rew[i], term[i], trunc[i], ends_info = e._end_step(a0, a1)
            ends.append(ends_info)
        done = [i for i in range(n) if term[i] or trunc[i]]
        fresh = dict(zip(done, self._reset_some(done, [None] * len(done)), strict=True)) if done else {}
        for i in range(n):
            info = ends[i]
            if i in fresh:
                info = {"final_obs": obs[i].copy(), "final_info": info, **fresh[i][1]}
                obs[i] = fresh[i][0]
            infos = self._add_info(infos, info, i)
        self._last_obs = obs.copy()
        return obs, rew, term, trunc, infos

    def close_extras(self, **kwargs: Any) -> None:
        for e in self.envs:
            e.close()
        if self._client is not None:
            self._p.disconnect(physicsClientId=self._client)
        self._client = None


def make_track_vec(num_envs: int, **kwargs: Any) -> SphereBotVectorEnv:
    """The ``vector_entry_point`` of ``SphereBotTrack``."""
    from envs.track import SphereBotTrackEnv
    return SphereBotVectorEnv(SphereBotTrackEnv, num_envs, **kwargs)


def make_waypoints_vec(num_envs: int, **kwargs: Any) -> SphereBotVectorEnv:
    """The ``vector_entry_point`` of ``SphereBotWaypoints``."""
    from envs.waypoints import SphereBotWaypointsEnv
    return SphereBotVectorEnv(SphereBotWaypointsEnv, num_envs, **kwargs)


def SB3VecEnv(venv: SphereBotVectorEnv) -> Any:  # noqa: N802  (a class factory: SB3 is imported only here)
    """A stable-baselines3 ``VecEnv`` over a ``SphereBotVectorEnv`` (terminal observations
    in ``infos[i]["terminal_observation"]``, ``"TimeLimit.truncated"`` as SB3 expects)."""
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class _SB3(VecEnv):
        def __init__(self, venv):
            self.venv = venv
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
            self._seed = None

        def reset(self):
            obs, _ = self.venv.reset(seed=self._seed)
            self._seed = None
            return obs

        def step_async(self, actions):
            self._actions = actions

        def step_wait(self):
            obs, rew, term, trunc, infos = self.venv.step(self._actions)
            out = []
            for i in range(self.num_envs):
                done = bool(term[i] or trunc[i])
                info = {"TimeLimit.truncated": bool(trunc[i] and not term[i])}
                if done:
                    info["terminal_observation"] = infos["final_obs"][i]
                out.append(info)
            return obs, rew.astype(np.float32), term | trunc, out

        def seed(self, seed=None):
            self._seed = seed
            return [None if seed is None else seed + i for i in range(self.num_envs)]

        def close(self):
            self.venv.close()

        def get_attr(self, name, indices=None):
            return [getattr(self.venv.envs[i], name) for i in self._get_indices(indices)]

        def set_attr(self, name, value, indices=None):
            for i in self._get_indices(indices):
                setattr(self.venv.envs[i], name, value)

        def env_method(self, name, *args, indices=None, **kwargs):
            return [getattr(self.venv.envs[i], name)(*args, **kwargs) for i in self._get_indices(indices)]

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False for _ in self._get_indices(indices)]

    return _SB3(venv)
