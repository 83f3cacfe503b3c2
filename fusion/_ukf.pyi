# Type stubs of the compiled fusion._ukf (fusion/_ukf.pyx).
from fusion._kalman import KalmanFilter

class UKF(KalmanFilter): ...
