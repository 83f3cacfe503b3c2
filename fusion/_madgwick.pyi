# Type stubs of the compiled fusion._madgwick (fusion/_madgwick.pyx).
from typing import Any, ClassVar

from fusion._core import Array, Estimator

class Madgwick(Estimator):
    name: ClassVar[str]
    def __init__(self, fs: float, frame: str = "ENU", on_invalid: str = "raise", **params: Any) -> None: ...
    @property
    def beta(self) -> float: ...
    @property
    def zeta(self) -> float: ...
    @property
    def bias(self) -> Array: ...
