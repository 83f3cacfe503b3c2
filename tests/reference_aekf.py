"""Plain-numpy reference of the `aekf` of docs/aekf.md (seed 001's adaptive EKF).

Written from docs/aekf.md and docs/estimators.md only (no import of `fusion`): the 7-state EKF
pieces come from tests/reference.py (RefEKF: full matrices, complex-step Jacobians, np.linalg.inv,
literal Joseph form); the adaptive tests, the magnetic reference learning, the 4-D quaternion
measurement and Wahba's problem are transcribed here. Wahba's problem is solved by Davenport's
q-method with np.linalg.eigh (the kernel uses QUEST's closed-form eigenvalue and an adjugate
column: a different route to the same quaternion).

Public: RefAEKF(fs, frame, on_invalid, **params) with the RefEKF interface plus `rejected`,
`tested`, `quest_updates`, `decisions` (every sample's code, as the kernel records them when
asked), `mag_reference`; wahba_davenport(b, r, w) and wahba_svd(b, r, w).
"""
import math

import numpy as np

import reference as ref
from reference import G, I3, I7, normalise, rotmat

DEG = math.pi / 180.0
UP = np.array([0.0, 0.0, 1.0])


# --- Wahba's problem, two independent numpy solutions -------------------------------------

def wahba_davenport(b, r, w):
    """Unit quaternion [w, x, y, z] (w >= 0) maximising Σ w_i r_iᵀ R(q) b_i: the eigenvector of
    the largest eigenvalue of Davenport's K (np.linalg.eigh). b, r: (n, 3) unit vectors."""
    B = sum(wi * np.outer(ri, bi) for wi, ri, bi in zip(w, r, b))
    sigma = np.trace(B)
    z = np.array([B[2, 1] - B[1, 2], B[0, 2] - B[2, 0], B[1, 0] - B[0, 1]])
    K = np.zeros((4, 4))
    K[0, 0] = sigma
    K[0, 1:] = z
    K[1:, 0] = z
    K[1:, 1:] = B + B.T - sigma * I3
    vals, vecs = np.linalg.eigh(K)
    q = vecs[:, np.argmax(vals)]
    return -q if q[0] < 0 else q


def wahba_svd(b, r, w):
    """The same problem by the SVD of B = Σ w_i r_i b_iᵀ (Markley 1988): R = U diag(1, 1, d) Vᵀ."""
    B = sum(wi * np.outer(ri, bi) for wi, ri, bi in zip(w, r, b))
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    R = U @ np.diag([1.0, 1.0, d]) @ Vt
    return ref.quat_from_matrix(R)


# --- the filter ---------------------------------------------------------------------------

