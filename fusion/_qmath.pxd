# Quaternion and small-matrix helpers shared by every kernel (inlined; no Python objects).
# Conventions: docs/estimators.md. q = [w, x, y, z], R(q) rotates body -> navigation (ENU).
from libc.math cimport sqrt, sin, cos, atan2, asin, isfinite, M_PI
from libc.float cimport DBL_MIN
from fusion._constants cimport lasted

cdef inline bint vec3_valid(const double* v) noexcept nogil:
    """A usable accelerometer / magnetometer sample: finite, with |v|^2 finite and a normal
    double (>= DBL_MIN, about 2.2e-308): components so large that |v|^2 overflows, or so small
    that it is denormal or zero, are rejected (1 / |v|^2 would overflow)."""
    cdef double n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    return isfinite(n2) and n2 >= DBL_MIN

cdef inline bint vec3_finite(const double* v) noexcept nogil:
    """A usable gyro sample: finite with a finite norm (zero rate is fine)."""
    return isfinite(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])

cdef inline double norm3(const double* v) noexcept nogil:
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])

cdef inline void unit3(const double* v, double* out) noexcept nogil:
    cdef double n = 1.0 / norm3(v)
    out[0] = v[0] * n
    out[1] = v[1] * n
    out[2] = v[2] * n

cdef inline void cross3(const double* a, const double* b, double* out) noexcept nogil:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]

cdef inline double sym3_adjugate(const double* S, double* Sa) noexcept nogil:
    """Sa = adj(S) for a symmetric 3x3 S (row-major); returns 1 / det(S), so that
    S^-1 = Sa / det(S). Callers may use Sa before the division is done."""
    cdef double det
    Sa[0] = S[4] * S[8] - S[5] * S[7]
    Sa[1] = S[2] * S[7] - S[1] * S[8]
    Sa[2] = S[1] * S[5] - S[2] * S[4]
    det = 1.0 / (S[0] * Sa[0] + S[3] * Sa[1] + S[6] * Sa[2])
    Sa[3] = Sa[1]
    Sa[4] = S[0] * S[8] - S[2] * S[6]
    Sa[5] = S[2] * S[3] - S[0] * S[5]
    Sa[6] = Sa[2]
    Sa[7] = Sa[5]
    Sa[8] = S[0] * S[4] - S[1] * S[3]
    return det

cdef inline void sym3_inverse(const double* S, double* Si) noexcept nogil:
    """Si = S^-1 for a symmetric 3x3 S (row-major), by the adjugate."""
    cdef double det = sym3_adjugate(S, Si)
    cdef int i
    for i in range(9):
        Si[i] *= det

cdef inline double quat_norm_factor(double n2) noexcept nogil:
    """1 / sqrt(n2), n2 the squared norm of a quaternion (quat_normalise's factor)."""
    cdef double d = n2 - 1.0
    if -1e-6 < d < 1e-6:
        # near unit, the usual case after a norm-preserving step: 1/sqrt(1 + d) by its
        # series, truncation 5/16 d^3 < 1e-18, without the sqrt and division (~40 cycles)
        # on the sample-to-sample dependency chain. NaN fails the test and takes the else.
        return 1.0 - d * (0.5 - 0.375 * d)
    return 1.0 / sqrt(n2)

cdef inline void quat_normalise(double* q) noexcept nogil:
    cdef double n = quat_norm_factor(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    q[0] *= n
    q[1] *= n
    q[2] *= n
    q[3] *= n

cdef inline void quat_mul(const double* p, const double* q, double* out) noexcept nogil:
    """out = p ⊗ q (out must not alias p or q)."""
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]

cdef inline void xi_matrix(const double* q, double* X) noexcept nogil:
    """X (4x3, row-major) = Ξ(q), with q ⊗ [0, w] = Ξ(q) w: how a body rate turns q."""
    X[0] = -q[1]; X[1] = -q[2]; X[2] = -q[3]
    X[3] = q[0];  X[4] = -q[3]; X[5] = q[2]
    X[6] = q[3];  X[7] = q[0];  X[8] = -q[1]
    X[9] = -q[2]; X[10] = q[1]; X[11] = q[0]


