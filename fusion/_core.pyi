# Type stubs of the compiled fusion._core (fusion/_core.pyx): the Estimator base class of every
# kernel and the shared checks. Keep in step with the .pyx (tests/test_code_health.py checks
# that the public names exist). A kernel's stub declares what it adds; its parameters and
# properties are read-only attributes (annotations here). Classes named with a leading underscore are
# stub-only groups of attributes that several kernels have (no such class at run time).
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.params import Param

Array = NDArray[np.float64]

GRAVITY: float
STANDARD_GRAVITY: float
FRAMES: tuple[str, ...]
ON_INVALID: tuple[str, ...]
STATE_VERSION: int
STATE_KEYS: tuple[str, ...]
BIAS_MAX: float
TIME_MAX: float
VALUE_MAX: float
COV_MAX: float
DT_MIN: float
DT_MAX: float
FUSED_CHECK_MIN: int

def check_fs(value: Any) -> float: ...
def check_dt(value: Any) -> float: ...
def unit_q0(q0: Any, name: str = ...) -> np.ndarray: ...

class Prefilter: ...

class Estimator:
    PARAMS: ClassVar[dict[str, Param]]
    name: ClassVar[str | None]
    fs: float
    # the class's parameters (PARAMS) as keywords; each kernel's _configure does the work
    def __init__(self, fs: float, frame: str = "ENU", on_invalid: str = "raise",
                 **params: Any) -> None: ...
    def reset(self, q0: ArrayLike | None = None) -> None: ...
    def update(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
               dt: float | None = None) -> Array: ...
    def run(self, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike | None = None,
            dt: float | ArrayLike | None = None) -> Array: ...
    def state(self) -> dict[str, Any]: ...
    def load_state(self, state: dict[str, Any]) -> None: ...
    @classmethod
    def from_state(cls, state: dict[str, Any]) -> Estimator: ...
    quaternion: Array
    euler: Array
    bias: Array | None
    covariance: Array | None
    gyro_range: float | None
    frame: str
    on_invalid: str
    initialised: bool
    skipped: dict[str, int]
    prefilters: dict[str, Prefilter | None]
    params: dict[str, Any]
    def __reduce__(self) -> tuple[Any, ...]: ...
