"""Plain-numpy reference implementations of the estimators of docs/estimators.md.

Written from the specification only (no import of `fusion`, nothing taken from the Cython
kernels), so that the kernels can be checked against an independent implementation. The code
favours literal, full-matrix transcriptions of the specification over speed:

- the EKF builds F, Q, H, S, K as numpy arrays, inverts S with np.linalg.inv and applies the
  Joseph form literally;
- measurement Jacobians are obtained by complex-step differentiation of the measurement
  functions themselves (exact to machine precision), not from hand-derived formulas.

Public classes: RefGyro(), RefMahony(kp, ki), RefEKF(gyro_noise, bias_noise, acc_noise,
mag_noise, q_init_std, bias_init_std); all take fs, frame ("ENU"/"NED") and on_invalid
("raise"/"skip") keywords and offer update(), run(), reset(), quaternion, euler, bias,
covariance and skipped.

Where docs/estimators.md is silent, this reference reads it as follows (the kernels agree):
- every invalid vector is counted in `skipped`, also in the samples before initialisation
  (there the accelerometer is invalid by definition; an invalid gyro or magnetometer in the
  same sample is counted too);
- "m parallel to u" at initialisation means |m × u| <= 1e-9 |m|;
- before initialisation the output is the identity attitude of the kernels' ENU frame, so with
  frame="NED" it is c = [0, √½, √½, 0];
- with frame="NED" the whole covariance is T P Tᵀ, T = blockdiag(L(c), I3) (the quaternion-bias
  cross blocks are rotated as well);
- an EKF magnetometer update skipped because the field is vertical is not counted in `skipped`;
- `bias` is None for the gyro integrator, `covariance` None except for the EKF.
"""
import math
import sys

import numpy as np

BIAS_MAX = 100.0    # rad/s: the learned gyro bias is held within it (no gyro has a larger one)

G = 9.81
C_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
CS_STEP = 1e-30
PARALLEL_TOL = 1e-9
STEP_SUM_TOL = 1e-9     # a duration summed from sample steps: its rounding


def lasted(t, duration):
    """t (s summed from steps) has reached duration."""
    return t >= duration * (1.0 - STEP_SUM_TOL)


def outlasted(t, duration):
    """t (s summed from steps) has gone beyond duration."""
    return t > duration * (1.0 + STEP_SUM_TOL)


# --- quaternion algebra -----------------------------------------------------------------

def qmul(p, q):
    """Hamilton product p ⊗ q of two quaternions [w, x, y, z]."""
    w1, x1, y1, z1 = np.asarray(p).tolist()
    w2, x2, y2, z2 = np.asarray(q).tolist()
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def qconj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def left_matrix(p):
    """L(p) with p ⊗ q = L(p) q."""
    w, x, y, z = np.asarray(p).tolist()
    return np.array([[w, -x, -y, -z],
                     [x, w, -z, y],
                     [y, z, w, -x],
                     [z, -y, x, w]])


def rotmat(q):
    """R(q) in its homogeneous quadratic form (works for complex q: complex step)."""
    w, x, y, z = np.asarray(q).tolist()    # python scalars: fast arithmetic
    return np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])


def omega_matrix(w):
    """Ω(ω) with q ⊗ [0, ω] = Ω(ω) q."""
    wx, wy, wz = np.asarray(w).tolist()
    return np.array([[0.0, -wx, -wy, -wz],
                     [wx, 0.0, wz, -wy],
                     [wy, -wz, 0.0, wx],
                     [wz, wy, -wx, 0.0]])


def xi_matrix(q):
    """Ξ(q) with q ⊗ [0, ω] = Ξ(q) ω."""
    w, x, y, z = np.asarray(q).tolist()
    return np.array([[-x, -y, -z],
                     [w, -z, y],
                     [z, w, -x],
                     [-y, x, w]])


I3, I4, I7 = np.eye(3), np.eye(4), np.eye(7)


def phi(w, dt):
    """Φ(ω, dt) = cos(θ/2) I4 + sin(θ/2)/|ω| Ω(ω), θ = |ω| dt; I4 for ω = 0."""
    n = math.sqrt(sum(c * c for c in np.asarray(w, float).tolist()))
    if n == 0.0:
        return I4.copy()
    half = 0.5 * n * dt
    return math.cos(half) * I4 + (math.sin(half) / n) * omega_matrix(w)


def normalise(v):
    return v / math.sqrt(v @ v)


def cross(a, b):
    """a × b (np.cross is slow for single vectors)."""
    a1, a2, a3 = a.tolist()
    b1, b2, b3 = b.tolist()
    return np.array([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1])


