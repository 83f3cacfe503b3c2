# Type stubs of the compiled fusion._ukf (fusion/_ukf.pyx).
from fusion._core import Estimator, _KalmanParams

class UKF(Estimator, _KalmanParams): ...