cdef inline void rot_to_body(const double* q, const double* v, double* out) noexcept nogil:
    """out = R(q)^T v (navigation -> body), homogeneous form."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    out[0] = (w*w + x*x - y*y - z*z) * v[0] + 2.0 * (x*y + w*z) * v[1] + 2.0 * (x*z - w*y) * v[2]
    out[1] = 2.0 * (x*y - w*z) * v[0] + (w*w - x*x + y*y - z*z) * v[1] + 2.0 * (y*z + w*x) * v[2]
    out[2] = 2.0 * (x*z + w*y) * v[0] + 2.0 * (y*z - w*x) * v[1] + (w*w - x*x - y*y + z*z) * v[2]

cdef inline void up_in_body(const double* q, double* out) noexcept nogil:
    """out = R(q)^T [0, 0, 1]: the navigation frame's up axis in body coordinates."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    out[0] = 2.0 * (x*z - w*y)
    out[1] = 2.0 * (y*z + w*x)
    out[2] = w*w - x*x - y*y + z*z

cdef inline void jac_up_in_body(const double* q, double* H) noexcept nogil:
    """H (3x4, row-major) = d(R(q)^T [0, 0, 1])/dq."""
    cdef double w = 2.0 * q[0], x = 2.0 * q[1], y = 2.0 * q[2], z = 2.0 * q[3]
    H[0] = -y; H[1] = z;  H[2] = -w;  H[3] = x
    H[4] = x;  H[5] = w;  H[6] = z;   H[7] = y
    H[8] = w;  H[9] = -x; H[10] = -y; H[11] = z

cdef inline void rot_to_nav(const double* q, const double* v, double* out) noexcept nogil:
    """out = R(q) v (body -> navigation), homogeneous form."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    out[0] = (w*w + x*x - y*y - z*z) * v[0] + 2.0 * (x*y - w*z) * v[1] + 2.0 * (x*z + w*y) * v[2]
    out[1] = 2.0 * (x*y + w*z) * v[0] + (w*w - x*x + y*y - z*z) * v[1] + 2.0 * (y*z - w*x) * v[2]
    out[2] = 2.0 * (x*z - w*y) * v[0] + 2.0 * (y*z + w*x) * v[1] + (w*w - x*x - y*y + z*z) * v[2]

cdef inline void jac_rot_to_body(const double* q, const double* v, double* H) noexcept nogil:
    """H (3x4, row-major) = d(R(q)^T v)/dq for a fixed v."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    cdef double a = v[0], b = v[1], c = v[2]
    H[0] = 2.0 * (w*a + z*b - y*c)
    H[1] = 2.0 * (x*a + y*b + z*c)
    H[2] = 2.0 * (-y*a + x*b - w*c)
    H[3] = 2.0 * (-z*a + w*b + x*c)
    H[4] = 2.0 * (-z*a + w*b + x*c)
    H[5] = 2.0 * (y*a - x*b + w*c)
    H[6] = 2.0 * (x*a + y*b + z*c)
    H[7] = 2.0 * (-w*a - z*b + y*c)
    H[8] = 2.0 * (y*a - x*b + w*c)
    H[9] = 2.0 * (z*a - w*b - x*c)
    H[10] = 2.0 * (w*a + z*b - y*c)
    H[11] = 2.0 * (x*a + y*b + z*c)

cdef inline void jac_rot_to_nav(const double* q, const double* v, double* H) noexcept nogil:
    """H (3x4, row-major) = d(R(q) v)/dq for a fixed v."""
    cdef double w = q[0], x = q[1], y = q[2], z = q[3]
    cdef double a = v[0], b = v[1], c = v[2]
    H[0] = 2.0 * (w*a - z*b + y*c)
    H[1] = 2.0 * (x*a + y*b + z*c)
    H[2] = 2.0 * (-y*a + x*b + w*c)
    H[3] = 2.0 * (-z*a - w*b + x*c)
    H[4] = 2.0 * (z*a + w*b - x*c)
    H[5] = 2.0 * (y*a - x*b - w*c)
    H[6] = 2.0 * (x*a + y*b + z*c)
    H[7] = 2.0 * (w*a - z*b + y*c)
    H[8] = 2.0 * (-y*a + x*b + w*c)
    H[9] = 2.0 * (z*a + w*b - x*c)
    H[10] = 2.0 * (-w*a + z*b - y*c)
    H[11] = 2.0 * (x*a + y*b + z*c)

