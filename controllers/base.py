"""The controller interface shared by PID and learned policies."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Controller", "obs_batch"]


class Controller:
    """``reset(index=None)`` clears internal state (all rows of a batch, or the given ones);
    ``act(obs) -> action``: obs (n_obs,) -> action (2,), or a batch (n, n_obs) -> (n, 2)."""

    def reset(self, index: int | Sequence[int] | None = None) -> None:
        pass

    def act(self, obs: ArrayLike) -> np.ndarray:
        raise NotImplementedError


def obs_batch(obs: ArrayLike) -> tuple[np.ndarray, bool]:
    """``obs`` as a float64 (n, n_obs) array and whether it was a single observation."""
    o = np.asarray(obs, dtype=np.float64)
    if o.ndim == 1:
        return o[None, :], True
    if o.ndim != 2:
        raise ValueError(f"obs must have shape (n_obs,) or (n_envs, n_obs), got shape {o.shape}")
    return o, False
