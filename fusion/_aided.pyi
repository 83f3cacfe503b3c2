# Type stubs of the compiled fusion._aided (fusion/_aided.pyx).
from fusion._core import Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import RestDetector

class AidedFilter(Estimator, _MagdistProperties):
    """The base of the filters that hold a rest detector, a magnetic disturbance detector and
    an accelerometer low-pass (ekf, iir-ekf, aekf, ukf, mahony, madgwick)."""
    rest: RestDetector
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    rest_gyro_drift_tol: float
    rest_acc_drift_tol: float
    at_rest: bool
    rest_samples: int
    acc_lowpass: float
    mag_update: str
