# Type stubs of the compiled fusion._mahony (fusion/_mahony.pyx).
from fusion._core import Array, Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import RestDetector

class Mahony(Estimator, _MagdistProperties):
    kp: float
    ki: float
    mag_weight: float
    rest_tau: float
    rest: RestDetector        # the rest properties but rest_noise (no zero-rate update)
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    at_rest: bool
    rest_samples: int
    bias: Array
