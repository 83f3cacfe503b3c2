from fusion._core cimport Prefilter

cdef class Butterworth(Prefilter):
    cdef readonly double fs, cutoff_hz
    cdef double b0, b1, b2, a1, a2
    cdef double z1[3]
    cdef double z2[3]
    cdef bint primed

cdef class SlidingMean(Prefilter):
    cdef readonly int window
    cdef double* buf          # window x 3 ring buffer
    cdef double total[3]
    cdef int count, head
