# Type stubs of the compiled fusion._cfekf (fusion/_cfekf.pyx).
from fusion._core import Array
from fusion._ekf import EKF

WINDOW_S: float
MAHONY_KI: float

def default_window(fs: float) -> int: ...

class CFEKF(EKF):
    window: int
    kp: float
    ki: float
    cf_noise: float
    bias_feedback: bool
    cf_quaternion: Array
