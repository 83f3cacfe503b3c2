# Type stubs of the compiled fusion._madgwick (fusion/_madgwick.pyx).
from fusion._core import Array, Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import _RestPullProperties

class Madgwick(Estimator, _MagdistProperties, _RestPullProperties):
    beta: float
    zeta: float
    acc_lowpass: float
    mag_update: str
    bias: Array
