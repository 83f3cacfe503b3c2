# Type stubs of the compiled fusion._cfekf (fusion/_cfekf.pyx).
from typing import ClassVar

from fusion._core import Array
from fusion._ekf import EKF

WINDOW_S: float
MAHONY_KI: float

def default_window(fs: float) -> int: ...

class CFEKF(EKF):
    name: ClassVar[str]
    @property
    def window(self) -> int: ...
    @property
    def kp(self) -> float | None: ...
    @property
    def ki(self) -> float | None: ...
    @property
    def cf_noise(self) -> float: ...
    @property
    def bias_feedback(self) -> bool: ...
    @property
    def cf_quaternion(self) -> Array: ...
