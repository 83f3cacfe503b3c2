# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The compiled part of fusion.Bank (fusion/bank.py): count estimator kernels stepped in one
loop without the GIL, the in-use guard, and the per-sample path.

The bank holds an array of pointers to count ordinary estimators. For most it calls each
one's batch loop (Estimator._run_batch, the code that est.update and est.run run) directly
through its C method table: the same compiled code as count separate estimators, so the same
numbers, bit for bit. A bank of `ekf` with acc_update="vector" and mag_update="heading" (the
defaults; soa_supported) also holds every filter's state field-major, lane l of field f at
soa[f * cap + l], and steps four filters per vector (fusion/_ekfbank.h, ekfb_block); a
filter whose sample is not the usual one (ekfb_fast) is stepped through its object, its
state copied in and back. The objects are brought up to the lanes' state before anything
reads them (_enter), and the lanes reloaded after anything may have changed them."""
from cpython.ref cimport PyObject
from libc.stdlib cimport malloc, calloc, free

from fusion._ekf cimport EKF
from fusion._rest cimport RestDetector
from fusion._ekf import EKF as _EKF

import numpy as np
cimport numpy as cnp

from fusion._core cimport Estimator, quat_out, in_use, mark_in_use
from fusion._core import DT_MAX, DT_MIN, FINITE_RULE, VALID_RULE, check_dt
from fusion.checks import not_masked, SAMPLES_HINT
from fusion._qmath cimport vec3_valid, vec3_finite

cnp.import_array()

# the ekf bank's structure-of-arrays step (fusion/_ekfbank.h)
cdef extern from "_ekfbank.h" nogil:
    int EKFB_AVAILABLE
    enum:
        EB_Q, EB_B, EB_P, EB_TUN, EB_RG, EB_RA, EB_RT, EB_RN, EB_RS, EB_MCUR, EB_MREF, EB_MCAND,
        EB_MTU, EB_MTC, EB_MTR, EB_MDIST, EB_MREJ, EB_MSET, EB_MDIRC, EB_MDIRS, EB_MTF, EB_LP, EB_LPS, EB_LPT,
        EB_INIT, EB_GN, EB_BN, EB_AN, EB_MN, EB_GR, EB_RTIME, EB_RGTOL, EB_RATOL, EB_RNOISE,
        EB_MTIME, EB_MNTOL, EB_MDTOL, EB_MNEW, EB_TAU, EB_FAST, EB_RG0, EB_RA0, EB_RLPT, EB_RGDTOL, EB_RADTOL, EB_RFG, EB_RFA, EB_RGATE, EB_RGATET, EB_RGS, EB_RGST, EB_RTAKEN, EB_NFIELDS
    int ekb_ix(int i, int j)
    size_t ekfb_fast(double* d, size_t cap, size_t n, const double* g, const double* a,
                     const double* m, const double* h, double dt, double dtn)
    void ekfb_block(double* d, size_t cap, size_t l, int nine, double qo[4][4])

#: True where the build has the ekf bank's structure-of-arrays step (fusion/_ekfbank.h: AVX)
SOA = bool(EKFB_AVAILABLE)

# the ekf's gains the structure-of-arrays step has (fusion/_ekf.pyx GAIN_*): acc_update
# "vector", mag_update "heading"
cdef int GAIN_FULL = 0, GAIN_HEADING = 1


cdef inline double* _lane(double* d, size_t cap, int f, size_t l) noexcept nogil:
    return d + <size_t>f * cap + l


cdef void _rest_to_lane(RestDetector r, double* d, size_t cap, size_t l) noexcept nogil:
    """The rest detector's state into lane l."""
    cdef int i
    for i in range(3):
        _lane(d, cap, EB_RG + i, l)[0] = r.gyr[i]
        _lane(d, cap, EB_RA + i, l)[0] = r.acc[i]
        _lane(d, cap, EB_RG0 + i, l)[0] = r.gyr0[i]
        _lane(d, cap, EB_RA0 + i, l)[0] = r.acc0[i]
        _lane(d, cap, EB_RFG + i, l)[0] = r.fgyr[i]
        _lane(d, cap, EB_RFA + i, l)[0] = r.facc[i]
        _lane(d, cap, EB_RGS + i, l)[0] = r.gsum[i]
    _lane(d, cap, EB_RT, l)[0] = r.t
    _lane(d, cap, EB_RLPT, l)[0] = r.lp_time
    _lane(d, cap, EB_RGST, l)[0] = r.gsum_t
    _lane(d, cap, EB_RTAKEN, l)[0] = 1.0 if r.taken else 0.0
    _lane(d, cap, EB_RN, l)[0] = <double>r.n
    _lane(d, cap, EB_RS, l)[0] = 1.0 if r.started else 0.0


