"""Compatibility: the names of the single environment class the tasks had before issue 14.

``SphereRobotEnv(task="track", ...)`` builds the task's class (envs/track.py
``SphereBotTrackEnv``, envs/waypoints.py ``SphereBotWaypointsEnv``) with the other arguments;
new code uses those classes or ``gymnasium.make``."""
from __future__ import annotations

from typing import Any

from envs.base import BASE_OBS, ESTIMATORS, MAX_SUBSTEPS, SphereRobotBase  # noqa: F401  (re-exported)
from envs.track import SphereBotTrackEnv
from envs.waypoints import SphereBotWaypointsEnv

__all__ = ["SphereRobotEnv", "TASKS", "TASK_CLASSES", "ESTIMATORS", "OBS_NAMES", "MAX_SUBSTEPS"]

#: task name -> its environment class
TASK_CLASSES = {cls.task: cls for cls in (SphereBotTrackEnv, SphereBotWaypointsEnv)}
TASKS = tuple(TASK_CLASSES)
#: the observation's names with the task's four as task_0..task_3 (each class: ``obs_names``, ``OBS``)
OBS_NAMES = tuple(name for name, _ in BASE_OBS) + ("task_0", "task_1", "task_2", "task_3")


def SphereRobotEnv(task: str = "track", *args: Any, **kwargs: Any) -> SphereRobotBase:  # noqa: N802  (the old class's name)
    """The environment of ``task`` ("track" or "waypoints") built with the other arguments."""
    if task not in TASK_CLASSES:
        raise ValueError(f"unknown task {task!r}; accepted: {', '.join(TASKS)}")
    return TASK_CLASSES[task](*args, **kwargs)
