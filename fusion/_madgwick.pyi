# Type stubs of the compiled fusion._madgwick (fusion/_madgwick.pyx).
from fusion._core import Array, Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import RestDetector

class Madgwick(Estimator, _MagdistProperties):
    beta: float
    zeta: float
    rest_tau: float
    rest: RestDetector        # the rest properties but rest_noise (no zero-rate update)
    rest_time: float
    rest_gyro_tol: float
    rest_acc_tol: float
    at_rest: bool
    rest_samples: int
    acc_lowpass: float
    mag_update: str
    bias: Array
