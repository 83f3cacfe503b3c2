# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`mahony`: explicit complementary filter with PI correction (seeds 000 and 004)."""
import numpy as np
from libc.math cimport sqrt

from fusion._core cimport Estimator
from fusion._core import check_positive, check_param
from fusion._qmath cimport (quat_propagate, quat_normalise, rot_to_body, rot_to_nav,
                            up_in_body, cross3, unit3)


cdef inline void mahony_error(const double* q, const double* acc, const double* mag,
                              double* e) noexcept nogil:
    """e = sum of measured x estimated directions, gravity and north-folded field (acc, mag
    may be NULL)."""
    cdef double u[3]
    cdef double v[3]
    cdef double c[3]
    cdef double h[3]
    e[0] = 0.0
    e[1] = 0.0
    e[2] = 0.0
    if acc != NULL:
        unit3(acc, u)
        up_in_body(q, v)
        cross3(u, v, e)
    if mag != NULL:
        unit3(mag, u)
        rot_to_nav(q, u, h)
        h[1] = sqrt(h[0] * h[0] + h[1] * h[1])   # turn the field about z onto north (y)
        h[0] = 0.0
        rot_to_body(q, h, v)
        cross3(u, v, c)
        e[0] += c[0]; e[1] += c[1]; e[2] += c[2]


cdef class Mahony(Estimator):
    """Mahony's explicit complementary filter: gravity and magnetic cross-product errors,
    proportional gain kp (1/s) and integral gain ki (1/s^2) on the gyro."""
    name = "mahony"
    PARAMS = {"kp": 0.5, "ki": 0.005}

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        Estimator.__init__(self, fs, frame, on_invalid)
        p = self._take_params(params)
        self.kp = check_param("kp", p["kp"], allow_zero=True)
        self.ki = check_param("ki", p["ki"], allow_zero=True)
        self.reset()

    cdef list _state_fields(self):
        return Estimator._state_fields(self) + [("eint", <double[:3]>self.eint, None)]

    cdef void _reset_state(self) noexcept nogil:
        self.eint[0] = 0.0
        self.eint[1] = 0.0
        self.eint[2] = 0.0

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        # Propagate with the integral-corrected gyro, then correct with this sample's
        # vectors: the measurements belong to the attitude after the step, as in the EKF.
        cdef double e[3]
        if gyr != NULL:
            quat_propagate(self.q, gyr[0] + self.ki * self.eint[0],
                           gyr[1] + self.ki * self.eint[1], gyr[2] + self.ki * self.eint[2], dt)
        mahony_error(self.q, acc, mag, e)
        if self.ki > 0.0:
            self.eint[0] += e[0] * dt
            self.eint[1] += e[1] * dt
            self.eint[2] += e[2] * dt
        if self.kp > 0.0:
            quat_propagate(self.q, self.kp * e[0], self.kp * e[1], self.kp * e[2], dt)
        quat_normalise(self.q)

    @property
    def bias(self):
        """The gyro bias the integral term has learned, rad/s (body frame)."""
        return -self.ki * np.array([self.eint[0], self.eint[1], self.eint[2]])
