# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Estimator base class: the public interface shared by every kernel (docs/estimators.md)."""
import numpy as np
cimport numpy as cnp
from libc.math cimport sqrt, atan2, asin, isfinite
from libc.string cimport memcpy
from fusion._constants cimport (GRAVITY as C_GRAVITY, STANDARD_GRAVITY as C_STANDARD_GRAVITY,
                               BIAS_MAX as C_BIAS_MAX)
from fusion.checks import number, choice, state_header, not_masked, SAMPLES_HINT

from fusion._qmath cimport (vec3_valid, vec3_finite, quat_from_acc_mag, quat_mul,
                            quat_normalise)

cnp.import_array()

# ENU -> NED: x_ned = y_enu, y_ned = x_enu, z_ned = -z_enu (180 deg about (1, 1, 0)/sqrt 2);
# c = [0, √½, √½, 0] (quat_out in _core.pxd), its conjugate for q0 given in NED.
cdef double C_NED_CONJ[4]
C_NED_CONJ[:] = [0.0, -SQRT_HALF, -SQRT_HALF, 0.0]

# fusion/_constants.pxd's values, for fusion.constants (their Python names)
GRAVITY = C_GRAVITY
STANDARD_GRAVITY = C_STANDARD_GRAVITY

FRAMES = ("ENU", "NED")
ON_INVALID = ("raise", "skip")

# --- state round trip (docs/estimators.md, "State, pickling, copies") --------------------
# 2: rest detection (ekf family, ukf, cf-ekf), cf-ekf t_quiet, mahony/madgwick t_recover;
# 3: magnetic disturbance detection; 4: rest detection in mahony, cf-ekf composed (an EKF core
# and a mahony, its fields "cf.*"), the disturbance detector a component (fields magd_*);
# 5: the accelerometer low-pass's running-mean start (acc_lp_time); 6: the low-pass held in
# the body frame (acc_lp; acc_qg gone), a version-5 acc_lp being in the frame acc_qg, and the
# magnetic disturbance detector's settling (magd_t_settle); 7: the detector's test of a field
# that turns with the sensor (magd_dir, magd_t_fixed); 8: the rest detector's drift test and
# running-mean start, its still tests' 10 ms low-pass (rest_gyr0, rest_acc0, rest_lp_time, rest_fgyr,
# rest_facc; rest_gyro_drift_tol, rest_acc_drift_tol); 9: the still run's gyro sum before rest,
# which the first zero-rate update takes (rest_gsum, rest_gsum_t)
STATE_VERSION = 9
STATE_KEYS = ("version", "estimator", "fs", "frame", "on_invalid", "params", "fields")
FLAG = (0, 1)           # check of a bint field
# check of a counter: below 2**62, so that stepping a loaded counter (one a sample) never
# overflows its long long (2**62 samples: 146 years at 1 GHz)
COUNT = (0, 2 ** 62)
# checks of float fields (_checked_field): (lo, hi) for every element; "unit" a unit vector
# (the quaternions); "cov" a covariance; None the default magnitude bound VALUE_MAX
BIAS_MAX = C_BIAS_MAX   # rad/s (fusion/_constants.pxd)
BIAS = (-BIAS_MAX, BIAS_MAX)
TIME_MAX = 1e9          # s (32 years): the timers (rest, unmeasured run, ...)
# A timer grows without bound (4 s of run() at dt=100 passes 1e9 s); est.state() exports it
# clamped at TIME_MAX, so that a state produced always loads. That changes no output: each
# timer is compared only with a time far below TIME_MAX (fusion/params.py and the PARAMS):
# rest t_rest with rest_time <= 1e4 s; the low-pass starts (rest_lp_time, acc_lp_time) are
# held at rest_tau / acc_lowpass <= 1e4 s; cf-ekf t_quiet with LEARN_HOLD = 0.5 s; aekf t_dir
# with acc_pred_timeout <= 1e4 s; t_unmeasured enters motion_rate t, whose square is capped
# at pi² from t = pi / motion_rate on: <= TIME_MAX, motion_rate being 0 or >= 1e-6 rad/s.
# The magnetic detector's timers (magd_*) are bounded by VALUE_MAX only: not clamped.
TIMER = (0.0, TIME_MAX)
RECOVERY = (-100.0, 3.0)    # recovery_gain's t_left: 3 s after a saturated sample, past 0 by < dt
VALUE_MAX = 1e100       # low-passes, sums and histories: their squares stay far from overflow
COV = "cov"
ACC_LP_CHECKS = {"lp_time": TIMER}     # struct_fields' checks of an AccLowpass (fusion/_acclp.pxd)
COV_MAX = 1e6           # largest variance of a loaded covariance (rad², (rad/s)²; a gap adds < pi²)