cdef void _lane_to_rest(double* d, size_t cap, size_t l, RestDetector r) noexcept nogil:
    """Lane l's rest detector state (what the four-lane step changes) into r."""
    cdef int i
    for i in range(3):
        r.gyr[i] = _lane(d, cap, EB_RG + i, l)[0]
        r.acc[i] = _lane(d, cap, EB_RA + i, l)[0]
        r.gyr0[i] = _lane(d, cap, EB_RG0 + i, l)[0]
        r.acc0[i] = _lane(d, cap, EB_RA0 + i, l)[0]
        r.fgyr[i] = _lane(d, cap, EB_RFG + i, l)[0]
        r.facc[i] = _lane(d, cap, EB_RFA + i, l)[0]
        r.gsum[i] = _lane(d, cap, EB_RGS + i, l)[0]
    r.t = _lane(d, cap, EB_RT, l)[0]
    r.lp_time = _lane(d, cap, EB_RLPT, l)[0]
    r.gsum_t = _lane(d, cap, EB_RGST, l)[0]
    r.taken = _lane(d, cap, EB_RTAKEN, l)[0] != 0.0
    r.n = <long long>_lane(d, cap, EB_RN, l)[0]


cdef void _obj_to_lane(EKF e, double* d, size_t cap, size_t l, bint params) noexcept nogil:
    """Filter e's state (and with params its parameters) into lane l."""
    cdef int i, j
    for i in range(4):
        _lane(d, cap, EB_Q + i, l)[0] = e.q[i]
    for i in range(3):
        _lane(d, cap, EB_B + i, l)[0] = e.s.b[i]
        _lane(d, cap, EB_LP + i, l)[0] = e.acc_lp.lp[i]
        _lane(d, cap, EB_MDIRC + i, l)[0] = e.magd.s.dir_cur[i]
        _lane(d, cap, EB_MDIRS + i, l)[0] = e.magd.s.dir_slow[i]
    for i in range(7):
        for j in range(i, 7):
            _lane(d, cap, EB_P + ekb_ix(i, j), l)[0] = e.s.P[7 * i + j]
    _lane(d, cap, EB_TUN, l)[0] = e.s.t_unmeasured
    _rest_to_lane(e.rest, d, cap, l)
    for i in range(2):
        _lane(d, cap, EB_MCUR + i, l)[0] = e.magd.s.cur[i]
        _lane(d, cap, EB_MREF + i, l)[0] = e.magd.s.ref[i]
        _lane(d, cap, EB_MCAND + i, l)[0] = e.magd.s.cand[i]
    _lane(d, cap, EB_MTU, l)[0] = e.magd.s.t_undist
    _lane(d, cap, EB_MTC, l)[0] = e.magd.s.t_cand
    _lane(d, cap, EB_MTR, l)[0] = e.magd.s.t_reject
    _lane(d, cap, EB_MDIST, l)[0] = 1.0 if e.magd.s.disturbed else 0.0
    _lane(d, cap, EB_MREJ, l)[0] = <double>e.magd.s.rejected
    _lane(d, cap, EB_MSET, l)[0] = e.magd.s.t_settle
    _lane(d, cap, EB_MTF, l)[0] = e.magd.s.t_fixed
    _lane(d, cap, EB_LPS, l)[0] = 1.0 if e.acc_lp.lp_started else 0.0
    _lane(d, cap, EB_LPT, l)[0] = e.acc_lp.lp_time
    _lane(d, cap, EB_INIT, l)[0] = 1.0 if e.is_init else 0.0
    if not params:
        return
    _lane(d, cap, EB_GN, l)[0] = e.kalman.gyro_noise
    _lane(d, cap, EB_BN, l)[0] = e.kalman.bias_noise
    _lane(d, cap, EB_AN, l)[0] = e.kalman.acc_noise
    _lane(d, cap, EB_MN, l)[0] = e.kalman.mag_noise
    _lane(d, cap, EB_GR, l)[0] = e.gyro_range_
    _lane(d, cap, EB_RTIME, l)[0] = e.rest.time
    _lane(d, cap, EB_RGTOL, l)[0] = e.rest.gyro_tol
    _lane(d, cap, EB_RATOL, l)[0] = e.rest.acc_tol
    _lane(d, cap, EB_RNOISE, l)[0] = e.rest.noise
    _lane(d, cap, EB_RGDTOL, l)[0] = e.rest.gyro_drift_tol
    _lane(d, cap, EB_RADTOL, l)[0] = e.rest.acc_drift_tol
    _lane(d, cap, EB_RGATE, l)[0] = e.rest.gate
    _lane(d, cap, EB_RGATET, l)[0] = e.rest.gate_time
    _lane(d, cap, EB_MTIME, l)[0] = e.magd.time
    _lane(d, cap, EB_MNTOL, l)[0] = e.magd.norm_tol
    _lane(d, cap, EB_MDTOL, l)[0] = e.magd.dip_tol
    _lane(d, cap, EB_MNEW, l)[0] = e.magd.new_time
    _lane(d, cap, EB_TAU, l)[0] = e.acc_lowpass