def complex_step_jacobian(f, q, h=CS_STEP):
    """(f(q), d f(q) / d q) by complex-step differentiation.

    Column k of the (m x 4) Jacobian is Im f(q + i h e_k) / h; Re f(q + i h e_k) is f(q) up to
    O(h²) = 1e-60, so the value comes with it.
    """
    q = np.asarray(q, float)
    cols = []
    for k in range(4):
        qc = q.astype(complex)
        qc[k] += 1j * h
        fc = f(qc)
        cols.append(fc.imag / h)
    return fc.real, np.column_stack(cols)


def quat_from_matrix(R):
    """Unit quaternion of the rotation matrix R (Shepperd's method), sign chosen with w >= 0."""
    t = np.trace(R)
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    if q[0] < 0:
        q = -q
    return normalise(q)


def euler_zyx(q):
    """[yaw, pitch, roll] (ZYX) in radians."""
    w, x, y, z = q
    return np.array([np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
                     np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0)),
                     np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))])


# --- sample handling --------------------------------------------------------------------

def gyro_valid(g):
    """Finite components (a gyro at exactly zero rate is valid)."""
    return all(math.isfinite(c) for c in g.tolist())


def vector_valid(v):
    """Finite components with |v|^2 finite and a normal double (the kernels' vec3_valid)."""
    c = v.tolist()
    n2 = sum(x * x for x in c)
    return all(math.isfinite(x) for x in c) and math.isfinite(n2) and n2 >= sys.float_info.min


def initial_attitude(acc, mag=None):
    """Attitude from one accelerometer (and optionally magnetometer) sample, ENU."""
    u = normalise(np.asarray(acc, float))
    if mag is not None:
        mag = np.asarray(mag, float)
        e = cross(mag, u)
        ne = math.sqrt(e @ e)
        # m parallel to u: magnetometer ignored. "Parallel" is taken as |m × u| <= 1e-9 |m|
        # (the angle between m and ±u below 1e-9 rad); the spec gives no tolerance.
        if ne > PARALLEL_TOL * math.sqrt(mag @ mag):
            e = e / ne
            n = cross(u, e)
            R0 = np.array([e, n, u])        # rows: body-to-navigation
            return quat_from_matrix(R0)
    roll = np.arctan2(u[1], u[2])
    pitch = np.arctan2(-u[0], np.sqrt(u[1] ** 2 + u[2] ** 2))
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return np.array([cp * cr, cp * sr, sp * cr, -sp * sr])


class RefEstimator:
    """Common sample handling, initialisation and frame conversion."""
    PARAMS = {}

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        if frame not in ("ENU", "NED"):
            raise ValueError("frame")
        if on_invalid not in ("raise", "skip"):
            raise ValueError("on_invalid")
        unknown = set(params) - set(self.PARAMS)
        if unknown:
            raise ValueError(f"unknown parameters {unknown}")
        self.fs = float(fs)
        self.frame = frame
        self.on_invalid = on_invalid
        self.params = dict(self.PARAMS, **params)
        for k, v in self.params.items():
            setattr(self, k, v if v is None or isinstance(v, str) else float(v))
        self.reset()

    # state handling
    def reset(self, q0=None):
        self.q = IDENTITY.copy()
        self.initialised = False
        self.skipped = {"gyr": 0, "acc": 0, "mag": 0}
        self._reset_state()
        if q0 is not None:
            q0 = normalise(np.asarray(q0, float))
            if self.frame == "NED":
                q0 = qmul(qconj(C_NED), q0)
            self.q = q0
            self.initialised = True

    def _reset_state(self):
        pass

    def _out(self, q):
        return qmul(C_NED, q) if self.frame == "NED" else q.copy()

    @property
    def quaternion(self):
        return self._out(self.q)

    @property
    def euler(self):
        return euler_zyx(self.quaternion)

    bias = covariance = None        # a filter with either overrides it

    # processing
    def _check(self, gyr, acc, mag):
        if not gyro_valid(gyr):
            raise ValueError("gyr must be finite")
        if not vector_valid(acc):
            raise ValueError("acc must be finite and non-zero")
        if mag is not None and not vector_valid(mag):
            raise ValueError("mag must be finite and non-zero")

    def update(self, gyr, acc, mag=None, dt=None):
        gyr = np.asarray(gyr, float)
        acc = np.asarray(acc, float)
        mag = None if mag is None else np.asarray(mag, float)
        dt = 1.0 / self.fs if dt is None else float(dt)
        if self.on_invalid == "raise":
            self._check(gyr, acc, mag)
        gv = gyro_valid(gyr)
        av = vector_valid(acc)
        mv = mag is not None and vector_valid(mag)
        # every invalid vector is counted, also in the samples before initialisation (where
        # the accelerometer is the invalid one by definition)
        self.skipped["gyr"] += not gv
        self.skipped["acc"] += not av
        self.skipped["mag"] += mag is not None and not mv
        if not self.initialised:
            if not av:
                return self._out(IDENTITY)
            self.q = initial_attitude(acc, mag if mv else None)
            self.initialised = True
        self._step(gyr if gv else None, acc if av else None, mag if mv else None, dt)
        return self._out(self.q)

    def run(self, gyr, acc, mag=None, dt=None):
        gyr = np.asarray(gyr, float)
        acc = np.asarray(acc, float)
        mag = None if mag is None else np.asarray(mag, float)
        n = len(gyr)
        if dt is None:
            dt = np.full(n, 1.0 / self.fs)
        else:
            dt = np.broadcast_to(np.asarray(dt, float), (n,))
        if self.on_invalid == "raise":
            for i in range(n):
                self._check(gyr[i], acc[i], None if mag is None else mag[i])
        out = np.empty((n, 4))
        for i in range(n):
            out[i] = self.update(gyr[i], acc[i], None if mag is None else mag[i], dt[i])
        return out

    def _step(self, gyr, acc, mag, dt):
        """One sample; gyr/acc/mag are None when invalid (skipped) or absent."""
        raise NotImplementedError