# a sample's rules, as fusion/_qmath.pxd's vec3_finite and vec3_valid test them: the squared
# norm must be finite too, so a finite 1e300 is refused
FINITE_RULE = "finite, with a finite squared norm (each component below about 1e154)"
VALID_RULE = "finite and non-zero, with a finite squared norm (each component below about 1e154)"

# Time steps (given, or 1 / fs) the kernels accept: a longer gap is a restart (reset), a
# shorter one is no IMU; beyond these, variances such as noise^2 / dt over- or underflow.
DT_MIN = 1e-6
DT_MAX = 100.0


def check_fs(value):
    """The sample rate in Hz: 1 / fs must be a valid dt."""
    return number("fs", value, 1.0 / DT_MAX, 1.0 / DT_MIN)


def check_dt(value):
    return number("dt", value, DT_MIN, DT_MAX)


def _as_samples(x, name, int n=-1, str hint=SAMPLES_HINT):
    """An (N, 3) float64 C-contiguous copy-or-view of x, or a ValueError saying what is accepted
    (hint: not_masked's, for an estimator's samples by default)."""
    not_masked(name, x, hint)
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be a real numeric array (float or int), got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if n >= 0 and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} samples but gyr has {n}; lengths must match")
    return np.ascontiguousarray(arr, dtype=np.float64)


# run() with on_invalid='raise' checks the samples inside its loop (no pass over the input
# before it) from this many samples on, which costs a copy of the state (a few microseconds)
FUSED_CHECK_MIN = 2048


def _check_samples(G, A, M, Py_ssize_t n):
    """ValueError naming the first invalid sample of the first sensor (gyr, acc, mag) that
    has one; nothing if every sample is valid."""
    cdef const double[:, ::1] g = G
    cdef const double[:, ::1] a = A
    cdef const double[:, ::1] m = M if M is not None else np.empty((0, 3))
    cdef bint has_mag = M is not None
    cdef Py_ssize_t i, bad_g = -1, bad_a = -1, bad_m = -1
    with nogil:
        for i in range(n):
            if bad_g < 0 and not vec3_finite(&g[i, 0]):
                bad_g = i
            if bad_a < 0 and not vec3_valid(&a[i, 0]):
                bad_a = i
            if has_mag and bad_m < 0 and not vec3_valid(&m[i, 0]):
                bad_m = i
    for arr, nm, b, rule in ((G, "gyr", bad_g, FINITE_RULE), (A, "acc", bad_a, VALID_RULE),
                             (M, "mag", bad_m, VALID_RULE)):
        if b >= 0:
            raise ValueError(f"{nm} must be {rule}; {nm}[{b}] = {arr[b]!r} "
                             f"(on_invalid='skip' skips such samples)")


def unit_q0(q0, name="q0"):
    """q0 (4 real numbers [w, x, y, z], finite, not all zero) as a unit float64 array, or a
    ValueError naming it: what est.reset(q0) and bank.reset(q0) accept."""
    not_masked(name, q0)
    a = np.asarray(q0)
    if a.dtype.kind not in "fiu" or a.shape != (4,):
        raise ValueError(f"{name} must be 4 real numbers [w, x, y, z], got {q0!r}")
    a = a.astype(np.float64)
    m = float(np.max(np.abs(a)))
    if not np.isfinite(m) or m == 0.0:
        raise ValueError(f"{name} must be finite and non-zero, got {q0!r}")
    a = a / m        # scaled first: the squares of 1e-160 or 1e200 under- or overflow
    return a / float(np.sqrt(np.sum(a * a)))


