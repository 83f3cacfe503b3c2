# acc_lowpass (docs/estimators.md): the accelerometer low-passed in a frame that turns with the
# bias-corrected gyro alone, as VQF's (Laidig & Seel, "VQF: Highly accurate IMU orientation
# estimation with bias estimation and magnetic disturbance rejection", 2023); the ekf family,
# mahony, madgwick and the ukf share it, each with its own AccLowpass (its state fields:
# fusion._core.struct_fields(<AccLowpass[:1]>&..., ACC_LP_CHECKS, "acc_")).
from libc.string cimport memcpy
from fusion._qmath cimport phi_matrix, quat_normalise, rot_to_nav, rot_to_body


cdef struct AccLowpass:
    double lp[3]        # the low-passed sample, in the frame qg
    double qg[4]        # the bias-corrected gyro integrated from the first sample, uncorrected
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
    linear acceleration in it, for about tau."""
    cdef double an[3]
    cdef double A[16]
    cdef double qn[4]
    cdef double k
    cdef double* lp = s.lp
    cdef double* qg = s.qg
    cdef int i
    if gyr != NULL and s.lp_started:
        phi_matrix(gyr[0] - b[0], gyr[1] - b[1], gyr[2] - b[2], dt, A)
        for i in range(4):
            qn[i] = A[i * 4] * qg[0] + A[i * 4 + 1] * qg[1] + A[i * 4 + 2] * qg[2] + A[i * 4 + 3] * qg[3]
        memcpy(qg, qn, 4 * sizeof(double))
        quat_normalise(qg)
    rot_to_nav(qg, acc, an)
    if not s.lp_started:
        lp[0] = an[0]
        lp[1] = an[1]
        lp[2] = an[2]
        s.lp_started = True
        s.lp_time = 0.0
    else:
        s.lp_time += dt
        if s.lp_time > tau:
            s.lp_time = tau
        k = dt / (s.lp_time + dt)
        lp[0] += k * (an[0] - lp[0])
        lp[1] += k * (an[1] - lp[1])
        lp[2] += k * (an[2] - lp[2])
    rot_to_body(qg, lp, out)


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
    s.qg[0] = 1.0
    s.qg[1] = 0.0
    s.qg[2] = 0.0
    s.qg[3] = 0.0
    s.lp_started = False
    s.lp_time = 0.0
