"""Plain-numpy references of docs/madgwick.md, docs/ukf.md and docs/cfekf.md.

Written from those specifications (no import of `fusion`, nothing taken from the Cython
kernels), in the style of tests/reference.py, whose sample handling, initialisation, frame
conversion and building blocks they reuse:

- madgwick: the gradient is J^T f with J from complex-step differentiation of the model
  functions themselves (R(q)^T d, d held fixed), not the hand-written Jacobians of the kernel;
- ukf: full numpy arrays of sigma points, np.linalg.cholesky, np.linalg.inv, literal weighted
  sums;
- cf-ekf: RefEKF's prediction, a RefMahony instance as the complementary filter, a literal 4-D
  Kalman update with H = [I4 0] and the Joseph form, and a sliding mean kept as a list of the
  last `window` valid samples (np.mean).

Public classes: RefMadgwick(beta, zeta), RefUKF(gyro_noise, bias_noise, acc_noise, mag_noise,
q_init_std, bias_init_std), RefCFEKF(gyro_noise, bias_noise, q_init_std, bias_init_std,
window, kp, ki, cf_noise); the keywords and methods of tests/reference.py.
"""
import math

import numpy as np

from reference import (BIAS_MAX, G, I3, I4, IDENTITY, MAGDIST_PARAMS, make_magdist, acc_lowpass_step, acc_lowpass_lost,
                       start_variance,
                       measured_gyr, RefEKF, RefEstimator, RefRest, RestAndMagCounts, RefMahony, complex_step_jacobian,
                       gyro_valid, unmeasured_variance, recovery_factor, is_saturated, lasted, left_matrix,
                       normalise, phi, qconj, qmul, rotmat, vector_valid)

UP = np.array([0.0, 0.0, 1.0])


# --- madgwick -----------------------------------------------------------------------------

def rotmat_unit_form(q):
    """R(q) as Madgwick writes it (diagonal 1 - 2(y² + z²), ...): equal to rotmat on unit q,
    different off the unit sphere, and therefore with a different gradient."""
    w, x, y, z = np.asarray(q).tolist()
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class RefMadgwick(RefEstimator):
    PARAMS = {"beta": 0.0075, "zeta": 5e-4, "gyro_range": None, "mag_update": "heading",
              "acc_lowpass": 2.0, "rest_time": 0.4, "rest_gyro_tol": math.radians(2.0), "rest_acc_tol": 0.5,
              "rest_gyro_drift_tol": math.radians(0.2),
              "rest_acc_drift_tol": 0.1,
              "rest_tau": 1.0, **MAGDIST_PARAMS}
    DEAD_ZONE = 1e-10

    def __init__(self, *args, written_form=False, **kwargs):
        """written_form=True: the gradient of Madgwick's written objective (rotmat_unit_form)
        instead of docs/madgwick.md's homogeneous one; not a kernel option, for the check
        against ahrs."""
        self.rot = rotmat_unit_form if written_form else rotmat
        super().__init__(*args, **kwargs)

    def _reset_state(self):
        self.bw = np.zeros(3)
        self.t_recover = 0.0
        self.rest = RefRest(self.rest_time, self.rest_gyro_tol, self.rest_acc_tol,
                            self.rest_gyro_drift_tol, self.rest_acc_drift_tol)
        self.magd = make_magdist(self)
        self.acc_lp, self.acc_qg = None, IDENTITY.copy()

    @property
    def bias(self):
        return self.bw.copy()

    @property
    def mag_rejected(self):
        return self.magd.n

    def _step(self, gyr, acc, mag, dt):
        sat = is_saturated(gyr, self.gyro_range)
        # the gyro did not measure the step (saturated, none, a gap > 2 periods): recover
        lost = sat or gyr is None or dt > 2.0 / self.fs
        boost, self.t_recover = recovery_factor(self.t_recover, lost, dt)
        q = self.q
        if mag is not None and not self.magd(q, mag, gyr, dt):         # disturbed
            mag = None
        acc_lowpass_lost(self, gyr, sat, dt)
        if self.rest(gyr, acc, dt):                     # at rest: the bias toward the rate
            z, T = self.rest.rate(gyr, dt)
            self.bw = self.bw + T / (self.rest_tau + T) * (z - self.bw)
        if acc is not None and self.acc_lowpass > 0:                     # acc_lowpass
            acc = acc_lowpass_step(self, gyr, self.bw, acc, dt)
        if gyr is not None:                                              # 1.
            q = phi(gyr - self.bw, dt) @ q
        grad = np.zeros(4)                                               # 2.
        if acc is not None:
            a = normalise(acc)
            f, J = complex_step_jacobian(lambda x: self.rot(x).T @ UP, q)
            grad += J.T @ (f - a)
        if mag is not None:                                              # 3.
            m = normalise(mag)
            h = rotmat(q) @ m
            b = np.array([0.0, math.hypot(h[0], h[1]), h[2]])           # held fixed in J
            f, J = complex_step_jacobian(lambda x: self.rot(x).T @ b, q)
            gm = J.T @ (f - m)
            if self.mag_update == "heading":     # onto a turn about the vertical, e_z ⊗ q
                u = qmul(np.array([0.0, 0.0, 0.0, 1.0]), q)
                gm = (u @ gm) / (u @ u) * u
            grad += gm
        n = math.sqrt(grad @ grad)                                       # 4.
        if n > self.DEAD_ZONE:
            g = grad / n
            if boost == 1.0:
                self.bw = np.clip(self.bw + self.zeta * dt * 2.0 * qmul(qconj(q), g)[1:], -BIAS_MAX, BIAS_MAX)
            # recovering: the ramp on at least the report's beta, 0.041 rad/s
            q = q - (self.beta if boost == 1.0 else boost * max(self.beta, 0.041)) * dt * g
        self.q = normalise(q)


