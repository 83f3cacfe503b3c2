from fusion._core cimport Estimator

cdef class Madgwick(Estimator):
    cdef readonly double beta, zeta
    cdef double bw[3]         # gyro bias learned with the zeta gain, rad/s
    cdef double t_recover     # s of raised gain left after a saturated gyro (recovery_gain)