# --- gyro -------------------------------------------------------------------------------

class RefGyro(RefEstimator):
    PARAMS = {}

    def _step(self, gyr, acc, mag, dt):
        if gyr is not None:
            self.q = normalise(phi(gyr, dt) @ self.q)


# --- mahony -----------------------------------------------------------------------------

def is_saturated(gyr, gyro_range):
    """docs/robustness.md, "Recovery": |w_i| >= 0.98 gyro_range on some axis."""
    return gyr is not None and gyro_range is not None and np.max(np.abs(gyr)) >= 0.98 * gyro_range


def measured_gyr(gyr, gyro_range):
    """docs/robustness.md, "Recovery": a sample with |w_i| > 1.02 gyro_range on some axis is
    not a measurement; the Kalman filters take it as dropped (None)."""
    out = gyr is not None and gyro_range is not None and np.max(np.abs(gyr)) > 1.02 * gyro_range
    return None if out else gyr


def recovery_factor(t_left, sat, dt):
    """docs/robustness.md, "Recovery" (complementary filters): (gain factor this step, new
    t_left). A saturated sample (sat) sets 3 s; the factor falls linearly from 20 to 1 over
    them."""
    if sat:
        t_left = 3.0
    if lasted(3.0 - t_left, 3.0):
        return 1.0, 0.0
    return 1.0 + 19.0 * t_left / 3.0, t_left - dt


MAGDIST_PARAMS = {"magdist_time": 60.0, "magdist_norm_tol": 0.1, "magdist_dip_tol": 5.0,
                  "magdist_new_time": 20.0}


class RefMagDist:
    """docs/estimators.md, "Magnetic disturbances": call with the attitude, the magnetometer
    and gyro samples; True when the sample may be used (rejections counted in n)."""
    CUR_TAU, REF_TAU, MIN_UNDIST, NEW_MIN_GYR, DECAY, FIRST_TIME = 0.05, 20.0, 0.5, math.radians(20.0), 2.0, 1.0
    DIR_TAU, DIR_TOL, FIXED_HOLD = 1.0, 0.1, 5.0

    def __init__(self, time, norm_tol, dip_tol_deg, new_time):
        self.time, self.norm_tol, self.dip_tol, self.new_time = time, norm_tol, math.radians(dip_tol_deg), new_time
        self.cur = self.ref = self.cand = None
        self.t_undist = self.t_cand = self.t_reject = 0.0
        self.t_settle = self.t_fixed = 0.0
        self.dir_cur = self.dir_slow = None
        self.disturbed = False
        self.n = 0

    def _close(self, a, r):
        return abs(a[0] - r[0]) < self.norm_tol * r[0] and abs(a[1] - r[1]) < self.dip_tol

    def _relearn(self, x):
        self.ref = x.copy()
        self.disturbed = False
        self.t_undist = self.MIN_UNDIST

    def __call__(self, q, mag, gyr, dt):
        if self.time <= 0:
            return True
        nrm = np.linalg.norm(mag)
        u = rotmat(q) @ mag / nrm        # the field's direction in the navigation frame
        x = np.array([nrm, -math.asin(np.clip(u[2], -1.0, 1.0))])
        if self.cur is None:
            self.cur, self.ref, self.cand = x.copy(), x.copy(), x.copy()
            self.t_undist, self.t_settle = self.MIN_UNDIST, dt
            self.dir_cur = self.dir_slow = u
            return True
        # the field turns with the sensor (a magnet fixed to it): no re-learning until it has
        # held its direction FIXED_HOLD s
        self.dir_cur = self.dir_cur + dt / (self.CUR_TAU + dt) * (u - self.dir_cur)
        self.dir_slow = self.dir_slow + dt / (self.DIR_TAU + dt) * (self.dir_cur - self.dir_slow)
        turned = lasted(self.t_settle, self.FIRST_TIME) and np.linalg.norm(self.dir_cur - self.dir_slow) > self.DIR_TOL
        self.t_fixed = 0.0 if turned else self.t_fixed + dt
        may_relearn = lasted(self.t_fixed, self.FIXED_HOLD)
        self.cur = self.cur + dt / (self.CUR_TAU + dt) * (x - self.cur)
        if not lasted(self.t_settle, self.FIRST_TIME):     # settling: the reference's dip is the current one
            self.ref[1] = self.cand[1] = self.cur[1]
            self.t_settle += dt
        k = dt / (self.REF_TAU + dt)
        if self._close(self.cur, self.ref):
            self.t_undist += dt
            if lasted(self.t_undist, self.MIN_UNDIST):
                self.disturbed = False
                self.ref = self.ref + k * (self.cur - self.ref)
        else:
            self.t_undist = 0.0
            self.disturbed = True
        if self._close(self.cur, self.cand) and not turned:
            if gyr is not None and np.linalg.norm(gyr) >= self.NEW_MIN_GYR:
                self.t_cand += dt
            self.cand = self.cand + k * (self.cur - self.cand)
            if self.disturbed and lasted(self.t_cand, self.new_time) and may_relearn:
                self._relearn(self.cand)
        else:
            self.t_cand = 0.0
            self.cand = self.cur.copy()
        if not self.disturbed:
            self.t_reject = max(self.t_reject - self.DECAY * dt, 0.0)
            return True
        self.t_reject += dt
        if outlasted(self.t_reject, self.time) and may_relearn:
            self._relearn(self.cur)
            self.t_reject = 0.0
            return True
        self.n += 1
        return False


