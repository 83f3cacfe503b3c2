# Type stubs of the compiled fusion._rest (fusion/_rest.pyx).
from typing import Any

class RestDetector:
    def __init__(self, p: dict[str, Any]) -> None: ...
    time: float
    gyro_tol: float
    acc_tol: float
    gyro_drift_tol: float
    acc_drift_tol: float
    noise: float
    tau: float
    gate: float
    gate_time: float
    at_rest: bool
    samples: int

REST_PROPERTIES: tuple[property, ...]
REST_TAU_PROPERTY: property
REST_GATE_PROPERTIES: tuple[property, property]

class _RestProperties:
    """The rest properties of cf-ekf, read from its EKF core's RestDetector (the filters that
    hold one themselves have them from fusion._aided.AidedFilter, rest_noise from
    fusion._kalman.KalmanFilter)."""
    rest: RestDetector
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    rest_gyro_drift_tol: float
    rest_acc_drift_tol: float
    rest_noise: float
    rest_bias_gate: float
    rest_gate_time: float
    at_rest: bool
    rest_samples: int
