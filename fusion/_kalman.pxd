# The base of the Kalman filters (ekf family, ukf): the parameters and parts they both hold.
from fusion._core cimport Estimator
from fusion._rest cimport RestDetector
from fusion._magdist cimport MagDetector
from fusion._acclp cimport AccLowpass

# their noise and recovery parameters, one struct: set from the checked parameters at once
# (self.kalman = p), read in Python by the KalmanFilter properties of the same names
cdef struct KalmanNoise:
    double gyro_noise       # rad/s/√Hz
    double bias_noise       # rad/s/√s
    double acc_noise        # m/s²/√Hz
    double mag_noise        # 1/√Hz, relative to the field norm
    double q_init_std       # initial std of each quaternion component
    double bias_init_std    # rad/s
    double motion_rate      # rad/s: rate std over unmeasured time (recovery, docs/robustness.md)

cdef class KalmanFilter(Estimator):
    cdef readonly KalmanNoise kalman
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly MagDetector magd    # magnetic disturbance detection (fusion/_magdist.pxd), time 0: off
    cdef readonly double acc_lowpass  # s, 0: off (fusion/_acclp.pxd)
    cdef AccLowpass acc_lp
    # the parts from the checked parameters (Estimator._take_params), in the subclass's __init__
    cdef int hold_parts(self, dict p) except -1
    # the parts' state fields (after the subclass's own), and their reset
    cdef list parts_fields(self)
    cdef void clear_parts(self) noexcept nogil
