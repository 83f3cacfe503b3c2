# Type stubs of the compiled fusion._aekf (fusion/_aekf.pyx).
import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._core import Array
from fusion._ekf import EKF

ACC_REJECTED: int
MAG_REJECTED: int
QUEST_USED: int

def quest(b1: ArrayLike, b2: ArrayLike, r1: ArrayLike, r2: ArrayLike, w1: float = 1.0,
          w2: float = 1.0) -> Array | None: ...

class AEKF(EKF):
    def record_decisions(self, on: bool = True) -> None: ...
    decisions: NDArray[np.uint8]
    last_decision: int
    rejected: dict[str, int]
    tested: dict[str, int]
    quest_updates: int
    mag_reference: tuple[float, float] | None
    measurement: str
    mag_norm: float | None
    mag_dip: float | None
    acc_norm_tol: float
    acc_pred_tol: float
    acc_pred_timeout: float
    mag_norm_tol: float
    mag_dip_tol: float
    reject_factor: float
    learn_time: float
    quest_mag_weight: float
