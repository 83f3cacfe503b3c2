# Type stubs of the compiled fusion._gyro (fusion/_gyro.pyx).
from typing import Any, ClassVar

from fusion._core import Estimator

class Gyro(Estimator):
    name: ClassVar[str]
    def __init__(self, fs: float, frame: str = "ENU", on_invalid: str = "raise", **params: Any) -> None: ...
