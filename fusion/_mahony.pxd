from fusion._core cimport Estimator

cdef class Mahony(Estimator):
    cdef readonly double kp, ki
    cdef double eint[3]       # integral of the correction error
    cdef void correction(self, const double* acc, const double* mag, double* e) noexcept nogil
