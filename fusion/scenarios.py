"""Built-in synthetic scenarios for open-loop estimator tests (numpy only).

A deliberately simple generator; the full IMU sensor model (bias instability, scale,
misalignment, quantisation, vibration, ...) belongs to ``fusion.imu``.

Model, in ENU (z up), at sample times ``t[i] = i / fs``:

- Motion: smooth ZYX angles, each a random start (any heading, up to ±15 deg of pitch and
  roll) plus a sum of three sines with random frequencies, phases and amplitudes from the
  seed, swinging pitch and roll by up to ±``tilt`` and yaw by up to ±``turn`` (tilt stays
  bounded, away from the ZYX gimbal lock); the body rate ``omega(tau)`` follows from the angles
  and their rates analytically.
- Truth: ``q_true[i] = q_true[i-1] ⊗ exp(omega_i dt)`` with ``omega_i`` the rate at the middle of
  the step ``(t[i] - dt, t[i]]`` held over the step: the exact exponential, so an ideal gyro
  integrated by ``fusion.make("gyro", fs)`` reproduces ``q_true`` to rounding. ``q_start`` is
  the attitude one step before the first sample: the step into sample 0 is
  ``q_true[0] = q_start ⊗ exp(omega_0 dt)``.
- Samples (what ``est.run(gyr, acc, mag, dt=dt)`` takes: sample ``i`` closes the step into
  ``t[i]``):

  - ``gyr = omega_i + gyro_bias + N(0, (gyro_noise sqrt(fs))²)``, a constant bias;
  - ``acc = R(q_true)ᵀ (a_lin + [0, 0, g]) + N(0, (acc_noise sqrt(fs))²)`` (specific force);
    ``a_lin`` (earth frame) is a few Hann-windowed bursts of linear acceleration;
  - ``mag = R(q_true)ᵀ field + N(0, (mag_noise sqrt(fs))²)``, field ENU ``[0, 0.4, -0.3]``
    (north and down, dip about 37 deg, same unit as the noise).

  Noise is given as a density (per √Hz) so that a scenario behaves alike at any ``fs``.
- Reproducible: ``numpy.random.default_rng`` streams spawned from ``seed``; the motion and the
  noise use separate streams, so ``ideal=True`` (no noise, no bias) gives the same ``q_true``
  as the noisy scenario of the same seed.

Variants (``SCENARIOS``): ``static`` (held still at a random tilted attitude, as seed 000's
experiment), ``slow`` (gentle rotations, no linear acceleration), ``mixed`` (rotations with
peaks of about 3 rad/s plus linear-acceleration bursts), ``shaking`` (gentle rotation, strong frequent
linear acceleration).
"""
from dataclasses import dataclass, field as dc_field
import numpy as np

from fusion import quat

__all__ = ["Scenario", "SCENARIOS", "make_scenario", "G", "FIELD"]

G = 9.81
FIELD = (0.0, 0.4, -0.3)

# motion and disturbance presets (angles in degrees, accelerations in m/s^2)
SCENARIOS = {
    "static": dict(tilt=0.0, turn=0.0, bursts_per_min=0.0, burst_acc=0.0,
                   doc="held still at a random tilted attitude"),
    "slow": dict(tilt=15.0, turn=45.0, freq=(0.03, 0.2), bursts_per_min=0.0, burst_acc=0.0,
                 doc="gentle rotations, no linear acceleration"),
    "mixed": dict(tilt=25.0, turn=90.0, freq=(0.05, 0.6), bursts_per_min=6.0, burst_acc=3.0,
                  doc="rotations with peaks of about 3 rad/s and linear-acceleration bursts"),
    "shaking": dict(tilt=10.0, turn=30.0, freq=(0.05, 0.3), bursts_per_min=30.0, burst_acc=8.0,
                    doc="gentle rotation, strong and frequent linear acceleration"),
}

DEFAULT_NOISE = dict(gyro_noise=3e-4,          # rad/s/sqrt(Hz): 0.003 rad/s per sample at 100 Hz
                     acc_noise=4e-3,           # m/s^2/sqrt(Hz): 0.04 m/s^2 at 100 Hz
                     mag_noise=5e-4,           # field unit/sqrt(Hz): 0.005 at 100 Hz (1 % of |field|)
                     gyro_bias=(0.01, -0.008, 0.005))   # rad/s, constant


