# Type stubs of the compiled fusion._mahony (fusion/_mahony.pyx).
from fusion._aided import AidedFilter
from fusion._core import Array

class Mahony(AidedFilter):
    kp: float
    ki: float
    mag_weight: float
    rest_tau: float
    bias: Array
