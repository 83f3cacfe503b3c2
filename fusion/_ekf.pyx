# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`ekf`: the 7-state quaternion + gyro-bias EKF of "EKF attitude estimation for a spherical robot"
(Software Engineering, 2022) and "IIR-EKF, IMU dynamic error suppression" (J. Nanjing Univ. Aero.
Astro., 2023) (docs/estimators.md)."""
import numpy as np
from libc.string cimport memset

from fusion._aided cimport rest_now, mag_accepted, acc_input
from fusion._acclp cimport acc_lowpass_settles, start_variance
from fusion._rest cimport rest_gate_open, rest_rate
from fusion._kalman cimport KalmanFilter
from fusion._kalman import STATE_CHECKS
from fusion._core cimport Estimator, run_fast, batch_loop
from fusion._prefilter cimport Butterworth
from fusion._core import struct_fields
from fusion.params import Param, table, REST, MAGDIST, GYRO_RANGE, MOTION_RATE, MAG_UPDATE, ACC_LOWPASS
from fusion._qmath cimport (sym3_adjugate, phi_matrix, xi_matrix, quat_normalise, up_in_body,
                            jac_up_in_body, unit3, unobserved_variance, saturated, out_of_range)

from fusion._constants cimport GRAVITY as G0

# the covariance arithmetic four lanes wide (fusion/_ekfcov.h)
cdef extern from "_ekfcov.h" nogil:
    void ekfc_predict(double* P, double* q, const double* A, double dt, double gq, double qb)
    double ekfc_mag_model(const double* q, const double* zv, double* h, double* H)
    void ekfc_pht(const double* P, const double* H, double r, double* U, double* S)
    void ekfc_optimal(double* P, double* q, double* b, const double* U, const double* Si, double det,
                      const double* y)
    void ekfc_heading(double* P, const double* U, const double* S, const double* u, const double* w,
                      const double* ka, const double* kc)

# the vector updates' gains: "vector" the Kalman gain (as written in "IIR-EKF, IMU dynamic
# error suppression"), "heading" the magnetometer's projected onto a turn about the vertical,
# "tilt" the accelerometer's off it
cdef enum:
    GAIN_FULL = 0
    GAIN_HEADING = 1
    GAIN_TILT = 2
    GAIN_BIAS = 3


cdef inline void ekf_propagate(EKF e, double* q, EKFState* s, const double* gyr, double dt,
                               bint sat) noexcept nogil:
    """The time update of one step: predict with the gyro where there is one, then grow
    the attitude covariance for the motion it did not measure (dropped sample, time gap,
    saturated sample: sat; docs/robustness.md, "Recovery")."""
    cdef bint measured = gyr != NULL and not sat
    cdef double v = unobserved_variance(&s.t_unmeasured, dt, e.dt_nominal, measured, e.kalman.motion_rate)
    if gyr != NULL:
        ekf_predict(e, q, s.b, s.P, gyr, dt)
    if v > 0.0:
        ekf_inflate_attitude(q, s.P, v, True)


cdef inline void ekf_inflate_attitude(const double* q, double* P, double v,
                                      bint heading) noexcept nogil:
    """Add v (rad²) to the variance of the attitude angle about every body axis, the way the
    gyro noise enters in predict: Pqq += (v / 4) Ξ(q) Ξ(q)ᵀ; heading False: about the two
    horizontal axes only (the tilt), Pqq += (v / 4) Ξ(q) (I - h hᵀ) Ξ(q)ᵀ, h the body-frame
    vertical, Ξ(q) h = [0, e_z] ⊗ q = u = (-q3, -q2, q1, q0)."""
    cdef double X[12]
    cdef double u[4]
    cdef double s
    cdef int i, j
    xi_matrix(q, X)
    u[0] = 0.0 if heading else -q[3]
    u[1] = 0.0 if heading else -q[2]
    u[2] = 0.0 if heading else q[1]
    u[3] = 0.0 if heading else q[0]
    for i in range(4):
        for j in range(i, 4):
            s = P[i * 7 + j] + 0.25 * v * (X[i * 3] * X[j * 3] + X[i * 3 + 1] * X[j * 3 + 1]
                                           + X[i * 3 + 2] * X[j * 3 + 2] - u[i] * u[j])
            P[i * 7 + j] = s
            P[j * 7 + i] = s


cdef inline void ekf_start_ended(EKF e, const double* q, double* P, double dt) noexcept nogil:
    """The accelerometer's low-pass ends its running-mean start (dt: this sample's step): the
    tilt's variance grows by that of the mean it ended with, start_variance, which the filter
    took as certain by fusing the growing mean sample by sample as if each were new
    (docs/estimators.md, "The start")."""
    ekf_inflate_attitude(q, P, start_variance(e.kalman.acc_noise / G0, e.acc_lowpass, dt), False)


cdef inline void ekf_predict(EKF e, double* q, const double* b, double* P, const double* gyr,
                             double dt) noexcept nogil:
    """q <- A q and P <- F P Fᵀ + Q, F = [[A, -(dt/2) Ξ(q)], [0, I]], A = Φ(gyr - b, dt),
    Q = diag((dt/4) gyro_noise² Ξ Ξᵀ, bias_noise² dt I3) (fusion/_ekfcov.h, ekfc_predict)."""
    cdef double A[16]
    phi_matrix(gyr[0] - b[0], gyr[1] - b[1], gyr[2] - b[2], dt, A)
    ekfc_predict(P, q, A, dt, 0.25 * dt * e.kalman.gyro_noise * e.kalman.gyro_noise,
                 e.kalman.bias_noise * e.kalman.bias_noise * dt)


cdef inline void heading_gain(const double* q, const double* U, const double* Sa, double det,
                              double* u, double* w, double* ka, double* kc) noexcept nogil:
    """The magnetometer's gain projected so that the update can only turn the attitude about
    the vertical (quaternion rows onto u = e_z (x) q, the direction of such a turn) and change
    the bias along the body-frame vertical w = R^T e_z: the magnetometer then corrects the
    heading alone, as in VQF and Fusion (docs/estimators.md). Projecting the rows of
    U S^-1 (U = P Hᵀ in ekfc_pht's columns, Sa = adj(S), det = 1 / det(S)) gives rank-one
    blocks, K_q = u kaᵀ with ka = S^-1 U_qᵀ u / |u|², K_b = w kcᵀ with kc = S^-1 U_bᵀ w:
    K = [u; 0] kaᵀ + [0; w] kcᵀ, held as its four vectors (ekf_vector_update)."""
    cdef double a[3]
    cdef double c[3]
    cdef double iuu
    cdef int j
    u[0] = -q[3]
    u[1] = -q[2]
    u[2] = q[1]
    u[3] = q[0]
    iuu = det      # / |u|² = |q|² = 1: q was normalised by the update or prediction before
    up_in_body(q, w)
    for j in range(3):
        a[j] = u[0] * U[8 * j] + u[1] * U[8 * j + 1] + u[2] * U[8 * j + 2] + u[3] * U[8 * j + 3]
        c[j] = w[0] * U[8 * j + 4] + w[1] * U[8 * j + 5] + w[2] * U[8 * j + 6]
    for j in range(3):
        ka[j] = (a[0] * Sa[j] + a[1] * Sa[3 + j] + a[2] * Sa[6 + j]) * iuu
        kc[j] = (c[0] * Sa[j] + c[1] * Sa[3 + j] + c[2] * Sa[6 + j]) * det


cdef inline void tilt_only_gain(const double* q, double* K) noexcept nogil:
    """The complement of heading_gain, for the accelerometer (acc_update="tilt"): K's
    quaternion rows projected off u = e_z (x) q (no turn about the vertical) and its bias
    rows off the body-frame vertical w = R^T e_z, so that a linear acceleration the filter
    takes for gravity cannot turn the heading or the bias along the vertical, which the
    accelerometer does not observe (docs/estimators.md, step 4)."""
    cdef double u[4]
    cdef double w[3]
    cdef double a, c
    cdef int i, j
    u[0] = -q[3]; u[1] = -q[2]; u[2] = q[1]; u[3] = q[0]
    up_in_body(q, w)
    for j in range(3):
        a = u[0] * K[j] + u[1] * K[3 + j] + u[2] * K[6 + j] + u[3] * K[9 + j]
        c = w[0] * K[12 + j] + w[1] * K[15 + j] + w[2] * K[18 + j]
        for i in range(4):
            K[i * 3 + j] -= u[i] * a
        for i in range(3):
            K[(4 + i) * 3 + j] -= w[i] * c


cdef inline void joseph_entry(double* P, const double* K, const double* U, const double* V,
                              int i, int j) noexcept nogil:
    """P[i, j] and P[j, i] of the Joseph update P - K Uᵀ - V Kᵀ (ekf_vector_update)."""
    cdef double s = P[i * 7 + j] - ((K[i * 3] * U[j * 3] + K[i * 3 + 1] * U[j * 3 + 1]
                                     + K[i * 3 + 2] * U[j * 3 + 2])
                                    + (V[i * 3] * K[j * 3] + V[i * 3 + 1] * K[j * 3 + 1]
                                       + V[i * 3 + 2] * K[j * 3 + 2]))
    P[i * 7 + j] = s
    P[j * 7 + i] = s


cdef inline void ekf_vector_update(double* q, double* b, double* P, const double* z,
                                   const double* h, const double* H, double r,
                                   int gain) noexcept nogil:
    """Kalman update with measurement z, prediction h, Jacobian H (3x4, zero on the bias)
    and noise variance r per axis; ``gain``: GAIN_FULL, or the gain projected by
    heading_gain / tilt_only_gain. The covariance in the Joseph form, which holds for any
    gain (kalman_apply), written for each gain's structure: P - K Uᵀ for the optimal gain
    (ekfc_optimal), the rank-four form for the heading gain (ekfc_heading)."""
    cdef double U[24]    # P Hᵀ, 7x3, as three columns of 8 (ekfc_pht)
    cdef double Ur[21]   # P Hᵀ, 7x3 row-major (kalman_apply)
    cdef double S[9]
    cdef double Si[9]    # adj(S)
    cdef double y[3]
    cdef double u[4]
    cdef double w[3]
    cdef double ka[3]
    cdef double kc[3]
    cdef double det, dq, db
    cdef int i, k
    ekfc_pht(P, H, r, U, S)
    y[0] = z[0] - h[0]
    y[1] = z[1] - h[1]
    y[2] = z[2] - h[2]
    if gain == GAIN_FULL:
        # K = U S^-1 = (U adj(S)) / det(S): the products with the adjugate do not wait for
        # the division (~13 cycles on the chain from P to the next update)
        det = sym3_adjugate(S, Si)
        ekfc_optimal(P, q, b, U, Si, det, y)
        quat_normalise(q)
    elif gain == GAIN_HEADING:
        det = sym3_adjugate(S, Si)
        heading_gain(q, U, Si, det, u, w, ka, kc)
        dq = ka[0] * y[0] + ka[1] * y[1] + ka[2] * y[2]
        db = kc[0] * y[0] + kc[1] * y[1] + kc[2] * y[2]
        for i in range(4):
            q[i] += u[i] * dq
        for i in range(3):
            b[i] += w[i] * db
        quat_normalise(q)
        ekfc_heading(P, U, S, u, w, ka, kc)
    else:
        for i in range(7):
            for k in range(3):
                Ur[i * 3 + k] = U[8 * k + i]
        kalman_apply(q, b, P, Ur, S, y, gain)


cdef inline void kalman_apply(double* q, double* b, double* P, const double* U,
                              double* S, const double* y, int gain) noexcept nogil:
    """The update of [q, b] and P for a 3-D measurement from U = P Hᵀ (7x3 row-major),
    S = H P Hᵀ + Rm and the residual y, for a gain other than the optimal or the heading one
    (ekf_vector_update): the tilt-only gain and the rest update's bias-only gain."""
    cdef double Si[9]    # adj(S)
    cdef double K[21]    # 7x3
    cdef double V[21]    # U - K S, 7x3
    cdef double det
    cdef int i, j
    # K = U S^-1 = (U adj(S)) / det(S): the products with the adjugate do not wait for the
    # division (~13 cycles on the chain from P to the next update)
    det = sym3_adjugate(S, Si)
    for i in range(7):
        for j in range(3):
            K[i * 3 + j] = (U[i * 3] * Si[j] + U[i * 3 + 1] * Si[3 + j] + U[i * 3 + 2] * Si[6 + j]) * det
    if gain == GAIN_TILT:
        tilt_only_gain(q, K)
    elif gain == GAIN_BIAS:
        for i in range(12):
            K[i] = 0.0
    for i in range(4):
        q[i] += K[i * 3] * y[0] + K[i * 3 + 1] * y[1] + K[i * 3 + 2] * y[2]
    for i in range(3):
        b[i] += K[(4 + i) * 3] * y[0] + K[(4 + i) * 3 + 1] * y[1] + K[(4 + i) * 3 + 2] * y[2]
    quat_normalise(q)
    # Joseph form (I - KH) P (I - KH)^T + r K K^T, expanded with H P = U^T and
    # H P H^T + r I = S: P - K U^T - U K^T + K S K^T = P - K U^T - (U - K S) K^T. Valid
    # for any K like the product form (an error in K enters at second order), at half
    # its cost; symmetric, so the upper half, mirrored.
    for i in range(7):
        for j in range(3):
            V[i * 3 + j] = U[i * 3 + j] - (K[i * 3] * S[j] + K[i * 3 + 1] * S[3 + j]
                                           + K[i * 3 + 2] * S[6 + j])
    # entry by entry with constant indices (the compiler keeps K, U, V in registers and
    # drops the triangular loop's index arithmetic, which cost as much as the products)
    joseph_entry(P, K, U, V, 0, 0); joseph_entry(P, K, U, V, 0, 1); joseph_entry(P, K, U, V, 0, 2)
    joseph_entry(P, K, U, V, 0, 3); joseph_entry(P, K, U, V, 0, 4); joseph_entry(P, K, U, V, 0, 5)
    joseph_entry(P, K, U, V, 0, 6)
    joseph_entry(P, K, U, V, 1, 1); joseph_entry(P, K, U, V, 1, 2); joseph_entry(P, K, U, V, 1, 3)
    joseph_entry(P, K, U, V, 1, 4); joseph_entry(P, K, U, V, 1, 5); joseph_entry(P, K, U, V, 1, 6)
    joseph_entry(P, K, U, V, 2, 2); joseph_entry(P, K, U, V, 2, 3); joseph_entry(P, K, U, V, 2, 4)
    joseph_entry(P, K, U, V, 2, 5); joseph_entry(P, K, U, V, 2, 6)
    joseph_entry(P, K, U, V, 3, 3); joseph_entry(P, K, U, V, 3, 4); joseph_entry(P, K, U, V, 3, 5)
    joseph_entry(P, K, U, V, 3, 6)
    joseph_entry(P, K, U, V, 4, 4); joseph_entry(P, K, U, V, 4, 5); joseph_entry(P, K, U, V, 4, 6)
    joseph_entry(P, K, U, V, 5, 5); joseph_entry(P, K, U, V, 5, 6)
    joseph_entry(P, K, U, V, 6, 6)


cdef inline void ekf_acc_update(EKF e, double* q, double* b, double* P, const double* acc,
                                double dt) noexcept nogil:
    cdef double z[3]
    cdef double h[3]
    cdef double H[12]
    cdef double sa = e.kalman.acc_noise / G0
    unit3(acc, z)
    up_in_body(q, h)
    jac_up_in_body(q, H)
    ekf_vector_update(q, b, P, z, h, H, sa * sa / dt, e.acc_gain)


cdef inline bint ekf_mag_update(EKF e, double* q, double* b, double* P, const double* mag,
                                double dt) noexcept nogil:
    """The magnetometer's update; False if the field has no heading information (q, b and P
    unchanged), True if it updated them (q normalised)."""
    # "IIR-EKF, IMU dynamic error suppression", eqs. 11-16: the measured field in the navigation
    # frame, its horizontal part folded onto north, h = R^T v (fusion/_ekfcov.h,
    # ekfc_mag_model). v depends on q, and so does the Jacobian: dh/dq = d(R^T v)/dq|v +
    # R^T dv/dn dn/dq, n = R m. Holding v fixed (as the paper does) lets heading residuals
    # tilt the estimate and drag the gyro bias with them.
    cdef double z[3]
    cdef double h[3]
    cdef double H[12]
    unit3(mag, z)
    if ekfc_mag_model(q, z, h, H) == 0.0:     # field along the vertical: no heading information
        return False
    ekf_vector_update(q, b, P, z, h, H, e.kalman.mag_noise * e.kalman.mag_noise / dt, e.mag_gain)
    return True


cdef const double* acc_nav_lowpass(EKF e, const double* gyr, bint sat, const double* q,
                                   EKFState* s, const double* acc, double dt,
                                   double* out) noexcept nogil:
    """acc_input (fusion/_aided.pxd) on the ekf's state, and where this sample ends the
    low-pass's running-mean start, the tilt's variance grown back (ekf_start_ended); out of
    line."""
    cdef double t0 = e.acc_lp.lp_time
    acc = acc_input(e, gyr, sat, s.b, acc, dt, out)
    if acc_lowpass_settles(e.acc_lowpass, &e.acc_lp, t0):
        ekf_start_ended(e, q, s.P, dt)
    return acc


cdef void ekf_rest(EKF e, double* q, EKFState* st, const double* gyr,
                   const double* acc, double dt) noexcept nogil:
    """Rest detection (fusion/_rest.pxd) and, at rest, the zero-rate update: the gyro measures
    the bias, z = rest_rate (the sample, or the still run's mean on its first update),
    h = b, H = [0 I3], the noise density over the time z averages, its gain on the bias only
    (docs/estimators.md, "Rest")."""
    cdef double U[21]    # P Hᵀ = P[:, 4:7]
    cdef double S[9]
    cdef double y[3]
    cdef double z[3]
    cdef double T
    cdef double* b = st.b
    cdef double* P = st.P
    cdef int i, j
    if not rest_now(e, gyr, acc, dt) or not rest_gate_open(e.rest, b, P[32], P[40], P[48]):
        return
    T = rest_rate(e.rest, gyr, dt, z)
    for i in range(7):
        for j in range(3):
            U[i * 3 + j] = P[i * 7 + 4 + j]
    for i in range(3):
        for j in range(3):
            S[i * 3 + j] = P[(4 + i) * 7 + 4 + j]
        S[i * 4] += e.rest.noise * e.rest.noise / T
        y[i] = z[i] - b[i]
    kalman_apply(q, b, P, U, S, y, GAIN_BIAS)


cdef inline void ekf_step(EKF e, double* q, EKFState* s, const double* gyr, const double* acc,
                          const double* mag, double dt) noexcept nogil:
    """One sample (gyr, acc, mag may be NULL) on the state q, s in place, with e's
    parameters: EKF._step and the batch loop both run this."""
    cdef double af[3]
    cdef bint sat
    # unit: q was normalised by the last update that changed it (each update normalises); a
    # second normalisation would only move its last bit and wait on the chain to the next step
    cdef bint unit = False
    if gyr != NULL and out_of_range(gyr, e.gyro_range_):
        gyr = NULL      # not a measurement: held as a dropped sample (the covariance grows)
    sat = gyr != NULL and saturated(gyr, e.gyro_range_)
    ekf_propagate(e, q, s, gyr, dt, sat)
    if e.rest.time > 0.0:
        ekf_rest(e, q, s, gyr, acc, dt)
    if e.acc_lowpass > 0.0:
        acc = acc_nav_lowpass(e, gyr, sat, q, s, acc, dt, af)
    if acc != NULL:     # one call site: the compiler inlines the update into the batch loop
        ekf_acc_update(e, q, s.b, s.P, acc, dt)
        unit = True
    if mag_accepted(e, q, mag, gyr, dt):
        unit = ekf_mag_update(e, q, s.b, s.P, mag, dt) or unit
    if not unit:
        quat_normalise(q)


cdef inline void ekf_batch_step(Estimator e, double* q, void* s, const double* gyr,
                                const double* acc, const double* mag, double dt) noexcept nogil:
    """ekf_step as fusion/_core.pxd's batch_loop calls it."""
    ekf_step(<EKF>e, q, <EKFState*>s, gyr, acc, mag, dt)


cdef class EKF(KalmanFilter):
    """Quaternion + gyro-bias extended Kalman filter with accelerometer and magnetometer
    vector measurements and the Joseph-form covariance update."""
    name = "ekf"
    # acc_noise and acc_lowpass chosen leave-one-set-out on the recorded sets (docs/accuracy.md)
    PARAMS = table(
        Param("gyro_noise", 0.015, "rad/s/√Hz", 1e-5, 10.0, "gyro white-noise density (inflated over "
              "datasheet figures, about 1e-4, to cover scale, misalignment and vibration)"),
        Param("bias_noise", 1e-4, "rad/s/√s", 1e-9, 0.01, "gyro bias random walk", allow_zero=True),
        Param("acc_noise", 0.5, "m/s²/√Hz", 1e-3, 1e3, "accelerometer noise density about gravity, "
              "including the linear acceleration a moving body adds (datasheets: about 0.002)"),
        Param("mag_noise", 0.2, "1/√Hz", 1e-4, 10.0, "magnetometer noise density, relative to the "
              "field norm, including disturbances and calibration residue (with gyro_noise it sets the "
              "heading's time constant, about mag_noise / (gyro_noise cos(dip)) seconds; chosen leave-one-set-out "
              "within the failure scenarios' bounds: docs/accuracy.md)"),
        Param("q_init_std", 0.05, "1", 1e-4, 1.0, "initial std of each quaternion component"),
        Param("bias_init_std", 0.0087, "rad/s", 1e-6, 1.0, "initial std of each gyro bias component "
              "(MEMS turn-on bias; 0.0087 = 0.5 °/s, VQF's, chosen leave-one-set-out: docs/accuracy.md)",
              allow_zero=True),
        GYRO_RANGE, MOTION_RATE, MAG_UPDATE, ACC_LOWPASS,
        Param("acc_update", "vector", "", doc='"vector": the IIR-EKF paper\'s update; "tilt": the accelerometer '
              "corrects the inclination (and the bias across the vertical) only, so that a linear "
              "acceleration taken for gravity cannot turn the heading", choices=("tilt", "vector")),
        *REST, *MAGDIST)

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked before the base takes anything
        self._take_base(fs, frame, on_invalid, p)
        self.mag_gain = GAIN_HEADING if p["mag_update"] == "heading" else GAIN_FULL
        self.acc_gain = GAIN_TILT if p["acc_update"] == "tilt" else GAIN_FULL
        self.own_step = type(self) is EKF   # a subclass steps its own way: no inlined loop
        self.configure(p)                   # noise, rest and disturbance detectors, low-pass; reset

    cdef list _filter_fields(self):
        return struct_fields(<EKFState[:1]>&self.s, STATE_CHECKS)

    cdef list _state_fields(self):
        return KalmanFilter._state_fields(self) + self._filter_fields()

    cdef void _reset_state(self) noexcept nogil:
        cdef int i
        KalmanFilter._reset_state(self)
        memset(&self.s, 0, sizeof(EKFState))
        for i in range(4):
            self.s.P[i * 8] = self.kalman.q_init_std * self.kalman.q_init_std
        for i in range(4, 7):
            self.s.P[i * 8] = self.kalman.bias_init_std * self.kalman.bias_init_std

    # the steps of ekf_step for a subclass (aekf) or a holder (cf-ekf), on this estimator's state
    cdef void propagate(self, const double* gyr, double dt, bint sat) noexcept nogil:
        ekf_propagate(self, self.q, &self.s, gyr, dt, sat)

    cdef void predict(self, const double* gyr, double dt) noexcept nogil:
        ekf_predict(self, self.q, self.s.b, self.s.P, gyr, dt)

    cdef const double* acc_sample(self, const double* gyr, bint sat, const double* acc, double dt,
                                  double* out) noexcept nogil:
        return acc_nav_lowpass(self, gyr, sat, self.q, &self.s, acc, dt, out)

    cdef void _acc_correct(self, const double* acc, double dt) noexcept nogil:
        ekf_acc_update(self, self.q, self.s.b, self.s.P, acc, dt)

    cdef void _mag_correct(self, const double* mag, double dt) noexcept nogil:
        ekf_mag_update(self, self.q, self.s.b, self.s.P, mag, dt)

    cdef void rest_update(self, const double* gyr, const double* acc, double dt) noexcept nogil:
        ekf_rest(self, self.q, &self.s, gyr, acc, dt)

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        ekf_step(self, self.q, &self.s, gyr, acc, mag, dt)

    cdef Py_ssize_t _run_batch(self, const double* g, const double* a, const double* m,
                               const double* d, double dt, double* o, Py_ssize_t n,
                               bint stop_invalid) noexcept nogil:
        # the state in locals (fusion/_core.pxd batch_loop): the compiler keeps q and b in
        # registers and P unreloaded
        cdef EKFState s
        if not (self.own_step and run_fast(self)):
            return Estimator._run_batch(self, g, a, m, d, dt, o, n, stop_invalid)
        return batch_loop(self, ekf_batch_step, &s, &self.s, sizeof(EKFState), g, a, m, d, dt, o, n,
                          stop_invalid)

    cdef bint _bias(self, double* out) noexcept nogil:
        out[0], out[1], out[2] = self.s.b[0], self.s.b[1], self.s.b[2]
        return True

    @property
    def acc_update(self):
        """"tilt" (the accelerometer corrects the inclination only) or "vector" (the IIR-EKF paper's)."""
        return "tilt" if self.acc_gain == GAIN_TILT else "vector"

    @property
    def covariance(self):
        """7x7 covariance of [q (in the estimator's frame), gyro bias]."""
        P = np.array([self.s.P[i] for i in range(49)]).reshape(7, 7)
        if self.ned:
            s = np.sqrt(0.5)
            Lc = np.array([[0, -s, -s, 0], [s, 0, 0, s], [s, 0, 0, -s], [0, -s, s, 0]])
            T = np.eye(7)
            T[:4, :4] = Lc
            P = T @ P @ T.T
        return P


cdef class IIREKF(EKF):
    """The IIR-EKF of "IIR-EKF, IMU dynamic error suppression" (J. Nanjing Univ. Aero. Astro., 2023):
    the `ekf` with a second-order Butterworth low-pass in front of the
    accelerometer (and optionally the magnetometer) to suppress vibration before it reaches
    the measurement update. cutoff_hz defaults to 40 Hz (the paper's, at 200 Hz sampling),
    lowered to 0.45 fs when the sample rate is too low for it."""
    name = "iir-ekf"
    PARAMS = table(*EKF.PARAMS.values(),
                   Param("cutoff_hz", 40.0, "Hz", 0.0, None, "the Butterworth's cutoff, from 1e-7 fs to below fs / 2; "
                         "not given: min(40, 0.45 fs)", open_low=True),
                   Param("filter_mag", False, "", doc="the magnetometer through the same low-pass"))

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)       # before the prefilter is replaced
        p = self._take_params(params)
        cutoff = p["cutoff_hz"] if "cutoff_hz" in params else min(p["cutoff_hz"], 0.45 * fs)
        pre_acc = Butterworth(fs, cutoff)
        pre_mag = Butterworth(fs, cutoff) if p["filter_mag"] else None
        self._take_prefilters(None, pre_acc, pre_mag)
        EKF._configure(self, fs, frame, on_invalid, params)

    @property
    def cutoff_hz(self):
        return self.pre_acc.cutoff_hz

    @property
    def filter_mag(self):
        return self.pre_mag is not None
