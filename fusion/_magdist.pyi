# Type stubs of the compiled fusion._magdist (fusion/_magdist.pyx).
from typing import Any

class MagDetector:
    def __init__(self, p: dict[str, Any]) -> None: ...
    time: float
    norm_tol: float
    dip_tol_deg: float
    new_time: float
    rejected: int

MAGDIST_PROPERTIES: tuple[property, ...]

class _MagdistProperties:
    """The disturbance properties of the estimators that declare fusion.params.MAGDIST and
    hold a MagDetector (ekf, iir-ekf, aekf, ukf, mahony, madgwick; cf-ekf its mahony's)."""
    magd: MagDetector
    magdist_time: float
    magdist_norm_tol: float
    magdist_dip_tol: float
    magdist_new_time: float
    mag_rejected: int
