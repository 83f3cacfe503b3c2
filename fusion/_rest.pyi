# Type stubs of the compiled fusion._rest (fusion/_rest.pyx).
from typing import Any

class RestDetector:
    def __init__(self, p: dict[str, Any]) -> None: ...
    time: float
    gyro_tol: float
    acc_tol: float
    noise: float
    at_rest: bool
    samples: int

REST_PROPERTIES: tuple[property, ...]

class _RestProperties:
    """The rest properties of the estimators that declare fusion.params.REST and hold a
    RestDetector (ekf, iir-ekf, aekf, ukf, cf-ekf)."""
    rest: RestDetector
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    rest_noise: float
    at_rest: bool
    rest_samples: int

class _RestPullProperties:
    """The rest properties of the complementary filters that declare fusion.params.REST_PULL
    (mahony, madgwick): no zero-rate update, so no rest_noise; rest_tau instead."""
    rest: RestDetector
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    rest_tau: float
    at_rest: bool
    rest_samples: int
