# Type stubs of the compiled fusion._mahony (fusion/_mahony.pyx).
from typing import Any, ClassVar

from fusion._core import Array, Estimator

class Mahony(Estimator):
    name: ClassVar[str]
    def __init__(self, fs: float, frame: str = "ENU", on_invalid: str = "raise", **params: Any) -> None: ...
    @property
    def kp(self) -> float: ...
    @property
    def ki(self) -> float: ...
    @property
    def bias(self) -> Array: ...
