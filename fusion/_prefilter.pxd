from libc.math cimport sqrt
from fusion._core cimport Prefilter


# The second-order Butterworth low-pass by the bilinear transform with pre-warping, one
# declaration for the `iir-ekf`'s prefilter and `ekf-lp`'s inclination filter: its design, and
# its step in direct form II transposed on one axis (states z1, z2).
cdef struct Biquad:
    double b0, b1, b2, a1, a2       # a0 = 1

cdef extern from *:
    """
    #define FUSION_CUTOFF_MIN 1e-7
    """
    # the lowest Butterworth cutoff, as a part of the sample rate: 1 + a1 + a2 = 4 w^2 / (1 +
    # sqrt(2) w + w^2), w = tan(pi fc / fs), is the DC gain's denominator, and the rounding of
    # a1 and a2 (1e-16) sets its error: 5e-4 of the gain here, several % at 1e-8, negative (a
    # pole above 1) from about 2.4e-9
    double C_CUTOFF_MIN "FUSION_CUTOFF_MIN"

cdef inline void butterworth2_design(double w, Biquad* c) noexcept nogil:
    """The coefficients for w = tan(pi fc dt) (the cutoff fc pre-warped, divided by 2 / dt):
    analogue prototype 1 / (s^2 + sqrt(2) s + 1) at w_a = (2 / dt) w."""
    cdef double r = sqrt(2.0)
    cdef double n = 1.0 / (1.0 + r * w + w * w)
    c.b0 = w * w * n
    c.b1 = 2.0 * c.b0
    c.b2 = c.b0
    c.a1 = 2.0 * (w * w - 1.0) * n
    c.a2 = (1.0 - r * w + w * w) * n

cdef inline void biquad_prime(const Biquad* c, double x, double* z1, double* z2) noexcept nogil:
    """The states at rest on x (the output x from the next sample on, no start-up transient)."""
    z2[0] = (c.b2 - c.a2) * x
    z1[0] = (c.b1 - c.a1) * x + z2[0]

cdef inline double biquad_step(const Biquad* c, double x, double* z1, double* z2) noexcept nogil:
    cdef double y = c.b0 * x + z1[0]
    z1[0] = c.b1 * x - c.a1 * y + z2[0]
    z2[0] = c.b2 * x - c.a2 * y
    return y


cdef class Butterworth(Prefilter):
    cdef readonly double fs, cutoff_hz
    cdef Biquad c
    cdef double z1[3]
    cdef double z2[3]
    cdef bint primed

cdef class SlidingMean(Prefilter):
    cdef readonly int window
    cdef double* buf          # window x 3 ring buffer
    cdef double total[3]
    cdef int count, head
