from fusion._ekf cimport EKF
from fusion._mahony cimport Mahony

cdef class CFEKF(EKF):
    cdef readonly double cf_noise
    cdef Mahony cf            # the complementary filter whose attitude is the measurement
    cdef bint cf_started
    cdef int sat_left         # samples the sliding window still holds a saturated raw sample
    cdef readonly bint bias_feedback   # the complementary filter integrates gyro - b
    cdef double t_quiet       # bias_feedback: s the filter has been quiet (bias learned after LEARN_HOLD)
