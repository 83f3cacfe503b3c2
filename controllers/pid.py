"""Cascaded PID for the spherical robot, from the observation only (estimated attitude,
bias-corrected rates, encoder): what a robot without ground truth can do.

Loops (all at the control rate, ``dt = 1 / control_hz``):

- heading -> steering: PID on the heading error (the task's heading or bearing error, both
  computed by the environment from the *estimated* heading), derivative on the measurement
  (the world-frame yaw rate from the estimated attitude and the body rates), plus damping
  of the sideways rocking (the frame's roll rate about its forward axis), which a
  pendulum-steered sphere barely damps on its own;
- speed -> drive voltage: feed-forward ``v / top_speed`` plus PI on the speed error, speed
  measured as ``r (encoder + frame pitch rate)`` (the shell's rolling rate over the ground),
  plus damping of the pendulum's fore-aft swing on the estimated pitch rate.

Anti-windup by conditional integration (the integrator holds while its output saturates
in the direction of the error), output limits [-1, 1]. Works on one observation (shape
(14,)) or a batch (n, 14) from a vector environment; state is kept per row.

Gains: ``PIDGains`` documents each, and how it was found (docs/controllers.md).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, asdict
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from controllers.base import Controller, obs_batch
from fusion.checks import number

__all__ = ["PID", "PIDGains"]


@dataclass(frozen=True)
class PIDGains:
    """Gains of the cascaded PID; units in brackets (action units are the [-1, 1] range)."""

    heading_kp: float = 1.5        # [1/rad] steering per rad of heading error
    heading_ki: float = 0.05       # [1/(rad s)]
    heading_kd: float = 0.15       # [s/rad] on the measured yaw rate
    roll_damping: float = 1.0      # [s/rad] on the frame's roll rate (sign: see PID.act)
    heading_i_limit: float = 0.3   # [1] largest integral contribution
    speed_kp: float = 0.6          # [s/m]
    speed_ki: float = 0.4          # [1/m]
    speed_i_limit: float = 0.4     # [1]
    pitch_damping: float = 0.02    # [s/rad] on the frame's pitch rate
    top_speed: float = 1.0         # [m/s] feed-forward: speed at full voltage
    # waypoints: the speed commanded from the distance and the bearing to the next point
    wp_speed: float = 0.5          # [m/s] cruise speed
    wp_slow_radius: float = 1.0    # [m] slow down linearly inside this distance
    wp_min_speed: float = 0.15     # [m/s]

    def __post_init__(self):
        for f in fields(self):
            # >= 0; the two a division uses > 0
            number(f"PIDGains.{f.name}", getattr(self, f.name), 0.0,
                   open_low=f.name in ("top_speed", "wp_slow_radius"))


class PID(Controller):
    """Cascaded PID (see the module docstring). ``task``: "track" or "waypoints" (the
    meaning of the observation's last four values, read by name from the task's ``OBS``);
    ``control_hz``: the environment's rate; ``shell_radius`` (m, encoder rate -> ground
    speed): the robot's, default ``RobotParams``'s (``for_env`` reads the environment's)."""

    def __init__(self, task: str = "track", gains: PIDGains | dict[str, float] | None = None,
                 control_hz: float = 50.0, shell_radius: float | None = None) -> None:
        from envs.robot import RobotParams
        from envs.sphere import TASK_CLASSES
        if task not in TASK_CLASSES:
            raise ValueError(f"unknown task {task!r}; accepted: {', '.join(TASK_CLASSES)}")
        if gains is None:
            gains = PIDGains()
        elif isinstance(gains, dict):
            names = {f.name for f in fields(PIDGains)}
            bad = sorted(set(gains) - names)
            if bad:
                raise ValueError(f"unknown PID gain(s) {', '.join(bad)}; accepted: {', '.join(sorted(names))}")
            gains = PIDGains(**gains)
        elif not isinstance(gains, PIDGains):
            raise ValueError(f"gains must be None, a dict or a PIDGains, got {type(gains).__name__}")
        control_hz = number("control_hz", control_hz, 0.0, open_low=True, unit=" Hz")
        if shell_radius is None:
            shell_radius = RobotParams().shell_radius
        self.task = task
        self.obs_index = TASK_CLASSES[task].OBS
        self.gains = gains
        self.dt = 1.0 / control_hz
        self.shell_radius = number("shell_radius", shell_radius, 0.0, open_low=True, unit=" m")
        self._n = None

    @classmethod
    def for_env(cls, env: Any, gains: PIDGains | dict[str, float] | None = None) -> PID:
        """A PID matching ``env``'s task and control rate (``env`` may be wrapped)."""
        base = env.unwrapped
        return cls(task=base.task, gains=gains, control_hz=base.control_hz, shell_radius=base.robot.shell_radius)

    def __repr__(self):
        return (f"PID(task={self.task!r}, gains={asdict(self.gains)!r}, control_hz={1.0 / self.dt:g}, "
                f"shell_radius={self.shell_radius:g})")

    def reset(self, index: int | Sequence[int] | None = None) -> None:
        """Clear the integrators: all rows, or only row(s) ``index`` (a vector env's done envs)."""
        if self._n is None:
            return
        if index is None:
            self._i_head[:] = 0.0
            self._i_speed[:] = 0.0
        else:
            self._i_head[index] = 0.0
            self._i_speed[index] = 0.0

    def _ensure(self, n):
        if self._n != n:
            self._n = n
            self._i_head = np.zeros(n)
            self._i_speed = np.zeros(n)

    def act(self, obs: ArrayLike) -> np.ndarray:
        o, single = obs_batch(obs)
        self._ensure(o.shape[0])
        g, dt, k = self.gains, self.dt, self.obs_index
        w, x, y, z = o[:, k["q_w"]], o[:, k["q_x"]], o[:, k["q_y"]], o[:, k["q_z"]]
        gx, gy, gz = o[:, k["rate_x"]], o[:, k["rate_y"]], o[:, k["rate_z"]]
        # world-frame yaw rate: third row of R(q) times the body rate
        yaw_rate = 2 * (x * z - w * y) * gx + 2 * (y * z + w * x) * gy + (1 - 2 * (x * x + y * y)) * gz
        # sideways rocking: steering *with* the frame's roll rate about its forward axis damps
        # it (the opposite sign drives it; measured in the gain search, docs/controllers.md)
        roll_rate = -gx
        v_meas = self.shell_radius * (o[:, k["encoder_speed"]] + gy)
        if self.task == "track":
            v_cmd = o[:, k["speed_cmd"]]
            e_head = np.arctan2(o[:, k["sin_heading_error"]], o[:, k["cos_heading_error"]])
        else:
            fwd, left = o[:, k["target_forward"]], o[:, k["target_left"]]
            e_head = np.arctan2(o[:, k["sin_bearing"]], o[:, k["cos_bearing"]])
            dist = np.hypot(fwd, left)
            v_cmd = np.clip(g.wp_speed * dist / g.wp_slow_radius, g.wp_min_speed, g.wp_speed) \
                * np.clip(np.cos(e_head), 0.2, 1.0)

        steer_pd = g.heading_kp * e_head - g.heading_kd * yaw_rate - g.roll_damping * roll_rate
        steer = steer_pd + self._i_head
        # conditional integration: hold the integrator while saturated the same way
        hold = ((steer >= 1.0) & (e_head > 0)) | ((steer <= -1.0) & (e_head < 0))
        self._i_head = np.where(hold, self._i_head,
                                np.clip(self._i_head + g.heading_ki * e_head * dt, -g.heading_i_limit,
                                        g.heading_i_limit))

        e_v = v_cmd - v_meas
        drive_pd = v_cmd / g.top_speed + g.speed_kp * e_v - g.pitch_damping * gy
        drive = drive_pd + self._i_speed
        hold = ((drive >= 1.0) & (e_v > 0)) | ((drive <= -1.0) & (e_v < 0))
        self._i_speed = np.where(hold, self._i_speed,
                                 np.clip(self._i_speed + g.speed_ki * e_v * dt, -g.speed_i_limit,
                                         g.speed_i_limit))
        act = np.clip(np.stack([drive, steer], axis=1), -1.0, 1.0).astype(np.float32)
        return act[0] if single else act