def acc_lowpass_lost(est, gyr, sat, dt):
    """The gyro did not measure the step (none, saturated, a gap > 2 periods): restart."""
    if est.acc_lowpass > 0 and (gyr is None or sat or dt > 2.0 / est.fs):
        est.acc_lp, est.acc_qg, est.acc_lp_time = None, IDENTITY.copy(), 0.0


def acc_lowpass_step(est, gyr, b, acc, dt, start_ended=None):
    """acc_lowpass: acc low-passed in the frame est.acc_qg that turns with gyr - b alone
    (never corrected), turned back into the body frame; est.acc_lp None before the first.
    For its first acc_lowpass seconds (est.acc_lp_time) the running mean of the samples;
    start_ended(dt) is called on the sample that ends them (the Kalman filters' tilt variance).
    The definition, VQF's frame form: the kernel (fusion/_acclp.pxd) holds the same filter in
    the body frame, and the kernel = reference tests check the two agree."""
    if gyr is not None and est.acc_lp is not None:
        est.acc_qg = normalise(phi(gyr - b, dt) @ est.acc_qg)
    an = rotmat(est.acc_qg) @ acc
    if est.acc_lp is None:
        est.acc_lp, est.acc_lp_time = an, 0.0
    else:
        settling = est.acc_lp_time < est.acc_lowpass
        est.acc_lp_time += dt
        if lasted(est.acc_lp_time, est.acc_lowpass):
            est.acc_lp_time = est.acc_lowpass
        est.acc_lp = est.acc_lp + dt / (est.acc_lp_time + dt) * (an - est.acc_lp)
        if settling and est.acc_lp_time >= est.acc_lowpass and start_ended is not None:
            start_ended(dt)
    return rotmat(est.acc_qg).T @ est.acc_lp


def start_variance(acc_noise, acc_lowpass, dt):
    """The variance of the running mean the start ended with: its n samples at the noise
    density acc_noise / g span acc_lowpass + dt; at most pi² (an angle's)."""
    return min((acc_noise / G) ** 2 / (acc_lowpass + dt), math.pi ** 2)


def make_magdist(est):
    return RefMagDist(est.magdist_time, est.magdist_norm_tol, est.magdist_dip_tol, est.magdist_new_time)


class RestAndMagCounts:
    """The counts of a filter that holds a rest detector (``rest``) and a magnetic disturbance
    detector (``magd``)."""

    @property
    def rest_samples(self):
        return self.rest.n

    @property
    def mag_rejected(self):
        return self.magd.n


