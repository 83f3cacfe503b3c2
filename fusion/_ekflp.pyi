# Type stubs of the compiled fusion._ekflp (fusion/_ekflp.pyx).
from fusion._ekf import EKF

class EKFLP(EKF):
    incl_lowpass: float
