# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`gyro`: integration of the gyro alone, the floor every filter must beat."""
from libc.string cimport memcpy

from fusion._core cimport Estimator, run_fast, sample_fast, sample_valid, quat_out
from fusion._qmath cimport quat_propagate, quat_normalise


cdef inline void gyro_step(double* q, const double* gyr, double dt) noexcept nogil:
    """One sample (gyr may be NULL), q in place: Gyro._step and the batch loop both run this."""
    if gyr != NULL:
        quat_propagate(q, gyr[0], gyr[1], gyr[2], dt)
        quat_normalise(q)


cdef class Gyro(Estimator):
    """Integrates the body rate with the exact exponential step; no correction."""
    name = "gyro"
    PARAMS = {}     # no parameters

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        Estimator.__init__(self, fs, frame, on_invalid)
        self._take_params(params)
        self.configured = True     # before reset(), which refuses an unconfigured object
        self.reset()

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        gyro_step(self.q, gyr, dt)

    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil:
        # the attitude lives in a local during the loop, in registers (as in Mahony's)
        cdef double q[4]
        cdef bint ned = self.ned
        cdef Py_ssize_t i
        cdef const double* mi
        if not run_fast(self):
            return Estimator._run_batch(self, g, a, m, d, dt, o, n, stop_invalid)
        memcpy(q, self.q, 4 * sizeof(double))
        for i in range(n):
            mi = m + 3 * i if m != NULL else NULL
            if sample_fast(self, g + 3 * i, a + 3 * i, mi):
                gyro_step(q, g + 3 * i, d[i] if d != NULL else dt)
            else:
                if stop_invalid and not sample_valid(g + 3 * i, a + 3 * i, mi):
                    return i
                memcpy(self.q, q, 4 * sizeof(double))
                self._process(g + 3 * i, a + 3 * i, mi, d[i] if d != NULL else dt)
                memcpy(q, self.q, 4 * sizeof(double))
            quat_out(q, ned, o + 4 * i)
        memcpy(self.q, q, 4 * sizeof(double))
        return n