# --- ukf ----------------------------------------------------------------------------------
# Sigma points are processed as arrays (one row per point) for speed; each line is the
# literal formula of docs/ukf.md applied row by row.

def qmul_left(p, q):
    """p ⊗ q_i for one quaternion p and the rows q_i of an (N, 4) array: rows of q L(p)^T."""
    return np.asarray(q, float) @ left_matrix(p).T


def rotmat_rows(q):
    """(N, 3, 3) R(q) of each row, homogeneous form."""
    w, x, y, z = np.asarray(q, float).T
    R = np.empty((len(w), 3, 3))
    R[:, 0, 0] = w * w + x * x - y * y - z * z
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = w * w - x * x + y * y - z * z
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = w * w - x * x - y * y + z * z
    return R


def phi_rows(w, dt):
    """(N, 4, 4) Φ(ω_i, dt) = cos(θ/2) I4 + sin(θ/2)/|ω| Ω(ω), θ = |ω| dt (I4 for ω = 0)."""
    w = np.asarray(w, float)
    n = np.sqrt(np.sum(w * w, axis=1))
    c = np.cos(0.5 * n * dt)
    s = np.where(n > 0, np.sin(0.5 * n * dt) / np.where(n > 0, n, 1.0), 0.5 * dt)
    wx, wy, wz = (s[:, None] * w).T
    F = np.empty((len(w), 4, 4))
    F[:, 0] = np.column_stack([c, -wx, -wy, -wz])
    F[:, 1] = np.column_stack([wx, c, wz, -wy])
    F[:, 2] = np.column_stack([wy, -wz, c, wx])
    F[:, 3] = np.column_stack([wz, wy, -wx, c])
    return F


def err_to_quat(p):
    """δq(p) = [16 - |p|², 8 p] / (16 + |p|²) per row, the inverse of p = 4 e_v / (1 + e_w)."""
    p = np.atleast_2d(p)
    s = np.sum(p * p, axis=1)
    e = np.empty((len(p), 4))
    e[:, 0] = 16.0 - s
    e[:, 1:] = 8.0 * p
    return e / (16.0 + s)[:, None]


def quat_to_err(e):
    """p = 4 e_v / (1 + e_w) per row, with the sign of e chosen so that e_w >= 0."""
    e = np.atleast_2d(e)
    e = np.where(e[:, :1] < 0, -e, e)
    return 4.0 * e[:, 1:] / (1.0 + e[:, :1])


