from fusion._core cimport Estimator
from fusion._magdist cimport MagDetector
from fusion._acclp cimport AccLowpass
from fusion._rest cimport RestDetector

cdef void mahony_error(const double* q, const double* acc, const double* mag,
                       double* e) noexcept nogil

# its state besides the attitude, one struct (as the ekf's EKFState; fusion._core.struct_fields)
cdef struct MahonyState:
    double eint[3]      # integral of the correction error
    double t_recover    # s of raised gain left after a saturated gyro (recovery_gain)

cdef class Mahony(Estimator):
    cdef readonly double kp, ki, mag_weight
    cdef MahonyState s
    cdef bint mag_heading     # mag_update="heading"
    cdef readonly double acc_lowpass   # s, 0: off (fusion/_acclp.pxd)
    cdef AccLowpass acc_lp
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly MagDetector magd    # magnetic disturbance detection (fusion/_magdist.pxd), time 0: off
    cdef readonly double rest_tau      # s: the bias's time constant at rest
    cdef void step_flagged(self, const double* gyr, const double* acc, const double* mag,
                           double dt, bint sat) noexcept nogil
