from fusion._core cimport Estimator
from fusion._rest cimport RestDetector

cdef void mahony_error(const double* q, const double* acc, const double* mag,
                       double* e) noexcept nogil

cdef class Mahony(Estimator):
    cdef readonly double kp, ki, mag_weight
    cdef double eint[3]       # integral of the correction error
    cdef double t_recover     # s of raised gain left after a saturated gyro (recovery_gain)
    cdef bint mag_heading     # mag_update="heading"
    cdef readonly double acc_lowpass   # s, 0: off (fusion/_acclp.pxd)
    cdef double acc_lp[3]
    cdef double acc_qg[4]
    cdef bint acc_lp_started
    cdef double acc_lp_time    # s since its first sample, held at acc_lowpass (the running-mean start)
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly double rest_tau      # s: the bias's time constant at rest
    cdef void step_flagged(self, const double* gyr, const double* acc, const double* mag,
                           double dt, bint sat) noexcept nogil
