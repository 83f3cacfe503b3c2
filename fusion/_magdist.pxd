# Magnetic disturbance detection and rejection (docs/estimators.md, "Magnetic disturbances"),
# after the design of Laidig & Seel, "VQF: Highly accurate IMU orientation estimation with bias
# estimation and magnetic disturbance rejection" (Information Fusion, 2023): the field's norm
# and dip angle against a reference learned while undisturbed. While disturbed the heading runs
# on the gyro; after `time` s of rejection the current field becomes the reference (a magnet
# fixed to the sensor is a new hard-iron offset), and a different field that stays steady for
# `new_time` s while the sensor turns replaces the reference sooner. Neither re-learning takes a
# field whose direction in the navigation frame turns with the sensor (a magnet fixed to it:
# its field is no earth field's however long it stays): the field must have held its direction
# for MAGD_FIXED_HOLD s first, and until then the heading stays on the gyro. Each filter skips its
# magnetometer update when magd_check says so. A component (fusion/_magdist.pyx) that the
# filters using the magnetometer hold, as they hold a RestDetector.
from libc.math cimport sqrt, asin, M_PI
from libc.string cimport memset
from fusion._constants cimport lasted, outlasted

cdef struct MagDistState:
    double cur[2]       # the low-passed (norm, dip) of the current sample
    double ref[2]       # the reference
    double cand[2]      # the candidate for a new reference
    double t_undist     # s undisturbed so far
    double t_settle     # s since the first sample (0: none yet), counted to MAGD_FIRST_TIME (magd_check)
    double t_cand       # s the candidate has held while turning
    double t_reject     # s of rejection (decays while undisturbed)
    double dir_cur[3]   # the field's direction in the navigation frame, low-passed as cur
    double dir_slow[3]  # the same, low-passed over MAGD_DIR_TAU
    double t_fixed      # s since the field last turned with the sensor (dir test)
    bint disturbed
    long long rejected  # samples rejected since the reset


cdef class MagDetector:
    cdef readonly double time         # s of rejection at most, then the reference is re-learned (0: off)
    cdef readonly double norm_tol     # relative: |norm - reference| < norm_tol * reference
    cdef readonly double dip_tol_deg  # degrees (the parameter's value)
    cdef double dip_tol               # the same, rad
    cdef readonly double new_time     # s: a steady new field (while turning) becomes the reference
    cdef MagDistState s
    # its state, as Estimator._state_fields: the holder's _state_fields adds it
    cdef list fields(self)


# fixed time constants and limits, VQF's: the current field's low-pass (s), the reference's
# (s), the undisturbed time before the reference follows again (s), the rate at which a
# candidate counts (rad/s, 20 deg/s: a field that stays steady while the sensor turns is
# homogeneous), how fast the rejection time decays while undisturbed (s per s); and ours: the
# settling before the dip is judged (s: the default accelerometer low-pass's running-mean
# start, after which the attitude's tilt has settled; docs/accuracy.md, "Ninth pass"); the
# field direction's low-pass (s), the distance from it (unit vectors, about rad) beyond which
# the field turns with the sensor, and how long it must then hold still before a re-learning
# (s) (docs/accuracy.md, "Tenth pass": the recorded earth fields stay within 0.063 of it,
# a magnet fixed to a turning sensor exceeds 0.1 on 79-92 % of its samples)
cdef extern from *:
    """
    #define FUSION_MAGD_CUR_TAU 0.05
    #define FUSION_MAGD_REF_TAU 20.0
    #define FUSION_MAGD_MIN_UNDIST 0.5
    #define FUSION_MAGD_NEW_MIN_GYR 0.3490658503988659
    #define FUSION_MAGD_DECAY 2.0
    #define FUSION_MAGD_FIRST_TIME 1.0
    #define FUSION_MAGD_DIR_TAU 1.0
    #define FUSION_MAGD_DIR_TOL 0.1
    #define FUSION_MAGD_FIXED_HOLD 5.0
    """
    double MAGD_CUR_TAU "FUSION_MAGD_CUR_TAU"
    double MAGD_REF_TAU "FUSION_MAGD_REF_TAU"
    double MAGD_MIN_UNDIST "FUSION_MAGD_MIN_UNDIST"
    double MAGD_NEW_MIN_GYR "FUSION_MAGD_NEW_MIN_GYR"
    double MAGD_DECAY "FUSION_MAGD_DECAY"
    double MAGD_FIRST_TIME "FUSION_MAGD_FIRST_TIME"
    double MAGD_DIR_TAU "FUSION_MAGD_DIR_TAU"
    double MAGD_DIR_TOL "FUSION_MAGD_DIR_TOL"
    double MAGD_FIXED_HOLD "FUSION_MAGD_FIXED_HOLD"


cdef inline void magd_clear(MagDetector d) noexcept nogil:
    memset(&d.s, 0, sizeof(MagDistState))


cdef inline bint magd_close(const double* a, const double* r, MagDetector d) noexcept nogil:
    """(norm, dip) a within the tolerances of r."""
    cdef double dn = a[0] - r[0], dd = a[1] - r[1]
    return (dn if dn > 0.0 else -dn) < d.norm_tol * r[0] and (dd if dd > 0.0 else -dd) < d.dip_tol


cdef inline void magd_relearn(MagDistState* d, const double* x) noexcept nogil:
    d.ref[0] = x[0]
    d.ref[1] = x[1]
    d.disturbed = False
    d.t_undist = MAGD_MIN_UNDIST


