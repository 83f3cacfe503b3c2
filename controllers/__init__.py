"""Controllers for the spherical robot: one interface (``reset()``, ``act(obs)``) for the
cascaded PID and for policies trained with stable-baselines3.

    from controllers import PID, load_policy, evaluate

``load_policy`` and ``evaluate`` are imported on first use, so ``import controllers`` needs
neither torch nor PyBullet.
"""
from controllers.base import Controller
from controllers.pid import PID, PIDGains

__all__ = ["Controller", "PID", "PIDGains", "load_policy", "evaluate"]


def __getattr__(name):
    if name == "load_policy":
        from controllers.rl import load_policy
        return load_policy
    if name == "evaluate":
        from controllers.evaluation import evaluate
        return evaluate
    raise AttributeError(f"module 'controllers' has no attribute {name!r}")
