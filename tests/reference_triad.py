"""Plain-numpy reference of docs/estimators.md, "triad" (no import of `fusion`, nothing taken
from the kernel): each sample's attitude as the solution of Wahba's problem by the SVD
(Markley 1988) for the body vectors (accelerometer, magnetometer) and the navigation vectors
(up, and the field with the dip the two measured vectors make), which both vectors then fit
exactly; without a magnetometer the rotation matrix of Euler ZYX (0, pitch, roll) that takes
the accelerometer to up. The low-pass: scipy's Butterworth coefficients, a transposed
direct-form II per sample, started at steady state on the first valid sample."""
import math

import numpy as np
from scipy import signal

from reference import RefEstimator, quat_from_matrix

UP = np.array([0.0, 0.0, 1.0])


def wahba_svd(b1, b2, r1, r2, w1=1.0, w2=1.0):
    B = w1 * np.outer(r1, b1) + w2 * np.outer(r2, b2)
    U, _, Vt = np.linalg.svd(B)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)]) @ Vt
    q = quat_from_matrix(R)
    return q if q[0] >= 0 else -q


def tilt_only(u):
    """R = Rz(0) Ry(pitch) Rx(roll) with R u = up, as a quaternion."""
    pitch = math.asin(max(-1.0, min(1.0, -u[0])))
    roll = math.atan2(u[1], u[2])
    cp, sp, cr, sr = math.cos(pitch), math.sin(pitch), math.cos(roll), math.sin(roll)
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    q = quat_from_matrix(Ry @ Rx)
    return q if q[0] >= 0 else -q


class RefButterworth:
    def __init__(self, fs, cutoff_hz):
        self.b, self.a = signal.butter(2, cutoff_hz, fs=fs)
        self.z = None

    def __call__(self, x):
        b, a = self.b, self.a
        if self.z is None:      # steady state at x: y = x throughout
            self.z = [(b[1] + b[2] - a[1] - a[2]) * x, (b[2] - a[2]) * x]
        y = b[0] * x + self.z[0]
        self.z = [b[1] * x - a[1] * y + self.z[1], b[2] * x - a[2] * y]
        return y


class RefTriad(RefEstimator):
    PARAMS = {"cutoff_hz": None}

    def _reset_state(self):
        c = self.params["cutoff_hz"]
        self.lp = None if c is None else (RefButterworth(self.fs, c), RefButterworth(self.fs, c))

    def update(self, gyr, acc, mag=None, dt=None):
        # the low-pass sees the valid samples only, before the attitude is set from them
        acc, mag = np.asarray(acc, float), None if mag is None else np.asarray(mag, float)
        if self.lp is not None:
            if np.isfinite(acc).all() and acc @ acc > 0:
                acc = self.lp[0](acc)
            if mag is not None and np.isfinite(mag).all() and mag @ mag > 0:
                mag = self.lp[1](mag)
        return super().update(gyr, acc, mag, dt)

    def _step(self, gyr, acc, mag, dt):
        if acc is None:
            return
        u = acc / np.linalg.norm(acc)
        if mag is not None:
            m = mag / np.linalg.norm(mag)
            c = float(u @ m)
            if np.linalg.norm(np.cross(m, u)) > 1e-9:
                self.q = wahba_svd(u, m, UP, np.array([0.0, math.sqrt(max(0.0, 1.0 - c * c)), c]))
                return
        self.q = tilt_only(u)