class RefAEKF(ref.RefEKF):
    PARAMS = dict(ref.RefEKF.PARAMS, bias_init_std=0.02, acc_update="tilt", acc_norm_tol=2.0, acc_pred_tol=2.0,
                  acc_pred_timeout=2.0, mag_norm_tol=0.1, mag_dip_tol=5.0, reject_factor=1e4, mag_norm=None,
                  mag_dip=None, learn_time=1.0, measurement="vectors", quest_mag_weight=0.01)

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        unknown = set(params) - set(self.PARAMS)
        if unknown:
            raise ValueError(f"unknown parameters {unknown}")
        p = dict(self.PARAMS, **params)
        if p["measurement"] not in ("vectors", "quest"):
            raise ValueError("measurement")
        self.measurement = p["measurement"]
        self.mag_norm = None if p["mag_norm"] is None else float(p["mag_norm"])
        self.mag_dip = None if p["mag_dip"] is None else float(p["mag_dip"])
        self.gyro_range = None if p["gyro_range"] is None else float(p["gyro_range"])
        self.mag_update = p["mag_update"]
        self.acc_update = p["acc_update"]
        self.fs = float(fs)
        self.frame = frame
        self.on_invalid = on_invalid
        self.params = p
        for k, v in p.items():
            if k not in ("measurement", "mag_norm", "mag_dip", "gyro_range", "mag_update", "acc_update"):
                setattr(self, k, float(v))
        learn = self.mag_norm is None or self.mag_dip is None
        self.n_learn = max(1, round(self.learn_time * self.fs)) if learn else 0
        self.reset()

    def _reset_state(self):
        super()._reset_state()
        self.t_dir = 0.0
        self.g_ref = G          # the tests' g: 9.81 until the first rest
        self.norms, self.dips = [], []
        self.norm_ref = self.mag_norm
        self.dip_ref = None if self.mag_dip is None else self.mag_dip * DEG
        self.rejected = {"acc": 0, "mag": 0}
        self.tested = {"acc": 0, "mag": 0}
        self.quest_updates = 0
        self.decisions = []
        self.code = 0

    @property
    def mag_reference(self):
        if self.norm_ref is None or self.dip_ref is None:
            return None
        return (self.norm_ref, self.dip_ref / DEG)

    def update(self, gyr, acc, mag=None, dt=None):
        self.code = 0
        out = super().update(gyr, acc, mag, dt)
        self.decisions.append(self.code)
        return out

    def _quat_correct(self, z, Rm):
        """Kalman update with the quaternion as the measurement: H = [I4 0], noise Rm (4x4)."""
        H = np.zeros((4, 7))
        H[:, :4] = np.eye(4)
        S = H @ self.P @ H.T + Rm
        K = self.P @ H.T @ np.linalg.inv(S)
        x = np.concatenate([self.q, self.b]) + K @ (z - self.q)
        self.q = normalise(x[:4])
        self.b = x[4:]
        IKH = I7 - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ Rm @ K.T

    def _step(self, gyr, acc, mag, dt):
        # 1. predict (the ekf's, with its recovery; out of range: dropped)
        gyr = ref.measured_gyr(gyr, self.gyro_range)
        self._propagate(gyr, dt)
        n_rest = self.rest.n
        self._rest(gyr, acc, dt)
        if self.rest.n > n_rest:        # at rest: this sensor's g, the low-passed norm
            self.g_ref = float(np.linalg.norm(self.rest.lp[1]))
        # the sample tested and taken: low-passed in the gyro's frame (the ekf's acc_lowpass);
        # the magnetic reference's dip is learned from the raw one
        raw = acc
        ref.acc_lowpass_lost(self, gyr, ref.is_saturated(gyr, self.gyro_range), dt)
        if acc is not None and self.acc_lowpass > 0:
            acc = ref.acc_lowpass_step(self, gyr, self.b, acc, dt, self._start_ended)
        # 2. the tests, against the readings the predicted attitude expects
        u = rotmat(self.q).T @ UP
        acc_rej = self._acc_test(acc, u, dt) if acc is not None else False
        mag_rej, mag_tested = self._mag_test(mag, raw, u) if mag is not None else (False, False)
        # 3a. QUEST measurement when the body is quiet and the shared detector accepts the
        # field (run once a sample)
        magd = None
        if (self.measurement == "quest" and acc is not None and mag_tested and not acc_rej
                and not mag_rej):
            magd = self.magd(self.q, mag, gyr, dt)
            if magd and self._quest_update(acc, mag, u, dt):
                self.P = (self.P + self.P.T) / 2
                return
        # 3b. the ekf's vector updates, variances times reject_factor when rejected
        if acc is not None:
            f = self.reject_factor if acc_rej else 1.0
            self._correct(normalise(acc), ref.acc_model, (self.acc_noise / G) ** 2 / dt * f * I3,
                          "tilt" if self.acc_update == "tilt" else "full")
        if mag is not None and (self.magd(self.q, mag, gyr, dt) if magd is None else magd):   # the shared detector
            z = normalise(mag)
            nx, ny, _ = (rotmat(self.q) @ z).tolist()
            if math.sqrt(nx * nx + ny * ny) >= 1e-9:
                f = self.reject_factor if mag_rej else 1.0
                self._correct(z, lambda q: ref.mag_model(q, z), self.mag_noise ** 2 / dt * f * I3,
                              "heading" if self.mag_update == "heading" else "full")
        self.P = (self.P + self.P.T) / 2

    def _acc_test(self, acc, u, dt):
        """Whether the accelerometer is rejected: its norm off g, or its direction off the
        predicted up axis u for at most acc_pred_timeout."""
        g = self.g_ref
        na = math.sqrt(acc @ acc)
        self.tested["acc"] += 1
        off_g = abs(na - g) > self.acc_norm_tol
        if off_g and self.acc_lowpass <= 0:
            rej = True
            self.t_dir = 0.0
        elif off_g or np.linalg.norm(acc - g * u) > self.acc_pred_tol:     # low-passed: timed out too
            self.t_dir += dt
            rej = not ref.outlasted(self.t_dir, self.acc_pred_timeout)
        else:
            rej = False
            self.t_dir = 0.0
        if rej:
            self.rejected["acc"] += 1
            self.code |= 1
        return rej

    def _mag_test(self, mag, acc, u):
        """(rejected, tested): the field's norm and dip against the learned (or given) ones."""
        nm = math.sqrt(mag @ mag)
        if acc is not None and len(self.norms) < self.n_learn:
            self.norms.append(nm)
            c = -(mag @ acc) / (nm * math.sqrt(acc @ acc))
            self.dips.append(math.asin(min(1.0, max(-1.0, c))))
            if self.mag_norm is None:
                self.norm_ref = sum(self.norms) / len(self.norms)
            if self.mag_dip is None:
                self.dip_ref = sum(self.dips) / len(self.dips)
        if self.norm_ref is None or self.dip_ref is None:
            return False, False
        self.tested["mag"] += 1
        dip = math.asin(min(1.0, max(-1.0, -(mag @ u) / nm)))
        rej = (abs(nm / self.norm_ref - 1.0) > self.mag_norm_tol
               or abs(dip - self.dip_ref) > self.mag_dip_tol * DEG)
        if rej:
            self.rejected["mag"] += 1
            self.code |= 2
        return rej, True

    def _quest_update(self, acc, mag, u, dt):
        """The QUEST quaternion as the measurement, where its geometry is defined: applied?"""
        a, m = normalise(acc), normalise(mag)
        rf = np.array([0.0, math.cos(self.dip_ref), -math.sin(self.dip_ref)])
        if not (np.linalg.norm(ref.cross(u, m)) > 1e-9 and np.linalg.norm(ref.cross(a, m)) > 1e-9
                and abs(math.cos(self.dip_ref)) > 1e-9):       # |UP × rf| = cos(dip)
            return False
        qm = wahba_davenport([a, m], [UP, rf], [1.0 - self.quest_mag_weight, self.quest_mag_weight])
        if qm @ self.q < 0:
            qm = -qm
        # body-frame angle covariance: tilt as the accelerometer's, heading (about the
        # predicted up axis u) as the magnetometer's horizontal part; mapped to the
        # quaternion by δq = Ξ(q) δθ / 2, plus σa²/4 along q itself
        sa = (self.acc_noise / G) ** 2 / dt
        sh = self.mag_noise ** 2 / dt / (np.linalg.norm(ref.cross(u, m)) ** 2)
        P_theta = sa * (I3 - np.outer(u, u)) + sh * np.outer(u, u)
        Xi = ref.xi_matrix(self.q)
        Rm = 0.25 * (Xi @ P_theta @ Xi.T) + 0.25 * sa * np.outer(self.q, self.q)
        self._quat_correct(qm, Rm)
        self.quest_updates += 1
        self.code |= 4
        return True
