# Type stubs of the compiled fusion._prefilter (fusion/_prefilter.pyx).
from numpy.typing import ArrayLike

from fusion._core import Array, Prefilter

WINDOW_MAX: int

class Butterworth(Prefilter):
    def __init__(self, fs: float, cutoff_hz: float) -> None: ...
    fs: float
    cutoff_hz: float
    coefficients: tuple[Array, Array]
    def reset(self) -> None: ...
    def run(self, x: ArrayLike) -> Array: ...

class SlidingMean(Prefilter):
    def __init__(self, window: int) -> None: ...
    window: int
    def reset(self) -> None: ...
    def run(self, x: ArrayLike) -> Array: ...