cdef inline bint magd_check(MagDetector m, const double* q, const double* mag,
                            const double* gyr, double dt) noexcept nogil:
    """One magnetometer sample with the attitude q (ENU, body -> navigation) and the gyro
    sample (NULL: none); True when the filter may use it, False to skip it (counted in
    m.s.rejected)."""
    cdef double nrm, nz, s, k, g2, r2, ux, uy, uz
    cdef double x[2]
    cdef bint turned
    cdef int i
    cdef MagDistState* d = &m.s
    if m.time <= 0.0:
        return True
    nrm = sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
    # the vertical component in the navigation frame: third row of R(q) times mag
    nz = (2.0 * (q[1] * q[3] - q[0] * q[2]) * mag[0] + 2.0 * (q[2] * q[3] + q[0] * q[1]) * mag[1]
          + (q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3]) * mag[2])
    s = nz / nrm
    # the field's direction in the navigation frame (R(q) mag / |mag|): an earth field keeps
    # it while the sensor turns, a magnet fixed to the sensor turns it with the sensor (uz is
    # the dip's sine, before the clip)
    ux = ((q[0] * q[0] + q[1] * q[1] - q[2] * q[2] - q[3] * q[3]) * mag[0]
          + 2.0 * (q[1] * q[2] - q[0] * q[3]) * mag[1] + 2.0 * (q[1] * q[3] + q[0] * q[2]) * mag[2]) / nrm
    uy = (2.0 * (q[1] * q[2] + q[0] * q[3]) * mag[0] + (q[0] * q[0] - q[1] * q[1] + q[2] * q[2] - q[3] * q[3]) * mag[1]
          + 2.0 * (q[2] * q[3] - q[0] * q[1]) * mag[2]) / nrm
    uz = s
    s = 1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)
    x[0] = nrm
    x[1] = -asin(s)             # the dip, positive down
    if d.t_settle == 0.0:       # the first sample since the reset
        for i in range(2):
            d.cur[i] = x[i]
            d.ref[i] = x[i]
            d.cand[i] = x[i]
        d.t_settle = dt
        d.t_undist = MAGD_MIN_UNDIST
        d.dir_cur[0] = d.dir_slow[0] = ux
        d.dir_cur[1] = d.dir_slow[1] = uy
        d.dir_cur[2] = d.dir_slow[2] = uz
        return True
    k = dt / (MAGD_CUR_TAU + dt)
    d.dir_cur[0] += k * (ux - d.dir_cur[0])
    d.dir_cur[1] += k * (uy - d.dir_cur[1])
    d.dir_cur[2] += k * (uz - d.dir_cur[2])
    k = dt / (MAGD_DIR_TAU + dt)
    d.dir_slow[0] += k * (d.dir_cur[0] - d.dir_slow[0])
    d.dir_slow[1] += k * (d.dir_cur[1] - d.dir_slow[1])
    d.dir_slow[2] += k * (d.dir_cur[2] - d.dir_slow[2])
    ux = d.dir_cur[0] - d.dir_slow[0]
    uy = d.dir_cur[1] - d.dir_slow[1]
    uz = d.dir_cur[2] - d.dir_slow[2]
    r2 = ux * ux + uy * uy + uz * uz
    turned = lasted(d.t_settle, MAGD_FIRST_TIME) and r2 > MAGD_DIR_TOL * MAGD_DIR_TOL
    if turned:
        d.t_fixed = 0.0
    else:
        d.t_fixed += dt
    k = dt / (MAGD_CUR_TAU + dt)
    for i in range(2):
        d.cur[i] += k * (x[i] - d.cur[i])
    if not lasted(d.t_settle, MAGD_FIRST_TIME):
        # settling: the dip is measured with the filter's attitude, which may start several
        # degrees off (a first accelerometer sample with linear acceleration in it); a dip
        # reference taken then would hold the true field out as disturbed for `time` s. For
        # the first MAGD_FIRST_TIME s the reference's dip is the current one (the norm, which
        # does not depend on the attitude, is judged from the first sample)
        d.ref[1] = d.cur[1]
        d.cand[1] = d.cur[1]
        d.t_settle += dt
    k = dt / (MAGD_REF_TAU + dt)
    if magd_close(d.cur, d.ref, m):
        d.t_undist += dt
        if lasted(d.t_undist, MAGD_MIN_UNDIST):
            d.disturbed = False
            for i in range(2):
                d.ref[i] += k * (d.cur[i] - d.ref[i])
    else:
        d.t_undist = 0.0
        d.disturbed = True
    # a new field: steady while the sensor turns for new_time s
    if magd_close(d.cur, d.cand, m) and not turned:
        g2 = 0.0 if gyr == NULL else gyr[0] * gyr[0] + gyr[1] * gyr[1] + gyr[2] * gyr[2]
        if g2 >= MAGD_NEW_MIN_GYR * MAGD_NEW_MIN_GYR:
            d.t_cand += dt
        for i in range(2):
            d.cand[i] += k * (d.cur[i] - d.cand[i])
        if d.disturbed and lasted(d.t_cand, m.new_time) and lasted(d.t_fixed, MAGD_FIXED_HOLD):
            magd_relearn(d, d.cand)
    else:
        d.t_cand = 0.0
        d.cand[0] = d.cur[0]
        d.cand[1] = d.cur[1]
    if not d.disturbed:
        d.t_reject -= MAGD_DECAY * dt
        if d.t_reject < 0.0:
            d.t_reject = 0.0
        return True
    d.t_reject += dt
    if outlasted(d.t_reject, m.time) and lasted(d.t_fixed, MAGD_FIXED_HOLD):     # rejected for too long: this field is the reference now
        magd_relearn(d, d.cur)
        d.t_reject = 0.0
        return True
    d.rejected += 1
    return False

