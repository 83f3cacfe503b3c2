# Type stubs of the compiled fusion._kalman (fusion/_kalman.pyx).
from fusion._aided import AidedFilter
from fusion._core import Array

NOISE: tuple[str, ...]
NOISE_PROPERTIES: tuple[property, ...]
STATE_CHECKS: dict[str, object]

class KalmanFilter(AidedFilter):
    """The base of the Kalman filters (ekf family, ukf)."""
    kalman: dict[str, float]     # the KalmanNoise struct, as a dict
    gyro_noise: float
    bias_noise: float
    acc_noise: float
    mag_noise: float
    q_init_std: float
    bias_init_std: float
    motion_rate: float
    rest_noise: float
    rest_bias_gate: float
    rest_gate_time: float
    bias: Array
    covariance: Array
