from fusion._kalman cimport KalmanFilter

# the ekf's state besides the attitude (the base class's q): the batch loop copies it in and
# out whole, state() / load_state() list its members (fusion._core.struct_fields)
cdef struct EKFState:
    double b[3]             # gyro bias, rad/s
    double P[49]            # covariance of [q, b], row-major 7x7
    double t_unmeasured     # s: the current run of unmeasured time (recovery, docs/robustness.md)

cdef class EKF(KalmanFilter):
    cdef EKFState s
    # the vector updates' gains (_ekf.pyx GAIN_*): mag_update="heading", acc_update="tilt"
    cdef int acc_gain, mag_gain
    cdef bint own_step        # _step is EKF's (not a subclass's): _run_batch may inline it
    # the parts of _step, on this filter's state, for subclasses (aekf) and holders (cf-ekf's core)
    cdef void propagate(self, const double* gyr, double dt, bint sat) noexcept nogil
    cdef void predict(self, const double* gyr, double dt) noexcept nogil
    # the accelerometer sample the update takes (acc_input, and the end of its low-pass's start)
    cdef const double* acc_sample(self, const double* gyr, bint sat, const double* acc, double dt,
                                  double* out) noexcept nogil
    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil
    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil
    cdef void rest_update(self, const double* gyr, const double* acc, double dt) noexcept nogil
    # the state of [q, b] and its recovery (EKFState), as _state_fields lists it
    cdef list _filter_fields(self)

cdef class IIREKF(EKF):
    pass
