# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Prefilter kernels that estimators compose (DESIGN.md): a second-order Butterworth low-pass
("IIR-EKF, IMU dynamic error suppression") and a sliding-window mean ("Attitude-angle solution
for a mobile robot"), each on one 3-axis sensor stream."""
import numpy as np
from libc.math cimport tan, M_PI
from libc.stdlib cimport calloc, free

from fusion._core cimport Prefilter
from fusion._qmath cimport vec3_finite
from fusion._core import _as_samples, FINITE_RULE, FLAG
from fusion.checks import number, integer


WINDOW_MAX = 100_000     # samples (1000 s at 100 Hz, 0.1 s at 1 MHz; 2.4 MB a stream)
CUTOFF_MIN = C_CUTOFF_MIN       # fusion/_prefilter.pxd's, for Python


cdef int _claim(Prefilter f) except -1:
    """Mark f in use, or a RuntimeError if it is (by another thread, or by its estimator's
    run): with the GIL held the test and the set are one step for Python threads."""
    if f.busy:
        raise RuntimeError("prefilter in use by another thread")
    f.busy = True
    return 0


def _run(Prefilter f, x):
    """Filter an (N, 3) array sample by sample (the prefilter's state carries over). A row
    that is not finite, or whose squared norm overflows (an estimator's gyro rule: such rows
    never reach its prefilters), is refused before any is filtered: one would make every
    later output NaN, in this call and the next (the filter's state)."""
    X = np.array(_as_samples(x, "x", hint=""), dtype=np.float64, order="C", copy=True)     # no on_invalid here
    cdef double[:, ::1] v = X
    cdef Py_ssize_t i, bad = -1
    with nogil:
        for i in range(v.shape[0]):
            if not vec3_finite(&v[i, 0]):
                bad = i
                break
    if bad >= 0:
        raise ValueError(f"x must be {FINITE_RULE}; x[{bad}] = {X[bad]!r}; nothing was filtered")
    _claim(f)
    try:
        with nogil:
            for i in range(v.shape[0]):
                f.apply(&v[i, 0])
    finally:
        f.busy = False
    return X


def _reset(Prefilter f):
    _claim(f)
    f.clear()
    f.busy = False


cdef class Butterworth(Prefilter):
    """Second-order Butterworth low-pass by the bilinear transform with pre-warping
    ("IIR-EKF, IMU dynamic error suppression"): analogue prototype 1 / (s^2 + sqrt(2) s + 1) at
    w_a = 2 fs tan(pi fc / fs), cutoff_hz from 1e-7 fs (CUTOFF_MIN, where the coefficients'
    rounding still holds) to below fs / 2.
    The state starts at steady state on the first sample (no start-up transient), as
    scipy.signal.lfilter with zi = lfilter_zi(b, a) * x[0]."""

    def __init__(self, fs, cutoff_hz):
        self.fs = number("fs", fs, 0.0, open_low=True)
        c = number("cutoff_hz", cutoff_hz, 0.0, open_low=True)
        if c >= 0.5 * self.fs:
            raise ValueError(f"cutoff_hz must be below the Nyquist frequency fs/2 = {0.5 * self.fs} Hz, "
                             f"got {cutoff_hz!r}")
        low = f"{C_CUTOFF_MIN * self.fs:.6g}"       # as the message prints it: accepted too
        if c < min(C_CUTOFF_MIN * self.fs, float(low)):
            raise ValueError(f"cutoff_hz must be at least {C_CUTOFF_MIN:g} fs = {low} Hz "
                             f"(below it the coefficients' rounding moves the poles), got {cutoff_hz!r}")
        self.cutoff_hz = c
        butterworth2_design(tan(M_PI * c / self.fs), &self.c)
        self.clear()

    @property
    def coefficients(self):
        """(b, a) as scipy.signal uses them."""
        return (np.array([self.c.b0, self.c.b1, self.c.b2]), np.array([1.0, self.c.a1, self.c.a2]))

    cdef void clear(self) noexcept nogil:
        self.primed = False

    cdef list _state_fields(self):
        return [("z1", <double[:3]>self.z1, None), ("z2", <double[:3]>self.z2, None),
                ("primed", <int[:1]><int*>&self.primed, FLAG)]

    cdef void apply(self, double* v) noexcept nogil:
        cdef int k
        if not self.primed:
            for k in range(3):
                biquad_prime(&self.c, v[k], &self.z1[k], &self.z2[k])
            self.primed = True
        for k in range(3):
            v[k] = biquad_step(&self.c, v[k], &self.z1[k], &self.z2[k])

    def reset(self):
        _reset(self)

    def run(self, x):
        """Filter an (N, 3) array; returns a new array. A non-finite row is refused (ValueError
        naming it) before any row is filtered."""
        if self.fs == 0.0:      # a subclass that skipped __init__: no coefficients
            raise RuntimeError("Butterworth object was not configured: call the class's __init__")
        return _run(self, x)

    def __repr__(self):
        return f"Butterworth(fs={self.fs!r}, cutoff_hz={self.cutoff_hz!r})"


cdef class SlidingMean(Prefilter):
    """Mean of the last `window` samples, step 1 (the preprocessing of
    "Attitude-angle solution for a mobile robot"). Until the window
    has filled, the mean of the samples so far."""

    def __cinit__(self, window):
        self.window = integer("window", window, 1, WINDOW_MAX, unit=" (samples)")
        self.buf = <double*>calloc(<size_t>3 * <size_t>self.window, sizeof(double))
        if self.buf == NULL:
            raise MemoryError("SlidingMean buffer")
        self.clear()

    def __dealloc__(self):
        free(self.buf)

    cdef list _state_fields(self):
        # count and head index the buffer: their ranges keep a loaded state memory-safe
        return [("buf", <double[:3 * self.window]>self.buf, None), ("total", <double[:3]>self.total, None),
                ("count", <int[:1]>&self.count, (0, self.window)),
                ("head", <int[:1]>&self.head, (0, self.window - 1))]

    cdef void clear(self) noexcept nogil:
        self.count = 0
        self.head = 0
        self.total[0] = 0.0
        self.total[1] = 0.0
        self.total[2] = 0.0

    cdef void apply(self, double* v) noexcept nogil:
        cdef int k, i
        cdef double* slot = self.buf + 3 * self.head
        cdef double inv
        if self.count == self.window:
            for k in range(3):
                self.total[k] -= slot[k]
        else:
            self.count += 1
        for k in range(3):
            slot[k] = v[k]
            self.total[k] += v[k]
        self.head += 1
        if self.head == self.window:
            self.head = 0
            # re-add the window exactly once per lap so rounding never accumulates
            for k in range(3):
                self.total[k] = 0.0
            for i in range(self.count):
                for k in range(3):
                    self.total[k] += self.buf[3 * i + k]
        inv = 1.0 / self.count
        for k in range(3):
            v[k] = self.total[k] * inv

    def reset(self):
        _reset(self)

    def run(self, x):
        """Filter an (N, 3) array; returns a new array. A non-finite row is refused (ValueError
        naming it) before any row is filtered."""
        return _run(self, x)

    def __repr__(self):
        return f"SlidingMean(window={self.window!r})"
