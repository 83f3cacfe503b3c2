from fusion._kalman cimport KalmanFilter

# the ukf's state besides the attitude, one struct (as the ekf's EKFState)
cdef struct UKFState:
    double b[3]             # gyro bias, rad/s
    double P[36]            # covariance of the error [p (attitude, body frame), db], 6x6 row-major
    double t_unmeasured     # s: the current run of unmeasured time (recovery, as the ekf's)

cdef class UKF(KalmanFilter):
    cdef UKFState s
    cdef bint heading_gain    # the update in progress is the magnetometer's, projected
    cdef void sigma_points(self, double* X) noexcept nogil
    cdef void sigma_attitudes(self, double* X, double* Qs) noexcept nogil
    cdef void predict(self, const double* gyr, double dt) noexcept nogil
    cdef void correct(self, const double* X, const double* Z, const double* z,
                      double r) noexcept nogil
    cdef void zero_rate_update(self, const double* gyr, double dt) noexcept nogil
    cdef void start_ended(self, double dt) noexcept nogil
    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil
    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil
