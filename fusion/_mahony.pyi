# Type stubs of the compiled fusion._mahony (fusion/_mahony.pyx).
from fusion._core import Array, Estimator

class Mahony(Estimator):
    kp: float
    ki: float
    rest_tau: float
    bias: Array
