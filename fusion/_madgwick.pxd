from fusion._core cimport Estimator
from fusion._rest cimport RestDetector

cdef class Madgwick(Estimator):
    cdef readonly double beta, zeta
    cdef double bw[3]         # gyro bias learned with the zeta gain, rad/s
    cdef double t_recover     # s of raised gain left after a saturated gyro (recovery_gain)
    cdef bint mag_heading     # mag_update="heading": the field's gradient turns the heading only
    cdef readonly double acc_lowpass   # s, 0: off (fusion/_acclp.pxd)
    cdef double acc_lp[3]
    cdef double acc_qg[4]
    cdef bint acc_lp_started
    cdef double acc_lp_time    # s since its first sample, held at acc_lowpass (the running-mean start)
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly double rest_tau      # s: the bias's time constant at rest