cdef void _lane_to_obj(double* d, size_t cap, size_t l, EKF e) noexcept nogil:
    """Lane l's state (what the four-lane step changes) into filter e."""
    cdef int i, j
    cdef double v
    for i in range(4):
        e.q[i] = _lane(d, cap, EB_Q + i, l)[0]
    for i in range(3):
        e.s.b[i] = _lane(d, cap, EB_B + i, l)[0]
        e.acc_lp.lp[i] = _lane(d, cap, EB_LP + i, l)[0]
        e.magd.s.dir_cur[i] = _lane(d, cap, EB_MDIRC + i, l)[0]
        e.magd.s.dir_slow[i] = _lane(d, cap, EB_MDIRS + i, l)[0]
    for i in range(7):
        for j in range(i, 7):
            v = _lane(d, cap, EB_P + ekb_ix(i, j), l)[0]
            e.s.P[7 * i + j] = v
            e.s.P[7 * j + i] = v
    e.s.t_unmeasured = _lane(d, cap, EB_TUN, l)[0]
    _lane_to_rest(d, cap, l, e.rest)
    for i in range(2):
        e.magd.s.cur[i] = _lane(d, cap, EB_MCUR + i, l)[0]
        e.magd.s.ref[i] = _lane(d, cap, EB_MREF + i, l)[0]
        e.magd.s.cand[i] = _lane(d, cap, EB_MCAND + i, l)[0]
    e.magd.s.t_undist = _lane(d, cap, EB_MTU, l)[0]
    e.magd.s.t_cand = _lane(d, cap, EB_MTC, l)[0]
    e.magd.s.t_reject = _lane(d, cap, EB_MTR, l)[0]
    e.magd.s.disturbed = _lane(d, cap, EB_MDIST, l)[0] != 0.0
    e.magd.s.rejected = <long long>_lane(d, cap, EB_MREJ, l)[0]
    e.magd.s.t_settle = _lane(d, cap, EB_MSET, l)[0]
    e.magd.s.t_fixed = _lane(d, cap, EB_MTF, l)[0]
    e.acc_lp.lp_time = _lane(d, cap, EB_LPT, l)[0]


