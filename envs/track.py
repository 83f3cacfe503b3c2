"""``SphereBotTrack``: follow a commanded speed and heading (the class docstring is its page)."""
from __future__ import annotations

import math

import numpy as np

from envs.base import SphereRobotBase, _wrap

__all__ = ["SphereBotTrackEnv"]


class SphereBotTrackEnv(SphereRobotBase):
    """## Description

    A pendulum-driven spherical robot (docs/envs/robot.md) must follow a commanded forward
    speed and heading that change during the episode. It knows its attitude only through
    the chosen estimator running on the simulated IMU (``fusion.imu``), so heading-estimation
    errors become tracking errors. Full page: docs/envs/sphere_bot_track.md.

    ## Action space

    ``Box(-1, 1, (2,), float32)``; outside [-1, 1] clipped and counted
    (``info["action_clipped"]``), non-finite or a wrong shape: ``ValueError``.

    | index | action | scaling |
    |---|---|---|
    | 0 | drive voltage | x ``motor_voltage``; positive rolls forward |
    | 1 | steering | x ``steer_max`` servo target; positive turns left |

    ## Observation space

    ``Box(-high, high, (14,), float32)``, clipped to the bounds; ``OBS`` maps each name to
    its index.

    | index | name | unit | bound | meaning |
    |---|---|---|---|---|
    | 0-3 | q_w, q_x, q_y, q_z | 1 | 1 | estimated attitude, body -> ENU, w >= 0 |
    | 4-6 | rate_x, rate_y, rate_z | rad/s | 20 | last gyro sample minus the estimator's bias |
    | 7 | encoder_speed | rad/s | 50 | Hall encoder, shell relative to frame |
    | 8-9 | last_drive, last_steer | 1 | 1 | the last applied action |
    | 10 | speed_cmd | m/s | 5 | commanded forward speed |
    | 11 | speed_error | m/s | 5 | speed_cmd - encoder_speed * shell_radius |
    | 12-13 | sin_heading_error, cos_heading_error | 1 | 1 | of commanded - estimated heading |

    ## Rewards

    Per step, from the true state (``info["reward_terms"]``): ``speed = -|v_fwd - speed_cmd|
    / 0.5``, ``heading = -|wrap(heading_true - heading_cmd)| / pi``, ``effort = -0.01 (a0^2 +
    a1^2)``; the reward is their sum.

    ## Starting state

    Shell centre uniform in [-0.5, 0.5]^2 m, heading uniform in [-pi, pi), at rest, then
    0.1 s of settling. Commands: first heading = start + U(-pi, pi), speeds U(0.1, 0.6) m/s,
    each held U(3, 8) s, each next heading the previous + U(-pi/2, pi/2).
    ``reset(options={"start_xy": (x, y), "start_yaw": yaw})`` overrides the start pose.

    ## Episode end

    Terminated: out of the arena (``info["out_of_arena"]``) or stuck (true speed < 2 cm/s
    for 3 s while |drive| > 0.5, ``info["stuck"]``). Truncated: after ``episode_s``
    (default 30 s = 1500 steps at 50 Hz; the registered ids set no step limit of their own).

    ## Arguments

    Those of ``SphereRobotBase`` (``estimator="ekf"``, ``imu="mpu9250"``, rates, ``robot``,
    ``realism``, arena and obstacles, ``render_mode``); ``episode_s`` default 30.

    ## Version history

    - v1: the real robot (docs/envs/robot.md, "Version history").
    - v0: the v1 code with ``realism="ideal"``.
    - Issue 14: one class per task; the same episodes bit for bit
      (tests/test_env_classes.py). The waypoint task's arguments (``n_waypoints``,
      ``waypoint_radius``, ``position_fix_hz``, ``position_fix_std``) are no longer accepted
      here (they meant nothing for this task).
    """

    task = "track"
    TASK_OBS = (("speed_cmd", 5.0), ("speed_error", 5.0), ("sin_heading_error", 1.0), ("cos_heading_error", 1.0))
    REWARD_TERMS = ("speed", "heading", "effort")
    default_episode_s = 30.0

    def _draw_task(self):
        rng = self.np_random
        n = int(math.ceil(self.episode_s / 3.0)) + 1
        gaps = rng.uniform(3.0, 8.0, size=n)
        speeds = rng.uniform(0.1, 0.6, size=n)
        turns = rng.uniform(-math.pi / 2, math.pi / 2, size=n)
        turns[0] = rng.uniform(-math.pi, math.pi)
        # plain floats (the same values): read every step, where numpy's scalars cost 0.5 us
        self._cmd_times = np.concatenate([[0.0], np.cumsum(gaps)])[:n].tolist()
        self._cmd_speed = speeds.tolist()
        self._cmd_heading = [_wrap(v) for v in (self._yaw0 + np.cumsum(turns)).tolist()]
        self._cmd_i = 0
        self._cmd = (self._cmd_speed[0], self._cmd_heading[0])

    def _command(self):
        """(speed, heading) commanded now."""
        return self._cmd

    def _task_obs(self, psi):
        vc, hc = self._cmd
        e_psi = _wrap(hc - psi)
        v_enc = self._enc_speed * self.robot.shell_radius
        return (vc, vc - v_enc, math.sin(e_psi), math.cos(e_psi))

    def _get_rew(self, a0, a1):
        times, i = self._cmd_times, self._cmd_i
        if i + 1 < len(times) and self._t >= times[i + 1]:
            while i + 1 < len(times) and self._t >= times[i + 1]:
                i += 1
            self._cmd_i = i
            self._cmd = (self._cmd_speed[i], self._cmd_heading[i])
        vc, hc = self._cmd
        psi = self._heading_true()
        terms = {"speed": -abs(self._forward_speed(psi) - vc) / 0.5,
                 "heading": -abs(_wrap(psi - hc)) / math.pi,
                 "effort": self._effort(a0, a1)}
        return terms, False

    def _task_info(self, info):
        info["command"] = self._command()
