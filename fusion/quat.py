"""Vectorised quaternion helpers on (..., 4) numpy arrays (numpy only).

Conventions as in docs/estimators.md: Hamilton product, scalar first ``[w, x, y, z]``, a
quaternion rotates body-frame vectors into the navigation frame (``v_n = R(q) v_b``); Euler
angles are ZYX and come as ``[..., (yaw, pitch, roll)]`` in radians.

Every function broadcasts over leading axes, e.g. ``mul(q_ref, q_rows)`` with ``q_ref`` of
shape (4,) and ``q_rows`` of shape (N, 4).
"""
import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.checks import not_masked

Array = NDArray[np.float64]

__all__ = ["as_quat", "mul", "conj", "normalise", "rotate", "rotate_inverse", "to_matrix", "to_rotvec",
           "to_euler", "from_euler", "from_rotvec", "exp", "from_axis_angle", "angle"]

_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _real(x, name):
    """``x`` as a float array; ValueError naming ``name`` for a masked array (its mask would be
    dropped: fill the masked rows with NaN, ``x.filled(np.nan)``, to leave them unscored) and for
    values that are not real numbers (complex, bool, strings, objects)."""
    not_masked(name, x, "{name}.filled(np.nan): NaN rows of a reference are not scored")
    a = np.asarray(x)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must hold real numbers (int or float), got dtype {a.dtype}")
    return a.astype(float, copy=False)


def as_quat(q: ArrayLike, name: str = "q") -> Array:
    """``q`` as a float array with last axis 4, else ValueError naming ``name``."""
    q = _real(q, name)
    if q.ndim == 0 or q.shape[-1] != 4:
        raise ValueError(f"{name} must have shape (..., 4) [w, x, y, z], got {q.shape}")
    return q


def _as_vec(v, name="v"):
    v = _real(v, name)
    if v.ndim == 0 or v.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {v.shape}")
    return v


