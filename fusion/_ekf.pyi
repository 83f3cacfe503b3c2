# Type stubs of the compiled fusion._ekf (fusion/_ekf.pyx).
from fusion._core import Estimator, _KalmanParams

class EKF(Estimator, _KalmanParams):
    acc_lowpass: float
    mag_update: str
    acc_update: str

class IIREKF(EKF):
    cutoff_hz: float
    filter_mag: bool
