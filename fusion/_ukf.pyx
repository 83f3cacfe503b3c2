# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`ukf`: unscented Kalman filter on the attitude error + gyro bias (docs/ukf.md), the UKF
that "IIR-EKF, IMU dynamic error suppression" (J. Nanjing Univ. Aero. Astro., 2023)
compares against, with the process and measurement models of `ekf`."""
import numpy as np
from libc.math cimport sqrt
from libc.string cimport memcpy, memset

from fusion._aided cimport rest_now, mag_accepted, acc_input
from fusion._acclp cimport acc_lowpass_settles, start_variance
from fusion._rest cimport rest_gate_open, rest_rate
from fusion._kalman cimport KalmanFilter
from fusion._kalman import STATE_CHECKS
from fusion._core cimport Estimator
from fusion._core import struct_fields
from fusion._ekf import EKF as _EKF
from fusion.params import table
from fusion._qmath cimport (sym3_inverse, half_angle_terms, quat_mul, quat_normalise, quat_propagate,
                            rot_to_nav, rot_to_body, up_in_body, unit3, unobserved_variance,
                            saturated, out_of_range)

from fusion._constants cimport GRAVITY as G0
# scaled unscented transform, n = 6, alpha = 1, beta = 2, kappa = 0: lambda = 0
DEF NS = 13                   # 2 n + 1 sigma points
cdef double GAMMA = sqrt(6.0)          # sqrt(n + lambda)
cdef double WM0 = 0.0                  # lambda / (n + lambda)
cdef double WC0 = 2.0                  # WM0 + 1 - alpha^2 + beta
cdef double WI = 1.0 / 12.0            # 1 / (2 (n + lambda)), both mean and covariance


cdef inline void err_to_quat(const double* p, double* e) noexcept nogil:
    """δq(p) = [16 - |p|², 8 p] / (16 + |p|²): the unit quaternion of p = 4 e_v / (1 + e_w)."""
    cdef double s = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
    cdef double k = 1.0 / (16.0 + s)
    e[0] = (16.0 - s) * k
    k *= 8.0
    e[1] = k * p[0]
    e[2] = k * p[1]
    e[3] = k * p[2]


cdef inline void quat_to_err(const double* e, double* p) noexcept nogil:
    """p = 4 e_v / (1 + e_w) with e's sign chosen so that e_w >= 0."""
    cdef double k
    if e[0] >= 0.0:
        k = 4.0 / (1.0 + e[0])
    else:
        k = -4.0 / (1.0 - e[0])
    p[0] = k * e[1]
    p[1] = k * e[2]
    p[2] = k * e[3]


cdef inline void rate_quat(double wx, double wy, double wz, double dt, double* e) noexcept nogil:
    """ε(w) = [cos(|w|dt/2), sin(|w|dt/2) w/|w|]: Φ(w, dt) q = q ⊗ ε(w)."""
    cdef double c, s
    half_angle_terms(wx, wy, wz, dt, &c, &s)
    e[0] = c
    e[1] = s * wx
    e[2] = s * wy
    e[3] = s * wz


cdef inline void sigma_mean_cov(double* Y, int n, double* mean, double* cov) noexcept nogil:
    """The unscented mean (n) and covariance (n x n, row-major) of the 13 sigma vectors Y
    (13 x n, a row each), Y replaced by their deviations from the mean."""
    cdef double s
    cdef int i, j, k
    for k in range(n):
        s = WM0 * Y[k]
        for i in range(1, NS):
            s += WI * Y[i * n + k]
        mean[k] = s
    for i in range(NS):
        for k in range(n):
            Y[i * n + k] -= mean[k]
    for j in range(n):
        for k in range(j, n):
            s = WC0 * Y[j] * Y[k]
            for i in range(1, NS):
                s += WI * Y[i * n + j] * Y[i * n + k]
            cov[j * n + k] = s
            cov[k * n + j] = s


