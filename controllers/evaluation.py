"""Closed-loop evaluation of a controller in the spherical-robot environment.

``evaluate(controller, env_kwargs, episodes, seed)`` runs ``episodes`` episodes (episode
``i`` reset with ``seed + i``) and scores them on the *true* state, whatever the controller
saw. Metrics per episode (``EPISODE_METRICS``):

- ``return``: the environment's reward summed over the episode;
- ``speed_rmse`` (m/s, track): true forward speed against the commanded speed;
- ``heading_rmse`` (deg, track): true heading against the commanded heading;
- ``success`` (0/1, waypoints): every waypoint reached before the time-out;
- ``time_to_goal`` (s, waypoints): NaN when not reached;
- ``waypoints_reached`` (waypoints);
- ``cross_track`` (m, waypoints): rms distance of the true position from the target path
  (the straight segment from the previous waypoint, or the start, to the current one);
- ``effort``: mean of drive^2 + steer^2 (action units);
- ``attitude_error`` (deg): rms of the estimator's total attitude error during the run;
- ``heading_est_error`` (deg): rms of the estimated heading's error during the run.

The first ``settle_s`` seconds of a track episode (2 s: the robot starting from rest) are
left out of the track RMSEs, the same for every controller.
"""
from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["evaluate", "run_episode", "aggregate", "EPISODE_METRICS", "MAIN_METRIC"]

EPISODE_METRICS = {
    "track": ("return", "speed_rmse", "heading_rmse", "effort", "attitude_error", "heading_est_error"),
    "waypoints": ("return", "success", "time_to_goal", "waypoints_reached", "cross_track", "effort",
                  "attitude_error", "heading_est_error"),
}
#: the metric each task is judged on, and whether larger is better
MAIN_METRIC = {"track": ("heading_rmse", False), "waypoints": ("success", True)}


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _segment_distance(p, a, b):
    ab = b - a
    L2 = float(ab @ ab)
    t = 0.0 if L2 == 0 else min(1.0, max(0.0, float((p - a) @ ab) / L2))
    return float(np.linalg.norm(p - (a + t * ab)))


def run_episode(controller, env, seed, settle_s=2.0, record_path=False):
    """One episode of ``controller`` in ``env`` (reset with ``seed``); returns a dict of the
    metrics of ``EPISODE_METRICS[task]`` (plus ``path`` and ``waypoints`` if asked)."""
    base = env.unwrapped
    task = base.task
    obs, info = env.reset(seed=seed)
    controller.reset()
    start = np.array(info["position"][:2])
    ret = 0.0
    sp, hd, eff, att, hest, xt, path = [], [], [], [], [], [], []
    settle = int(round(settle_s * base.control_hz))
    k = 0
    while True:
        a = np.asarray(controller.act(obs), dtype=np.float64)
        obs, r, terminated, truncated, info = env.step(a)
        ret += r
        k += 1
        a = np.clip(a, -1.0, 1.0)
        eff.append(float(a @ a))
        att.append(info["attitude_error_deg"])
        hest.append(math.degrees(_wrap(info["heading_est"] - info["heading_true"])))
        pos = np.asarray(info["position"][:2])
        if record_path:
            path.append(pos.copy())
        if task == "track":
            if k > settle:
                vc, hc = info["command"]
                psi = info["heading_true"]
                v = info["velocity"]
                sp.append(v[0] * math.cos(psi) + v[1] * math.sin(psi) - vc)
                hd.append(math.degrees(_wrap(psi - hc)))
        else:
            i = info["waypoint_index"]
            wps = base._waypoints
            prev = start if i == 0 else wps[i - 1]
            xt.append(_segment_distance(pos, prev, wps[i]))
        if terminated or truncated:
            break
    rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")   # noqa: E731
    out = {"return": float(ret), "effort": float(np.mean(eff)), "attitude_error": rms(att),
           "heading_est_error": rms(hest), "steps": k}
    if task == "track":
        out.update(speed_rmse=rms(sp), heading_rmse=rms(hd))
    else:
        ok = bool(info.get("goal_reached", False))
        reached = info["waypoint_index"] + (1 if ok else 0)
        out.update(success=float(ok), time_to_goal=float(info["t"]) if ok else float("nan"),
                   waypoints_reached=float(reached), cross_track=rms(xt))
    if record_path:
        out["path"] = np.array(path)
        out["start"] = start
        out["waypoints"] = base._waypoints.copy() if task == "waypoints" else None
    return out


def _check_int(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
    return int(v)


def evaluate(controller, env_kwargs=None, episodes=10, seed=0, record_path=False, env=None):
    """Run ``controller`` for ``episodes`` episodes of ``SphereRobotEnv(**env_kwargs)``
    (or of ``env`` if given), episode ``i`` seeded ``seed + i``. Returns
    ``{"episodes": [per-episode dicts], "summary": aggregate(...)}``."""
    episodes = _check_int("episodes", episodes, 1)
    seed = _check_int("seed", seed, 0)
    own = env is None
    if own:
        from envs.sphere import SphereRobotEnv
        env = SphereRobotEnv(**dict(env_kwargs or {}))
    try:
        eps = [run_episode(controller, env, seed + i, record_path=record_path) for i in range(episodes)]
    finally:
        if own:
            env.close()
    return {"episodes": eps, "summary": aggregate(eps, env.unwrapped.task)}


def aggregate(episodes, task):
    """Mean, standard deviation, the 95 % confidence half-width of the mean (Student t) and
    the count of finite values, per metric."""
    from scipy import stats
    out = {}
    for m in EPISODE_METRICS[task]:
        v = np.array([e[m] for e in episodes], dtype=float)
        v = v[np.isfinite(v)]
        n = len(v)
        mean = float(v.mean()) if n else float("nan")
        sd = float(v.std(ddof=1)) if n > 1 else float("nan")
        hw = float(stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n)) if n > 1 else float("nan")
        out[m] = {"mean": mean, "std": sd, "ci95": hw, "n": n}
    return out