def mul(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q``."""
    p, q = as_quat(p, "p"), as_quat(q, "q")
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def conj(q: ArrayLike) -> Array:
    """Conjugate (the inverse for unit quaternions)."""
    return as_quat(q) * _CONJ


def normalise(q: ArrayLike) -> Array:
    """Unit-norm copy; zero rows (and rows with a non-finite component) become NaN rather than
    silently passing."""
    q = as_quat(q)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        ok = (n > 0) & np.isfinite(n)
        out = np.where(ok, q / n, np.nan)
        if not ok.all():
            # a finite, non-zero row whose squares overflow (1e200) or underflow (1e-200) reads
            # as norm inf or 0: scaled by its largest component first
            odd = ~ok & np.isfinite(q).all(axis=-1, keepdims=True) & (q != 0).any(axis=-1, keepdims=True)
            s = q / np.where(odd, np.max(np.abs(q), axis=-1, keepdims=True), 1.0)
            out = np.where(odd, s / np.linalg.norm(s, axis=-1, keepdims=True), out)
        return out


def to_matrix(q: ArrayLike) -> Array:
    """Rotation matrices (..., 3, 3) body -> navigation, ``R(q)`` of docs/estimators.md
    (homogeneous form; ``q`` is normalised first)."""
    w, x, y, z = np.moveaxis(normalise(q), -1, 0)
    return np.stack([
        np.stack([w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], -1),
    ], axis=-2)


def rotate(q: ArrayLike, v: ArrayLike) -> Array:
    """``R(q) v``: body-frame vectors (..., 3) into the navigation frame."""
    return np.einsum("...ij,...j->...i", to_matrix(q), _as_vec(v))


def rotate_inverse(q: ArrayLike, v: ArrayLike) -> Array:
    """``R(q)ᵀ v``: navigation-frame vectors (..., 3) into the body frame."""
    return np.einsum("...ji,...j->...i", to_matrix(q), _as_vec(v))


def to_euler(q: ArrayLike) -> Array:
    """ZYX Euler angles ``[..., (yaw, pitch, roll)]`` in radians (docs/estimators.md)."""
    w, x, y, z = np.moveaxis(normalise(q), -1, 0)
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    return np.stack([yaw, pitch, roll], axis=-1)


def from_euler(euler: ArrayLike) -> Array:
    """Quaternion (``w >= 0`` for |angles| within ±pi) from ZYX Euler angles
    ``[..., (yaw, pitch, roll)]`` in radians: ``q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)``."""
    e = _as_vec(euler, "euler")
    cy, cp, cr = (np.cos(e[..., i] / 2) for i in range(3))
    sy, sp, sr = (np.sin(e[..., i] / 2) for i in range(3))
    return np.stack([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy], axis=-1)


def from_rotvec(rv: ArrayLike) -> Array:
    """Quaternion of the rotation vector ``rv`` (..., 3) (axis times angle, rad), exact:
    ``[cos(|rv|/2), sin(|rv|/2) rv/|rv|]`` (Taylor series for tiny angles)."""
    rv = _as_vec(rv, "rv")
    th = np.linalg.norm(rv, axis=-1)
    h = th / 2
    small = h < 1e-4
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(small, 0.5 - h * h / 12.0, np.sin(h) / np.where(small, 1.0, th))
    return np.concatenate([np.cos(h)[..., None], k[..., None] * rv], axis=-1)


def to_rotvec(q: ArrayLike) -> Array:
    """Rotation vector (..., 3) of the quaternion ``q`` (..., 4): the inverse of
    ``from_rotvec``, angle in [0, pi] (``q`` and ``-q`` give the same vector)."""
    q = normalise(as_quat(q))
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    th = 2 * np.arctan2(s, q[..., 0])
    small = s < 1e-8
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(small, 2.0 / q[..., 0], th / np.where(small, 1.0, s))
    return k[..., None] * q[..., 1:]


def exp(omega: ArrayLike, dt: float | ArrayLike) -> Array:
    """Increment of a constant body rate ``omega`` (..., 3) over ``dt`` (scalar or (...,)):
    ``q⁺ = q ⊗ exp(omega, dt)``, the exact exponential (``Φ`` of docs/estimators.md)."""
    omega = _as_vec(omega, "omega")
    return from_rotvec(omega * _per_row(dt, "dt", omega.shape[:-1])[..., None])


def _per_row(x, name, rows):
    """``x`` (a scalar, or one value per row of shape ``rows``, or any shape for one row, whose
    result then has x's shape) as floats; ValueError otherwise (a column ``(N, 1)`` against
    ``N`` rows would broadcast to ``N x N``)."""
    x = _real(x, name)
    if rows and x.ndim and x.shape != tuple(rows):
        raise ValueError(f"{name} must be a scalar or have shape {tuple(rows)} (one per row), got {x.shape}")
    return x


def from_axis_angle(axis: ArrayLike, angle: float | ArrayLike) -> Array:
    """Quaternion of a rotation by ``angle`` (rad) about ``axis`` (normalised here)."""
    axis = _as_vec(axis, "axis")
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if not (np.isfinite(norm).all() and (norm > 0).all()):
        raise ValueError("axis must be finite and non-zero (a rotation about no axis is undefined)")
    return from_rotvec(axis / norm * _per_row(angle, "angle", axis.shape[:-1])[..., None])


def angle(p: ArrayLike, q: ArrayLike) -> Array:
    """Rotation angle (rad, in [0, pi]) between attitudes ``p`` and ``q``, per row;
    ``2 atan2(|e_xyz|, |e_w|)`` with ``e = p ⊗ conj(q)`` (exact near zero, sign-blind)."""
    e = mul(normalise(p), conj(normalise(q)))
    return 2 * np.arctan2(np.linalg.norm(e[..., 1:], axis=-1), np.abs(e[..., 0]))