@dataclass(eq=False)
class Scenario:
    """A synthetic recording with its truth. Arrays have N rows (N = round(duration * fs))."""
    name: str
    fs: float
    seed: int
    t: np.ndarray            # (N,) s
    dt: np.ndarray           # (N,) s, the step into each sample (all 1/fs)
    q_true: np.ndarray       # (N, 4) true attitude at t, body -> ENU
    q_start: np.ndarray      # (4,) attitude one step before t[0]
    omega: np.ndarray        # (N, 3) true body rate held over the step into each sample, rad/s
    a_lin: np.ndarray        # (N, 3) true linear acceleration, earth frame, m/s^2
    gyr: np.ndarray          # (N, 3) rad/s
    acc: np.ndarray          # (N, 3) m/s^2
    mag: np.ndarray          # (N, 3) field unit
    field: np.ndarray        # (3,) earth field, ENU
    gyro_bias: np.ndarray    # (3,) rad/s
    params: dict = dc_field(default_factory=dict)

    @property
    def n(self):
        return self.t.shape[0]


def _sines(rng, amp_rad, freq, n_sines=3):
    """Per axis, ``n_sines`` sines ``a_k sin(2 pi f_k tau + p_k)`` with the amplitudes ``a_k``
    summing to ``amp_rad[axis]``: returns (a, f, p), each (3, n_sines)."""
    f = rng.uniform(freq[0], freq[1], (3, n_sines))
    p = rng.uniform(0, 2 * np.pi, (3, n_sines))
    w = rng.uniform(0.5, 1.0, (3, n_sines))
    a = np.asarray(amp_rad, dtype=float)[:, None] * w / w.sum(axis=1, keepdims=True)
    return a, f, p


def _euler_path(tau, e0, sines):
    """ZYX angles (yaw, pitch, roll) ``e0 + sum of sines`` at ``tau`` and their rates."""
    a, f, p = sines
    arg = 2 * np.pi * f[None] * tau[:, None, None] + p[None]          # (N, 3, n_sines)
    e = np.asarray(e0, dtype=float) + (a * np.sin(arg)).sum(axis=-1)
    de = (a * 2 * np.pi * f * np.cos(arg)).sum(axis=-1)
    return e, de


def _body_rate(e, de):
    """Body-frame angular velocity from ZYX Euler angles and their rates."""
    _, th, ph = e.T
    dps, dth, dph = de.T
    return np.stack([dph - dps * np.sin(th),
                     dth * np.cos(ph) + dps * np.cos(th) * np.sin(ph),
                     -dth * np.sin(ph) + dps * np.cos(th) * np.cos(ph)], axis=-1)


def _bursts(rng, t, per_min, amp):
    """Hann-windowed sinusoidal bursts of linear acceleration, earth frame (len(t), 3)."""
    a = np.zeros((t.shape[0], 3))
    duration = t[-1] - t[0] if t.shape[0] > 1 else 0.0
    n = rng.poisson(per_min * duration / 60.0) if per_min > 0 else 0
    for _ in range(n):
        c = rng.uniform(t[0], t[-1])
        width = rng.uniform(0.5, 2.0)                        # s
        f = rng.uniform(1.0, 4.0)                            # Hz
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        u = (t - c) / width + 0.5                            # 0..1 inside the burst
        inside = (u >= 0) & (u <= 1)
        win = np.where(inside, np.sin(np.pi * np.clip(u, 0, 1)) ** 2, 0.0)
        a += amp * rng.uniform(0.5, 1.0) * (win * np.sin(2 * np.pi * f * (t - c)))[:, None] * d
    return a


def _cumprod_quat(d):
    """Running Hamilton product ``d[0] ⊗ d[1] ⊗ ... ⊗ d[i]`` for every i (log-depth scan)."""
    p = d.copy()
    s = 1
    while s < p.shape[0]:
        p[s:] = quat.mul(p[:-s], p[s:])
        s *= 2
    return p