cdef inline void half_angle_terms(double wx, double wy, double wz, double dt,
                                  double* c, double* s) noexcept nogil:
    """c = cos(|w| dt / 2), s = sin(|w| dt / 2) / |w| (s -> dt/2 as w -> 0)."""
    cdef double n2 = wx * wx + wy * wy + wz * wz
    cdef double h2 = n2 * (0.25 * dt * dt)   # (theta/2)^2; dt's factor is off the w chain
    cdef double h4, n
    if h2 < 0.0025:   # theta/2 < 0.05: Taylor series to h2^4, truncation < 1e-19
        # Estrin's scheme (h2 and h4 = h2^2 in parallel) instead of Horner's: half the
        # dependent multiply-adds, which is what a sample's latency is made of; multiplications
        # by reciprocals, as a chain of divisions would cost ~30 ns
        h4 = h2 * h2
        c[0] = (1.0 - 0.5 * h2) + h4 * ((1.0 / 24.0 - h2 * (1.0 / 720.0)) + h4 * (1.0 / 40320.0))
        s[0] = (0.5 * dt) * ((1.0 - h2 * (1.0 / 6.0))
                             + h4 * ((1.0 / 120.0 - h2 * (1.0 / 5040.0)) + h4 * (1.0 / 362880.0)))
    else:
        n = sqrt(n2)
        c[0] = cos(0.5 * n * dt)
        s[0] = sin(0.5 * n * dt) / n

cdef inline void phi_matrix(double wx, double wy, double wz, double dt, double* A) noexcept nogil:
    """A (4x4, row-major) = cos(θ/2) I + sin(θ/2)/|w| Ω(w), the exact one-step transition."""
    cdef double c, s
    half_angle_terms(wx, wy, wz, dt, &c, &s)
    wx *= s
    wy *= s
    wz *= s
    A[0] = c;   A[1] = -wx; A[2] = -wy;  A[3] = -wz
    A[4] = wx;  A[5] = c;   A[6] = wz;   A[7] = -wy
    A[8] = wy;  A[9] = -wz; A[10] = c;   A[11] = wx
    A[12] = wz; A[13] = wy; A[14] = -wx; A[15] = c

cdef inline void quat_propagate(double* q, double wx, double wy, double wz, double dt) noexcept nogil:
    """q <- Φ(w, dt) q (in place)."""
    cdef double c, s, w0 = q[0], x0 = q[1], y0 = q[2], z0 = q[3]
    half_angle_terms(wx, wy, wz, dt, &c, &s)
    wx *= s
    wy *= s
    wz *= s
    q[0] = c * w0 - wx * x0 - wy * y0 - wz * z0
    q[1] = wx * w0 + c * x0 + wz * y0 - wy * z0
    q[2] = wy * w0 - wz * x0 + c * y0 + wx * z0
    q[3] = wz * w0 + wy * x0 - wx * y0 + c * z0

cdef inline void quat_from_acc_mag(const double* acc, const double* mag, double* q) noexcept nogil:
    """Initial attitude (docs/estimators.md): mag may be NULL (yaw = 0)."""
    cdef double u[3]
    cdef double e[3]
    cdef double n[3]
    cdef double R[9]
    cdef double ne, ch, sh, cr, sr, roll, pitch, tr, s
    unit3(acc, u)
    if mag != NULL:
        cross3(mag, u, e)
        ne = norm3(e)
        if ne > 1e-9 * norm3(mag):
            e[0] /= ne; e[1] /= ne; e[2] /= ne
            cross3(u, e, n)
            R[0] = e[0]; R[1] = e[1]; R[2] = e[2]
            R[3] = n[0]; R[4] = n[1]; R[5] = n[2]
            R[6] = u[0]; R[7] = u[1]; R[8] = u[2]
            # Shepperd: pick the largest of 4w², 4x², 4y², 4z² for stability
            tr = R[0] + R[4] + R[8]
            if tr >= R[0] and tr >= R[4] and tr >= R[8]:
                s = 2.0 * sqrt(1.0 + tr)
                q[0] = 0.25 * s; q[1] = (R[7] - R[5]) / s
                q[2] = (R[2] - R[6]) / s; q[3] = (R[3] - R[1]) / s
            elif R[0] >= R[4] and R[0] >= R[8]:
                s = 2.0 * sqrt(1.0 + R[0] - R[4] - R[8])
                q[0] = (R[7] - R[5]) / s; q[1] = 0.25 * s
                q[2] = (R[1] + R[3]) / s; q[3] = (R[2] + R[6]) / s
            elif R[4] >= R[8]:
                s = 2.0 * sqrt(1.0 + R[4] - R[0] - R[8])
                q[0] = (R[2] - R[6]) / s; q[1] = (R[1] + R[3]) / s
                q[2] = 0.25 * s; q[3] = (R[5] + R[7]) / s
            else:
                s = 2.0 * sqrt(1.0 + R[8] - R[0] - R[4])
                q[0] = (R[3] - R[1]) / s; q[1] = (R[2] + R[6]) / s
                q[2] = (R[5] + R[7]) / s; q[3] = 0.25 * s
            if q[0] < 0.0:
                q[0] = -q[0]; q[1] = -q[1]; q[2] = -q[2]; q[3] = -q[3]
            quat_normalise(q)
            return
    roll = atan2(u[1], u[2])
    pitch = atan2(-u[0], sqrt(u[1] * u[1] + u[2] * u[2]))
    ch = cos(0.5 * pitch); sh = sin(0.5 * pitch)
    cr = cos(0.5 * roll); sr = sin(0.5 * roll)
    q[0] = ch * cr
    q[1] = ch * sr
    q[2] = sh * cr
    q[3] = -sh * sr

