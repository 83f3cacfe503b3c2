from libc.string cimport memcpy
from fusion._qmath cimport vec3_valid, vec3_finite, quat_mul

# sqrt(1/2) to the last bit (the NED frame change)
cdef extern from *:
    """
    #define FUSION_SQRT_HALF 0.70710678118654752440084436210484903928483593768847
    """
    double SQRT_HALF "FUSION_SQRT_HALF"

cdef class Prefilter:
    """A per-sample filter on one 3-vector sensor stream (Butterworth, sliding mean, ...)."""
    cdef void apply(self, double* v) noexcept nogil    # in place
    cdef void clear(self) noexcept nogil              # forget the history
    cdef list _state_fields(self)                     # its history, as Estimator._state_fields
    cdef bint busy                                    # in use: a run, or its estimator's


# The base class every estimator kernel derives from: sample validation, initial attitude,
# the frame boundary, the per-call and batch entry points. Subclasses implement _step.

cdef class Estimator:
    cdef double q[4]            # attitude, ENU, body -> navigation
    cdef readonly double fs     # nominal sample rate, Hz
    cdef double dt_nominal      # 1 / fs
    cdef bint ned               # convert at the public boundary
    cdef double gyro_range_     # rad/s at which a gyro sample is saturated; 0: unknown
    cdef bint skip_invalid      # on_invalid == "skip"
    cdef bint is_init             # start attitude set
    cdef bint has_q0            # reset() was given a start attitude
    cdef double q0[4]
    cdef long long n_skip_gyr, n_skip_acc, n_skip_mag
    # optional prefilters an estimator composes (None: raw samples), applied to valid samples
    cdef Prefilter pre_gyr, pre_acc, pre_mag
    # set by the kernel's _configure: a subclass whose __init__ skips the base's is refused
    cdef bint configured
    # an __init__ / run / reset / state / load_state in progress (docs/estimators.md, "Threads")
    cdef bint busy

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil
    cdef void _reset_state(self) noexcept nogil
    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil
    cdef void _output_q(self, double* out) noexcept nogil
    # a kernel's _configure sets its prefilters (None: raw samples) through this
    cdef void _take_prefilters(self, Prefilter gyr, Prefilter acc, Prefilter mag) noexcept
    # the estimated gyro bias (rad/s, body frame) into out[3]; False: the estimator has none.
    # The bias property and the environment's compiled loop both read it here.
    cdef bint _bias(self, double* out) noexcept nogil
    # run()'s loop over n samples, rows of 3 (gyr, acc, mag; mag NULL for 6-axis) and 4 (out),
    # d the (n,) time steps or NULL for dt throughout. The base loops over _process; a kernel
    # may override it with a loop that inlines its step (see run_fast). With stop_invalid it
    # stops at the first sample that is not sample_valid and returns its index (the state is
    # then undefined: run() restores it); otherwise it returns n.
    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil
    # Every C field that determines future outputs, as (name, typed memoryview onto the field,
    # check) with check None, (lo, hi) for integers (hi None: unbounded) or "unit" for a
    # quaternion. state() / load_state() / pickling are built on it in the base class; a
    # kernel with state of its own extends its parent's list.
    cdef list _state_fields(self)


# the in-use flag (docs/estimators.md, "Threads") for a kernel's own entry points: _claim
# raises RuntimeError if the estimator is unconfigured or in use, else marks it in use
cdef int _claim(Estimator e) except -1
cdef void _release(Estimator e) noexcept

# the flags themselves, with no test of configuration or raising (the bank sets them on its
# filters for a step): the estimator's and its prefilters'
cdef inline bint pre_busy(Prefilter p) noexcept:
    return p is not None and p.busy

cdef inline void pre_mark(Prefilter p, bint busy) noexcept:
    if p is not None:
        p.busy = busy

cdef inline bint in_use(Estimator e) noexcept:
    return e.busy or pre_busy(e.pre_gyr) or pre_busy(e.pre_acc) or pre_busy(e.pre_mag)

cdef inline void mark_in_use(Estimator e, bint busy) noexcept:
    e.busy = busy
    pre_mark(e.pre_gyr, busy)
    pre_mark(e.pre_acc, busy)
    pre_mark(e.pre_mag, busy)


