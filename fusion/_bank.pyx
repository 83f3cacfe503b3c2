# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The compiled part of fusion.Bank (fusion/bank.py): count estimator kernels stepped in one
loop without the GIL, and the input checks of the per-sample path.

The kernels keep their state per object today, so the bank holds an array of pointers to
count ordinary estimators and calls each one's batch loop (Estimator._run_batch, the code
that est.update and est.run run) directly through its C method table: the same compiled
code as count separate estimators, so the same numbers, bit for bit."""
from cpython.ref cimport PyObject
from libc.stdlib cimport malloc, free

import numpy as np
cimport numpy as cnp

from fusion._core cimport Estimator, output_q
from fusion._qmath cimport vec3_valid, vec3_finite

cnp.import_array()

_RULE = {"gyr": "finite", "acc": "finite and non-zero", "mag": "finite and non-zero"}


def as_samples(x, str name, tuple shape, str what, Py_ssize_t count):
    """x as a C-contiguous float64 array of `shape` ((count, 3) or (T, count, 3)), or a
    ValueError naming the argument: a wrong count of filters is said as such."""
    if (type(x) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>x) == cnp.NPY_DOUBLE
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>x) and x.shape == shape):
        return x                                       # the per-sample path: no copy, no more checks
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array (float or int), got dtype {a.dtype}")
    if a.shape != shape:
        dim = len(shape) - 2
        if a.ndim == len(shape) and a.shape[a.ndim - 1] == 3 and a.shape[dim] != count:
            raise ValueError(f"{name} has {a.shape[dim]} filters (shape {a.shape}) but the bank has "
                             f"count {count}; {name} must have shape {what}")
        raise ValueError(f"{name} must have shape {what}, got {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


cdef Py_ssize_t _first_invalid(const double* g, const double* a, const double* m, Py_ssize_t n,
                               int* sensor) noexcept nogil:
    """The first of n rows of 3 (g, a, m; m NULL: 6-axis) with an invalid vector, in row order
    then gyr, acc, mag, with sensor 0, 1, 2 (what on_invalid='raise' refuses: a non-finite
    gyro, a non-finite or all-zero accelerometer or magnetometer); -1 if all are valid."""
    cdef Py_ssize_t k
    for k in range(n):
        if not vec3_finite(g + 3 * k):
            sensor[0] = 0
            return k
        if not vec3_valid(a + 3 * k):
            sensor[0] = 1
            return k
        if m != NULL and not vec3_valid(m + 3 * k):
            sensor[0] = 2
            return k
    return -1


cdef inline const double* _ptr(object x):
    return <const double*>cnp.PyArray_DATA(<cnp.ndarray>x) if x is not None else NULL


def check_samples(G, A, M, Py_ssize_t count, bint timed):
    """ValueError naming the first invalid sample: sensor, filter index, and (timed: arrays
    (T, count, 3)) the sample index; nothing if all are valid. G, A, M from as_samples."""
    cdef const double* g = _ptr(G)
    cdef const double* a = _ptr(A)
    cdef const double* m = _ptr(M)
    cdef Py_ssize_t n = cnp.PyArray_SIZE(<cnp.ndarray>G) // 3
    cdef Py_ssize_t k
    cdef int s = 0
    with nogil:
        k = _first_invalid(g, a, m, n, &s)
    if k < 0:
        return
    sensor = ("gyr", "acc", "mag")[s]
    t, i = divmod(k, count)
    row = (G, A, M)[s].reshape(-1, 3)[k]
    where = f"{sensor}[{t}, {i}]" if timed else f"{sensor}[{i}]"
    at = f"filter {i}, sample {t}" if timed else f"filter {i}"
    raise ValueError(f"{sensor} must be {_RULE[sensor]}; {where} = {row!r} ({at}; "
                     f"on_invalid='skip' skips such samples)")


cdef class Kernels:
    """Borrowed pointers to count estimators (kept alive by self.refs), for nogil loops.
    The caller (fusion.Bank) holds the in-use guard and checks time steps; the arrays come
    from as_samples."""
    cdef PyObject** p
    cdef readonly Py_ssize_t count
    cdef readonly list refs

    def __cinit__(self, list ests):
        cdef Py_ssize_t i
        for e in ests:
            if not isinstance(e, Estimator):
                raise TypeError(f"Kernels holds fusion estimators, got {type(e).__name__}")
        self.refs = list(ests)
        self.count = len(self.refs)
        self.p = <PyObject**>malloc(max(self.count, 1) * sizeof(PyObject*))
        if self.p == NULL:
            raise MemoryError()
        for i in range(self.count):
            self.p[i] = <PyObject*>self.refs[i]

    def __dealloc__(self):
        free(self.p)

    def update(self, gyr, acc, mag, d, double dt, bint check):
        """One sample per filter: gyr, acc, mag (count, 3) (mag None: 6-axis), d None (dt for
        all) or a checked (count,) float64 array of steps; check: refuse invalid samples
        (before any filter steps). Returns (count, 4) quaternions."""
        cdef Py_ssize_t n = self.count, i
        what = f"({n}, 3)"
        G = as_samples(gyr, "gyr", (n, 3), what, n)
        A = as_samples(acc, "acc", (n, 3), what, n)
        M = None if mag is None else as_samples(mag, "mag", (n, 3), what, n)
        if check:
            check_samples(G, A, M, n, False)
        cdef cnp.npy_intp dims[2]
        dims[0] = n
        dims[1] = 4
        out = cnp.PyArray_SimpleNew(2, dims, cnp.NPY_DOUBLE)
        cdef const double* g = _ptr(G)
        cdef const double* a = _ptr(A)
        cdef const double* m = _ptr(M)
        cdef const double* h = _ptr(d)
        cdef double* o = <double*>cnp.PyArray_DATA(<cnp.ndarray>out)
        with nogil:
            for i in range(n):
                (<Estimator>self.p[i])._run_batch(g + 3 * i, a + 3 * i, m + 3 * i if m != NULL else NULL,
                                                  NULL, h[i] if h != NULL else dt, o + 4 * i, 1, False)
        return out

    def run(self, G, A, M, D, double dt, out):
        """T samples per filter, filter-major: G, A, M C-contiguous float64 (count, T, 3) (M
        None: 6-axis), D None (dt throughout) or (count, T) steps; out (count, T, 4). Each
        filter's batch loop runs over its T samples in one call, as est.run does."""
        cdef Py_ssize_t i, n = G.shape[1]
        cdef const double* g = _ptr(G)
        cdef const double* a = _ptr(A)
        cdef const double* m = _ptr(M)
        cdef const double* h = _ptr(D)
        cdef double* o = <double*>cnp.PyArray_DATA(<cnp.ndarray>out)
        if n == 0:
            return
        with nogil:
            for i in range(self.count):
                (<Estimator>self.p[i])._run_batch(g + 3 * n * i, a + 3 * n * i,
                                                  m + 3 * n * i if m != NULL else NULL,
                                                  h + n * i if h != NULL else NULL, dt,
                                                  o + 4 * n * i, n, False)

    def quaternions(self):
        """(count, 4): every filter's attitude in its public frame."""
        out = np.empty((self.count, 4))
        cdef double[:, ::1] o = out
        cdef Py_ssize_t i
        for i in range(self.count):
            output_q(<Estimator>self.p[i], &o[i, 0])
        return out