cdef int _read_vec3(object v, str name, double* out) except -1:
    """One 3-vector from a float64 array (fast path), or anything array-like of 3 numbers."""
    cdef cnp.ndarray arr
    cdef char* p
    cdef Py_ssize_t st
    if type(v) is np.ndarray:
        arr = <cnp.ndarray>v
        # native byte order and aligned (ISBEHAVED_RO): a big-endian array goes the slow way
        if (cnp.PyArray_TYPE(arr) == cnp.NPY_DOUBLE and cnp.PyArray_NDIM(arr) == 1
                and cnp.PyArray_DIM(arr, 0) == 3 and cnp.PyArray_ISBEHAVED_RO(arr)):
            p = <char*>cnp.PyArray_DATA(arr)
            st = cnp.PyArray_STRIDE(arr, 0)
            out[0] = (<double*>p)[0]
            out[1] = (<double*>(p + st))[0]
            out[2] = (<double*>(p + 2 * st))[0]
            return 0
    not_masked(name, v, SAMPLES_HINT)
    a = np.asarray(v)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be 3 real numbers, got dtype {a.dtype}")
    if a.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {a.shape}")
    out[0] = float(a[0])
    out[1] = float(a[1])
    out[2] = float(a[2])
    return 0


cdef class Prefilter:
    """Base of the prefilter kernels (fusion._prefilter)."""

    cdef void apply(self, double* v) noexcept nogil:
        pass

    cdef void clear(self) noexcept nogil:
        pass

    cdef list _state_fields(self):
        return []


def struct_fields(view, checks=None, prefix=""):
    """The state fields of one C struct, as _state_fields lists them: view is the struct as a
    typed memoryview of one element (``<S[:1]>&self.s``), whose structured dtype gives every
    member's name, type and length, so that a member added to the struct is saved, loaded
    and checked with no other line. Each member is a field prefix + its name, a view onto
    the struct; its check from checks (name -> check), else None for doubles, FLAG for a
    bint (C int) and COUNT for a long long (an int member other than a bint must be given)."""
    a = np.asarray(view)
    checks = checks or {}
    unknown = set(checks) - set(a.dtype.names)
    if unknown:     # a misspelt name would fall back to the default check unnoticed
        raise ValueError(f"checks for no member of the struct: {sorted(unknown)}; members: {a.dtype.names}")
    out = []
    for name in a.dtype.names:
        v = a[name].reshape(-1)
        default = None if v.dtype.kind == "f" else (FLAG if v.dtype.itemsize == 4 else COUNT)
        out.append((prefix + name, v, checks.get(name, default)))
    return out


cdef list _fields_of(Estimator e):
    """The estimator's state fields followed by those of its prefilters ("pre_acc.z1", ...)."""
    fields = e._state_fields()
    for key, pre in (("pre_gyr", e.pre_gyr), ("pre_acc", e.pre_acc), ("pre_mag", e.pre_mag)):
        if pre is not None:
            fields += [(f"{key}.{n}", v, c) for n, v, c in (<Prefilter>pre)._state_fields()]
    return fields


def _check_header(state):
    state_header(state, STATE_KEYS, STATE_VERSION, "est.state()")
    if not isinstance(state["fields"], dict) or not isinstance(state["params"], dict):
        raise ValueError("state['fields'] and state['params'] must be dicts")


def _checked_field(name, value, view, check):
    """value as an array of the field's dtype and length, or a ValueError saying why not."""
    target = np.asarray(view)
    cdef Py_ssize_t n = target.shape[0]
    is_float = target.dtype.kind == "f"
    v = np.asarray(value)
    if v.dtype.kind not in ("fiu" if is_float else "iub"):
        kind = "real numbers" if is_float else "integers"
        raise ValueError(f"state field {name!r} must hold {kind}, got {value!r}")
    shape = () if n == 1 else (n,)
    if v.shape != shape:
        # a buffer's length follows a parameter (cf-ekf's window): a state saved with another
        # value (or another version's default) has its length
        raise ValueError(f"state field {name!r} must have shape {shape}, got {v.shape} (a state saved "
                         f"with other parameters? Estimator.from_state(state) makes an estimator with "
                         f"the state's own)")
    if is_float:
        v = v.astype(np.float64)
        if not np.isfinite(v).all():
            raise ValueError(f"state field {name!r} must be finite, got {value!r}")
        # (a component beyond 1 is no unit vector; the test keeps v @ v from overflowing)
        if check == "unit" and ((np.abs(v) > 1.0 + 1e-9).any() or abs(float(np.sqrt(v @ v)) - 1.0) > 1e-9):
            raise ValueError(f"state field {name!r} must be a unit {'quaternion' if n == 4 else 'vector'}, got {value!r}")
        if check == COV:
            _check_covariance(name, v.reshape(n), value)
        elif check != "unit":
            lo, hi = (-VALUE_MAX, VALUE_MAX) if check is None else check
            if (v < lo).any() or (v > hi).any():
                raise ValueError(f"state field {name!r} must be in [{lo:g}, {hi:g}], got {value!r}")
    else:
        lo, hi = check
        hi = np.iinfo(target.dtype).max if hi is None else hi
        if (v < lo).any() or (v > hi).any():
            raise ValueError(f"state field {name!r} must be in [{lo}, {hi}], got {value!r}")
    return v.astype(target.dtype).reshape(n)


