"""Controllers for the spherical robot: one interface (``reset()``, ``act(obs)``) for the
cascaded PID and for policies trained with stable-baselines3."""
from controllers.base import Controller
from controllers.pid import PID, PIDGains

__all__ = ["Controller", "PID", "PIDGains"]
