# Type stubs of the compiled fusion._ekf (fusion/_ekf.pyx).
from fusion._core import Estimator, _KalmanParams
from fusion._magdist import _MagdistProperties
from fusion._rest import _RestProperties

class EKF(Estimator, _KalmanParams, _RestProperties, _MagdistProperties):
    acc_lowpass: float
    mag_update: str
    acc_update: str

class IIREKF(EKF):
    cutoff_hz: float
    filter_mag: bool