def _check_covariance(name, v, value):
    """v (k² values, row-major) a symmetric positive-semidefinite covariance whose variances
    are at most COV_MAX, or a ValueError: an indefinite P stays indefinite, a huge one
    overflows. Semidefinite within rounding, judged on the correlations (so that one large
    variance cannot hide a negative one): the kernels make such a P themselves (a zero
    bias_init_std's bias block, zero variances with zero rows; the ukf's rounding, an eigenvalue
    of -1e-17, which its sigma points take), and their own state must load."""
    cdef Py_ssize_t k = int(round(np.sqrt(v.shape[0])))
    P = v.reshape(k, k)
    scale = float(np.abs(P).max())
    if not (np.abs(P - P.T) <= 1e-12 * scale).all():
        raise ValueError(f"state field {name!r} must be a symmetric covariance, got {value!r}")
    d = np.diag(P)
    if d.max() > COV_MAX:
        raise ValueError(f"state field {name!r} must have variances <= {COV_MAX:g}, got {value!r}")
    if d.min() < 0.0:
        raise ValueError(f"state field {name!r} must have variances >= 0, got {value!r}")
    live = d > 0.0
    if np.abs(P[~live]).max(initial=0.0) > 0.0:       # a zero variance with a non-zero covariance
        raise ValueError(f"state field {name!r} must be positive semidefinite, got {value!r}")
    if not live.any():
        return
    s = 1.0 / np.sqrt(d[live])
    C = P[np.ix_(live, live)] * np.outer(s, s)
    # rounding of the largest entries, seen through the smallest variance
    tol = 1e-9 + 1e-13 * scale / d[live].min()
    if np.linalg.eigvalsh(0.5 * (C + C.T)).min() < -tol:
        raise ValueError(f"state field {name!r} must be positive semidefinite, got {value!r}")


def _restore(cls, state):
    """Unpickling: rebuild from the state (Estimator.__reduce__)."""
    return cls.from_state(state)


cdef int _ready(Estimator e) except -1:
    """A RuntimeError unless e was configured and no call is using it."""
    if not e.configured:
        raise RuntimeError(f"{type(e).__name__} object was not configured: call the class's "
                           f"__init__ (a subclass's __init__ must call super().__init__) or use fusion.make")
    return _not_in_use(e)


cdef int _not_in_use(Estimator e) except -1:
    if in_use(e):
        raise RuntimeError("estimator in use by another thread")
    return 0


cdef int _claim(Estimator e) except -1:
    """_ready, then mark e and its prefilters in use (docs/estimators.md, "Threads"): the test
    and the set run with the GIL held and call no Python code, so for Python threads they
    are one step."""
    _ready(e)
    mark_in_use(e, True)
    return 0


cdef int _hold(Estimator e) except -1:
    """_claim without the configured test (__init__'s)."""
    _not_in_use(e)
    mark_in_use(e, True)
    return 0


cdef void _release(Estimator e) noexcept:
    mark_in_use(e, False)


cdef object _exclusively(Estimator e, f, tuple args):
    """f(*args) with e claimed for the call (_claim), released however the call ends."""
    _claim(e)
    try:
        return f(*args)
    finally:
        _release(e)