def make_scenario(name="mixed", fs=100.0, duration=60.0, seed=0, *, ideal=False,
                  gyro_noise=None, acc_noise=None, mag_noise=None, gyro_bias=None,
                  field=FIELD, g=G, q_start=None, **motion):
    """Generate the scenario ``name`` (one of ``SCENARIOS``) at ``fs`` Hz for ``duration`` s.

    ideal: noise-free sensors without gyro bias (the linear acceleration, being motion, stays).
    gyro_noise / acc_noise / mag_noise (densities per √Hz) and gyro_bias (rad/s, 3) override the
    defaults in ``DEFAULT_NOISE``. q_start: attitude one step before the first sample (default:
    the start of the motion's angle path). motion: overrides of the preset
    (``tilt``, ``turn`` in deg, ``freq`` (lo, hi) Hz, ``bursts_per_min``, ``burst_acc`` m/s^2).
    """
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; available: {', '.join(SCENARIOS)}")
    fs, duration = float(fs), float(duration)
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sample rate in Hz, got {fs}")
    n = int(round(duration * fs))
    if n < 1:
        raise ValueError(f"duration * fs must give at least one sample, got {duration} s at {fs} Hz")
    preset = {k: v for k, v in SCENARIOS[name].items() if k != "doc"}
    unknown = set(motion) - {"tilt", "turn", "freq", "bursts_per_min", "burst_acc"}
    if unknown:
        raise ValueError(f"unknown scenario parameter(s) {sorted(unknown)}")
    preset.update(motion)
    noise = dict(DEFAULT_NOISE)
    for k, v in dict(gyro_noise=gyro_noise, acc_noise=acc_noise, mag_noise=mag_noise,
                     gyro_bias=gyro_bias).items():
        if v is not None:
            noise[k] = v
    if ideal:
        noise = dict(gyro_noise=0.0, acc_noise=0.0, mag_noise=0.0, gyro_bias=(0.0, 0.0, 0.0))

    motion_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    dt_s = 1.0 / fs
    t = np.arange(n) * dt_s
    dt = np.full(n, dt_s)

    # smooth motion: ZYX angles = start + sums of sines; the body rate follows analytically
    e0 = np.array([motion_rng.uniform(-np.pi, np.pi), *np.radians(motion_rng.uniform(-15, 15, 2))])
    sines = _sines(motion_rng, np.radians([preset["turn"], preset["tilt"], preset["tilt"]]),
                   preset.get("freq", (0.05, 0.5)))
    if q_start is None:
        q_start = quat.from_euler(_euler_path(np.array([-dt_s]), e0, sines)[0][0])
    q_start = quat.normalise(quat.as_quat(q_start, "q_start"))
    omega = _body_rate(*_euler_path(t - dt_s / 2, e0, sines))      # mid-step rate, held
    q_true = quat.normalise(quat.mul(q_start, _cumprod_quat(quat.exp(omega, dt_s))))
    a_lin = _bursts(motion_rng, t, preset["bursts_per_min"], preset["burst_acc"])

    field_v = np.asarray(field, dtype=float)
    bias = np.asarray(noise["gyro_bias"], dtype=float)
    sq = np.sqrt(fs)
    gyr = omega + bias + noise["gyro_noise"] * sq * noise_rng.standard_normal((n, 3))
    acc = quat.rotate_inverse(q_true, a_lin + np.array([0.0, 0.0, g])) \
        + noise["acc_noise"] * sq * noise_rng.standard_normal((n, 3))
    mag = quat.rotate_inverse(q_true, field_v) + noise["mag_noise"] * sq * noise_rng.standard_normal((n, 3))

    params = dict(preset, **{k: (tuple(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
                             for k, v in noise.items()}, duration=duration, ideal=ideal, g=g)
    return Scenario(name=name, fs=fs, seed=seed, t=t, dt=dt, q_true=q_true, q_start=q_start,
                    omega=omega, a_lin=a_lin, gyr=gyr, acc=acc, mag=mag, field=field_v,
                    gyro_bias=bias, params=params)
