# Type stubs of the compiled fusion._madgwick (fusion/_madgwick.pyx).
from fusion._aided import AidedFilter
from fusion._core import Array

class Madgwick(AidedFilter):
    beta: float
    zeta: float
    rest_tau: float
    bias: Array
