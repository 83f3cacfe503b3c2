# Type stubs of the compiled fusion._bank (fusion/_bank.pyx): the loop under fusion.Bank.
from typing import Any

from numpy.typing import ArrayLike

from fusion._core import Array

def as_samples(x: ArrayLike, name: str, shape: tuple[int, ...], what: str, count: int) -> Array: ...
def check_samples(G: Array, A: Array, M: Array | None, count: int, timed: bool) -> None: ...
def time_steps(dt: Any, shape: tuple[int, ...]) -> Array | None: ...
SOA: bool

def soa_supported(ests: list[Any]) -> bool: ...

class BankCore:
    def update(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
               dt: float | ArrayLike | None = None) -> Array: ...
