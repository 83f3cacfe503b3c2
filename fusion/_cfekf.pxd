from fusion._core cimport Estimator
from fusion._ekf cimport EKF
from fusion._mahony cimport Mahony
from fusion._rest cimport RestDetector

# its state besides its core's and its complementary filter's, one struct (as the ekf's
# EKFState; fusion._core.struct_fields)
cdef struct CFEKFState:
    bint cf_started     # the complementary filter has its start attitude (the EKF's)
    int sat_left        # samples the sliding window still holds a saturated raw sample
    double t_quiet      # bias_feedback: s the filter has been quiet (bias learned after LEARN_HOLD)

cdef class CFEKF(Estimator):
    # the quaternion + gyro-bias EKF it feeds (its b, P, recovery and rest detector are
    # cf-ekf's; its attitude is this estimator's q, copied in and out around each step)
    cdef EKF core
    cdef readonly RestDetector rest   # the core's
    cdef readonly double cf_noise
    cdef Mahony cf            # the complementary filter whose attitude is the measurement
    cdef readonly bint bias_feedback   # the complementary filter integrates gyro - b
    cdef CFEKFState s
