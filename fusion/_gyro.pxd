from fusion._core cimport Estimator

cdef class Gyro(Estimator):
    pass