class RefMahony(RestAndMagCounts, RefEstimator):
    PARAMS = {"kp": 1.0, "ki": 0.01, "mag_weight": 1.0, "gyro_range": None, "mag_update": "heading", "acc_lowpass": 1.5,
              "rest_time": 0.4, "rest_gyro_tol": math.radians(2.0), "rest_acc_tol": 0.5,
              "rest_gyro_drift_tol": math.radians(0.2),
              "rest_acc_drift_tol": 0.1, "rest_tau": 1.0,
              **MAGDIST_PARAMS}

    def _reset_state(self):
        self.eps = np.zeros(3)
        self.rest = RefRest(self.rest_time, self.rest_gyro_tol, self.rest_acc_tol,
                            self.rest_gyro_drift_tol, self.rest_acc_drift_tol)
        self.t_recover = 0.0
        self.magd = make_magdist(self)
        self.acc_lp, self.acc_qg = None, IDENTITY.copy()

    @property
    def bias(self):
        return -self.ki * self.eps

    def _step(self, gyr, acc, mag, dt, sat=None):
        """sat: the sample is saturated (None: test gyr against gyro_range)."""
        if sat is None:
            sat = is_saturated(gyr, self.gyro_range)
        f, self.t_recover = recovery_factor(self.t_recover, sat, dt)
        recovering = f != 1.0
        if recovering and f * self.kp * dt > 0.5:      # at most half the error per step
            f = max(1.0, 0.5 / (self.kp * dt))
        q = self.q
        if mag is not None and not self.magd(q, mag, gyr, dt):         # disturbed
            mag = None
        acc_lowpass_lost(self, gyr, sat, dt)
        if self.rest(gyr, acc, dt) and self.ki > 0:     # at rest: -ki eps toward the rate
            z, T = self.rest.rate(gyr, dt)
            self.eps = self.eps + T / (self.rest_tau + T) * (-z / self.ki - self.eps)
        if acc is not None and self.acc_lowpass > 0:                     # acc_lowpass
            acc = acc_lowpass_step(self, gyr, -self.ki * self.eps, acc, dt)
        if gyr is not None:                                              # 1.
            q = normalise(phi(gyr + self.ki * self.eps, dt) @ q)
        e = np.zeros(3)
        if acc is not None:                                              # 2.
            a = normalise(acc)
            v = rotmat(q).T @ np.array([0.0, 0.0, 1.0])
            e += cross(a, v)
        if mag is not None:                                              # 3.
            m = normalise(mag)
            h = rotmat(q) @ m
            b = np.array([0.0, np.sqrt(h[0] ** 2 + h[1] ** 2), h[2]])
            w = rotmat(q).T @ b
            c = cross(m, w)
            if self.mag_update == "heading":     # only the turn about the vertical
                up = rotmat(q).T @ np.array([0.0, 0.0, 1.0])
                c = (c @ up) * up
            e += self.mag_weight * c
        if self.ki > 0 and not recovering:                               # 4.
            # held where the bias, -ki eps, is BIAS_MAX (a loop its gains made unstable)
            self.eps = np.clip(self.eps + e * dt, -BIAS_MAX / self.ki, BIAS_MAX / self.ki)
        if self.kp > 0:
            q = phi(f * self.kp * e, dt) @ q
        self.q = normalise(q)


# --- ekf --------------------------------------------------------------------------------

def acc_model(q):
    """h(q) = R(q)^T [0, 0, 1], the third row of R(q)."""
    return rotmat(q)[2]


def mag_model(q, z):
    """h(q) = R(q)^T v(q), v(q) = [0, sqrt(nx² + ny²), nz], n = R(q) z."""
    R = rotmat(q)
    nx, ny, nz = (R @ z).tolist()
    v = np.array([0.0, (nx * nx + ny * ny) ** 0.5, nz])    # complex for a complex q
    return R.T @ v


def unmeasured_variance(t_run, gyr, dt, fs, sat, motion_rate):
    """docs/robustness.md, "Recovery": (new t_run, attitude variance in rad² to add) for a step
    whose gyro sample is gyr (None: dropped). Unmeasured time: the whole step without a
    trustworthy rate (dropped, or saturated: sat), else the part beyond 1 / fs of a step longer
    than 1.5 / fs; over a run of
    it the rate is an unknown constant of std motion_rate: total (motion_rate t_run)², capped
    at pi²."""
    measured = gyr is not None and not sat
    # a measured step is a gap only beyond 1.5 nominal periods (shorter: stamp jitter)
    t = (dt - 1.0 / fs if dt > 1.5 / fs else 0.0) if measured else dt
    if t <= 0:
        return 0.0, 0.0
    def total(tr):
        return min((motion_rate * tr) ** 2, math.pi ** 2)
    return t_run + t, total(t_run + t) - total(t_run)


