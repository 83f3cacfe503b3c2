"""Controllers for the spherical robot: one interface (``reset()``, ``act(obs)``) for the
cascaded PID and for policies trained with stable-baselines3.

    from controllers import PID, load_policy, evaluate, available_policies

``load_policy("ppo-waypoints-truth")`` takes a shipped policy by name (``available_policies()``)
or a path. ``load_policy``, ``available_policies`` and ``evaluate`` are imported on first
use, so ``import controllers`` needs neither torch nor PyBullet.
"""
from controllers.base import Controller
from controllers.pid import PID, PIDGains

__all__ = ["Controller", "PID", "PIDGains", "load_policy", "available_policies", "evaluate"]


def __getattr__(name):
    if name in ("load_policy", "available_policies"):
        from controllers import rl
        return getattr(rl, name)
    if name == "evaluate":
        from controllers.evaluation import evaluate
        return evaluate
    raise AttributeError(f"module 'controllers' has no attribute {name!r}")