# --- for a kernel's own _run_batch: its step inlined, no virtual calls per sample ----------

cdef inline bint run_fast(Estimator e) noexcept nogil:
    """The samples go to the step as they are: no prefilter to apply."""
    return e.pre_gyr is None and e.pre_acc is None and e.pre_mag is None

cdef inline bint sample_valid(const double* g, const double* a, const double* m) noexcept nogil:
    """Every vector of the raw sample valid (what on_invalid='raise' requires)."""
    return vec3_finite(g) and vec3_valid(a) and (m == NULL or vec3_valid(m))

cdef inline bint sample_fast(Estimator e, const double* g, const double* a,
                             const double* m) noexcept nogil:
    """Initialised and every vector valid: _process would only call _step. Otherwise
    (skips, counting, the first attitude) the sample goes through _process."""
    return e.is_init and vec3_finite(g) and vec3_valid(a) and (m == NULL or vec3_valid(m))

# The state's one path through a kernel's batch loop: q and the kernel's state struct (size
# bytes at own; size 0: none) copied into locals before the loop (batch_enter), back after it
# (batch_leave), and around each sample the loop leaves to _process (batch_slow_sample).

cdef inline void batch_enter(Estimator e, double* q, void* local, const void* own,
                             size_t size) noexcept nogil:
    memcpy(q, e.q, 4 * sizeof(double))
    if size:
        memcpy(local, own, size)

cdef inline void batch_leave(Estimator e, const double* q, const void* local, void* own,
                             size_t size) noexcept nogil:
    memcpy(e.q, q, 4 * sizeof(double))
    if size:
        memcpy(own, local, size)

cdef inline bint batch_slow_sample(Estimator e, double* q, void* local, void* own, size_t size,
                                   const double* g, const double* a, const double* m, double dt,
                                   bint stop_invalid) noexcept nogil:
    """A sample sample_fast refused, through e._process with the locals written back first and
    read again after. True: the batch stops here (stop_invalid, and the sample is invalid)."""
    if stop_invalid and not sample_valid(g, a, m):
        return True
    batch_leave(e, q, local, own, size)
    e._process(g, a, m, dt)
    batch_enter(e, q, local, own, size)
    return False

# The batch loop itself, one for every kernel with a step of its own: step is the kernel's
# sample on the local state (local: its struct; q: the attitude), called through a constant
# pointer, which the compiler inlines into the kernel's _run_batch (no call per sample).
ctypedef void (*batch_step)(Estimator e, double* q, void* local, const double* g, const double* a,
                            const double* m, double dt) noexcept nogil

cdef inline Py_ssize_t batch_loop(Estimator e, batch_step step, void* local, void* own, size_t size,
                                  const double* g, const double* a, const double* m,
                                  const double* d, double dt, double* o, Py_ssize_t n,
                                  bint stop_invalid) noexcept nogil:
    """Estimator._run_batch's loop with the state in locals (stores through o cannot alias
    them, so the compiler keeps them in registers): the samples sample_fast accepts go to
    step, the others through batch_slow_sample."""
    cdef double q[4]
    cdef bint ned = e.ned
    cdef Py_ssize_t i
    cdef const double* mi
    cdef double h
    batch_enter(e, q, local, own, size)
    for i in range(n):
        mi = m + 3 * i if m != NULL else NULL
        h = d[i] if d != NULL else dt
        if sample_fast(e, g + 3 * i, a + 3 * i, mi):
            step(e, q, local, g + 3 * i, a + 3 * i, mi, h)
        elif batch_slow_sample(e, q, local, own, size, g + 3 * i, a + 3 * i, mi, h, stop_invalid):
            return i
        quat_out(q, ned, o + 4 * i)
    batch_leave(e, q, local, own, size)
    return n

cdef inline void quat_out(const double* q, bint ned, double* out) noexcept nogil:
    """The attitude q (ENU) in the public frame: c ⊗ q for NED."""
    cdef double c[4]
    if ned:
        c[0] = 0.0; c[1] = SQRT_HALF; c[2] = SQRT_HALF; c[3] = 0.0
        quat_mul(c, q, out)
    else:
        out[0] = q[0]; out[1] = q[1]; out[2] = q[2]; out[3] = q[3]