cdef inline double unobserved_variance(double* t_run, double dt, double dt_nominal,
                                       bint measured, double motion_rate) noexcept nogil:
    """Attitude variance (rad², about every axis) to add for motion the gyro did not measure
    (docs/robustness.md, "Recovery"): the whole step when the rate was not measured (sample
    dropped, gyro saturated), the part of a step beyond the nominal period when the step is a
    gap (longer than 1.5 nominal periods: a sample missing). A shorter step is stamp
    jitter or a rate off the nominal: the gyro measured it, and counting it would inflate the
    variance on every late stamp. t_run (s) is the length of the current run of unmeasured
    time; over a run the rate is taken as an unknown constant of standard deviation
    motion_rate, so the added variances sum to (motion_rate t_run)², capped at π² (no
    attitude is further off than π)."""
    cdef double t = dt if not measured else (dt - dt_nominal if dt > 1.5 * dt_nominal else 0.0)
    cdef double v0, v1
    if t <= 0.0:
        t_run[0] = 0.0
        return 0.0
    v0 = motion_rate * t_run[0]
    t_run[0] += t
    v1 = motion_rate * t_run[0]
    v0 = v0 * v0 if v0 < M_PI else M_PI * M_PI
    v1 = v1 * v1 if v1 < M_PI else M_PI * M_PI
    return v1 - v0


cdef inline double recovery_gain(double* t_left, bint saturated_now, double dt) noexcept nogil:
    """Factor on a complementary filter's correction gain this step, after a saturated gyro
    (docs/robustness.md, "Recovery"): 20 at a saturated sample, falling linearly back to 1
    over the 3 s after the last one (x-io Fusion's restart ramp: gain 10 for 0.5, over 3 s).
    t_left (s) counts down; > 0 while recovering (the filter then holds its bias learning),
    the 3 s over once they have lasted (fusion/_steps.h: the steps may sum short of them)."""
    cdef double f
    if saturated_now:
        t_left[0] = 3.0
    if lasted(3.0 - t_left[0], 3.0):
        t_left[0] = 0.0
        return 1.0
    f = 1.0 + 19.0 * t_left[0] * (1.0 / 3.0)
    t_left[0] -= dt
    return f


cdef inline bint saturated(const double* gyr, double gyro_range) noexcept nogil:
    """A gyro sample at or beyond 98 % of the range on any axis (gyro_range 0: range
    unknown, never). The margin, as x-io Fusion's: after bias and scale calibration a
    clipped sample lands near the range, not on it."""
    cdef double r = 0.98 * gyro_range
    return gyro_range > 0.0 and (gyr[0] >= r or gyr[0] <= -r or gyr[1] >= r or gyr[1] <= -r
                                 or gyr[2] >= r or gyr[2] <= -r)


cdef inline bint out_of_range(const double* gyr, double gyro_range) noexcept nogil:
    """A gyro sample beyond the range on some axis by more than saturated's margin mirrored
    (2 %: a calibrated rail sample lands within it): no sensor of that range reads it, so it
    is not a measurement; the Kalman filters hold their propagation over it as over a dropped
    sample (docs/robustness.md, "Recovery"). gyro_range 0: range unknown, never."""
    cdef double r = 1.02 * gyro_range
    return gyro_range > 0.0 and (gyr[0] > r or gyr[0] < -r or gyr[1] > r or gyr[1] < -r
                                 or gyr[2] > r or gyr[2] < -r)


