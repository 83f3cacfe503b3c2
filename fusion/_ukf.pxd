from fusion._core cimport Estimator, KalmanNoise
from fusion._magdist cimport MagDetector
from fusion._acclp cimport AccLowpass
from fusion._rest cimport RestDetector

cdef class UKF(Estimator):
    cdef readonly KalmanNoise kalman  # its noise and recovery parameters (as the ekf's)
    cdef double b[3]          # gyro bias, rad/s
    cdef double P[36]         # covariance of the error [p (attitude, body frame), db], 6x6 row-major
    cdef double t_run
    cdef bint mag_heading     # mag_update="heading"
    cdef readonly double acc_lowpass   # s, 0: off (fusion/_acclp.pxd)
    cdef AccLowpass acc_lp
    cdef bint heading_gain    # the update in progress is the magnetometer's, projected
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly MagDetector magd    # magnetic disturbance detection (fusion/_magdist.pxd), time 0: off
    cdef void sigma_points(self, double* X) noexcept nogil
    cdef void sigma_attitudes(self, double* X, double* Qs) noexcept nogil
    cdef void predict(self, const double* gyr, double dt) noexcept nogil
    cdef void correct(self, const double* X, const double* Z, const double* z,
                      double r) noexcept nogil
    cdef void zero_rate_update(self, const double* gyr, double dt) noexcept nogil
    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil
    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil
