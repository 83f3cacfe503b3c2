# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`mahony`: explicit complementary filter with PI correction, the baseline of "EKF attitude
estimation for a spherical robot" (Software Engineering, 2022) and the filter inside "Attitude-angle
solution for a mobile robot" (Chinese patent, 2019)."""
import numpy as np
from libc.math cimport sqrt

from libc.string cimport memcpy, memset

from fusion._core cimport Estimator, run_fast, batch_loop
from fusion._constants cimport BIAS_MAX
from fusion._core import struct_fields, RECOVERY
from fusion.params import Param, table, MAGDIST, GYRO_RANGE, MAG_UPDATE, ACC_LOWPASS, REST_PULL
from fusion._aided cimport AidedFilter, rest_now, mag_accepted, acc_input
from fusion._rest cimport rest_rate
from fusion._rest import REST_TAU_PROPERTY
from fusion._qmath cimport (quat_propagate, quat_normalise, rot_to_body, rot_to_nav,
                            up_in_body, cross3, half_angle_terms, quat_norm_factor, recovery_gain,
                            saturated)


cdef double RECOVERY_STEP_MAX = 0.5    # share of the error one recovery step may correct
cdef inline void mahony_error(const double* q, const double* acc, const double* mag,
                              double* e) noexcept nogil:
    """e = sum of measured x estimated directions, gravity and north-folded field (acc, mag
    may be NULL)."""
    cdef double v[3]
    cdef double c[3]
    cdef double h[3]
    cdef double k
    e[0] = 0.0
    e[1] = 0.0
    e[2] = 0.0
    if acc != NULL:
        # (acc/|acc|) x v, scaled after the cross product
        k = 1.0 / sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
        up_in_body(q, v)
        cross3(acc, v, e)
        e[0] *= k; e[1] *= k; e[2] *= k
    if mag != NULL:
        # the folded field is linear in mag, so u x v(u) = (mag x v(mag)) / |mag|^2: one
        # division for the unit vector, no square root
        k = 1.0 / (mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        rot_to_nav(q, mag, h)
        h[1] = sqrt(h[0] * h[0] + h[1] * h[1])   # turn the field about z onto north (y)
        h[0] = 0.0
        rot_to_body(q, h, v)
        cross3(mag, v, c)
        e[0] += c[0] * k; e[1] += c[1] * k; e[2] += c[2] * k


cdef inline void rot_matrix(const double* q, double* R) noexcept nogil:
    """R (3x3, row-major) = R(q) in the homogeneous form of rot_to_nav (|q|² times the
    rotation, so R(p ⊗ r) = R(p) R(r) for any p, r)."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    cdef double ww = w * w, xx = x * x, yy = y * y, zz = z * z
    R[0] = (ww + xx) - (yy + zz)
    R[1] = 2.0 * (x * y - w * z)
    R[2] = 2.0 * (x * z + w * y)
    R[3] = 2.0 * (x * y + w * z)
    R[4] = (ww - xx) + (yy - zz)
    R[5] = 2.0 * (y * z - w * x)
    R[6] = 2.0 * (x * z - w * y)
    R[7] = 2.0 * (y * z + w * x)
    R[8] = (ww - xx) - (yy - zz)


cdef inline void mat_vec(const double* R, const double* v, double* out) noexcept nogil:
    out[0] = R[0] * v[0] + R[1] * v[1] + R[2] * v[2]
    out[1] = R[3] * v[0] + R[4] * v[1] + R[5] * v[2]
    out[2] = R[6] * v[0] + R[7] * v[1] + R[8] * v[2]


cdef inline void mat_t_vec(const double* R, const double* v, double* out) noexcept nogil:
    out[0] = R[0] * v[0] + R[3] * v[1] + R[6] * v[2]
    out[1] = R[1] * v[0] + R[4] * v[1] + R[7] * v[2]
    out[2] = R[2] * v[0] + R[5] * v[1] + R[8] * v[2]


cdef void half_angle_any(double wx, double wy, double wz, double dt, double* c,
                         double* s) noexcept nogil:
    """half_angle_terms out of line, for the large angles (sin, cos) mahony_step rarely
    sees: kept out of the step so that the compiler inlines the step into the batch loop."""
    half_angle_terms(wx, wy, wz, dt, c, s)


cdef inline void half_angle_fast(double wx, double wy, double wz, double dt, double* c,
                                 double* s) noexcept nogil:
    """half_angle_terms: its series inline, the rest out of line (the same numbers)."""
    cdef double n2 = wx * wx + wy * wy + wz * wz
    cdef double h2 = n2 * (0.25 * dt * dt)
    cdef double h4
    if h2 < 0.0025:
        h4 = h2 * h2
        c[0] = (1.0 - 0.5 * h2) + h4 * ((1.0 / 24.0 - h2 * (1.0 / 720.0)) + h4 * (1.0 / 40320.0))
        s[0] = (0.5 * dt) * ((1.0 - h2 * (1.0 / 6.0))
                             + h4 * ((1.0 / 120.0 - h2 * (1.0 / 5040.0)) + h4 * (1.0 / 362880.0)))
    else:
        half_angle_any(wx, wy, wz, dt, c, s)


cdef inline void mahony_step(double* q, double* eint, double kp, double ki,
                             const double* gyr, const double* acc, const double* mag,
                             double dt, bint heading, double km) noexcept nogil:
    """One sample (gyr, acc, mag may be NULL), q and eint in place: Mahony._step and the
    batch loop both run this. heading (mag_update="heading"): the magnetometer's error
    keeps only its component about the vertical, so that it turns the heading alone; km
    (mag_weight) weighs the magnetometer's error against the accelerometer's."""
    # Propagate with the integral-corrected gyro, q1 = q ⊗ p, then correct with this
    # sample's vectors: the measurements belong to the attitude after the step, as in the
    # EKF. The error (mahony_error at q1) is evaluated in the navigation frame, with one
    # rotation matrix R1 = R(q1) for both vectors:
    #   e = ka acc x R1ᵀ z + km mag x R1ᵀ v = R1ᵀ (ka (R1 acc) x z + km (R1 mag) x v),
    # which leaves less after the square root on the sample-to-sample dependency chain
    # (q -> error -> correction -> normalise -> q) that a sample's time is made of.
    cdef double wg[3]
    cdef double Q[4]
    cdef double q1[4]
    cdef double R1[9]
    cdef double h[3]
    cdef double W[2]     # w = [W0, W1, 0] + rho [G0, 0, G1]
    cdef double G[2]
    cdef double e[3]
    cdef double P[4]
    cdef double c, s, k, rho, rho2, h2, h4, n1, n2, n
    cdef int i
    if gyr != NULL:
        # q1 = q ⊗ [c, s wg] = c q + s (q ⊗ [0, wg]): the product with wg does not wait for
        # c and s (the gyro's chain: eint -> wg -> |wg| -> c, s -> q1)
        wg[0] = gyr[0] + ki * eint[0]
        wg[1] = gyr[1] + ki * eint[1]
        wg[2] = gyr[2] + ki * eint[2]
        Q[0] = -(q[1] * wg[0] + q[2] * wg[1]) - q[3] * wg[2]
        Q[1] = (q[0] * wg[0] - q[3] * wg[1]) + q[2] * wg[2]
        Q[2] = (q[3] * wg[0] + q[0] * wg[1]) - q[1] * wg[2]
        Q[3] = (q[1] * wg[1] - q[2] * wg[0]) + q[0] * wg[2]
        half_angle_fast(wg[0], wg[1], wg[2], dt, &c, &s)
        q1[0] = c * q[0] + s * Q[0]
        q1[1] = c * q[1] + s * Q[1]
        q1[2] = c * q[2] + s * Q[2]
        q1[3] = c * q[3] + s * Q[3]
    else:
        q1[0] = q[0]; q1[1] = q[1]; q1[2] = q[2]; q1[3] = q[3]
    # the normalisation: the correction below is a rotation (norm 1 to rounding), so
    # normalise(q1 ⊗ r) = normalise(q1) ⊗ r; its factor n is ready long before the
    # correction is, and goes into c and s, instead of a normalisation after it
    n1 = (q1[0] * q1[0] + q1[1] * q1[1]) + (q1[2] * q1[2] + q1[3] * q1[3])
    n = quat_norm_factor(n1)
    rot_matrix(q1, R1)
    # the error in the navigation frame, w = W + rho G (rho the square root below, of the
    # folded field), and everything made of it linearly (e = R1ᵀ w, the correction's P) in
    # the same split: after the square root, one product and one sum each
    W[0] = 0.0
    W[1] = 0.0
    G[0] = 0.0
    G[1] = 0.0
    rho = 0.0
    rho2 = 0.0
    if acc != NULL:
        # (R1 acc) x z / |acc| = [a1, -a0, 0] / |acc|
        k = 1.0 / sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
        W[0] = (R1[3] * acc[0] + R1[4] * acc[1] + R1[5] * acc[2]) * k
        W[1] = -(R1[0] * acc[0] + R1[1] * acc[1] + R1[2] * acc[2]) * k
    if mag != NULL:
        # h = R1 mag, turned about z onto north: v = [0, rho, h2]; h x v = [h2 (h1 - rho),
        # -h0 h2, h0 rho], over |mag|^2 (the folded field is linear in mag)
        k = km / (mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        mat_vec(R1, mag, h)
        if not heading:         # heading: only the vertical component, h0 rho
            W[0] += (h[2] * k) * h[1]
            W[1] -= (h[0] * k) * h[2]
            G[0] = -(h[2] * k)  # G = [G0, 0, G1]
        G[1] = h[0] * k
        rho2 = h[0] * h[0] + h[1] * h[1]
        rho = sqrt(rho2)
    # e = R1ᵀ w
    e[0] = (R1[0] * W[0] + R1[3] * W[1]) + rho * (R1[0] * G[0] + R1[6] * G[1])
    e[1] = (R1[1] * W[0] + R1[4] * W[1]) + rho * (R1[1] * G[0] + R1[7] * G[1])
    e[2] = (R1[2] * W[0] + R1[5] * W[1]) + rho * (R1[2] * G[0] + R1[8] * G[1])
    if ki > 0.0:
        eint[0] += e[0] * dt
        eint[1] += e[1] * dt
        eint[2] += e[2] * dt
        # gains that make the loop unstable (ki dt near 1) wind the integral up without bound:
        # held where its bias, -ki eint, is BIAS_MAX
        for i in range(3):
            if ki * eint[i] > BIAS_MAX:
                eint[i] = BIAS_MAX / ki
            elif ki * eint[i] < -BIAS_MAX:
                eint[i] = -BIAS_MAX / ki
    if kp > 0.0:
        # q2 = q1 ⊗ [c, s kp e] = c q1 + s kp P, P = q1 ⊗ [0, e] = q1 ⊗ [0, R1ᵀ w] =
        # |q1|² [0, w] ⊗ q1 (R1 is R's homogeneous form, |q1|² times the rotation): P from
        # [0, W] ⊗ q1 + rho [0, G] ⊗ q1; |e| = |w| likewise: c and s come from
        # |w|² = |W|² + rho² |G|² + 2 rho W·G
        P[0] = (-(W[0] * q1[1] + W[1] * q1[2])) + rho * (-(G[0] * q1[1] + G[1] * q1[3]))
        P[1] = (W[0] * q1[0] + W[1] * q1[3]) + rho * (G[0] * q1[0] - G[1] * q1[2])
        P[2] = (W[1] * q1[0] - W[0] * q1[3]) + rho * (G[1] * q1[1] - G[0] * q1[3])
        P[3] = (W[0] * q1[2] - W[1] * q1[1]) + rho * (G[0] * q1[2] + G[1] * q1[0])
        n2 = ((W[0] * W[0] + W[1] * W[1]) + rho2 * (G[0] * G[0] + G[1] * G[1])
              + rho * (2.0 * W[0] * G[0]))
        h2 = n2 * (0.25 * kp * kp * dt * dt)
        if h2 < 1e-6:
            # half_angle_terms' series cut after h2^2: the next terms (h2^3/720, h2^3/5040)
            # are below 1.4e-21
            h4 = h2 * h2
            c = (1.0 - 0.5 * h2) + h4 * (1.0 / 24.0)
            s = (0.5 * dt * kp) * ((1.0 - h2 * (1.0 / 6.0)) + h4 * (1.0 / 120.0))
        else:
            half_angle_any(kp * e[0], kp * e[1], kp * e[2], dt, &c, &s)
            s *= kp
        c *= n
        s *= n * n1
        q[0] = c * q1[0] + s * P[0]
        q[1] = c * q1[1] + s * P[1]
        q[2] = c * q1[2] + s * P[2]
        q[3] = c * q1[3] + s * P[3]
    else:
        q[0] = q1[0] * n; q[1] = q1[1] * n; q[2] = q1[2] * n; q[3] = q1[3] * n


cdef const double* mahony_acc_lowpass(Mahony e, const double* eint, const double* gyr, bint sat,
                                      const double* acc, double dt, double* out) noexcept nogil:
    """acc_input (fusion/_aided.pxd) with the integral term's bias, -ki eint (out of line:
    the batch loop keeps its inlined step)."""
    cdef double b[3]
    b[0] = -e.ki * eint[0]
    b[1] = -e.ki * eint[1]
    b[2] = -e.ki * eint[2]
    return acc_input(e, gyr, sat, b, acc, dt, out)


cdef void mahony_rest(Mahony e, double* eint, const double* gyr, const double* acc,
                      double dt) noexcept nogil:
    """Rest detection (fusion/_rest.pxd) on the raw samples and, at rest, the bias -ki eint
    pulled toward the measured rate (rest_rate, over the time T it averages) with the time
    constant rest_tau (first order; out of line: the batch loop keeps its inlined step)."""
    cdef double k, T
    cdef double z[3]
    cdef int i
    if not rest_now(e, gyr, acc, dt) or e.ki <= 0.0:
        return
    T = rest_rate(e.rest, gyr, dt, z)
    k = T / (e.rest.tau + T)
    for i in range(3):
        eint[i] += k * (-z[i] / e.ki - eint[i])


cdef inline void mahony_batch_step(Estimator e, double* q, void* s, const double* gyr,
                                   const double* acc, const double* mag, double dt) noexcept nogil:
    """step_flagged without recovery (gyro_range unknown), on the batch loop's local state
    (fusion/_core.pxd batch_loop)."""
    cdef double* eint = (<MahonyState*>s).eint
    cdef double af[3]
    if not mag_accepted(<Mahony>e, q, mag, gyr, dt):
        mag = NULL
    if (<Mahony>e).rest.time > 0.0:
        mahony_rest(<Mahony>e, eint, gyr, acc, dt)
    if (<Mahony>e).acc_lowpass > 0.0:
        acc = mahony_acc_lowpass(<Mahony>e, eint, gyr, False, acc, dt, af)
    mahony_step(q, eint, (<Mahony>e).kp, (<Mahony>e).ki, gyr, acc, mag, dt, (<Mahony>e).mag_heading,
                (<Mahony>e).mag_weight)


cdef class Mahony(AidedFilter):
    """Mahony's explicit complementary filter ("Nonlinear complementary filters on the special
    orthogonal group", IEEE TAC 2008): gravity and magnetic cross-product errors,
    proportional gain kp (1/s) and integral gain ki (1/s^2) on the gyro. With gyro_range
    (rad/s) a saturated sample raises kp and holds the integral for 3 s (recovery_gain). At
    rest (rest_*) the bias -ki ε is pulled toward the measured rate (with ki > 0 only)."""
    name = "mahony"
    # kp, ki and acc_lowpass chosen leave-one-set-out on the recorded sets (docs/accuracy.md);
    # kp / ki = 100 s as before, so the integral learns the bias as fast. acc_lowpass 1.5 s
    # (sixth pass): the folds' kp 0.7, ki 0.015 took 31 s to recover from a gyro dropout
    PARAMS = table(
        Param("kp", 1.0, "1/s", 1e-6, 1e3, "proportional gain on the gravity and field errors",
              allow_zero=True),
        Param("ki", 0.01, "1/s²", 1e-9, 1e3, "integral gain (the bias learned is -ki ε)", allow_zero=True),
        GYRO_RANGE.but(doc=GYRO_RANGE.doc + "; for 3 s after a saturated sample kp is raised and the "
                       "integral held"),
        Param("mag_weight", 1.0, "1", 1e-6, 1e3, "weight of the magnetometer's error against the "
              "accelerometer's (1: Mahony's; the heading's time constant is about 1 / (kp mag_weight cos²(dip)) s)",
              allow_zero=True),
        MAG_UPDATE, ACC_LOWPASS.but(default=1.5), *MAGDIST,
        # the shared rest detector; no zero-rate update here, so no rest_noise
        *REST_PULL)
    rest_tau = REST_TAU_PROPERTY        # REST_PULL's, read from its rest detector

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked before the base takes anything
        self._take_base(fs, frame, on_invalid, p)
        self.kp = p["kp"]
        self.ki = p["ki"]
        self.mag_weight = p["mag_weight"]
        self.configure(p)                   # rest and disturbance detectors, low-pass; reset

    cdef list _state_fields(self):
        # the bias learned, -ki eint, within the plausible range (eint is unused at ki = 0)
        eint = (-BIAS_MAX / self.ki, BIAS_MAX / self.ki) if self.ki > 0.0 else None
        return (AidedFilter._state_fields(self)
                + struct_fields(<MahonyState[:1]>&self.s, {"eint": eint, "t_recover": RECOVERY}))

    cdef void _reset_state(self) noexcept nogil:
        AidedFilter._reset_state(self)
        memset(&self.s, 0, sizeof(MahonyState))

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        self.step_flagged(gyr, acc, mag, dt, gyr != NULL and saturated(gyr, self.gyro_range_))

    cdef void step_flagged(self, const double* gyr, const double* acc, const double* mag,
                           double dt, bint sat) noexcept nogil:
        """_step with the saturation test done by the caller (cf-ekf tests its raw samples)."""
        cdef double f = recovery_gain(&self.s.t_recover, sat, dt)
        cdef double eint[3]
        cdef double af[3]
        if not mag_accepted(self, self.q, mag, gyr, dt):
            mag = NULL
        if self.rest.time > 0.0:
            mahony_rest(self, self.s.eint, gyr, acc, dt)
        if self.acc_lowpass > 0.0:
            acc = mahony_acc_lowpass(self, self.s.eint, gyr, sat, acc, dt, af)
        if f == 1.0:
            mahony_step(self.q, self.s.eint, self.kp, self.ki, gyr, acc, mag, dt, self.mag_heading,
                        self.mag_weight)
            return
        # recovering: the large error is the attitude's, not the gyro's bias. At low rates
        # the raised gain would turn by more than the error in one step and overshoot: at
        # most RECOVERY_STEP_MAX of it per step (never below the plain gain)
        if f * self.kp * dt > RECOVERY_STEP_MAX:
            f = max(1.0, RECOVERY_STEP_MAX / (self.kp * dt))
        memcpy(eint, self.s.eint, 3 * sizeof(double))
        mahony_step(self.q, self.s.eint, f * self.kp, self.ki, gyr, acc, mag, dt, self.mag_heading,
                    self.mag_weight)
        memcpy(self.s.eint, eint, 3 * sizeof(double))

    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil:
        # the state in locals (fusion/_core.pxd batch_loop): the compiler keeps them in
        # registers, which it cannot for self.q (any store through o or eint might alias it)
        cdef MahonyState st
        if not run_fast(self) or self.gyro_range_ > 0.0:     # recovery: step by step
            return Estimator._run_batch(self, g, a, m, d, dt, o, n, stop_invalid)
        return batch_loop(self, mahony_batch_step, &st, &self.s, sizeof(MahonyState), g, a, m, d, dt,
                          o, n, stop_invalid)

    cdef bint _bias(self, double* out) noexcept nogil:
        # the gyro bias the integral term has learned
        out[0], out[1], out[2] = -self.ki * self.s.eint[0], -self.ki * self.s.eint[1], -self.ki * self.s.eint[2]
        return True
