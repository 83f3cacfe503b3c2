# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`gyro`: integration of the gyro alone, the floor every filter must beat."""
from fusion._core cimport Estimator
from fusion._qmath cimport quat_propagate, quat_normalise


cdef class Gyro(Estimator):
    """Integrates the body rate with the exact exponential step; no correction."""
    name = "gyro"
    PARAMS = {}

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        Estimator.__init__(self, fs, frame, on_invalid)
        self._take_params(params)
        self.reset()

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        if gyr != NULL:
            quat_propagate(self.q, gyr[0], gyr[1], gyr[2], dt)
            quat_normalise(self.q)