cdef inline void quat_measurement_update(double* q, double* b, double* P, const double* z,
                                         double r, const double* v, double rv, bint learn_bias=True) noexcept nogil:
    """Kalman update of the quaternion + gyro-bias state (q, b, P 7x7 row-major) with a
    quaternion measurement z (sign-aligned with q): H = [I4 0], noise Rm = r I4 + rv v vᵀ
    (v may be NULL). K = P Hᵀ S⁻¹, S⁻¹ = L⁻ᵀ L⁻¹ from the Cholesky factor L of S = Pqq + Rm;
    Joseph form (I - K H) P (I - K H)ᵀ + K Rm Kᵀ (right for any gain: learn_bias=False zeroes
    the bias rows of K, the bias is then not learned from z). cf-ekf and aekf
    (measurement="quest")."""
    cdef double S[16]     # Pqq + Rm
    cdef double L[16]     # Cholesky factor of S, lower
    cdef double Ld[4]     # 1 / diag(L)
    cdef double Li[16]    # L⁻¹, lower
    cdef double K[28]     # 7x4
    cdef double T[49]     # (I - K H) P
    cdef double y[4]
    cdef double Kv[7]
    cdef double d, s
    cdef int i, j, k
    for i in range(4):
        for j in range(4):
            S[i * 4 + j] = P[i * 7 + j]
        S[i * 5] += r
    if v != NULL:
        for i in range(4):
            for j in range(4):
                S[i * 4 + j] += rv * v[i] * v[j]
    for j in range(4):              # S = L Lᵀ
        d = S[j * 5]
        for k in range(j):
            d -= L[j * 4 + k] * L[j * 4 + k]
        d = 1.0 / sqrt(d)
        Ld[j] = d
        L[j * 5] = 1.0 / d
        for i in range(j + 1, 4):
            s = S[i * 4 + j]
            for k in range(j):
                s -= L[i * 4 + k] * L[j * 4 + k]
            L[i * 4 + j] = s * d
    for j in range(4):              # L⁻¹, lower
        Li[j * 5] = Ld[j]
        for i in range(j + 1, 4):
            s = 0.0
            for k in range(j, i):
                s -= L[i * 4 + k] * Li[k * 4 + j]
            Li[i * 4 + j] = s * Ld[i]
    for i in range(4):              # S⁻¹ = L⁻ᵀ L⁻¹
        for j in range(i, 4):
            s = 0.0
            for k in range(j, 4):
                s += Li[k * 4 + i] * Li[k * 4 + j]
            S[i * 4 + j] = s
            S[j * 4 + i] = s
    for i in range(7):              # K = P Hᵀ S⁻¹
        for j in range(4):
            K[i * 4 + j] = (P[i * 7] * S[j] + P[i * 7 + 1] * S[4 + j]
                            + P[i * 7 + 2] * S[8 + j] + P[i * 7 + 3] * S[12 + j])
    if not learn_bias:
        for i in range(16, 28):
            K[i] = 0.0
    for j in range(4):
        y[j] = z[j] - q[j]
    for i in range(4):
        q[i] += K[i * 4] * y[0] + K[i * 4 + 1] * y[1] + K[i * 4 + 2] * y[2] + K[i * 4 + 3] * y[3]
    for i in range(3):
        b[i] += (K[(4 + i) * 4] * y[0] + K[(4 + i) * 4 + 1] * y[1]
                 + K[(4 + i) * 4 + 2] * y[2] + K[(4 + i) * 4 + 3] * y[3])
    quat_normalise(q)
    # Joseph form: T = P - K P[:4, :]; P = T - T[:, :4] Kᵀ + r K Kᵀ + rv (K v)(K v)ᵀ
    for i in range(7):
        Kv[i] = 0.0
    if v != NULL:
        for i in range(7):
            Kv[i] = K[i * 4] * v[0] + K[i * 4 + 1] * v[1] + K[i * 4 + 2] * v[2] + K[i * 4 + 3] * v[3]
    for i in range(7):
        for j in range(7):
            T[i * 7 + j] = P[i * 7 + j] - (K[i * 4] * P[j] + K[i * 4 + 1] * P[7 + j]
                                           + K[i * 4 + 2] * P[14 + j] + K[i * 4 + 3] * P[21 + j])
    for i in range(7):
        for j in range(i, 7):
            s = T[i * 7 + j] - (T[i * 7] * K[j * 4] + T[i * 7 + 1] * K[j * 4 + 1]
                                + T[i * 7 + 2] * K[j * 4 + 2] + T[i * 7 + 3] * K[j * 4 + 3])
            s += r * (K[i * 4] * K[j * 4] + K[i * 4 + 1] * K[j * 4 + 1]
                      + K[i * 4 + 2] * K[j * 4 + 2] + K[i * 4 + 3] * K[j * 4 + 3])
            s += rv * Kv[i] * Kv[j]
            P[i * 7 + j] = s
            P[j * 7 + i] = s
