"""Attitude estimation from IMU data: Cython kernels behind one interface.

    import fusion
    est = fusion.make("ekf", fs=100.0)          # fusion.available() lists the names
    q = est.run(gyr, acc, mag)                  # (N, 4) quaternions [w, x, y, z]

Conventions (docs/estimators.md): Hamilton quaternions, scalar first, rotating body vectors
into the navigation frame (ENU, or NED with frame="NED"); ZYX Euler angles; SI units.
"""
from typing import Any

from fusion._version import __version__
from fusion.params import Param
from fusion._core import Estimator
from fusion._gyro import Gyro
from fusion._mahony import Mahony
from fusion._ekf import EKF, IIREKF
from fusion._ekflp import EKFLP
from fusion._madgwick import Madgwick
from fusion._ukf import UKF
from fusion._cfekf import CFEKF
from fusion._aekf import AEKF
from fusion._triad import Triad
from fusion._prefilter import Butterworth, SlidingMean
from fusion.bank import Bank, make_bank

__all__ = ["__version__", "Param", "make", "make_bank", "available", "Bank", "Estimator", "Gyro", "Mahony", "EKF",
           "EKFLP", "IIREKF", "Madgwick", "UKF", "CFEKF", "AEKF", "Triad", "Butterworth", "SlidingMean"]

_REGISTRY = {cls.name: cls for cls in (Gyro, Mahony, EKF, EKFLP, IIREKF, Madgwick, UKF, CFEKF, AEKF, Triad)}


def available() -> list[str]:
    """Names accepted by make(), in a stable order."""
    return list(_REGISTRY)


def make(name: str, fs: float, frame: str = "ENU", on_invalid: str = "raise", **params: Any) -> Estimator:
    """Build the estimator called `name` for sample rate `fs` (Hz).

    frame: "ENU" (default) or "NED", the navigation frame of quaternions in and out.
    on_invalid: "raise" (a ValueError names the first non-finite or all-zero sample) or
    "skip" (that measurement update is skipped and counted in est.skipped).
    params: the estimator's own parameters, type(est).PARAMS declares them (name -> fusion.Param:
    default, unit, accepted range, meaning).
    """
    try:
        cls = _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown estimator {name!r}; available: {', '.join(available())}") from None
    return cls(fs, frame=frame, on_invalid=on_invalid, **params)