def soa_supported(list ests):
    """True when these estimators can take the ekf bank's structure-of-arrays step: every one
    an `ekf` (not a subclass) with acc_update="vector" and mag_update="heading", and the
    compiler had vector extensions (fusion/_ekfbank.h)."""
    if not EKFB_AVAILABLE or not ests:
        return False
    for e in ests:
        if type(e) is not _EKF or (<EKF>e).acc_gain != GAIN_FULL or (<EKF>e).mag_gain != GAIN_HEADING:
            return False
    return True


# samples per filter gathered per call of its batch loop in BankCore._run
cdef Py_ssize_t RUN_BLOCK = 128

_RULE = {"gyr": FINITE_RULE, "acc": VALID_RULE, "mag": VALID_RULE}


def as_samples(x, str name, tuple shape, str what, Py_ssize_t count):
    """x as a C-contiguous float64 array of `shape` ((count, 3) or (T, count, 3)), or a
    ValueError naming the argument: a wrong count of filters is said as such."""
    # native byte order and aligned too (ISBEHAVED_RO): the type number of '>f8' is NPY_DOUBLE
    if (type(x) is np.ndarray and cnp.PyArray_TYPE(<cnp.ndarray>x) == cnp.NPY_DOUBLE
            and cnp.PyArray_IS_C_CONTIGUOUS(<cnp.ndarray>x) and cnp.PyArray_ISBEHAVED_RO(<cnp.ndarray>x)
            and x.shape == shape):
        return x                                       # the per-sample path: no copy, no more checks
    not_masked(name, x, SAMPLES_HINT)
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array (float or int), got dtype {a.dtype}")
    if a.shape != shape:
        dim = len(shape) - 2
        if a.ndim == len(shape) and a.shape[a.ndim - 1] == 3 and a.shape[dim] != count:
            raise ValueError(f"{name} has {a.shape[dim]} filters (shape {a.shape}) but the bank has "
                             f"count {count}; {name} must have shape {what}")
        raise ValueError(f"{name} must have shape {what}, got {a.shape}")
    return np.require(a, np.float64, ("C", "A"))      # aligned, native order


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


def time_steps(dt, tuple shape):
    """dt as a C-contiguous float64 array of `shape` with every step in [DT_MIN, DT_MAX], None
    if it is not a real array of that shape, or a ValueError naming the first bad step."""
    not_masked("dt", dt)
    D = np.asarray(dt)
    if D.dtype.kind not in "fiu" or D.shape != shape:
        return None
    D = np.require(D, np.float64, ("C", "A"))
    bad = np.flatnonzero(~((D >= DT_MIN) & (D <= DT_MAX)))     # NaN fails too
    if bad.size:
        idx = np.unravel_index(bad[0], shape)
        raise ValueError(f"dt must be finite and > 0 and in [{DT_MIN:g}, {DT_MAX:g}] s; "
                         f"dt[{', '.join(map(str, idx))}] = {D[idx]!r}")
    return D


cdef inline bint _rows_ok(object x, Py_ssize_t n) noexcept:
    """x is already what as_samples would return for shape (n, 3)."""
    cdef cnp.ndarray arr
    if type(x) is not np.ndarray:
        return False
    arr = <cnp.ndarray>x
    return (cnp.PyArray_TYPE(arr) == cnp.NPY_DOUBLE and cnp.PyArray_IS_C_CONTIGUOUS(arr)
            and cnp.PyArray_ISBEHAVED_RO(arr) and cnp.PyArray_NDIM(arr) == 2 and cnp.PyArray_DIM(arr, 0) == n
            and cnp.PyArray_DIM(arr, 1) == 3)


