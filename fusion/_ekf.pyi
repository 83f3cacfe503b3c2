# Type stubs of the compiled fusion._ekf (fusion/_ekf.pyx).
from fusion._kalman import KalmanFilter

class EKF(KalmanFilter):
    acc_update: str

class IIREKF(EKF):
    cutoff_hz: float
    filter_mag: bool
