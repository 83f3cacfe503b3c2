cdef class Prefilter:
    """A per-sample filter on one 3-vector sensor stream (Butterworth, sliding mean, ...)."""
    cdef void apply(self, double* v) noexcept nogil    # in place
    cdef void clear(self) noexcept nogil              # forget the history
    cdef list _state_fields(self)                     # its history, as Estimator._state_fields


# The base class every estimator kernel derives from: sample validation, initial attitude,
# the frame boundary, the per-call and batch entry points. Subclasses implement _step.

cdef class Estimator:
    cdef double q[4]            # attitude, ENU, body -> navigation
    cdef readonly double fs     # nominal sample rate, Hz
    cdef double dt_nominal      # 1 / fs
    cdef bint ned               # convert at the public boundary
    cdef bint skip_invalid      # on_invalid == "skip"
    cdef bint is_init             # start attitude set
    cdef bint has_q0            # reset() was given a start attitude
    cdef double q0[4]
    cdef long long n_skip_gyr, n_skip_acc, n_skip_mag
    # optional prefilters an estimator composes (None: raw samples), applied to valid samples
    cdef Prefilter pre_gyr, pre_acc, pre_mag

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil
    cdef void _reset_state(self) noexcept nogil
    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil
    cdef void _output_q(self, double* out) noexcept nogil
    # Every C field that determines future outputs, as (name, typed memoryview onto the field,
    # check) with check None, (lo, hi) for integers (hi None: unbounded) or "unit" for a
    # quaternion. state() / load_state() / pickling are built on it in the base class; a
    # kernel with state of its own extends its parent's list.
    cdef list _state_fields(self)