class RefRest:
    """docs/estimators.md, "Rest": call with each sample; True at rest (counted in n)."""
    TAU = 0.5       # s, the low-passes
    STILL_TAU = 0.01    # s, the still tests' low-pass

    def __init__(self, time, gyro_tol, acc_tol, gyro_drift_tol, acc_drift_tol):
        self.time, self.gyro_tol, self.acc_tol = time, gyro_tol, acc_tol
        self.drift_tol = (gyro_drift_tol, acc_drift_tol)
        self.lp = None          # the low-passed (gyr, acc)
        self.lp0 = None         # the low-passes where the still run began
        self.t = 0.0
        self.n = 0
        self.taken = False

    def __call__(self, gyr, acc, dt):
        if self.time <= 0:
            return False
        if gyr is None or acc is None:
            self.t = 0.0
            return False
        if self.lp is None:
            self.lp = (gyr.copy(), acc.copy())
            self.fast = (gyr.copy(), acc.copy())
            self.lp_time = 0.0
            return False
        self.lp_time = min(self.lp_time + dt, self.TAU)     # a running mean for its first TAU s
        k = dt / (self.lp_time + dt)
        lg, la = (lp + k * (x - lp) for lp, x in zip(self.lp, (gyr, acc)))
        self.lp = (lg, la)
        # the still tests' samples: a STILL_TAU low-pass, the samples themselves at dt >= STILL_TAU
        kf = dt / self.STILL_TAU
        self.fast = tuple(x.copy() if kf >= 1 else f + kf * (x - f) for f, x in zip(self.fast, (gyr, acc)))
        fg, fa = self.fast
        still = (np.linalg.norm(fg - lg) < self.gyro_tol and np.linalg.norm(fa - la) < self.acc_tol
                 and np.max(np.abs(lg)) < self.gyro_tol)
        # a still run ends when a low-pass drifts from where it began (a turning point)
        if still and self.t == 0.0:
            self.lp0 = (lg.copy(), la.copy())
            self.run = []               # the run's (gyr, dt) until an update takes them
            self.taken = False
        elif still:
            still = all(tol <= 0 or np.linalg.norm(lp - lp0) <= tol
                        for lp, lp0, tol in zip(self.lp, self.lp0, self.drift_tol))
        if still and not self.taken:
            self.run.append((gyr, dt))
        self.t = self.t + dt if still else 0.0
        if lasted(self.t, self.time):
            self.n += 1
            return True
        return False

    def rate(self, gyr, dt):
        """At rest, for the update made (after a gate's yes): (the rate it takes, the time it
        averages): the run's first update takes the mean of its samples so far (dt-weighted),
        a later one the sample."""
        if not self.taken:
            self.taken = True
            g = np.array([x for x, _ in self.run])
            w = np.array([d for _, d in self.run])
            return (w[:, None] * g).sum(axis=0) / w.sum(), float(w.sum())
        return gyr, dt

    def gate_open(self, b, var, gate, gate_time):
        """A Kalman filter's zero-rate update at rest goes ahead unless the still run is shorter
        than gate_time and the gyro's low-pass is more than gate standard deviations (var: the
        bias estimate b's variances) plus the gyro drift tolerance from b on some axis."""
        if gate <= 0 or lasted(self.t, gate_time):
            return True
        return bool(np.all(np.abs(self.lp[0] - b) <= gate * np.sqrt(var) + self.drift_tol[0]))


