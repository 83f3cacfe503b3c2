# Type stubs of the compiled fusion._gyro (fusion/_gyro.pyx).
from fusion._core import Estimator

class Gyro(Estimator): ...
