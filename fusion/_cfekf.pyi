# Type stubs of the compiled fusion._cfekf (fusion/_cfekf.pyx).
from fusion._core import Array, Estimator
from fusion._magdist import _MagdistProperties
from fusion._rest import _RestProperties

WINDOW_S: float
MAHONY_KI: float
CORE_PARAMS: tuple[str, ...]

def seed_window(fs: float) -> int: ...

class CFEKF(Estimator, _RestProperties, _MagdistProperties):
    gyro_noise: float
    bias_noise: float
    q_init_std: float
    bias_init_std: float
    motion_rate: float
    bias: Array
    covariance: Array
    window: int
    kp: float
    ki: float
    mag_weight: float
    cf_noise: float
    bias_feedback: bool
    mag_update: str
    acc_lowpass: float
    cf_quaternion: Array