class RefEKF(RestAndMagCounts, RefEstimator):
    PARAMS = {"gyro_noise": 0.015, "bias_noise": 1e-4, "acc_noise": 0.5, "mag_noise": 0.2,
              "q_init_std": 0.05, "bias_init_std": 0.0087, "gyro_range": None, "motion_rate": 1.0,
              "mag_update": "heading", "acc_lowpass": 1.0, "rest_time": 0.4,
              "rest_gyro_tol": math.radians(2.0), "rest_acc_tol": 0.5,
              "rest_gyro_drift_tol": math.radians(0.2),
              "rest_acc_drift_tol": 0.1, "rest_noise": 1e-3, "rest_bias_gate": 2.0, "rest_gate_time": 2.0,
              "acc_update": "vector", **MAGDIST_PARAMS}

    def _reset_state(self):
        self.acc_lp = None          # acc_lowpass: the low-passed accelerometer, in the frame acc_qg
        self.acc_qg = IDENTITY.copy()   # the bias-corrected gyro integrated (never corrected)
        self.rest = RefRest(self.rest_time, self.rest_gyro_tol, self.rest_acc_tol,
                            self.rest_gyro_drift_tol, self.rest_acc_drift_tol)
        self.magd = make_magdist(self)
        self.b = np.zeros(3)
        self.P = np.diag([self.q_init_std ** 2] * 4 + [self.bias_init_std ** 2] * 3)
        self.t_run = 0.0

    def _propagate(self, gyr, dt, sat=None):
        """Predict, then the attitude angle variance grows by v about every body axis for the
        motion the gyro did not measure: Pqq += (v / 4) Xi Xiᵀ. sat: as RefMahony._step."""
        if sat is None:
            sat = is_saturated(gyr, self.gyro_range)
        self.t_run, v = unmeasured_variance(self.t_run, gyr, dt, self.fs, sat, self.motion_rate)
        if gyr is not None:
            self._predict(gyr, dt)
        if v > 0:
            Xi = xi_matrix(self.q)
            self.P[:4, :4] += (v / 4) * (Xi @ Xi.T)

    def _start_ended(self, dt):
        """The low-pass's running-mean start ends: the tilt's variance grows by start_variance
        about the two horizontal axes: Pqq += (v / 4) Xi (I - h hᵀ) Xiᵀ, h the body-frame
        vertical."""
        Xi, h = xi_matrix(self.q), acc_model(self.q)
        v = start_variance(self.acc_noise, self.acc_lowpass, dt)
        self.P[:4, :4] += v / 4 * (Xi @ (I3 - np.outer(h, h)) @ Xi.T)

    @property
    def bias(self):
        return self.b.copy()

    @property
    def covariance(self):
        if self.frame == "NED":
            T = np.eye(7)
            T[:4, :4] = left_matrix(C_NED)
            return T @ self.P @ T.T
        return self.P.copy()

    def _predict(self, w, dt):
        q_old = self.q
        wc = w - self.b
        A1 = phi(wc, dt)
        L = -(dt / 2) * xi_matrix(q_old)
        F = np.zeros((7, 7))
        F[:4, :4] = A1
        F[:4, 4:] = L
        F[4:, 4:] = I3
        Xi = xi_matrix(q_old)
        Q = np.zeros((7, 7))
        Q[:4, :4] = (dt / 4) * self.gyro_noise ** 2 * (Xi @ Xi.T)
        Q[4:, 4:] = self.bias_noise ** 2 * dt * I3
        self.q = normalise(A1 @ q_old)
        self.P = F @ self.P @ F.T + Q

    def _rest(self, gyr, acc, dt):
        """Rest detection; at rest the zero-rate update z = gyr, h = b, H = [0 I3] (bias only)."""
        if self.rest(gyr, acc, dt) and self.rest.gate_open(self.b, np.diag(self.P)[4:],
                                                           self.rest_bias_gate, self.rest_gate_time):
            H = np.zeros((3, 7))
            H[:, 4:] = I3
            z, T = self.rest.rate(gyr, dt)
            self._update(z - self.b, H, self.rest_noise ** 2 / T * I3, "bias")

    def _correct(self, z, hfun, Rm, gain="full"):
        h, J = complex_step_jacobian(hfun, self.q)
        H = np.zeros((3, 7))
        H[:, :4] = J
        self._update(z - h, H, Rm, gain)

    def _update(self, y, H, Rm, gain="full"):
        """gain "heading": projected so that the update turns the attitude about the vertical
        only (quaternion part onto the direction u = e_z (x) q of such a turn) and moves the
        bias along the body-frame vertical w only; "tilt": the complement (off u and off w);
        "bias": the bias alone (quaternion rows zero). The Joseph form holds for any gain."""
        S = H @ self.P @ H.T + Rm
        K = self.P @ H.T @ np.linalg.inv(S)
        if gain == "bias":
            K[:4] = 0.0
        elif gain != "full":
            u = qmul(np.array([0.0, 0.0, 0.0, 1.0]), self.q)
            w = acc_model(self.q)
            Pu = np.outer(u, u) / (u @ u)
            Pw = np.outer(w, w)
            if gain == "tilt":
                Pu, Pw = np.eye(4) - Pu, I3 - Pw
            K[:4] = Pu @ K[:4]
            K[4:] = Pw @ K[4:]
        x = np.concatenate([self.q, self.b]) + K @ y
        self.q = normalise(x[:4])
        self.b = x[4:]
        IKH = I7 - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ Rm @ K.T

    def _step(self, gyr, acc, mag, dt):
        gyr = measured_gyr(gyr, self.gyro_range)                         # out of range: dropped
        self._propagate(gyr, dt)                                         # 1.
        acc_lowpass_lost(self, gyr, is_saturated(gyr, self.gyro_range), dt)
        self._rest(gyr, acc, dt)                                         # rest
        if acc is not None and self.acc_lowpass > 0:                     # 2. (acc_lowpass)
            acc = acc_lowpass_step(self, gyr, self.b, acc, dt, self._start_ended)
        if acc is not None:                                              # 2.
            Rm = (self.acc_noise / G) ** 2 / dt * I3
            self._correct(normalise(acc), acc_model, Rm, "tilt" if self.acc_update == "tilt" else "full")
        if mag is not None and self.magd(self.q, mag, gyr, dt):          # 3.
            z = normalise(mag)
            nx, ny, _ = (rotmat(self.q) @ z).tolist()
            if math.sqrt(nx * nx + ny * ny) >= 1e-9:
                Rm = self.mag_noise ** 2 / dt * I3
                self._correct(z, lambda q: mag_model(q, z), Rm,
                              "heading" if self.mag_update == "heading" else "full")
        self.P = (self.P + self.P.T) / 2                                 # 5.


