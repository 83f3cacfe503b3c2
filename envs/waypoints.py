"""``SphereBotWaypoints``: drive through waypoints by dead reckoning (the class docstring is its page)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from envs.base import SphereRobotBase
from fusion.imu import IMUSpec
from fusion.checks import integer, number

__all__ = ["SphereBotWaypointsEnv"]


class SphereBotWaypointsEnv(SphereRobotBase):
    """## Description

    The spherical robot (docs/envs/robot.md) must roll through a sequence of waypoints,
    knowing its position only by dead reckoning: each control period it advances its
    estimate by ``shell_radius x (encoder speed + bias-corrected pitch rate averaged over
    the period)`` along its *estimated* heading, so a heading error bends the believed path
    away from the real one. An optional slow, noisy position fix resets the estimate to the
    true position plus noise. Full page: docs/envs/sphere_bot_waypoints.md.

    ## Action space

    As ``SphereBotTrackEnv``: drive voltage and steering in [-1, 1].

    ## Observation space

    ``Box(-high, high, (14,), float32)``, clipped to the bounds; ``OBS`` maps each name to
    its index. Indices 0-9 as ``SphereBotTrackEnv``, then:

    | index | name | unit | bound | meaning |
    |---|---|---|---|---|
    | 10 | target_forward | m | 50 | current waypoint from the dead-reckoned position, along the estimated heading |
    | 11 | target_left | m | 50 | the same, to the left |
    | 12-13 | sin_bearing, cos_bearing | 1 | 1 | of atan2(target_left, target_forward) |

    ## Rewards

    Per step, from the true state (``info["reward_terms"]``): ``progress = 10 x`` the
    decrease of the true distance to the current waypoint (m), ``reached = +10`` when it
    falls below ``waypoint_radius`` (the next waypoint becomes current), ``time = -0.02``,
    ``effort = -0.01 (a0^2 + a1^2)``; the reward is their sum.

    ## Starting state

    As ``SphereBotTrackEnv``; the dead-reckoned position starts at the true start.
    ``n_waypoints`` waypoints, each 1.5-3.5 m from the previous in a random direction, kept
    within 40 % of the arena size of the centre: a direction that leaves that square is turned,
    in steps of 5 degrees either way, to the nearest one that stays in it (below an arena of
    6.2 m, where no direction may, the step goes toward the farthest corner, as far as fits).

    ## Episode end

    Terminated: all waypoints reached (``info["goal_reached"]``), out of the arena or stuck
    (as the track task). Truncated: after ``episode_s`` (default 60 s = 3000 steps at 50 Hz;
    the registered ids set no step limit of their own).

    ## Arguments

    Those of ``SphereRobotBase``, ``episode_s`` default 60, and:

    | argument | default | meaning |
    |---|---|---|
    | n_waypoints | 4 | number of waypoints, in [1, 1000] |
    | waypoint_radius | 0.5 m | reached when the true distance is below it, in [0.05, 10] |
    | position_fix_hz | 0 | rate of the optional position fix (0: none), at most control_hz |
    | position_fix_std | 0.5 m | its noise per axis, in [0, 100] |

    ## Version history

    - v1: the real robot (docs/envs/robot.md, "Version history").
    - v0: the v1 code with ``realism="ideal"``.
    - Issue 14: one class per task; the same episodes bit for bit (tests/test_env_classes.py).
    """

    task = "waypoints"
    TASK_OBS = (("target_forward", 50.0), ("target_left", 50.0), ("sin_bearing", 1.0), ("cos_bearing", 1.0))
    REWARD_TERMS = ("progress", "reached", "time", "effort")
    default_episode_s = 60.0

    def __init__(self, estimator: str = "ekf", imu: str | IMUSpec = "mpu9250", *, n_waypoints: int = 4,
                 waypoint_radius: float = 0.5, position_fix_hz: float = 0.0, position_fix_std: float = 0.5,
                 **kwargs: Any) -> None:
        super().__init__(estimator, imu, **kwargs)
        self.n_waypoints = integer("n_waypoints", n_waypoints, 1, 1000)
        self.waypoint_radius = number("waypoint_radius", waypoint_radius, 0.05, 10.0)
        self.position_fix_hz = number("position_fix_hz", position_fix_hz, 0.0, self.control_hz)
        self.position_fix_std = number("position_fix_std", position_fix_std, 0.0, 100.0)

    def _draw_task(self):
        rng = self.np_random
        pts = []
        x, y = float(self._xy0[0]), float(self._xy0[1])
        lim = 0.4 * self.arena_size
        ang = rng.uniform(-math.pi, math.pi, size=self.n_waypoints)
        dist = rng.uniform(1.5, 3.5, size=self.n_waypoints)
        for a, d in zip(ang, dist, strict=True):
            x, y = _step_within(x, y, a, d, lim)
            pts.append((x, y))
        self._waypoints = np.array(pts)
        self._wp_xy = pts       # the same, as floats: read every step (numpy's scalars are slower)
        self._wp_i = 0

    def _reset_task(self):
        super()._reset_task()
        self._dist_prev = self._true_dist()

    def _true_dist(self):
        pos = self._true[0]
        wx, wy = self._wp_xy[self._wp_i]
        return math.hypot(wx - pos[0], wy - pos[1])

    def _task_obs(self, psi):
        tx, ty = self._wp_xy[self._wp_i]
        dx, dy = tx - self._pos_est[0], ty - self._pos_est[1]
        c, s = math.cos(psi), math.sin(psi)
        fwd, left = c * dx + s * dy, -s * dx + c * dy
        bear = math.atan2(left, fwd)
        return (fwd, left, math.sin(bear), math.cos(bear))

    def _get_rew(self, a0, a1):
        d = self._true_dist()
        progress = 10.0 * (self._dist_prev - d)
        reached = 0.0
        done = False
        if d < self.waypoint_radius:
            reached = 10.0
            self._wp_i += 1
            if self._wp_i >= len(self._waypoints):
                done = True
                self._wp_i = len(self._waypoints) - 1
                d = 0.0
            else:
                d = self._true_dist()
        self._dist_prev = d
        return {"progress": progress, "reached": reached, "time": -0.02, "effort": self._effort(a0, a1)}, done

    def _task_info(self, info):
        info["waypoint_index"] = self._wp_i
        info["waypoint"] = self._waypoints[self._wp_i].copy()
        info["position_est"] = np.array(self._pos_est)

    def _task_step_info(self, info, success):
        info["goal_reached"] = bool(success)


def _step_within(x, y, a, d, lim):
    """The point d from (x, y) in the direction nearest to a (turned 5 degrees at a time)
    inside the square |x|, |y| <= lim; toward its farthest corner, as far as fits, if none.
    (A clamp to the square put consecutive waypoints on the same corner: a reward for
    reaching one point twice.)"""
    for k in range(37):
        for b in ((a,) if k == 0 else (a + math.radians(5 * k), a - math.radians(5 * k))):
            nx, ny = x + d * math.cos(b), y + d * math.sin(b)
            if -lim <= nx <= lim and -lim <= ny <= lim:
                return nx, ny
    cx, cy = (-lim if x > 0 else lim), (-lim if y > 0 else lim)
    r = math.hypot(cx - x, cy - y)
    f = min(d, r) / r
    return x + f * (cx - x), y + f * (cy - y)