def acc_model_rows(q):
    """R(q)^T [0, 0, 1] per row."""
    return rotmat_rows(q)[:, 2, :]


def mag_model_rows(q, z):
    """R(q)^T v(q), v = [0, sqrt(nx² + ny²), nz], n = R(q) z, per row."""
    R = rotmat_rows(q)
    n = R @ z
    v = np.zeros_like(n)
    v[:, 1] = np.hypot(n[:, 0], n[:, 1])
    v[:, 2] = n[:, 2]
    return np.einsum("kji,kj->ki", R, v)


class RefUKF(RestAndMagCounts, RefEstimator):
    PARAMS = dict({k: v for k, v in RefEKF.PARAMS.items() if k not in ("acc_update",)}, acc_noise=0.5, acc_lowpass=1.0,
                  gyro_noise=0.01)
    N_ERR = 6
    ALPHA, BETA, KAPPA = 1.0, 2.0, 0.0

    def __init__(self, *args, sigma_mean=False, **kwargs):
        """sigma_mean=True: the textbook UKF means (sigma-point means in the prediction and in
        the innovation) instead of docs/ukf.md's centre; not a kernel option, for comparison."""
        self.sigma_mean = sigma_mean
        n = self.N_ERR
        lam = self.ALPHA ** 2 * (n + self.KAPPA) - n
        self.gamma = math.sqrt(n + lam)
        self.Wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
        self.Wm[0] = lam / (n + lam)
        self.Wc = self.Wm.copy()
        self.Wc[0] += 1.0 - self.ALPHA ** 2 + self.BETA
        super().__init__(*args, **kwargs)

    def _reset_state(self):
        self.b = np.zeros(3)
        self.P = np.diag([(2 * self.q_init_std) ** 2] * 3 + [self.bias_init_std ** 2] * 3)
        self.t_run = 0.0
        self.rest = RefRest(self.rest_time, self.rest_gyro_tol, self.rest_acc_tol,
                            self.rest_gyro_drift_tol, self.rest_acc_drift_tol)
        self.magd = make_magdist(self)
        self.acc_lp, self.acc_qg = None, np.array([1.0, 0.0, 0.0, 0.0])

    def _start_ended(self, dt):
        """As RefEKF's: the low-pass's start ends, the tilt's variance grows by start_variance:
        P[:3, :3] += v (I - h hᵀ), h the body-frame vertical (the error is a body-frame angle)."""
        h = rotmat(self.q)[2]
        self.P[:3, :3] += start_variance(self.acc_noise, self.acc_lowpass, dt) * (I3 - np.outer(h, h))

    @property
    def bias(self):
        return self.b.copy()

    @property
    def covariance(self):
        return self.P.copy()         # body-frame error: the same in ENU and NED

    def _sigma(self):
        """(13, 6) error sigma points: 0, +γ L_j, -γ L_j (L the Cholesky factor of P)."""
        L = np.linalg.cholesky(self.P)
        return np.vstack([np.zeros(6), self.gamma * L.T, -self.gamma * L.T])

    def _predict(self, w, dt):
        X = self._sigma()
        qs = qmul_left(self.q, err_to_quat(X[:, :3]))              # sigma attitudes
        bs = self.b + X[:, 3:]                                      # sigma biases
        qp = np.einsum("kij,kj->ki", phi_rows(w - bs, dt), qs)      # propagated
        q0 = qp[0]
        Y = np.column_stack([quat_to_err(qmul_left(qconj(q0), qp)), bs - self.b])
        mean = self.Wm @ Y
        D = Y - mean
        Q = np.diag([self.gyro_noise ** 2 * dt] * 3 + [self.bias_noise ** 2 * dt] * 3)
        self.P = (D.T * self.Wc) @ D + Q
        if self.sigma_mean:      # the textbook variant: the mean of the sigma points
            self.q = normalise(qmul(q0, err_to_quat(mean[:3])[0]))
            self.b = self.b + mean[3:]
        else:                    # docs/ukf.md: the propagated centre, bias unchanged
            self.q = normalise(q0)

    def _correct(self, z, hfun, Rm, heading=False):
        """heading: the gain's attitude and bias rows projected onto the body-frame vertical
        (the magnetometer turns the heading only), P by the general form."""
        X = self._sigma()
        Z = hfun(qmul_left(self.q, err_to_quat(X[:, :3])))
        zhat = self.Wm @ Z
        DZ = Z - zhat
        Pzz = (DZ.T * self.Wc) @ DZ + Rm
        Pxz = (X.T * self.Wc) @ DZ
        K = Pxz @ np.linalg.inv(Pzz)
        if heading:
            w = rotmat(self.q).T @ np.array([0.0, 0.0, 1.0])
            Pw = np.outer(w, w)
            K[:3] = Pw @ K[:3]
            K[3:] = Pw @ K[3:]
        dx = K @ (z - (zhat if self.sigma_mean else Z[0]))
        self.q = normalise(qmul(self.q, err_to_quat(dx[:3])[0]))
        self.b = self.b + dx[3:]
        if heading:
            P = self.P - K @ Pxz.T - Pxz @ K.T + K @ Pzz @ K.T
        else:
            P = self.P - K @ Pzz @ K.T
        self.P = (P + P.T) / 2

    def _step(self, gyr, acc, mag, dt):
        # the ekf's recovery; the error p is the attitude angle (rad) to first order
        gyr = measured_gyr(gyr, self.gyro_range)
        self.t_run, v = unmeasured_variance(self.t_run, gyr, dt, self.fs,
                                            is_saturated(gyr, self.gyro_range), self.motion_rate)
        if gyr is not None:
            self._predict(gyr, dt)
        self.P[:3, :3] += v * I3
        # zero-rate update, linear, on the bias only
        if self.rest(gyr, acc, dt) and self.rest.gate_open(self.b, np.diag(self.P)[3:], self.rest_bias_gate,
                                                           self.rest_gate_time):
            H = np.zeros((3, 6))
            H[:, 3:] = I3
            z, T = self.rest.rate(gyr, dt)
            Rm = self.rest_noise ** 2 / T * I3
            K = np.zeros((6, 3))
            K[3:] = self.P[3:, 3:] @ np.linalg.inv(self.P[3:, 3:] + Rm)
            self.b = self.b + K[3:] @ (z - self.b)
            IKH = np.eye(6) - K @ H
            self.P = IKH @ self.P @ IKH.T + K @ Rm @ K.T
        acc_lowpass_lost(self, gyr, is_saturated(gyr, self.gyro_range), dt)
        if acc is not None and self.acc_lowpass > 0:
            acc = acc_lowpass_step(self, gyr, self.b, acc, dt, self._start_ended)
        if acc is not None:
            self._correct(normalise(acc), acc_model_rows, (self.acc_noise / G) ** 2 / dt * I3)
        if mag is not None and self.magd(self.q, mag, gyr, dt):
            z = normalise(mag)
            nx, ny, _ = (rotmat(self.q) @ z).tolist()
            if math.sqrt(nx * nx + ny * ny) >= 1e-9:
                self._correct(z, lambda q: mag_model_rows(q, z), self.mag_noise ** 2 / dt * I3,
                              self.mag_update == "heading")
        self.q = normalise(self.q)