def butterworth2(tau, fs):
    """Second-order Butterworth low-pass, cutoff sqrt(2) / (2 pi tau) Hz, by the bilinear
    transform with the cutoff prewarped: (b, a) of H(z), a[0] = 1, from the analog
    prototype w² / (s² + sqrt(2) w s + w²) with s = k (1 - 1/z) / (1 + 1/z)."""
    w = math.sqrt(2.0) / tau                    # rad/s
    k = w / math.tan(w / (2.0 * fs))            # prewarped: the cutoff maps onto itself
    one_minus, one_plus = np.array([1.0, -1.0]), np.array([1.0, 1.0])
    num = w * w * np.polymul(one_plus, one_plus)
    den = (k * k * np.polymul(one_minus, one_minus) + math.sqrt(2.0) * w * k * np.polymul(one_minus, one_plus)
           + w * w * np.polymul(one_plus, one_plus))
    return num / den[0], den / den[0]


def incl_corrected(q, y, frac=1.0):
    """q turned about a horizontal axis (on the left) so that its body-frame vertical points
    along y: the shortest rotation of u = R(q) y / |y| onto e_z, the fraction frac of its
    angle; q where u points down."""
    if np.linalg.norm(y) == 0.0:
        return q.copy()
    u = rotmat(q) @ (y / np.linalg.norm(y))
    axis = np.cross(u, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(axis), u[2]
    if c <= -1.0 + 2e-12 or s == 0.0:
        return q.copy()
    ang = frac * math.atan2(s, c)
    turn = np.concatenate([[math.cos(ang / 2)], math.sin(ang / 2) * axis / s])
    return normalise(qmul(turn, q))


class RefEKFLP(RefEKF):
    """ekf-lp: RefEKF, reporting the inclination of the accelerometer low-passed in the frame
    il_qg (the gyro minus the filter's bias, integrated from the low-pass's first sample):
    the running mean of the samples (the first weighing 1 / fs, the others their dt) until
    their weights sum to incl_lowpass, then a second-order Butterworth (butterworth2, designed
    for each sample's step) started at rest on that mean. During the running mean the
    reported inclination turns the fraction (weights' sum) / incl_lowpass of the way from the
    filter's to the mean's."""
    PARAMS = dict(RefEKF.PARAMS, incl_lowpass=3.0)

    def _reset_state(self):
        super()._reset_state()
        self.il_started = False
        self.il_qg = IDENTITY.copy()
        self.il_y = None        # the low-passed accelerometer, in the frame il_qg
        self.il_t = 0.0
        self.il_z = None        # the Butterworth's states (transposed direct form II); None: the start

    def _step(self, gyr, acc, mag, dt):
        super()._step(gyr, acc, mag, dt)
        g = measured_gyr(gyr, self.gyro_range)
        if g is None or is_saturated(g, self.gyro_range) or dt > 2.0 / self.fs:
            self.il_started = False
        elif self.il_started:
            self.il_qg = normalise(phi(g - self.b, dt) @ self.il_qg)
        if acc is None:
            return
        if not self.il_started:
            self.il_started, self.il_qg, self.il_z = True, IDENTITY.copy(), None
            self.il_y, self.il_t = acc.astype(float), 1.0 / self.fs     # one sample's weight
        else:
            x = rotmat(self.il_qg) @ acc
            if self.il_z is None:
                self.il_t += dt
                self.il_y = self.il_y + dt / self.il_t * (x - self.il_y)
            else:
                b, a = butterworth2(self.incl_lowpass, 1.0 / dt)
                z0, z1 = self.il_z
                y = b[0] * x + z0
                self.il_z = (b[1] * x - a[1] * y + z1, b[2] * x - a[2] * y)
                self.il_y = y
                return
        if lasted(self.il_t, self.incl_lowpass):     # the start ends: steady state on the mean
            b, a = butterworth2(self.incl_lowpass, 1.0 / dt)
            self.il_t = self.incl_lowpass
            self.il_z = (self.il_y * (1 - b[0]), self.il_y * (b[2] - a[2]))

    @property
    def quaternion(self):
        q = self.q
        if self.il_started:
            q = incl_corrected(q, rotmat(self.il_qg).T @ self.il_y, min(self.il_t / self.incl_lowpass, 1.0))
        return self._out(q)

    def update(self, gyr, acc, mag=None, dt=None):
        super().update(gyr, acc, mag, dt)
        return self.quaternion


REFERENCES = {"gyro": RefGyro, "mahony": RefMahony, "ekf": RefEKF, "ekf-lp": RefEKFLP}


def make(name, fs, frame="ENU", on_invalid="raise", **params):
    return REFERENCES[name](fs, frame=frame, on_invalid=on_invalid, **params)
