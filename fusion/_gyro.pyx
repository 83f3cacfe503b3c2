# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`gyro`: integration of the gyro alone, the floor every filter must beat."""
from fusion._core cimport Estimator, run_fast, batch_loop
from fusion._qmath cimport quat_propagate, quat_normalise


cdef inline void gyro_step(double* q, const double* gyr, double dt) noexcept nogil:
    """One sample (gyr may be NULL), q in place: Gyro._step and the batch loop both run this."""
    if gyr != NULL:
        quat_propagate(q, gyr[0], gyr[1], gyr[2], dt)
        quat_normalise(q)


cdef inline void gyro_batch_step(Estimator e, double* q, void* s, const double* gyr,
                                 const double* acc, const double* mag, double dt) noexcept nogil:
    gyro_step(q, gyr, dt)


cdef class Gyro(Estimator):
    """Integrates the body rate with the exact exponential step; no correction."""
    name = "gyro"
    PARAMS = {}     # no parameters

    def _configure(self, fs, frame, on_invalid, params):
        self._take_base(self._check_init(fs, frame, on_invalid), frame, on_invalid,
                        self._take_params(params))
        self.configured = True
        self._reset(None)

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        gyro_step(self.q, gyr, dt)

    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil:
        # the attitude in a local, in registers (fusion/_core.pxd batch_loop); no other state
        if not run_fast(self):
            return Estimator._run_batch(self, g, a, m, d, dt, o, n, stop_invalid)
        return batch_loop(self, gyro_batch_step, NULL, NULL, 0, g, a, m, d, dt, o, n, stop_invalid)
