# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`mahony`: explicit complementary filter with PI correction (seeds 000 and 004)."""
import numpy as np
from libc.math cimport sqrt

from libc.string cimport memcpy

from fusion._core cimport Estimator, run_fast, sample_fast, quat_out
from fusion._core import check_positive, check_param
from fusion._qmath cimport (quat_propagate, quat_normalise, rot_to_body, rot_to_nav,
                            up_in_body, cross3)


cdef inline void mahony_error(const double* q, const double* acc, const double* mag,
                              double* e) noexcept nogil:
    """e = sum of measured x estimated directions, gravity and north-folded field (acc, mag
    may be NULL)."""
    cdef double v[3]
    cdef double c[3]
    cdef double h[3]
    cdef double k
    e[0] = 0.0
    e[1] = 0.0
    e[2] = 0.0
    if acc != NULL:
        # (acc/|acc|) x v, scaled after the cross product
        k = 1.0 / sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
        up_in_body(q, v)
        cross3(acc, v, e)
        e[0] *= k; e[1] *= k; e[2] *= k
    if mag != NULL:
        # the folded field is linear in mag, so u x v(u) = (mag x v(mag)) / |mag|^2: one
        # division for the unit vector, no square root
        k = 1.0 / (mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        rot_to_nav(q, mag, h)
        h[1] = sqrt(h[0] * h[0] + h[1] * h[1])   # turn the field about z onto north (y)
        h[0] = 0.0
        rot_to_body(q, h, v)
        cross3(mag, v, c)
        e[0] += c[0] * k; e[1] += c[1] * k; e[2] += c[2] * k


cdef inline void mahony_step(double* q, double* eint, double kp, double ki,
                             const double* gyr, const double* acc, const double* mag,
                             double dt) noexcept nogil:
    """One sample (gyr, acc, mag may be NULL), q and eint in place: Mahony._step and the
    batch loop both run this."""
    # Propagate with the integral-corrected gyro, then correct with this sample's
    # vectors: the measurements belong to the attitude after the step, as in the EKF.
    cdef double e[3]
    if gyr != NULL:
        quat_propagate(q, gyr[0] + ki * eint[0], gyr[1] + ki * eint[1], gyr[2] + ki * eint[2], dt)
    mahony_error(q, acc, mag, e)
    if ki > 0.0:
        eint[0] += e[0] * dt
        eint[1] += e[1] * dt
        eint[2] += e[2] * dt
    if kp > 0.0:
        quat_propagate(q, kp * e[0], kp * e[1], kp * e[2], dt)
    quat_normalise(q)


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
        mahony_step(self.q, self.eint, self.kp, self.ki, gyr, acc, mag, dt)

    cdef void _run_batch(self, const double* g, const double* a, const double* m,
                         const double* d, double dt, double* o, Py_ssize_t n) noexcept nogil:
        # the state lives in locals during the loop: the compiler keeps them in registers,
        # which it cannot for self.q (any store through o or eint might alias it)
        cdef double q[4]
        cdef double eint[3]
        cdef double kp = self.kp, ki = self.ki
        cdef bint ned = self.ned
        cdef Py_ssize_t i
        cdef const double* mi
        if not run_fast(self):
            Estimator._run_batch(self, g, a, m, d, dt, o, n)
            return
        memcpy(q, self.q, 4 * sizeof(double))
        memcpy(eint, self.eint, 3 * sizeof(double))
        for i in range(n):
            mi = m + 3 * i if m != NULL else NULL
            if sample_fast(self, g + 3 * i, a + 3 * i, mi):
                mahony_step(q, eint, kp, ki, g + 3 * i, a + 3 * i, mi, d[i] if d != NULL else dt)
            else:
                memcpy(self.q, q, 4 * sizeof(double))
                memcpy(self.eint, eint, 3 * sizeof(double))
                self._process(g + 3 * i, a + 3 * i, mi, d[i] if d != NULL else dt)
                memcpy(q, self.q, 4 * sizeof(double))
                memcpy(eint, self.eint, 3 * sizeof(double))
            quat_out(q, ned, o + 4 * i)
        memcpy(self.q, q, 4 * sizeof(double))
        memcpy(self.eint, eint, 3 * sizeof(double))

    @property
    def bias(self):
        """The gyro bias the integral term has learned, rad/s (body frame)."""
        return -self.ki * np.array([self.eint[0], self.eint[1], self.eint[2]])
