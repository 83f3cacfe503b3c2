# Rest detection (docs/estimators.md, "Rest"): a component the filters that learn the gyro bias
# at rest hold (the ekf family, the ukf, cf-ekf through its EKF core); each does its own
# zero-rate update when rest_detect says so. docs/contributing.md says how a filter takes it.

from libc.math cimport sqrt, fmin, fmax
from fusion._constants cimport BIAS_MAX, lasted


cdef class RestDetector:
    cdef readonly double time       # s at rest before the gyro measures its bias (0: detection off)
    cdef readonly double gyro_tol   # rad/s: gyro within this of its low-pass, the low-pass within this of 0
    cdef readonly double acc_tol    # m/s^2: accelerometer within this of its low-pass
    cdef readonly double gyro_drift_tol   # rad/s: a still run ends when the gyro's low-pass moves this far (0: never)
    cdef readonly double acc_drift_tol    # m/s^2: ... or the accelerometer's (0: never)
    cdef readonly double noise      # rad/s/sqrt(Hz): the zero-rate measurement's noise density (REST)
    cdef readonly double tau        # s: the bias pulled toward the measured rate at rest (REST_PULL)
    cdef readonly double gate       # bias standard deviations: a Kalman filter's zero-rate update gate (REST; 0: off)
    cdef readonly double gate_time  # s: a still run this long passes the gate
    cdef double gyr[3]              # the low-passes
    cdef double acc[3]
    cdef double gyr0[3]             # the low-passes when the still run began
    cdef double acc0[3]
    cdef double fgyr[3]             # the samples the still tests judge (STILL_TAU low-passes)
    cdef double facc[3]
    cdef double t                   # s at rest so far
    cdef double lp_time             # s since the low-passes' first sample, held at REST_TAU (the running-mean start)
    cdef bint started               # the low-passes have their first sample
    cdef double gsum[3]             # the still run's gyro samples times dt, until an update takes them
    cdef double gsum_t              # s: the time they span (from about time on, at rest)
    cdef bint taken                 # an update has taken the run's sum (rest_rate)
    cdef long long n                # samples at rest since the reset (zero-rate updates and gated ones)
    # its state, as Estimator._state_fields: the holder's _state_fields adds it
    cdef list fields(self)


cdef extern from "_rest.h":
    # s: the low-passes (VQF's restFilterTau); the still tests' low-pass (fusion/_rest.h)
    double REST_TAU "FUSION_REST_TAU"
    double STILL_TAU "FUSION_REST_STILL_TAU"


cdef inline void rest_clear(RestDetector r) noexcept nogil:
    cdef int i
    for i in range(3):
        r.gyr[i] = 0.0
        r.acc[i] = 0.0
        r.gyr0[i] = 0.0
        r.acc0[i] = 0.0
        r.fgyr[i] = 0.0
        r.facc[i] = 0.0
        r.gsum[i] = 0.0
    r.gsum_t = 0.0
    r.taken = False
    r.t = 0.0
    r.lp_time = 0.0
    r.started = False
    r.n = 0


cdef inline void rest_start(RestDetector r, const double* gyr, const double* acc) noexcept nogil:
    """The low-passes start at the first sample with both (which is not at rest)."""
    cdef int i
    for i in range(3):
        r.gyr[i] = gyr[i]
        r.acc[i] = acc[i]
        r.fgyr[i] = gyr[i]
        r.facc[i] = acc[i]
    r.started = True
    r.t = 0.0
    r.lp_time = 0.0


cdef inline bint rest_in_place(RestDetector r) noexcept nogil:
    """The drift tests: True while both low-passes are within their drift tolerances of their
    values at the still run's first sample (a tolerance of 0: that test off)."""
    cdef double d, drift_g = 0.0, drift_a = 0.0
    cdef int i
    for i in range(3):
        d = r.gyr[i] - r.gyr0[i]
        drift_g += d * d
        d = r.acc[i] - r.acc0[i]
        drift_a += d * d
    return ((r.gyro_drift_tol <= 0.0 or drift_g <= r.gyro_drift_tol * r.gyro_drift_tol)
            and (r.acc_drift_tol <= 0.0 or drift_a <= r.acc_drift_tol * r.acc_drift_tol))


cdef inline void rest_count(RestDetector r, bint still, const double* gyr, double dt) noexcept nogil:
    """The still run's clock r.t, and its samples summed until an update takes them
    (rest_rate): still, as only the run's length shows."""
    cdef int i
    if still and r.t == 0.0:
        for i in range(3):
            r.gsum[i] = 0.0
        r.gsum_t = 0.0
        r.taken = False
    if still and not r.taken:
        for i in range(3):
            r.gsum[i] += gyr[i] * dt
        r.gsum_t += dt
    r.t = r.t + dt if still else 0.0


