"""The spherical robot in PyBullet as Gymnasium environments.

    import gymnasium as gym
    import envs                                  # registers the ids below
    env = gym.make("SphereBotTrack-v1", estimator="ekf", imu="mpu9250")

Ids: ``SphereBotTrack-v1`` (follow a commanded speed and heading; class
``envs.SphereBotTrackEnv``) and ``SphereBotWaypoints-v1`` (drive through waypoints by dead
reckoning; ``envs.SphereBotWaypointsEnv``), both on ``envs.base.SphereRobotBase``: the real robot
(damping, compliant servo and contact, friction, deadband, latency, battery sag, drive
vibration). ``-v0`` ids: the same environments with ``realism="ideal"`` (none of those;
not bit-identical to the environments that were called v0 before v1: docs/envs/robot.md,
"Version history"). Importing this package registers them; it imports neither PyBullet
nor creates a physics client (the environment connects at its first ``reset``).
Docs: docs/envs/.
"""
try:
    import gymnasium as _gym
except ImportError as e:
    from fusion.checks import missing_extra
    raise ModuleNotFoundError(missing_extra("envs", "sim") or str(e), name=e.name) from e

__all__ = ["SphereBotTrackEnv", "SphereBotWaypointsEnv", "SphereRobotBase", "SphereRobotEnv", "RobotParams",
           "ENV_IDS"]
_LAZY = {"SphereBotTrackEnv": "envs.track", "SphereBotWaypointsEnv": "envs.waypoints",
         "SphereRobotBase": "envs.base", "SphereRobotEnv": "envs.sphere", "RobotParams": "envs.robot"}

ENV_IDS = ("SphereBotTrack-v1", "SphereBotWaypoints-v1", "SphereBotTrack-v0", "SphereBotWaypoints-v0")

_TRACK, _WAYPOINTS = "envs.track:SphereBotTrackEnv", "envs.waypoints:SphereBotWaypointsEnv"
# No max_episode_steps: each environment truncates its own episodes after episode_s (s), which a
# TimeLimit of a fixed step count would override (episode_s or control_hz given to gym.make)
_SPECS = {
    "SphereBotTrack-v1": dict(entry_point=_TRACK, kwargs={}),
    "SphereBotWaypoints-v1": dict(entry_point=_WAYPOINTS, kwargs={}),
    "SphereBotTrack-v0": dict(entry_point=_TRACK, kwargs={"realism": "ideal"}),
    "SphereBotWaypoints-v0": dict(entry_point=_WAYPOINTS, kwargs={"realism": "ideal"}),
}
# N robots in one process and one physics client (envs/vector.py): gymnasium.make_vec(id,
# num_envs=N, vectorization_mode="vector_entry_point")
_VECTOR = {"SphereBotTrack": "envs.vector:make_track_vec", "SphereBotWaypoints": "envs.vector:make_waypoints_vec"}
for _id, _spec in _SPECS.items():
    _spec["vector_entry_point"] = _VECTOR[_id.split("-")[0]]

for _id, _spec in _SPECS.items():
    if _id not in _gym.registry:
        _gym.register(id=_id, **_spec)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
