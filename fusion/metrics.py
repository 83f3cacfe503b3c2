"""Attitude errors, the way the source documents and the field report them (numpy only).

- ``euler_table``: mean, std, MAE and RMSE of the ZYX Euler-angle errors in degrees, per angle
  (yaw, pitch, roll): the tables of the source documents ("The four source
  documents, in short").
- ``attitude_errors`` / ``score``: total, heading and inclination error in degrees from the
  earth-frame error quaternion, as the data folder's README ("Recorded IMU data with a
  reference orientation") scores recorded data; with
  ``remove_heading_offset`` for 6-axis estimators, whose heading has no absolute reference.
- ``spectrum``: one-sided amplitude spectrum (the vibration analysis of
  "IIR-EKF, IMU dynamic error suppression").

Rows whose reference quaternion is not finite (a lost reference) are ignored everywhere; an
estimate that is not a finite, nonzero quaternion on any other row is a ValueError (scoring the
other rows would hide the failure).
"""
from typing import Literal, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion import quat
from fusion.checks import flag
from fusion.quat import Array

__all__ = ["ANGLES", "reference_rows", "euler_errors", "euler_table", "attitude_errors", "heading_offset",
           "remove_heading_offset", "score", "rmse", "spectrum"]

ANGLES = ("yaw", "pitch", "roll")
STATS = ("mean", "std", "MAE", "RMSE")


def _pair(q_est, q_ref, names=("q_est", "q_ref")):
    """Both as float (N, 4) arrays of the same N (a single (4,) quaternion broadcasts);
    ValueError where the estimate cannot be normalised on a row with a finite reference."""
    a, b = (quat.as_quat(q, n) for q, n in zip((q_est, q_ref), names))
    if a.ndim == 1:
        a = a[None]
    if b.ndim == 1:
        b = b[None]
    if a.ndim != 2 or b.ndim != 2:
        raise ValueError(f"{names[0]} and {names[1]} must be (N, 4) or (4,), got {a.shape} and {b.shape}")
    if a.shape[0] != b.shape[0]:
        if a.shape[0] == 1:
            a = np.broadcast_to(a, b.shape)
        elif b.shape[0] == 1:
            b = np.broadcast_to(b, a.shape)
        else:
            raise ValueError(f"{names[0]} and {names[1]} must have the same number of rows, "
                             f"got {a.shape[0]} and {b.shape[0]}")
    bad = reference_rows(b) & ~reference_rows(a)
    if bad.any():
        raise ValueError(f"{names[0]} must be a finite, nonzero quaternion on every row with a "
                         f"reference: {int(bad.sum())} of {a.shape[0]} rows are not (first: row "
                         f"{int(np.argmax(bad))}, {a[np.argmax(bad)]}); only rows without a "
                         f"reference (a non-finite or zero {names[1]}) are dropped")
    return a, b


def reference_rows(q: ArrayLike) -> NDArray[np.bool_]:
    """The rows of q that are a rotation (finite, not zero): where the reference is one, a row
    is scored; where it is not, it is dropped."""
    return np.isfinite(quat.normalise(q)).all(axis=1)


