"""The spherical robot in PyBullet as Gymnasium environments.

    import gymnasium as gym
    import envs                                  # registers the ids below
    env = gym.make("SphereBotTrack-v0", estimator="ekf", imu="mpu9250")

Ids: ``SphereBotTrack-v0`` (follow a commanded speed and heading) and
``SphereBotWaypoints-v0`` (drive through waypoints by dead reckoning). Importing this
package registers them; it imports neither PyBullet nor creates a physics client (the
environment connects at its first ``reset``). Docs: docs/envs/.
"""
import gymnasium as _gym

__all__ = ["SphereRobotEnv", "RobotParams", "ENV_IDS"]

ENV_IDS = ("SphereBotTrack-v0", "SphereBotWaypoints-v0")

_SPECS = {
    "SphereBotTrack-v0": dict(kwargs={"task": "track"}, max_episode_steps=1500),       # 30 s at 50 Hz
    "SphereBotWaypoints-v0": dict(kwargs={"task": "waypoints"}, max_episode_steps=3000),  # 60 s at 50 Hz
}

for _id, _spec in _SPECS.items():
    if _id not in _gym.registry:
        _gym.register(id=_id, entry_point="envs.sphere:SphereRobotEnv", **_spec)


def __getattr__(name):
    if name == "SphereRobotEnv":
        from envs.sphere import SphereRobotEnv
        return SphereRobotEnv
    if name == "RobotParams":
        from envs.robot import RobotParams
        return RobotParams
    raise AttributeError(f"module 'envs' has no attribute {name!r}")