cdef inline bint rest_detect(RestDetector r, const double* gyr, const double* acc,
                             double dt) noexcept nogil:
    """One sample (gyr or acc NULL: the rest run ends); True when the body has been still for
    r.time s (counted in r.n): the caller then makes its zero-rate update."""
    cdef double k, kf, dg = 0.0, da = 0.0, d, m
    cdef bint still = True
    cdef int i
    if r.time <= 0.0:
        return False
    if gyr == NULL or acc == NULL:
        r.t = 0.0
        return False
    if not r.started:
        rest_start(r, gyr, acc)
        return False
    # REST_TAU low-passes, the running mean of the samples for their first REST_TAU s: a start
    # at one sample would hold its noise for a second, and the drift test below would take the
    # low-pass settling from it for motion
    r.lp_time += dt
    if r.lp_time > REST_TAU:
        r.lp_time = REST_TAU
    k = dt / (r.lp_time + dt)
    # the still tests judge the samples through a STILL_TAU low-pass above 1 / STILL_TAU Hz
    # (the samples themselves below): their noise, which grows with the rate, would otherwise
    # fail the tolerances at 1 kHz on a still sensor
    kf = dt / STILL_TAU
    for i in range(3):
        r.gyr[i] += k * (gyr[i] - r.gyr[i])
        r.acc[i] += k * (acc[i] - r.acc[i])
        if kf >= 1.0:
            r.fgyr[i] = gyr[i]
            r.facc[i] = acc[i]
        else:
            r.fgyr[i] += kf * (gyr[i] - r.fgyr[i])
            r.facc[i] += kf * (acc[i] - r.facc[i])
        d = r.fgyr[i] - r.gyr[i]
        dg += d * d
        d = r.facc[i] - r.acc[i]
        da += d * d
        # a steady turn is not rest, however smooth: the mean rate must be bias-sized
        m = r.gyr[i] if r.gyr[i] > 0.0 else -r.gyr[i]
        still = still and m < r.gyro_tol
    still = still and dg < r.gyro_tol * r.gyro_tol and da < r.acc_tol * r.acc_tol
    # the turning point of a slow oscillation passes the tests above for a moment, but its
    # low-passes keep moving (the rate's through zero, the tilt's vertical): at rest they stay
    if still and r.t == 0.0:
        for i in range(3):
            r.gyr0[i] = r.gyr[i]
            r.acc0[i] = r.acc[i]
    elif still:
        still = rest_in_place(r)
    rest_count(r, still, gyr, dt)
    if not lasted(r.t, r.time):
        return False
    r.n += 1
    return True


cdef inline double rest_rate(RestDetector r, const double* gyr, double dt, double* z) noexcept nogil:
    """The rate the zero-rate update (or the bias pull) takes at rest (rest_detect True, and a
    gate's yes), into z; returns the time it averages. The run's first update takes the mean of
    its samples so far (at least r.time s of them): they were still, as only the run's length
    shows, and an update that took the one sample would lose them; after it, the sample
    itself (dt). (At rest the sample is still, so the sum holds it until taken.) The mean is
    held within BIAS_MAX: the detector's tolerances bound it far below, but a loaded state's
    sum and time are checked one by one, and a crafted pair (sum 1e6 rad, time 1 s) pulled the
    Kalman filters' bias to 7e5 rad/s, a state they could not load again."""
    cdef int i
    if not r.taken:
        r.taken = True
        for i in range(3):
            z[i] = fmin(fmax(r.gsum[i] / r.gsum_t, -BIAS_MAX), BIAS_MAX)
        return r.gsum_t
    for i in range(3):
        z[i] = gyr[i]
    return dt


cdef inline bint rest_gate_open(RestDetector r, const double* b, double v0, double v1,
                                double v2) noexcept nogil:
    """A Kalman filter's zero-rate update at rest (rest_detect True) goes ahead unless the still
    run is shorter than r.gate_time and the gyro's low-pass is more than r.gate bias standard
    deviations (variances v0, v1, v2 of the estimate b) plus r.gyro_drift_tol from b on some
    axis: the turning point of a slow turn about the vertical, whose rate stays under the
    rest tolerances for a second, is not taken for a bias the filter already knows better."""
    cdef double v[3]
    cdef double d
    cdef int i
    if r.gate <= 0.0 or lasted(r.t, r.gate_time):
        return True
    v[0] = v0
    v[1] = v1
    v[2] = v2
    for i in range(3):
        d = r.gyr[i] - b[i]
        if d * d > (r.gate * sqrt(v[i]) + r.gyro_drift_tol) ** 2:
            return False
    return True
