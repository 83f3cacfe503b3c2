# Type stubs of the compiled fusion._mahony (fusion/_mahony.pyx).
from fusion._core import Array, Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import _RestPullProperties

class Mahony(Estimator, _MagdistProperties, _RestPullProperties):
    kp: float
    ki: float
    mag_weight: float
    bias: Array