# --- cf-ekf -------------------------------------------------------------------------------

class RefSlidingMean:
    """Mean of the last `window` samples given (of all samples so far until it is full)."""

    def __init__(self, window):
        self.window = int(window)
        self.buf = []

    def __call__(self, v):
        self.buf.append(np.array(v, float))
        if len(self.buf) > self.window:
            self.buf.pop(0)
        return np.mean(self.buf, axis=0)


class RefCFEKF(RefEKF):
    PARAMS = {"gyro_noise": 0.01, "bias_noise": 1e-4, "q_init_std": 0.05, "bias_init_std": 0.02,
              "window": 1, "kp": 1.0, "ki": None, "mag_weight": 0.3, "cf_noise": 0.005, "gyro_range": None,
              "motion_rate": 1.0, "bias_feedback": True, "mag_update": "heading", "acc_lowpass": 0.5,
              **{k: v for k, v in RefEKF.PARAMS.items() if k.startswith("rest_") or k.startswith("magdist_")},
              "rest_bias_gate": 0.0}
    LEARN_ACC_TOL, LEARN_ANGLE, LEARN_HOLD = 0.5, math.radians(2.0), 0.5     # bias_feedback

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        if params.get("ki") is None:            # no integral of its own with the bias fed back
            params["ki"] = 0.0 if params.get("bias_feedback", True) else 0.005
        super().__init__(fs, frame=frame, on_invalid=on_invalid, **params)

    def _reset_state(self):
        super()._reset_state()
        self.cf = RefMahony(self.fs, kp=self.kp, ki=self.ki, mag_weight=self.mag_weight, gyro_range=self.gyro_range,
                            mag_update=self.mag_update, acc_lowpass=self.acc_lowpass, rest_time=0.0,
                            **{k: getattr(self, k) for k in MAGDIST_PARAMS})
        self.cf_started = False
        self.pre = [RefSlidingMean(self.window) for _ in range(3)]
        self.sat_left = 0       # samples the window still holds a saturated raw gyro sample
        self.sat = False
        self.t_quiet = 0.0      # bias_feedback: time the filter has been quiet

    def update(self, gyr, acc, mag=None, dt=None):
        """Prefilter the valid raw vectors, then the usual sample handling on the means."""
        gyr = np.asarray(gyr, float)
        acc = np.asarray(acc, float)
        mag = None if mag is None else np.asarray(mag, float)
        if self.on_invalid == "raise":
            self._check(gyr, acc, mag)
        entered = gyro_valid(gyr)
        if entered:
            if is_saturated(gyr, self.gyro_range):      # the raw sample, not the mean
                self.sat_left = int(self.window)
            self.sat = self.sat_left > 0
            gyr = self.pre[0](gyr)
        if vector_valid(acc):
            acc = self.pre[1](acc)
        if mag is not None and vector_valid(mag):
            mag = self.pre[2](mag)
        mode, self.on_invalid = self.on_invalid, "skip"      # checked above, on the raw vectors
        try:
            return super().update(gyr, acc, mag, dt)
        finally:
            self.on_invalid = mode
            if entered:
                self.sat_left = max(0, self.sat_left - 1)

    def _step(self, gyr, acc, mag, dt):
        if not self.cf_started:                                          # 1.
            self.cf.q = self.q.copy()
            self.cf_started = True
        sat = gyr is not None and self.sat
        w = gyr
        if gyr is not None and self.bias_feedback:      # the EKF's bias before this sample
            w = gyr - self.b
        self.cf._step(w, acc, mag, dt, sat)                              # 2.
        self._propagate(gyr, dt, sat)                                    # 3.
        self._rest(gyr, acc, dt)                                         # 3a. rest
        if acc is not None or mag is not None:                           # 4.
            z = self.cf.q.copy()
            if z @ self.q < 0:
                z = -z
            H = np.zeros((4, 7))
            H[:, :4] = I4
            Rm = self.cf_noise ** 2 / dt * I4
            S = H @ self.P @ H.T + Rm
            K = self.P @ H.T @ np.linalg.inv(S)
            if self.bias_feedback:                  # learned only while the filter is quiet
                na = G if acc is None else np.linalg.norm(acc)
                angle = 2 * math.acos(min(1.0, abs(z @ self.q)))
                if abs(na - G) > self.LEARN_ACC_TOL or angle > self.LEARN_ANGLE:
                    self.t_quiet = 0.0
                    K[4:] = 0.0
                else:
                    self.t_quiet += dt
                    if not lasted(self.t_quiet, self.LEARN_HOLD):
                        K[4:] = 0.0
            x = np.concatenate([self.q, self.b]) + K @ (z - H @ np.concatenate([self.q, self.b]))
            self.q = normalise(x[:4])
            self.b = x[4:]
            IKH = np.eye(7) - K @ H
            self.P = IKH @ self.P @ IKH.T + K @ Rm @ K.T
        self.P = (self.P + self.P.T) / 2                                 # 5.
        self.q = normalise(self.q)


REFERENCES = {"madgwick": RefMadgwick, "ukf": RefUKF, "cf-ekf": RefCFEKF}


def make(name, fs, frame="ENU", on_invalid="raise", **params):
    return REFERENCES[name](fs, frame=frame, on_invalid=on_invalid, **params)
