# acc_lowpass (docs/estimators.md): the accelerometer low-passed in a frame that turns with the
# bias-corrected gyro alone, as VQF's (Laidig & Seel, "VQF: Highly accurate IMU orientation
# estimation with bias estimation and magnetic disturbance rejection", 2023); the ekf family,
# mahony, madgwick and the ukf share it, each with its own AccLowpass (its state fields:
# fusion._core.struct_fields(<AccLowpass[:1]>&..., ACC_LP_CHECKS, "acc_")).
from libc.math cimport M_PI
from fusion._qmath cimport half_angle_terms, rot_to_body
from fusion._constants cimport lasted


cdef struct AccLowpass:
    double lp[3]        # the low-passed sample, in the body frame (acc_gyro_lowpass)
    bint lp_started     # lp has its first sample
    double lp_time      # s since its first sample, held at tau (the running-mean start)


cdef inline void acc_gyro_lowpass(double tau, AccLowpass* s, const double* gyr,
                                  const double* b, const double* acc,
                                  double dt, double* out) noexcept nogil:
    """The sample turned into the frame qg (the gyro minus the bias b integrated from the
    first sample, never corrected; gyr NULL: not turned), low-passed there (first order,
    time constant tau; the first sample starts it), and turned back with qg into out: a
    body-frame vertical the linear acceleration of a shaken body averages out of, and that
    does not depend on the filter's corrections. For its first tau seconds (lp_time: the time
    since the first sample, held at tau after) it is the running mean of the samples so far,
    which weighs them alike: an exponential low-pass would hold the first sample, and the
    linear acceleration in it, for about tau.
    Computed in the body frame, the same filter: with qg <- qg ⊗ dq (dq the step's turn,
    Φ(gyr - b, dt)'s first column) and l = R(qg)ᵀ lp_nav, the frame qg's low-pass
    lp_nav <- lp_nav + k (R(qg) acc - lp_nav) is l <- R(dq)ᵀ l + k (acc - R(dq)ᵀ l): one
    rotation a sample where the frame form took qg's propagation, its normalisation and two
    rotations (the ekf's 9-axis sample about 15 ns faster: benchmarks/README.md); the
    outputs move by round-off, which the low-pass forgets at the rate k."""
    cdef double dq[4]
    cdef double t[3]
    cdef double k, c, sn
    cdef double* lp = s.lp
    if not s.lp_started:
        lp[0] = acc[0]
        lp[1] = acc[1]
        lp[2] = acc[2]
        s.lp_started = True
        s.lp_time = 0.0
    else:
        if gyr != NULL:
            half_angle_terms(gyr[0] - b[0], gyr[1] - b[1], gyr[2] - b[2], dt, &c, &sn)
            dq[0] = c
            dq[1] = (gyr[0] - b[0]) * sn
            dq[2] = (gyr[1] - b[1]) * sn
            dq[3] = (gyr[2] - b[2]) * sn
            rot_to_body(dq, lp, t)
            lp[0] = t[0]
            lp[1] = t[1]
            lp[2] = t[2]
        s.lp_time += dt
        if lasted(s.lp_time, tau):      # (the steps' sum may fall short of tau by round-off)
            s.lp_time = tau
        k = dt / (s.lp_time + dt)
        lp[0] += k * (acc[0] - lp[0])
        lp[1] += k * (acc[1] - lp[1])
        lp[2] += k * (acc[2] - lp[2])
    out[0] = lp[0]
    out[1] = lp[1]
    out[2] = lp[2]


cdef inline bint acc_lowpass_settles(double tau, const AccLowpass* s, double t0) noexcept nogil:
    """This sample ended the low-pass's running-mean start: its lp_time was t0 (< tau) before
    the sample and is tau now (a restart, where the gyro frame is lost, sets it to 0; tau 0:
    never). The Kalman filters' tilt variance grows back then (docs/estimators.md, "The
    start")."""
    return t0 < tau <= s.lp_time


cdef inline double start_variance(double sa, double tau, double dt) noexcept nogil:
    """The variance (rad² of tilt) of the running mean that ends the start on a sample of step
    dt: sa² / (tau + dt), sa the accelerometer's noise density over g, the n samples of the
    mean spanning lp_time + dt = tau + dt; at most π², an angle's (tau below one step: about
    one sample's own variance, sa² / dt)."""
    cdef double v = sa * sa / (tau + dt)
    return v if v < M_PI * M_PI else M_PI * M_PI


cdef inline bint acc_lowpass_lost(const double* gyr, bint sat, double dt, double dt_nominal) noexcept nogil:
    """True when the gyro did not measure this step's motion (no sample, a saturated one, or a
    gap of more than two nominal periods): the gyro frame is lost, and the low-pass restarts
    from the next accelerometer sample (the filter's attitude variance has grown for the same
    reason, so it takes that raw sample as it would without the low-pass)."""
    return gyr == NULL or sat or dt > 2.0 * dt_nominal


cdef inline const double* acc_lowpassed(double tau, AccLowpass* s, const double* gyr, bint sat,
                                        const double* b, const double* acc, double dt,
                                        double dt_nominal, double* out) noexcept nogil:
    """The accelerometer sample a filter corrects with: low-passed (into out) when tau > 0,
    acc itself otherwise (NULL stays NULL); the low-pass restarts first when the gyro frame
    is lost (acc_lowpass_lost; sat: the gyro sample is saturated)."""
    if tau <= 0.0:
        return acc
    if acc_lowpass_lost(gyr, sat, dt, dt_nominal):
        acc_lowpass_clear(s)
    if acc == NULL:
        return NULL
    acc_gyro_lowpass(tau, s, gyr, b, acc, dt, out)
    return out


cdef inline void acc_lowpass_clear(AccLowpass* s) noexcept nogil:
    s.lp[0] = 0.0
    s.lp[1] = 0.0
    s.lp[2] = 0.0
    s.lp_started = False
    s.lp_time = 0.0