cdef class Estimator:
    """Base of every attitude estimator. Use fusion.make(name, fs, ...) to build one."""

    #: This estimator's parameters, name -> fusion.Param (default, unit, range, doc); the
    #: subclasses declare theirs, with fusion.params.table.
    PARAMS = {}
    #: Registry name (subclasses fill it in).
    name = None

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        """Configure the estimator (fusion.make calls this; a second call re-configures it):
        fs in Hz, frame, on_invalid, and the class's PARAMS as keywords. The object is held
        for the whole call as a run holds it (docs/estimators.md, "Threads"): a call from
        another thread is refused meanwhile, and this is refused while one is in progress.
        The kernel's _configure checks every argument before it takes any, so that a refused
        __init__ changes nothing."""
        old = (self.pre_gyr, self.pre_acc, self.pre_mag)
        _hold(self)         # test and set with the GIL held and no Python code between
        try:
            self._configure(fs, frame, on_invalid, params)
        finally:
            for p in old:   # those _configure replaced (_take_prefilters marked the new ones)
                pre_mark(p, False)
            _release(self)

    def _configure(self, fs, frame, on_invalid, params):
        """A kernel's configuration (overridden by each; docs/contributing.md): check
        everything (_check_init, _take_params, its own checks), then take it, the base's part
        with _take_base, set `configured`, and end with self._reset(None)."""
        self._take_base(self._check_init(fs, frame, on_invalid), frame, on_invalid,
                        self._take_params(params))

    def _take_base(self, fs, frame, on_invalid, p):
        """The base's part, all checked before (_check_init's fs): fs, frame, on_invalid, and of
        the checked parameters p (_take_params) the saturation range, in the estimators that
        declare it."""
        self.fs = fs
        self.dt_nominal = 1.0 / fs
        self.ned = frame == "NED"
        self.skip_invalid = on_invalid == "skip"
        if "gyro_range" in p:
            self.gyro_range_ = 0.0 if p["gyro_range"] is None else p["gyro_range"]

    cdef void _take_prefilters(self, Prefilter gyr, Prefilter acc, Prefilter mag) noexcept:
        """The prefilters in front of the three streams (None: raw samples), in use as the
        estimator is (in _configure, which __init__ holds: no other thread runs them before
        __init__ returns)."""
        pre_mark(gyr, self.busy)
        pre_mark(acc, self.busy)
        pre_mark(mag, self.busy)
        self.pre_gyr, self.pre_acc, self.pre_mag = gyr, acc, mag

    def _check_init(self, fs, frame, on_invalid):
        """__init__'s own arguments checked; fs as a float."""
        fs = check_fs(fs)
        choice("frame", frame, FRAMES)
        choice("on_invalid", on_invalid, ON_INVALID)
        return fs

    def _take_params(self, params):
        """The parameters: each given one checked by its Param, the defaults for the rest.
        Unknown names, and bad values, are a ValueError naming them and what is accepted.
        Nothing is taken here: the base's part by _take_base, a component the kernel holds
        (rest detection: fusion._rest; magnetic disturbance detection: fusion._magdist) built
        by the kernel from the values returned."""
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            accepted = ", ".join(sorted(self.PARAMS)) or "none"
            raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for estimator "
                             f"{self.name!r}; accepted: {accepted}")
        return {k: d.check(params[k]) if k in params else d.default for k, d in self.PARAMS.items()}

    # --- kernel hooks -------------------------------------------------------------------
    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        pass

    cdef void _reset_state(self) noexcept nogil:
        pass

    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil:
        """Prefilter and validate one sample (NULL = absent or invalid), initialise if
        needed, then step."""
        cdef double g[3]
        cdef double a[3]
        cdef double m[3]
        cdef bint gyr_ok = vec3_finite(gyr)
        cdef bint acc_ok = vec3_valid(acc)
        cdef bint mag_ok = mag != NULL and vec3_valid(mag)
        # prefilters see valid samples only, so a glitch never enters their history
        if gyr_ok and self.pre_gyr is not None:
            memcpy(g, gyr, 3 * sizeof(double))
            self.pre_gyr.apply(g)
            gyr = g
            gyr_ok = vec3_finite(g)
        if acc_ok and self.pre_acc is not None:
            memcpy(a, acc, 3 * sizeof(double))
            self.pre_acc.apply(a)
            acc = a
            acc_ok = vec3_valid(a)
        if mag_ok and self.pre_mag is not None:
            memcpy(m, mag, 3 * sizeof(double))
            self.pre_mag.apply(m)
            mag = m
            mag_ok = vec3_valid(m)
        if not gyr_ok:
            self.n_skip_gyr += 1
        if not acc_ok:
            self.n_skip_acc += 1
        if mag != NULL and not mag_ok:
            self.n_skip_mag += 1
        if not self.is_init:
            if not acc_ok:
                return
            quat_from_acc_mag(acc, mag if mag_ok else NULL, self.q)
            self.is_init = True
        self._step(gyr if gyr_ok else NULL, acc if acc_ok else NULL,
                   mag if mag_ok else NULL, dt)

    cdef list _state_fields(self):
        return [("q", <double[:4]>self.q, "unit"), ("q0", <double[:4]>self.q0, "unit"),
                ("is_init", <int[:1]><int*>&self.is_init, FLAG), ("has_q0", <int[:1]><int*>&self.has_q0, FLAG),
                ("n_skip_gyr", <long long[:1]>&self.n_skip_gyr, COUNT),
                ("n_skip_acc", <long long[:1]>&self.n_skip_acc, COUNT),
                ("n_skip_mag", <long long[:1]>&self.n_skip_mag, COUNT)]

    cdef void _output_q(self, double* out) noexcept nogil:
        quat_out(self.q, self.ned, out)

    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil:
        cdef Py_ssize_t i
        cdef const double* mi
        for i in range(n):
            mi = m + 3 * i if m != NULL else NULL
            if stop_invalid and not sample_valid(g + 3 * i, a + 3 * i, mi):
                return i
            self._process(g + 3 * i, a + 3 * i, mi, d[i] if d != NULL else dt)
            self._output_q(o + 4 * i)      # virtual: a kernel may report other than q (ekf-lp)
        return n

    # --- public interface ---------------------------------------------------------------
    def reset(self, q0=None):
        """Forget everything. q0 ([w, x, y, z] in the estimator's frame) fixes the start
        attitude; without it the first valid accelerometer (+ magnetometer) sample sets it."""
        _exclusively(self, self._reset, (q0,))

    def _reset(self, q0):
        cdef double qin[4]
        if q0 is not None:
            a = unit_q0(q0)
            for i in range(4):
                qin[i] = a[i]
            if self.ned:
                quat_mul(C_NED_CONJ, qin, self.q0)
            else:
                memcpy(self.q0, qin, 4 * sizeof(double))
            self.has_q0 = True
        else:
            self.has_q0 = False
            self.q0[:] = [1.0, 0.0, 0.0, 0.0]
        memcpy(self.q, self.q0, 4 * sizeof(double))
        self.is_init = self.has_q0
        self.n_skip_gyr = 0
        self.n_skip_acc = 0
        self.n_skip_mag = 0
        for pre in (self.pre_gyr, self.pre_acc, self.pre_mag):
            if pre is not None:
                (<Prefilter>pre).clear()
        self._reset_state()


    def update(self, gyr, acc, mag=None, dt=None):
        """One sample: gyr (rad/s), acc (m/s^2), mag (any unit, or None for 6-axis), all body
        frame, shape (3,); dt in s (default 1/fs). Returns the quaternion [w, x, y, z]."""
        cdef double g[3]
        cdef double a[3]
        cdef double m[3]
        cdef double h
        cdef cnp.npy_intp four = 4
        _read_vec3(gyr, "gyr", g)
        _read_vec3(acc, "acc", a)
        if mag is not None:
            _read_vec3(mag, "mag", m)
        h = self.dt_nominal if dt is None else check_dt(dt)
        if not self.skip_invalid:
            if not vec3_finite(g):
                raise ValueError(f"gyr must be {FINITE_RULE}, got {gyr!r} (on_invalid='skip' skips such samples)")
            if not vec3_valid(a):
                raise ValueError(f"acc must be {VALID_RULE}, got {acc!r} (on_invalid='skip' skips such samples)")
            if mag is not None and not vec3_valid(m):
                raise ValueError(f"mag must be {VALID_RULE}, got {mag!r} (on_invalid='skip' skips such samples)")
        out = cnp.PyArray_SimpleNew(1, &four, cnp.NPY_DOUBLE)
        # in use elsewhere? Tested here, after the last Python call: from here on the step
        # holds the GIL, so no other call can start before it ends (no flag to set)
        _ready(self)
        # through the batch loop, so that update() and run() run the same compiled code (the
        # compiler may fuse multiply-adds differently in two copies of a step)
        self._run_batch(g, a, m if mag is not None else NULL, NULL, h,
                        <double*>cnp.PyArray_DATA(out), 1, False)
        return out

    def run(self, gyr, acc, mag=None, dt=None):
        """A batch: gyr, acc, mag as (N, 3) arrays (mag None for 6-axis); dt None (1/fs), a
        scalar, or an (N,) array of time steps in s for uneven time stamps. Returns (N, 4)
        quaternions, the same numbers as N calls of update()."""
        return _exclusively(self, self._run, (gyr, acc, mag, dt))    # its loop releases the GIL

    def _run(self, gyr, acc, mag, dt):
        G = _as_samples(gyr, "gyr")
        cdef Py_ssize_t n = G.shape[0]
        A = _as_samples(acc, "acc", n)
        M = None if mag is None else _as_samples(mag, "mag", n)
        D = None
        cdef double dt_const = self.dt_nominal
        if dt is not None:
            if np.ndim(dt) == 0:
                dt_const = check_dt(dt)
            else:
                not_masked("dt", dt)
                D = np.asarray(dt)
                if D.dtype.kind not in "fiu" or D.shape != (n,):
                    raise ValueError(f"dt must be None, a scalar or an array of shape ({n},), "
                                     f"got dtype {D.dtype} shape {D.shape}")
                D = np.ascontiguousarray(D, dtype=np.float64)
                bad = np.flatnonzero(~((D >= DT_MIN) & (D <= DT_MAX)))     # NaN fails too
                if bad.size:
                    raise ValueError(f"dt must be finite and > 0 and in [{DT_MIN:g}, {DT_MAX:g}] s; "
                                     f"dt[{bad[0]}] = {D[bad[0]]!r}")
        cdef const double[:, ::1] g = G
        cdef const double[:, ::1] a = A
        cdef const double[:, ::1] m = M if M is not None else np.empty((0, 3))
        cdef const double[::1] d = D if D is not None else np.empty(0)
        cdef bint has_mag = M is not None
        cdef bint has_dt = D is not None
        cdef Py_ssize_t done
        cdef bint fused = not self.skip_invalid and n > FUSED_CHECK_MIN
        out = np.empty((n, 4))
        cdef double[:, ::1] o = out
        if n == 0:
            return out
        if not self.skip_invalid and not fused:
            _check_samples(G, A, M, n)     # raises naming the first invalid sample
        if fused:
            # on_invalid='raise' over a long batch: the loop checks each sample as it goes
            # (no separate pass over the input first) and stops at the first invalid one;
            # then the state is put back as it was and the same error raised
            saved = [np.array(view, copy=True) for _, view, _ in _fields_of(self)]
        with nogil:
            done = self._run_batch(&g[0, 0], &a[0, 0], &m[0, 0] if has_mag else NULL,
                                   &d[0] if has_dt else NULL, dt_const, &o[0, 0], n, fused)
        if done < n:
            for (_, view, _), v in zip(_fields_of(self), saved):
                np.asarray(view)[:] = v
            _check_samples(G, A, M, n)
            raise AssertionError(f"sample {done} stopped the batch but passes the checks")
        return out

    @property
    def quaternion(self):
        """Current attitude [w, x, y, z] in the estimator's frame (body -> navigation)."""
        cdef cnp.npy_intp four = 4
        out = cnp.PyArray_SimpleNew(1, &four, cnp.NPY_DOUBLE)
        self._output_q(<double*>cnp.PyArray_DATA(out))
        return out

    @property
    def euler(self):
        """Current ZYX Euler angles [yaw, pitch, roll] in radians, in the estimator's frame."""
        cdef double q[4]
        self._output_q(q)
        w, x, y, z = q[0], q[1], q[2], q[3]
        s = 2.0 * (w * y - x * z)
        s = 1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)
        return np.array([atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)), asin(s),
                         atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))])

    cdef bint _bias(self, double* out) noexcept nogil:
        return False

    @property
    def bias(self):
        """Estimated gyro bias (rad/s, body frame), or None if the estimator has none."""
        cdef double b[3]
        if not self._bias(b):
            return None
        return np.array([b[0], b[1], b[2]])

    @property
    def covariance(self):
        """State covariance, or None if the estimator keeps none."""
        return None

    @property
    def gyro_range(self):
        """Gyro range (rad/s) at which a sample counts as saturated, or None (unknown, or an
        estimator without saturation handling)."""
        return self.gyro_range_ if self.gyro_range_ > 0.0 else None

    @property
    def frame(self):
        return "NED" if self.ned else "ENU"

    @property
    def on_invalid(self):
        return "skip" if self.skip_invalid else "raise"

    @property
    def initialised(self):
        """True once the start attitude is set (by reset(q0) or a valid accelerometer sample)."""
        return bool(self.is_init)

    @property
    def skipped(self):
        """Counts of samples skipped as invalid since the last reset, per sensor."""
        return {"gyr": self.n_skip_gyr, "acc": self.n_skip_acc, "mag": self.n_skip_mag}

    @property
    def prefilters(self):
        """The prefilter in front of each sensor stream (None where samples go in raw)."""
        return {"gyr": self.pre_gyr, "acc": self.pre_acc, "mag": self.pre_mag}

    @property
    def params(self):
        """This estimator's parameters (name -> value)."""
        return {k: getattr(self, k) for k in self.PARAMS}

    # --- state, pickling, copies ---------------------------------------------------------
    def state(self):
        """Everything that determines future outputs (attitude, bias, covariance, integrator
        terms, flags, counters, prefilter histories), with the configuration, as a plain dict
        of Python numbers, lists and strings (picklable, JSON-serialisable, exact).
        est.load_state(s) or Estimator.from_state(s) resumes bit-identically."""
        return _exclusively(self, self._state, ())

    def _state(self):
        fields = {}
        for name, view, check in _fields_of(self):
            a = np.asarray(view)
            if check == TIMER:      # clamped: see TIMER
                a = np.minimum(a, TIME_MAX)
            fields[name] = a.tolist() if a.shape[0] > 1 else a[0].item()
        return {"version": STATE_VERSION, "estimator": self.name, "fs": self.fs,
                "frame": self.frame, "on_invalid": self.on_invalid, "params": self.params,
                "fields": fields}

    def load_state(self, state):
        """Restore a state from est.state() of an estimator of the same kind. The dynamic
        state is replaced; this estimator's configuration (fs, frame, parameters) is kept.
        A ValueError (and nothing changed) for another estimator, another state version,
        missing or extra fields, wrong shapes or types, or values out of their ranges (each
        field's in _state_fields: a covariance symmetric positive semidefinite, a bias within
        BIAS_MAX, timers within TIME_MAX, ...)."""
        _exclusively(self, self._load_state, (state,))

    def _load_state(self, state):
        _check_header(state)
        if state["estimator"] != self.name:
            raise ValueError(f"state is of estimator {state['estimator']!r}, not {self.name!r}")
        given = state["fields"]
        fields = _fields_of(self)
        names = [f[0] for f in fields]
        missing = [k for k in names if k not in given]
        extra = sorted(set(given) - set(names))
        if missing or extra:
            raise ValueError(f"state fields do not match this {self.name!r} estimator (a different "
                             f"prefilter or window, or a state saved by another version?): missing {missing}, unexpected {extra}")
        # check everything before writing anything
        values = [_checked_field(name, given[name], view, check) for name, view, check in fields]
        for (name, view, check), v in zip(fields, values):
            np.asarray(view)[:] = v

    @classmethod
    def from_state(cls, state):
        """A new estimator with the configuration and state in `state` (from est.state())."""
        _check_header(state)
        if cls.name is not None and state["estimator"] != cls.name:
            raise ValueError(f"state is of estimator {state['estimator']!r}, not {cls.name!r}")
        if cls.name is None:
            import fusion
            est = fusion.make(state["estimator"], state["fs"], frame=state["frame"],
                              on_invalid=state["on_invalid"], **state["params"])
        else:
            est = cls(state["fs"], frame=state["frame"], on_invalid=state["on_invalid"],
                      **state["params"])
        est.load_state(state)
        return est

    def __reduce__(self):
        # pickle, copy.copy and copy.deepcopy all go through the state: one mechanism
        return (_restore, (type(self), self.state()))

    def __repr__(self):
        if not self.configured:
            return f"<{type(self).__name__} object, not configured>"
        extra = "".join(f", {k}={v!r}" for k, v in self.params.items())
        return f"fusion.make({self.name!r}, fs={self.fs!r}, frame={self.frame!r}{extra})"