cdef class BankCore:
    """The compiled base of fusion.Bank: borrowed pointers to count estimators (kept alive by
    self._filters), the in-use flag, and the per-sample path. fusion.Bank (bank.py) adds the
    rest of the interface in Python."""
    cdef PyObject** p
    cdef Py_ssize_t count
    cdef readonly double dt_nominal    # 1/fs as the filters hold it
    cdef bint check                  # on_invalid == "raise"
    cdef bint busy                   # a call is in progress (set and tested with the GIL held)
    cdef readonly list _filters
    # the ekf's structure-of-arrays step (fusion/_ekfbank.h): soa the fields of cap lanes
    # (NULL: the filters are stepped through their own batch loops); fresh: the lanes hold the
    # filters' latest state (the objects may be behind them until _sync_out)
    cdef double* soa
    cdef size_t cap
    cdef bint fresh
    cdef bint ned

    def __dealloc__(self):
        free(self.p)
        free(self.soa)

    def _bind(self, list ests, bint check):
        """Take these estimators (fusion.Bank._setup has checked them)."""
        cdef Py_ssize_t i
        cdef PyObject** p
        cdef double* soa = NULL
        cdef size_t cap = (len(ests) + 3) // 4 * 4
        for e in ests:
            if not isinstance(e, Estimator):
                raise TypeError(f"a bank holds fusion estimators, got {type(e).__name__}")
        p = <PyObject**>malloc(max(len(ests), 1) * sizeof(PyObject*))
        if p == NULL:
            raise MemoryError()
        if soa_supported(ests):
            soa = <double*>calloc(EB_NFIELDS * cap, sizeof(double))
            if soa == NULL:
                free(p)
                raise MemoryError()
        self._enter()
        free(self.p)
        free(self.soa)
        self.p = p
        self.soa = soa
        self.cap = cap
        self.fresh = False
        self._filters = list(ests)
        self.count = len(self._filters)
        for i in range(self.count):
            self.p[i] = <PyObject*>self._filters[i]
        self.dt_nominal = (<Estimator>self._filters[0]).dt_nominal
        self.ned = (<Estimator>self._filters[0]).ned
        self.check = check
        self._exit()

    @property
    def _soa(self):
        """True: the bank steps its filters four at a time, state in structure-of-arrays
        layout (fusion/_ekfbank.h); False: each through its own batch loop."""
        return self.soa != NULL

    def _objects_only(self):
        """Drop the structure-of-arrays lanes (their state written to the objects first): from
        here on the bank steps the objects' own batch loops, so that code holding the filter
        objects themselves (envs/vector.py: each robot its filter) may use them between steps."""
        self._enter()
        free(self.soa)
        self.soa = NULL
        self._exit()

    cdef void _load_lanes(self) noexcept nogil:
        """Every lane from its filter; the padding lanes copies of lane 0."""
        cdef size_t l, f
        for l in range(<size_t>self.count):
            _obj_to_lane(<EKF>self.p[l], self.soa, self.cap, l, True)
        for l in range(<size_t>self.count, self.cap):
            for f in range(<size_t>EB_NFIELDS):
                self.soa[f * self.cap + l] = self.soa[f * self.cap]
        self.fresh = True

    cdef void _sync_out(self) noexcept nogil:
        """The objects brought up to the lanes' state."""
        cdef size_t l
        if self.soa != NULL and self.fresh:
            for l in range(<size_t>self.count):
                _lane_to_obj(self.soa, self.cap, l, <EKF>self.p[l])

    cdef void _soa_step(self, const double* g, const double* a, const double* m, const double* hd,
                        double h, double* o) noexcept nogil:
        """One sample for every filter on the lanes: the four-lane step where ekfb_fast allows
        it, the filter's own batch loop (with its state copied in and back) elsewhere."""
        cdef size_t n = self.count, cap = self.cap, l, k, slow
        cdef double* d = self.soa
        cdef double qo[4][4]
        cdef double qq[4]
        if not self.fresh:
            self._load_lanes()
        slow = ekfb_fast(d, cap, n, g, a, m, hd, h, self.dt_nominal)
        if slow:
            for l in range(n):
                if d[EB_FAST * cap + l] == 0.0:
                    _lane_to_obj(d, cap, l, <EKF>self.p[l])
        for l in range(0, cap, 4):
            ekfb_block(d, cap, l, m != NULL, qo)
            for k in range(4):
                if l + k < n:
                    qq[0] = qo[0][k]; qq[1] = qo[1][k]; qq[2] = qo[2][k]; qq[3] = qo[3][k]
                    quat_out(qq, self.ned, o + 4 * (l + k))
        if slow:
            for l in range(n):
                if d[EB_FAST * cap + l] == 0.0:
                    (<Estimator>self.p[l])._run_batch(g + 3 * l, a + 3 * l, m + 3 * l if m != NULL else NULL,
                                                      NULL, hd[l] if hd != NULL else h, o + 4 * l, 1, False)
                    _obj_to_lane(<EKF>self.p[l], d, cap, l, False)

    # --- in-use guard: the GIL is held from the test to the set, so two threads cannot both pass
    def _enter(self, int mode=2):
        """Mark the bank in use. mode 2 (a call that may change the filter objects: reset,
        load_state): the objects brought up to date and the lanes reloaded from them at the
        next step; 1 (a call that reads them): brought up to date; 0 (a step): neither."""
        if self.busy:
            raise RuntimeError("this bank is in use by another thread (a call on it is in "
                               "progress); give each thread its own bank")
        self.busy = True
        if mode >= 1:
            self._sync_out()
        if mode == 2:
            self.fresh = False

    def _exit(self):
        self.busy = False

    cdef int _hold_filters(self) except -1:
        """Mark every filter (and its prefilters) in use for a step, as its own run would: a
        filter object reached from elsewhere (envs.vector's robots hold theirs) is refused
        meanwhile, its __init__ included, rather than changed under the step. Tested, then
        set in one pass, with the GIL held and no Python code between (one step for Python
        threads); the bank's filters are distinct objects, so a flag found set is another's."""
        cdef Py_ssize_t i, j
        for i in range(self.count):
            if in_use(<Estimator>self.p[i]):
                for j in range(i):
                    mark_in_use(<Estimator>self.p[j], False)
                raise RuntimeError("estimator in use by another thread")
            mark_in_use(<Estimator>self.p[i], True)
        return 0

    cdef void _release_filters(self) noexcept:
        cdef Py_ssize_t i
        for i in range(self.count):
            mark_in_use(<Estimator>self.p[i], False)

    @property
    def _in_use(self):
        return bool(self.busy)

    def update(self, gyr, acc, mag=None, dt=None):
        """One sample for every filter: gyr, acc, mag (count, 3) arrays (mag None: 6-axis);
        dt None (1/fs), a scalar, or (count,) steps in s. Returns (count, 4) quaternions."""
        cdef Py_ssize_t n = self.count, i
        cdef double h = self.dt_nominal
        D = None
        if dt is not None:
            if np.ndim(dt) == 0:
                h = check_dt(dt)
            else:
                D = time_steps(dt, (n,))
                if D is None:
                    raise ValueError(f"dt must be None, a scalar or an array of shape ({n},), got {dt!r}")
        G = gyr if _rows_ok(gyr, n) else as_samples(gyr, "gyr", (n, 3), f"({n}, 3)", n)
        A = acc if _rows_ok(acc, n) else as_samples(acc, "acc", (n, 3), f"({n}, 3)", n)
        M = None if mag is None else (mag if _rows_ok(mag, n) else as_samples(mag, "mag", (n, 3), f"({n}, 3)", n))
        cdef cnp.npy_intp dims[2]
        dims[0] = n
        dims[1] = 4
        out = cnp.PyArray_SimpleNew(2, dims, cnp.NPY_DOUBLE)
        cdef const double* g = _ptr(G)
        cdef const double* a = _ptr(A)
        cdef const double* m = _ptr(M)
        cdef const double* hd = _ptr(D)
        cdef double* o = <double*>cnp.PyArray_DATA(<cnp.ndarray>out)
        cdef int s = 0
        if self.busy:
            self._enter()                                      # raises
        self.busy = True
        try:
            if self.check:
                with nogil:
                    i = _first_invalid(g, a, m, n, &s)
                if i >= 0:
                    check_samples(G, A, M, n, False)           # raises, naming it
            self._hold_filters()
            try:
                if self.soa != NULL:
                    with nogil:
                        self._soa_step(g, a, m, hd, h, o)
                else:
                    with nogil:
                        for i in range(n):
                            (<Estimator>self.p[i])._run_batch(g + 3 * i, a + 3 * i, m + 3 * i if m != NULL else NULL,
                                                              NULL, hd[i] if hd != NULL else h, o + 4 * i, 1, False)
            finally:
                self._release_filters()
        finally:
            self.busy = False
        return out

    def _run(self, G, A, M, D, double dt, out):
        """T samples per filter: G, A, M C-contiguous float64 (T, count, 3) (M None: 6-axis),
        D None (dt throughout) or (T, count) steps; out (T, count, 4). Block by block of time,
        each filter's samples are gathered into rows of 3 and its batch loop runs over them:
        the same steps as one est.run over the whole column."""
        cdef Py_ssize_t T = G.shape[0]
        cdef const double* g = _ptr(G)
        cdef const double* a = _ptr(A)
        cdef const double* m = _ptr(M)
        cdef const double* h = _ptr(D)
        cdef double* o = <double*>cnp.PyArray_DATA(<cnp.ndarray>out)
        if T == 0:
            return
        self._hold_filters()
        try:
            self._run_held(g, a, m, h, dt, o, T)
        finally:
            self._release_filters()

    cdef int _run_held(self, const double* g, const double* a, const double* m, const double* h,
                       double dt, double* o, Py_ssize_t T) except -1:
        cdef Py_ssize_t c = self.count
        cdef Py_ssize_t t0, nb, i, k, src
        if self.soa != NULL:
            with nogil:
                for t0 in range(T):
                    self._soa_step(g + 3 * c * t0, a + 3 * c * t0, m + 3 * c * t0 if m != NULL else NULL,
                                   h + c * t0 if h != NULL else NULL, dt, o + 4 * c * t0)
            return 0
        # gathered block by block (in cache): whole (count, T, 3) transposed copies cost 15 %
        # of a 64-ekf bank's run; gathered, the bank runs as fast as count separate est.run
        cdef double* buf = <double*>malloc(RUN_BLOCK * 14 * sizeof(double))
        if buf == NULL:
            raise MemoryError()
        cdef double* sg = buf
        cdef double* sa = buf + 3 * RUN_BLOCK
        cdef double* sm = buf + 6 * RUN_BLOCK
        cdef double* so = buf + 9 * RUN_BLOCK
        cdef double* sd = buf + 13 * RUN_BLOCK
        with nogil:
            t0 = 0
            while t0 < T:
                nb = min(RUN_BLOCK, T - t0)
                for i in range(c):
                    for k in range(nb):
                        src = 3 * ((t0 + k) * c + i)
                        sg[3 * k] = g[src]; sg[3 * k + 1] = g[src + 1]; sg[3 * k + 2] = g[src + 2]
                        sa[3 * k] = a[src]; sa[3 * k + 1] = a[src + 1]; sa[3 * k + 2] = a[src + 2]
                        if m != NULL:
                            sm[3 * k] = m[src]; sm[3 * k + 1] = m[src + 1]; sm[3 * k + 2] = m[src + 2]
                        if h != NULL:
                            sd[k] = h[(t0 + k) * c + i]
                    (<Estimator>self.p[i])._run_batch(sg, sa, sm if m != NULL else NULL,
                                                      sd if h != NULL else NULL, dt, so, nb, False)
                    for k in range(nb):
                        src = 4 * ((t0 + k) * c + i)
                        o[src] = so[4 * k]; o[src + 1] = so[4 * k + 1]
                        o[src + 2] = so[4 * k + 2]; o[src + 3] = so[4 * k + 3]
                t0 += nb
        free(buf)
        return 0

    def _quaternions(self):
        """(count, 4): every filter's attitude in its public frame."""
        out = np.empty((self.count, 4))
        cdef double[:, ::1] o = out
        cdef Py_ssize_t i
        for i in range(self.count):
            (<Estimator>self.p[i])._output_q(&o[i, 0])
        return out