def _wrap_deg(a):
    """Angles in degrees wrapped to [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


def euler_errors(q_est: ArrayLike, q_true: ArrayLike) -> Array:
    """ZYX Euler-angle differences est - true in degrees, wrapped to [-180, 180), shape (M, 3)
    with columns (yaw, pitch, roll); rows with a non-finite (or zero) reference dropped, as
    ``score`` ignores them."""
    a, b = _pair(q_est, q_true, ("q_est", "q_true"))
    keep = reference_rows(b)
    d = np.degrees(quat.to_euler(a[keep]) - quat.to_euler(b[keep]))
    return _wrap_deg(d)


def euler_table(q_est: ArrayLike, q_true: ArrayLike) -> dict[str, dict[str, float]]:
    """The seed papers' table: ``{angle: {"mean", "std", "MAE", "RMSE"}}`` in degrees for
    angle in ("yaw", "pitch", "roll"), over the rows with a finite reference.

    The error is the difference of ZYX Euler angles (est - true), wrapped to [-180, 180);
    ``std`` is the population standard deviation (ddof=0), so RMSE² = mean² + std².
    """
    d = euler_errors(q_est, q_true)
    if d.shape[0] == 0:
        raise ValueError("no rows with a finite reference quaternion to score")
    return {ang: {"mean": float(d[:, i].mean()), "std": float(d[:, i].std()),
                  "MAE": float(np.abs(d[:, i]).mean()), "RMSE": float(np.sqrt((d[:, i] ** 2).mean()))}
            for i, ang in enumerate(ANGLES)}


def _error_quaternion(q_est, q_ref):
    a, b = _pair(q_est, q_ref)
    return quat.mul(quat.normalise(a), quat.conj(quat.normalise(b)))


def attitude_errors(q_est: ArrayLike, q_ref: ArrayLike) -> dict[str, Array]:
    """Per-sample errors in degrees, as the data folder's README scores: with the earth-frame
    error ``e = q_est ⊗ conj(q_ref)`` (both normalised),

    - total ``2 acos(|e_w|)``, heading ``2 atan(|e_z / e_w|)``,
      inclination ``2 acos(sqrt(e_w² + e_z²))``,

    evaluated in the equivalent atan2 forms ``2 atan2(|e_xyz|, |e_w|)``,
    ``2 atan2(|e_z|, |e_w|)``, ``2 atan2(hypot(e_x, e_y), hypot(e_w, e_z))`` (identical for unit
    ``e``, but exact near zero where acos loses half the digits, and defined at ``e_w = 0``).

    Returns a dict of (N,) arrays ``total``, ``heading``, ``inclination``; rows with a
    non-finite reference are NaN (``score`` ignores them). ValueError where the estimate is not
    a finite, nonzero quaternion on another row.
    """
    e = _error_quaternion(q_est, q_ref)
    w, x, y, z = np.abs(np.moveaxis(e, -1, 0))
    return {"total": np.degrees(2 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)),
            "heading": np.degrees(2 * np.arctan2(z, w)),
            "inclination": np.degrees(2 * np.arctan2(np.hypot(x, y), np.hypot(w, z)))}


def heading_offset(q_est: ArrayLike, q_ref: ArrayLike) -> float:
    """The one constant heading offset ``psi`` (rad, in (-pi, pi]) with
    ``q_est ≈ q_z(psi) ⊗ q_ref``, ``q_z`` a rotation about the earth z axis.

    Least squares in the chordal sense: ``psi`` minimises ``sum_i sin²(theta_i / 2)`` over the
    rows with a finite reference, ``theta_i`` the total error left after removing it. With
    ``e_i = q_est ⊗ conj(q_ref)`` the residual's scalar part is
    ``cos(psi/2) e_w + sin(psi/2) e_z``, so ``[cos(psi/2), sin(psi/2)]`` is the dominant
    eigenvector of the 2x2 matrix ``sum_i [e_w, e_z]ᵀ [e_w, e_z]`` (closed form, insensitive to
    the sign of each quaternion). For small, tight errors it is the mean heading error.
    """
    e = _error_quaternion(q_est, q_ref)
    e = e[np.isfinite(e).all(axis=1)]
    if e.shape[0] == 0:
        raise ValueError("no rows with a finite reference quaternion to fit a heading offset")
    wz = e[:, [0, 3]]
    _, vec = np.linalg.eigh(wz.T @ wz)
    c, s = vec[:, -1]
    if c < 0:
        c, s = -c, -s
    return float(2 * np.arctan2(s, c))


@overload
def remove_heading_offset(q_est: ArrayLike, q_ref: ArrayLike, return_offset: Literal[False] = ...) -> Array: ...
@overload
def remove_heading_offset(q_est: ArrayLike, q_ref: ArrayLike, return_offset: Literal[True]) -> tuple[Array, float]: ...


def remove_heading_offset(q_est: ArrayLike, q_ref: ArrayLike,
                          return_offset: bool = False) -> Array | tuple[Array, float]:
    """``q_z(-psi) ⊗ q_est`` with ``psi = heading_offset(q_est, q_ref)``: the estimate turned
    about the earth z axis by the one constant heading offset per trial that fits best (see
    ``heading_offset``). For scoring 6-axis estimators. With ``return_offset`` also ``psi``
    (rad)."""
    psi = heading_offset(q_est, q_ref)
    a, _ = _pair(q_est, q_ref)
    rz = np.array([np.cos(psi / 2), 0.0, 0.0, -np.sin(psi / 2)])
    out = quat.mul(rz, a)
    return (out, psi) if return_offset else out


def rmse(x: ArrayLike) -> float:
    """Root mean square over the finite entries (NaN if none). Meant for ``attitude_errors``'
    arrays, whose only NaN rows are those without a reference (it refuses bad estimates)."""
    a = np.asarray(x, dtype=float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def score(q_est: ArrayLike, q_ref: ArrayLike, six_axis: bool = False) -> dict[str, float]:
    """RMSE in degrees of the total, heading and inclination errors over the rows with a
    finite reference: ``{"total", "heading", "inclination"}``; ValueError where the estimate is
    not a finite, nonzero quaternion on one of them. With ``six_axis=True`` one
    constant heading offset is removed first (``remove_heading_offset``), as
    the data folder's README asks for estimators without a magnetometer."""
    err = attitude_errors(remove_heading_offset(q_est, q_ref) if flag("six_axis", six_axis) else q_est, q_ref)
    if not np.isfinite(err["total"]).any():
        raise ValueError("no rows with a finite reference quaternion to score")
    return {k: rmse(v) for k, v in err.items()}


def spectrum(signal: ArrayLike, fs: float, detrend: bool = True) -> tuple[NDArray[np.floating], NDArray[np.floating]]:
    """One-sided amplitude spectrum along axis 0: ``(freqs (M,), amplitude (M, ...))`` with
    ``M = N//2 + 1``, ``freqs`` in Hz, via ``numpy.fft.rfft``.

    Scaled so that a sinusoid ``A sin(2 pi f t)`` on a frequency bin shows amplitude ``A``
    (``|X| / N``, doubled except for the DC and Nyquist bins). ``detrend`` removes the mean
    first (DC bin then ~0). No window is applied.
    """
    x = np.asarray(signal, dtype=float)
    if x.ndim == 0 or x.shape[0] < 2:
        raise ValueError(f"signal must have at least 2 samples along axis 0, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("signal must be finite")
    fs = float(fs)
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate in Hz, got {fs}")
    n = x.shape[0]
    if detrend:
        x = x - x.mean(axis=0)
    amp = np.abs(np.fft.rfft(x, axis=0)) / n
    amp[1:n - n // 2] *= 2.0       # every bin except DC and (for even n) Nyquist
    return np.fft.rfftfreq(n, 1.0 / fs), amp