cdef inline void heading_only_rows(const double* q, double* K) noexcept nogil:
    """mag_update="heading": the gain's attitude rows (body-frame error) and bias rows (6x3)
    projected onto the body-frame vertical w = Rᵀ e_z, so that the magnetometer only turns
    the attitude about the vertical (as the ekf's heading_gain)."""
    cdef double w[3]
    cdef double a, c
    cdef int j
    up_in_body(q, w)
    for j in range(3):
        a = w[0] * K[j] + w[1] * K[3 + j] + w[2] * K[6 + j]
        c = w[0] * K[9 + j] + w[1] * K[12 + j] + w[2] * K[15 + j]
        K[j] = w[0] * a; K[3 + j] = w[1] * a; K[6 + j] = w[2] * a
        K[9 + j] = w[0] * c; K[12 + j] = w[1] * c; K[15 + j] = w[2] * c


cdef class UKF(KalmanFilter):
    """Unscented Kalman filter: 13 sigma points on the 6-D error [attitude (4 x modified
    Rodrigues parameters, body frame), gyro bias]; gyro process and accelerometer /
    north-folded magnetometer measurements as the `ekf`."""
    name = "ukf"
    # acc_noise and acc_lowpass chosen leave-one-set-out on the recorded sets (docs/accuracy.md)
    # the ekf's but acc_update; every variance > 0: the sigma points need a positive-definite
    # covariance
    PARAMS = table(*[p for p in _EKF.PARAMS.values() if p.name != "acc_update"],
                   _EKF.PARAMS["gyro_noise"].but(default=0.01),
                   _EKF.PARAMS["bias_noise"].but(allow_zero=False),
                   _EKF.PARAMS["bias_init_std"].but(allow_zero=False))

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked before the base takes anything
        self._take_base(fs, frame, on_invalid, p)
        self.configure(p)                   # noise, rest and disturbance detectors, low-pass; reset

    cdef list _state_fields(self):
        return KalmanFilter._state_fields(self) + struct_fields(<UKFState[:1]>&self.s, STATE_CHECKS)

    cdef void _reset_state(self) noexcept nogil:
        cdef int i
        cdef double sq = 2.0 * self.kalman.q_init_std     # quaternion-component std -> angle std
        KalmanFilter._reset_state(self)
        memset(&self.s, 0, sizeof(UKFState))
        for i in range(3):
            self.s.P[i * 7] = sq * sq
        for i in range(3, 6):
            self.s.P[i * 7] = self.kalman.bias_init_std * self.kalman.bias_init_std

    cdef void sigma_points(self, double* X) noexcept nogil:
        """X (13 x 6): 0, +γ L_j, -γ L_j with L L^T = P (Cholesky; a non-positive pivot
        gives a zero column)."""
        cdef double L[36]
        cdef double* P = self.s.P
        cdef double d, s
        cdef int i, j, k
        for i in range(36):
            L[i] = 0.0
        for j in range(6):
            d = P[j * 7]
            for k in range(j):
                d -= L[j * 6 + k] * L[j * 6 + k]
            if d <= 0.0:
                continue
            d = sqrt(d)
            L[j * 7] = d
            d = 1.0 / d
            for i in range(j + 1, 6):
                s = P[i * 6 + j]
                for k in range(j):
                    s -= L[i * 6 + k] * L[j * 6 + k]
                L[i * 6 + j] = s * d
        for k in range(6):
            X[k] = 0.0
        for j in range(6):
            for k in range(6):
                s = GAMMA * L[k * 6 + j]
                X[(1 + j) * 6 + k] = s
                X[(7 + j) * 6 + k] = -s

    cdef void predict(self, const double* gyr, double dt) noexcept nogil:
        cdef double X[NS * 6]
        cdef double Y[NS * 6]
        cdef double mean[6]
        cdef double e0[4]
        cdef double dq[4]
        cdef double ei[4]
        cdef double t[4]
        cdef double* P = self.s.P
        cdef double* x
        cdef double w0x = gyr[0] - self.s.b[0], w0y = gyr[1] - self.s.b[1], w0z = gyr[2] - self.s.b[2]
        cdef double s, wgt, qg, qb
        cdef int i, j, k
        self.sigma_points(X)
        # sigma attitude q̂ ⊗ δq(p_i), bias b̂ + δb_i, propagated by Φ(ω - b_i); its error
        # about the propagated centre q̂ ⊗ ε(ω - b̂) is ε(ω - b̂)* ⊗ δq(p_i) ⊗ ε(ω - b_i)
        rate_quat(-w0x, -w0y, -w0z, dt, e0)        # ε(ω - b̂)* = ε(-(ω - b̂))
        for i in range(NS):
            x = X + i * 6
            err_to_quat(x, dq)
            rate_quat(w0x - x[3], w0y - x[4], w0z - x[5], dt, ei)
            quat_mul(dq, ei, t)
            quat_mul(e0, t, ei)
            quat_to_err(ei, Y + i * 6)
            Y[i * 6 + 3] = x[3]
            Y[i * 6 + 4] = x[4]
            Y[i * 6 + 5] = x[5]
        sigma_mean_cov(Y, 6, mean, P)
        qg = self.kalman.gyro_noise * self.kalman.gyro_noise * dt
        qb = self.kalman.bias_noise * self.kalman.bias_noise * dt
        for j in range(3):
            P[j * 7] += qg
            P[(j + 3) * 7] += qb
        # the predicted mean is the propagated centre; the bias is unchanged
        quat_propagate(self.q, w0x, w0y, w0z, dt)
        quat_normalise(self.q)

    cdef void correct(self, const double* X, const double* Z, const double* z,
                      double r) noexcept nogil:
        """Update with measurement z, sigma predictions Z (13 x 3, Z_0 = h(q̂)) of sigma errors
        X (13 x 6) and noise variance r per axis."""
        cdef double zh[3]
        cdef double D[NS * 3]
        cdef double S[9]
        cdef double Si[9]
        cdef double C[18]     # Pxz, 6x3
        cdef double K[18]     # 6x3
        cdef double nu[3]
        cdef double dx[6]
        cdef double dq[4]
        cdef double qn[4]
        cdef double* P = self.s.P
        cdef double s
        cdef int i, j, k
        memcpy(D, Z, NS * 3 * sizeof(double))
        sigma_mean_cov(D, 3, zh, S)
        S[0] += r
        S[4] += r
        S[8] += r
        for j in range(6):          # X_0 = 0: the centre adds nothing to Pxz
            for k in range(3):
                s = 0.0
                for i in range(1, NS):
                    s += X[i * 6 + j] * D[i * 3 + k]
                C[j * 3 + k] = WI * s
        sym3_inverse(S, Si)
        for i in range(6):
            for j in range(3):
                K[i * 3 + j] = C[i * 3] * Si[j] + C[i * 3 + 1] * Si[3 + j] + C[i * 3 + 2] * Si[6 + j]
        if self.heading_gain:
            heading_only_rows(self.q, K)
        # innovation about the prediction at the mean, h(q̂) = Z_0 (docs/ukf.md)
        nu[0] = z[0] - Z[0]
        nu[1] = z[1] - Z[1]
        nu[2] = z[2] - Z[2]
        for i in range(6):
            dx[i] = K[i * 3] * nu[0] + K[i * 3 + 1] * nu[1] + K[i * 3 + 2] * nu[2]
        err_to_quat(dx, dq)
        quat_mul(self.q, dq, qn)
        self.q[0] = qn[0]
        self.q[1] = qn[1]
        self.q[2] = qn[2]
        self.q[3] = qn[3]
        quat_normalise(self.q)
        self.s.b[0] += dx[3]
        self.s.b[1] += dx[4]
        self.s.b[2] += dx[5]
        if self.heading_gain:
            # the projected gain is not the Kalman gain: P - K Pxzᵀ - Pxz Kᵀ + K Pzz Kᵀ
            for i in range(6):
                for j in range(3):
                    D[i * 3 + j] = K[i * 3] * S[j] + K[i * 3 + 1] * S[3 + j] + K[i * 3 + 2] * S[6 + j]
            for i in range(6):
                for j in range(i, 6):
                    s = P[i * 6 + j]
                    for k in range(3):
                        s += -K[i * 3 + k] * C[j * 3 + k] - C[i * 3 + k] * K[j * 3 + k] + D[i * 3 + k] * K[j * 3 + k]
                    P[i * 6 + j] = s
                    P[j * 6 + i] = s
            return
        # P - K Pzz K^T = P - K Pxz^T, symmetrised
        for i in range(6):
            for j in range(i, 6):
                s = P[i * 6 + j] - 0.5 * (K[i * 3] * C[j * 3] + K[i * 3 + 1] * C[j * 3 + 1]
                                          + K[i * 3 + 2] * C[j * 3 + 2] + K[j * 3] * C[i * 3]
                                          + K[j * 3 + 1] * C[i * 3 + 1] + K[j * 3 + 2] * C[i * 3 + 2])
                P[i * 6 + j] = s
                P[j * 6 + i] = s

    cdef void zero_rate_update(self, const double* gyr, double dt) noexcept nogil:
        """At rest the gyro measures the bias (docs/estimators.md, "Rest"): z = rest_rate (the
        sample, or the still run's mean on its first update; r: the noise density over the time
        it averages), h = b, H = [0 I3] on the error (linear: no sigma points), the gain on the
        bias only, K = [0; Pbb S⁻¹], S = Pbb + r I; P by the Joseph form: Ppp unchanged,
        Ppb (I - Kb)ᵀ, (I - Kb) Pbb (I - Kb)ᵀ + r Kb Kbᵀ."""
        cdef double S[9]
        cdef double Si[9]
        cdef double Kb[9]
        cdef double A[9]      # I - Kb
        cdef double T[18]     # rows of [Ppb; Pbb] times (I - Kb)ᵀ, 6x3
        cdef double y[3]
        cdef double z[3]
        cdef double* P = self.s.P
        cdef double r = self.rest.noise * self.rest.noise / rest_rate(self.rest, gyr, dt, z)
        cdef double s
        cdef int i, j, k
        for i in range(3):
            for j in range(3):
                S[i * 3 + j] = P[(3 + i) * 6 + 3 + j]
            S[i * 4] += r
            y[i] = z[i] - self.s.b[i]
        sym3_inverse(S, Si)
        for i in range(3):
            for j in range(3):
                Kb[i * 3 + j] = (P[(3 + i) * 6 + 3] * Si[j] + P[(3 + i) * 6 + 4] * Si[3 + j]
                                 + P[(3 + i) * 6 + 5] * Si[6 + j])
                A[i * 3 + j] = (1.0 if i == j else 0.0) - Kb[i * 3 + j]
        for i in range(3):
            self.s.b[i] += Kb[i * 3] * y[0] + Kb[i * 3 + 1] * y[1] + Kb[i * 3 + 2] * y[2]
        for i in range(6):          # T = P[:, 3:6] Aᵀ
            for j in range(3):
                T[i * 3 + j] = P[i * 6 + 3] * A[j * 3] + P[i * 6 + 4] * A[j * 3 + 1] + P[i * 6 + 5] * A[j * 3 + 2]
        for i in range(3):          # Ppb <- Ppb Aᵀ
            for j in range(3):
                P[i * 6 + 3 + j] = T[i * 3 + j]
                P[(3 + j) * 6 + i] = T[i * 3 + j]
        for i in range(3):          # Pbb <- A Pbb Aᵀ + r Kb Kbᵀ
            for j in range(i, 3):
                s = A[i * 3] * T[9 + j] + A[i * 3 + 1] * T[12 + j] + A[i * 3 + 2] * T[15 + j]
                for k in range(3):
                    s += r * Kb[i * 3 + k] * Kb[j * 3 + k]
                P[(3 + i) * 6 + 3 + j] = s
                P[(3 + j) * 6 + 3 + i] = s

    cdef void sigma_attitudes(self, double* X, double* Qs) noexcept nogil:
        """X (13 x 6) the sigma points, Qs (13 x 4) their attitudes q̂ ⊗ δq(p_i): what each
        measurement model is evaluated at."""
        cdef double dq[4]
        cdef int i
        self.sigma_points(X)
        for i in range(NS):
            err_to_quat(X + i * 6, dq)
            quat_mul(self.q, dq, Qs + i * 4)

    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil:
        cdef double X[NS * 6]
        cdef double Qs[NS * 4]
        cdef double Z[NS * 3]
        cdef double z[3]
        cdef double sa = self.kalman.acc_noise / G0
        cdef int i
        self.sigma_attitudes(X, Qs)
        for i in range(NS):
            up_in_body(Qs + i * 4, Z + i * 3)
        unit3(acc, z)
        self.correct(X, Z, z, sa * sa / dt)

    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil:
        cdef double X[NS * 6]
        cdef double Qs[NS * 4]
        cdef double Z[NS * 3]
        cdef double z[3]
        cdef double n[3]
        cdef int i
        unit3(mag, z)
        rot_to_nav(self.q, z, n)
        if sqrt(n[0] * n[0] + n[1] * n[1]) < 1e-9:     # field vertical: no heading information
            return
        self.sigma_attitudes(X, Qs)
        for i in range(NS):
            rot_to_nav(Qs + i * 4, z, n)
            n[1] = sqrt(n[0] * n[0] + n[1] * n[1])     # folded onto north
            n[0] = 0.0
            rot_to_body(Qs + i * 4, n, Z + i * 3)
        self.correct(X, Z, z, self.kalman.mag_noise * self.kalman.mag_noise / dt)

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        # the ekf's time update (EKF.propagate): unmeasured motion grows the attitude error
        # variance, here directly in rad² (the error p is the angle to first order); a sample
        # out of range is not a measurement: held as a dropped one (ekf_step)
        cdef bint measured
        cdef double t0
        cdef double af[3]
        cdef double v
        if gyr != NULL and out_of_range(gyr, self.gyro_range_):
            gyr = NULL
        measured = gyr != NULL and not saturated(gyr, self.gyro_range_)
        v = unobserved_variance(&self.s.t_unmeasured, dt, self.dt_nominal, measured, self.kalman.motion_rate)
        if gyr != NULL:
            self.predict(gyr, dt)
        if v > 0.0:
            self.s.P[0] += v
            self.s.P[7] += v
            self.s.P[14] += v
        if rest_now(self, gyr, acc, dt) and rest_gate_open(self.rest, self.s.b, self.s.P[21],
                                                           self.s.P[28], self.s.P[35]):
            self.zero_rate_update(gyr, dt)
        t0 = self.acc_lp.lp_time
        acc = acc_input(self, gyr, not measured and gyr != NULL, self.s.b, acc, dt, af)
        if acc_lowpass_settles(self.acc_lowpass, &self.acc_lp, t0):
            self.start_ended(dt)
        if acc != NULL:
            self._acc_correct(acc, dt)
        if mag_accepted(self, self.q, mag, gyr, dt):
            self.heading_gain = self.mag_heading
            self._mag_correct(mag, dt)
            self.heading_gain = False
        quat_normalise(self.q)

    cdef void start_ended(self, double dt) noexcept nogil:
        """The accelerometer's low-pass ends its running-mean start: the tilt's variance
        grows by that of the mean it ended with, as the ekf's (ekf_start_ended):
        P[:3, :3] += start_variance (I - h hᵀ), h the body-frame vertical."""
        cdef double h[3]
        cdef double v = start_variance(self.kalman.acc_noise / G0, self.acc_lowpass, dt)
        cdef int i, j
        up_in_body(self.q, h)
        for i in range(3):
            for j in range(3):
                self.s.P[i * 6 + j] += v * ((1.0 if i == j else 0.0) - h[i] * h[j])

    cdef bint _bias(self, double* out) noexcept nogil:
        out[0], out[1], out[2] = self.s.b[0], self.s.b[1], self.s.b[2]
        return True

    @property
    def covariance(self):
        """6x6 covariance of the error [attitude (rad, body frame: the same in ENU and NED),
        gyro bias (rad/s)]."""
        return np.array([self.s.P[i] for i in range(36)]).reshape(6, 6)
