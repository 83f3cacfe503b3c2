# Type stubs of the compiled fusion._triad (fusion/_triad.pyx).
from fusion._core import Estimator

class Triad(Estimator):
    cutoff_hz: float | None
