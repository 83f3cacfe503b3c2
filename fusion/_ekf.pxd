from fusion._core cimport Estimator
from fusion._rest cimport RestDetector

cdef class EKF(Estimator):
    cdef readonly double gyro_noise, bias_noise, acc_noise, mag_noise, q_init_std, bias_init_std
    cdef double b[3]          # gyro bias, rad/s
    cdef double P[49]         # covariance of [q, b], row-major 7x7
    # recovery (docs/robustness.md; the gyro range is the base class's): rate std over
    # unmeasured time (rad/s), length of the current run of unmeasured time (s)
    cdef readonly double motion_rate
    cdef double t_run
    # the vector updates' gains (_ekf.pyx GAIN_*): mag_update="heading", acc_update="tilt"
    cdef int acc_gain, mag_gain
    # acc_lowpass (s, 0: off): the accelerometer low-passed in a gyro-integrated frame
    cdef readonly double acc_lowpass
    cdef double acc_lp[3]     # its state, in the gyro-integrated frame acc_qg
    cdef double acc_qg[4]     # that frame: the bias-corrected gyro integrated, uncorrected
    cdef bint acc_lp_started
    cdef double acc_lp_time    # s since its first sample, held at acc_lowpass (the running-mean start)
    cdef bint own_step        # _step is EKF's (not a subclass's): _run_batch may inline it
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    # the parts of _step, on this filter's state, for subclasses (aekf) and holders (cf-ekf's core)
    cdef void propagate(self, const double* gyr, double dt, bint sat) noexcept nogil
    cdef void predict(self, const double* gyr, double dt) noexcept nogil
    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil
    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil
    cdef void rest_update(self, const double* gyr, const double* acc, double dt) noexcept nogil
    # the state of [q, b] and its recovery (b, P, t_unmeasured), as _state_fields lists it
    cdef list _filter_fields(self)

cdef class IIREKF(EKF):
    pass
