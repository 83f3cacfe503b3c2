# Type stubs of the compiled fusion._ukf (fusion/_ukf.pyx).
from fusion._core import Estimator, _KalmanParams
from fusion._magdist import _MagdistProperties
from fusion._rest import _RestProperties

class UKF(Estimator, _KalmanParams, _RestProperties, _MagdistProperties):
    acc_lowpass: float
    mag_update: str
