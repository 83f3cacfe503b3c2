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
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from fusion import imu as imu_model
from fusion import quat
from fusion.checks import finite_vector, integer, number
from fusion.constants import GRAVITY

__all__ = ["Scenario", "SCENARIOS", "make_scenario", "G", "FIELD",
           "SEED_SCENARIOS", "seed_scenario", "EARTH_FIELD_UT", "ACC_DISTURBED", "MAG_DISTURBED"]

G = GRAVITY
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
    preset: str = ""                          # IMU model (seed scenarios; "" for make_scenario's)
    acc_disturbed: np.ndarray | None = None  # (N,) bool: |a_lin| > ACC_DISTURBED (seed scenarios)
    mag_disturbed: np.ndarray | None = None  # (N,) bool: field disturbance > MAG_DISTURBED |field|

    @property
    def n(self):
        return self.t.shape[0]

    @property
    def disturbed(self):
        """(N,) bool: accelerometer or magnetometer disturbed, or None if not known."""
        if self.acc_disturbed is None or self.mag_disturbed is None:
            return None
        return self.acc_disturbed | self.mag_disturbed


def _sines(rng, amp_rad, freq, n_sines=3):
    """Per axis, ``n_sines`` sines ``a_k sin(2 pi f_k tau + p_k)`` with the amplitudes ``a_k``
    summing to ``amp_rad[axis]``: returns (a, f, p), each (3, n_sines)."""
    f = rng.uniform(freq[0], freq[1], (3, n_sines))
    p = rng.uniform(0, 2 * np.pi, (3, n_sines))
    w = rng.uniform(0.5, 1.0, (3, n_sines))
    a = np.asarray(amp_rad, dtype=float)[:, None] * w / w.sum(axis=1, keepdims=True)
    return a, f, p


def _draw_path(rng, turn, tilt, freq):
    """A random smooth path: start ``e0`` (any heading, pitch and roll within ±15 deg) and the
    sines swinging yaw by up to ±``turn`` and pitch, roll by up to ±``tilt`` (deg)."""
    e0 = np.array([rng.uniform(-np.pi, np.pi), *np.radians(rng.uniform(-15, 15, 2))])
    return e0, _sines(rng, np.radians([turn, tilt, tilt]), freq)


def _euler_path(tau, e0, sines, envelope=None):
    """ZYX angles (yaw, pitch, roll) ``e0 + w(tau) * sum of sines`` at ``tau`` and their rates;
    ``envelope`` (a function of tau returning ``(w, dw)``) fades the motion in and out, default
    ``w = 1``."""
    a, f, p = sines
    arg = 2 * np.pi * f[None] * tau[:, None, None] + p[None]          # (N, 3, n_sines)
    s = (a * np.sin(arg)).sum(axis=-1)
    ds = (a * 2 * np.pi * f * np.cos(arg)).sum(axis=-1)
    if envelope is not None:
        w, dw = envelope(tau)
        s, ds = w[:, None] * s, dw[:, None] * s + w[:, None] * ds
    return np.asarray(e0, dtype=float) + s, ds


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


def _checked_motion(name, motion):
    """The preset of scenario ``name`` with make_scenario's ``motion`` overrides, checked."""
    preset = {k: v for k, v in SCENARIOS[name].items() if k != "doc"}
    unknown = set(motion) - {"tilt", "turn", "freq", "bursts_per_min", "burst_acc"}
    if unknown:
        raise ValueError(f"unknown scenario parameter(s) {sorted(unknown)}")
    preset.update(motion)
    for k in ("tilt", "turn"):
        preset[k] = number(k, preset[k], 0.0, 1e4, unit=" deg")
    # (at most one burst a second on average: a huge rate looped for minutes)
    preset["bursts_per_min"] = number("bursts_per_min", preset["bursts_per_min"], 0.0, 60.0)
    preset["burst_acc"] = number("burst_acc", preset["burst_acc"], 0.0, 1e3, unit=" m/s^2")
    if "freq" in preset:
        lo, hi = map(float, finite_vector("freq", preset["freq"], 2))
        if not 0.0 < lo <= hi <= 1e3:
            raise ValueError(f"freq must be (lo, hi) Hz with 0 < lo <= hi <= 1000, got {preset['freq']!r}")
        preset["freq"] = (lo, hi)
    return preset


def _checked_noise(ideal, gyro_bias, **densities):
    """make_scenario's sensor errors: DEFAULT_NOISE with the given ones, checked; none if ideal."""
    if ideal:
        return dict(gyro_noise=0.0, acc_noise=0.0, mag_noise=0.0, gyro_bias=(0.0, 0.0, 0.0))
    noise = dict(DEFAULT_NOISE)
    for k, v in densities.items():
        if v is not None:
            noise[k] = number(k, v, 0.0, 1e3)
    if gyro_bias is not None:
        noise["gyro_bias"] = finite_vector("gyro_bias", gyro_bias, 3)
    return noise


def make_scenario(name: str = "mixed", fs: float = 100.0, duration: float = 60.0, seed: int = 0, *,
                  ideal: bool = False, gyro_noise: float | None = None, acc_noise: float | None = None,
                  mag_noise: float | None = None, gyro_bias: ArrayLike | None = None, field: ArrayLike = FIELD,
                  g: float = G, q_start: ArrayLike | None = None, **motion: Any) -> Scenario:
    """Generate the scenario ``name`` (one of ``SCENARIOS``) at ``fs`` Hz for ``duration`` s.

    ideal: noise-free sensors without gyro bias (the linear acceleration, being motion, stays).
    gyro_noise / acc_noise / mag_noise (densities per √Hz) and gyro_bias (rad/s, 3) override the
    defaults in ``DEFAULT_NOISE``. q_start: attitude one step before the first sample (default:
    the start of the motion's angle path). motion: overrides of the preset
    (``tilt``, ``turn`` in deg, ``freq`` (lo, hi) Hz, ``bursts_per_min``, ``burst_acc`` m/s^2).
    """
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; available: {', '.join(SCENARIOS)}")
    fs, seed = number("fs", fs, 0.0, 1e6, open_low=True, unit=" Hz"), integer("seed", seed, 0)
    duration = number("duration", duration, 0.0, 1e6, open_low=True, unit=" s")
    n = int(round(duration * fs))
    if n < 1:
        raise ValueError(f"duration * fs must give at least one sample, got {duration} s at {fs} Hz")
    preset = _checked_motion(name, motion)
    g = number("g", g, 0.0, 1e3, open_low=True, unit=" m/s^2")
    noise = _checked_noise(ideal, gyro_noise=gyro_noise, acc_noise=acc_noise, mag_noise=mag_noise,
                           gyro_bias=gyro_bias)
    field = finite_vector("field", field, 3)
    if not np.any(field):
        raise ValueError("field must not be zero")

    motion_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    dt_s = 1.0 / fs
    t = np.arange(n) * dt_s
    dt = np.full(n, dt_s)

    # smooth motion: ZYX angles = start + sums of sines; the body rate follows analytically
    e0, sines = _draw_path(motion_rng, preset["turn"], preset["tilt"], preset.get("freq", (0.05, 0.5)))
    if q_start is None:
        q_start = quat.from_euler(_euler_path(np.array([-dt_s]), e0, sines)[0][0])
    q_start = quat.as_quat(q_start, "q_start")
    if q_start.shape != (4,) or not np.all(np.isfinite(q_start)) or not np.any(q_start):
        raise ValueError(f"q_start must be 4 finite numbers [w, x, y, z], not all zero, got {q_start!r}")
    q_start = quat.normalise(q_start)
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


# ---------------------------------------------------------------------------------------
# Seed scenarios: the experiments of the four source documents, through the IMU model

EARTH_FIELD_UT = 100.0 * np.asarray(FIELD)   # ENU, uT: 50 uT, dip 36.9 deg (FIELD in uT)
ACC_DISTURBED = 0.5     # m/s^2: a sample is acc-disturbed above this |a_lin| (the aekf's e_a1)
MAG_DISTURBED = 0.05    # a sample is mag-disturbed above this |B_disturbance| / |B_earth|


def _field_ut(norm_ut, dip_deg):
    """Earth field, ENU, pointing north and down by ``dip_deg``."""
    d = np.radians(dip_deg)
    return norm_ut * np.array([0.0, np.cos(d), -np.sin(d)])


# The source documents by seed number: 000 "EKF attitude estimation for a spherical robot"
# (Software Engineering, 2022), 001 "Adaptive EKF from predicted measurements, for arm
# attitude", 003 "IIR-EKF, IMU dynamic error suppression" (J. Nanjing Univ. Aero. Astro., 2023),
# 004 "Attitude-angle solution for a mobile robot" (Chinese patent, 2019).
# Per scenario: IMU preset, output rate fs (Hz), physics rate = ratio * fs, length (samples or
# s), motion (turn, tilt in deg, freq in Hz, as SCENARIOS), window (s: still before and after,
# seed 001's experiment B), lever (m: IMU on an arm this far from the pivot, along body x: the
# arm's own linear acceleration), bursts (per min, m/s^2), sustained (episodes, m/s^2, hold s),
# magnet (a pass at a fraction of the record, closest m, speed m/s, on-axis peak uT), vibration.
_SEED = {
    "seed000-static": dict(
        doc="seed 000: robot held still, mpu6050+mag3110 at 10 Hz, 150 s",
        preset="mpu6050+mag3110", fs=10.0, ratio=100, duration=150.0),
    "seed001-slow": dict(
        doc="seed 001 exp. A: slow arm swinging (IMU 0.5 m from the shoulder), mti10 at 256 Hz, 30 s",
        preset="mti10", fs=256.0, ratio=8, duration=30.0, field=(50.0, 32.0), lever=0.5,
        motion=dict(turn=45.0, tilt=30.0, freq=(0.05, 0.3))),
    "seed001-fast": dict(
        doc="seed 001 exp. B: still, fast arm swinging from 6.5 to 15.4 s, still; a magnet passes "
            "during the motion; mti10 at 256 Hz, 22 s",
        preset="mti10", fs=256.0, ratio=8, duration=22.0, field=(50.0, 32.0), lever=0.5,
        motion=dict(turn=60.0, tilt=40.0, freq=(0.3, 1.0)), window=(6.5, 15.4),
        magnet=dict(when=(0.35, 0.65), closest=0.15, speed=0.15, peak=30.0)),
    "seed001-faster": dict(
        doc="seed 001 exp. C: as seed001-fast, swinging faster (rates up to about 6 rad/s)",
        preset="mti10", fs=256.0, ratio=8, duration=22.0, field=(50.0, 32.0), lever=0.5,
        motion=dict(turn=60.0, tilt=45.0, freq=(0.5, 1.4)), window=(6.5, 15.4),
        magnet=dict(when=(0.35, 0.65), closest=0.15, speed=0.15, peak=30.0)),
    "seed003-static": dict(
        doc="seed 003: IMU still, icm20602+qmc5883l at 200 Hz, 5000 samples",
        preset="icm20602+qmc5883l", fs=200.0, ratio=10, samples=5000),
    "seed003-dynamic": dict(
        doc="seed 003: normal attitude-measuring motion, icm20602+qmc5883l at 200 Hz, 4417 samples",
        preset="icm20602+qmc5883l", fs=200.0, ratio=10, samples=4417, lever=0.1,
        motion=dict(turn=30.0, tilt=20.0, freq=(0.1, 0.5))),
    "seed003-vibration": dict(
        doc="seed 003: IMU still on a mount with motors running (130-200 Hz, "
            "imu.VIBRATION_SEED003), icm20602+qmc5883l at 200 Hz, 5000 samples",
        preset="icm20602+qmc5883l", fs=200.0, ratio=10, samples=5000, vibration=True),
    "seed004-static": dict(
        doc="seed 004: mobile robot standing still, mpu9250 at 500 Hz, 60 s",
        preset="mpu9250", fs=500.0, ratio=4, duration=60.0),
    "seed004-fast": dict(
        doc="seed 004: mobile robot driving fast (quick turns, driving accelerations), mpu9250 at 500 Hz, 30 s",
        preset="mpu9250", fs=500.0, ratio=4, duration=30.0,
        motion=dict(turn=60.0, tilt=10.0, freq=(0.1, 0.6)), bursts=(20.0, 3.0)),
    "linear-acceleration": dict(
        doc="gentle rotation with three sustained horizontal accelerations of 2-4 m/s^2 held 3-6 s, "
            "icm20602+qmc5883l at 200 Hz, 60 s",
        preset="icm20602+qmc5883l", fs=200.0, ratio=10, duration=60.0,
        motion=dict(turn=20.0, tilt=5.0, freq=(0.03, 0.2)),
        sustained=dict(n=3, amp=(2.0, 4.0), hold=(3.0, 6.0))),
    "magnetic-disturbance": dict(
        doc="gentle rotation; a magnet (motor) passes within 12 cm (up to 40 uT, about 4 s above "
            "5 % of the earth field), icm20602+qmc5883l at 200 Hz, 60 s",
        preset="icm20602+qmc5883l", fs=200.0, ratio=10, duration=60.0,
        motion=dict(turn=30.0, tilt=10.0, freq=(0.03, 0.2)),
        magnet=dict(when=(0.3, 0.7), closest=0.12, speed=0.1, peak=40.0)),
}

SEED_SCENARIOS = {name: d["doc"] for name, d in _SEED.items()}


def _plateau(tau, t0, t1, ramp):
    """Smooth window and its derivative: 0 before ``t0``, raised-cosine rise over ``ramp`` s, 1,
    fall over ``ramp`` s to 0 at ``t1``."""
    ramp = max(min(ramp, 0.5 * (t1 - t0)), 1e-9)
    up, down = (tau - t0) / ramp, (t1 - tau) / ramp
    u = np.clip(np.minimum(up, down), 0.0, 1.0)
    rising = up < down
    du = np.where((u > 0) & (u < 1), np.where(rising, 1.0, -1.0) / ramp, 0.0)
    return 0.5 - 0.5 * np.cos(np.pi * u), 0.5 * np.pi * np.sin(np.pi * u) * du


def _random_unit(rng, n=None):
    v = rng.normal(size=(3,) if n is None else (n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _lever_arm_acc(path, tau, lever, h=1e-3):
    """Earth-frame acceleration of the point ``[lever, 0, 0]`` (body) of a body turning about a
    fixed pivot along ``path``: second central difference of its position (the path is
    analytic; truncation ~ h² ω⁴ r / 12 < 1e-4 m/s², rounding ~ 1e-9)."""
    r = np.array([lever, 0.0, 0.0])
    def pos(tt):
        return quat.rotate(quat.from_euler(path(tt)[0]), r)
    return (pos(tau + h) - 2.0 * pos(tau) + pos(tau - h)) / (h * h)


def _sustained(rng, t, n, amp, hold, ramp=0.5):
    """``n`` horizontal accelerations (earth frame), one in each n-th of the record, each of
    a random direction and size in ``amp`` (m/s^2), held ``hold`` s between raised-cosine
    ramps: a vehicle speeding up, or a turn, not a shake."""
    a = np.zeros((t.shape[0], 3))
    slot = (t[-1] - t[0]) / n
    for k in range(n):
        hk, u, az, size = rng.uniform(*hold), rng.uniform(), rng.uniform(-np.pi, np.pi), rng.uniform(*amp)
        hk = min(hk, 0.8 * slot - 2 * ramp)      # short records: shorter episodes
        if hk <= 0:
            continue
        start = t[0] + k * slot + u * (slot - hk - 2 * ramp)
        w, _ = _plateau(t, start, start + hk + 2 * ramp, ramp)
        a += size * w[:, None] * np.array([np.cos(az), np.sin(az), 0.0])
    return a


def _magnet_pass(rng, t, when, closest, speed, peak):
    """Earth-frame field (uT) of a dipole (a magnet, a motor) moving past the sensor on a
    straight line: closest approach ``closest`` m at a random fraction ``when`` of the record,
    ``speed`` m/s, moment of random direction whose on-axis field at ``closest`` is ``peak`` uT."""
    tc = t[0] + rng.uniform(*when) * (t[-1] - t[0])
    d = _random_unit(rng)
    u = _random_unit(rng)
    u -= d * (u @ d)
    u /= np.linalg.norm(u)
    moment = imu_model.dipole_moment_for(peak, closest) * _random_unit(rng)
    magnet = closest * d + np.outer((t - tc) * speed, u)        # relative to the sensor
    return imu_model.dipole_field(-magnet, np.zeros(3), moment)


def _seed_spec(imu, default, calibrated, fs, vibration):
    """The IMUSpec of a seed scenario: a preset name (``calibrated`` applies) or an IMUSpec (as
    given), at the scenario's rate, with seed 003's vibration where the scenario has it."""
    if imu is None:
        imu = default
    if isinstance(imu, imu_model.IMUSpec):
        spec = imu
    elif isinstance(imu, str):
        spec = imu_model.preset(imu, calibrated=calibrated)
    else:
        raise ValueError(f"imu must be None, an IMUSpec or one of the presets "
                         f"{', '.join(imu_model.available())}; got {type(imu).__name__}")
    spec = spec.replace(rate_hz=fs)
    if vibration and spec.vibration is None:      # a spec's own vibration wins (e.g. gyro-only)
        spec = spec.replace(vibration=imu_model.VIBRATION_SEED003)
    return spec


def _seed_samples(cfg, duration):
    """The sample count of a seed scenario: its documented one, or ``round(duration * fs)``."""
    fs = cfg["fs"]
    if duration is None:
        return cfg["samples"] if "samples" in cfg else int(round(cfg["duration"] * fs))
    n = int(round(number("duration", duration, 0.0, open_low=True) * fs))
    if n < 2:
        raise ValueError(f"duration must give at least 2 samples at {fs:g} Hz "
                         f"(>= {1.5 / fs:g} s), got {duration!r}")
    return n


def _seed_disturbances(cfg, rng, path, tau):
    """A seed scenario's linear acceleration (lever arm, bursts, sustained), earth field and
    magnet field at the physics instants ``tau``: ``(a_lin, field, b_dist)``."""
    a_lin = _lever_arm_acc(path, tau, cfg["lever"]) if cfg.get("lever") else np.zeros((tau.shape[0], 3))
    if "bursts" in cfg:
        a_lin = a_lin + _bursts(rng, tau, *cfg["bursts"])
    if "sustained" in cfg:
        a_lin = a_lin + _sustained(rng, tau, **cfg["sustained"])
    field = _field_ut(*cfg["field"]) if "field" in cfg else EARTH_FIELD_UT.copy()
    b_dist = _magnet_pass(rng, tau, **cfg["magnet"]) if "magnet" in cfg else np.zeros_like(a_lin)
    return a_lin, field, b_dist


def seed_scenario(name: str, seed: int = 0, *, duration: float | None = None,
                  imu: imu_model.IMUSpec | str | None = None, calibrated: bool = True) -> Scenario:
    """The experiment ``name`` (one of ``SEED_SCENARIOS``) through the IMU model: a ``Scenario``.

    The true motion is generated at a physics rate (an integer multiple of the IMU rate, 800 Hz
    to 2 kHz) and read by ``fusion.imu.IMU(spec).simulate``; the arrays are at the IMU's sample
    instants (jitter included). duration: seconds (default the documented length; the sample
    count is ``round(duration * fs)``). imu: a preset name or an ``IMUSpec`` in place of the
    scenario's sensor (its rate is replaced by the scenario's; ``calibrated`` applies to preset
    names: residual biases and iron after a power-on calibration). See docs/scenarios.md.
    """
    if not isinstance(name, str) or name not in _SEED:
        raise ValueError(f"unknown seed scenario {name!r}; available: {', '.join(_SEED)}")
    integer("seed", seed, 0)
    cfg = _SEED[name]
    fs = cfg["fs"]
    n = _seed_samples(cfg, duration)
    spec = _seed_spec(imu, cfg["preset"], calibrated, fs, cfg.get("vibration", False))
    physics = fs * cfg["ratio"]
    motion_rng, dist_rng, imu_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))

    # true motion at the physics rate; one IMU period spare for the last sample's jitter
    tau = np.arange((n + 1) * cfg["ratio"]) / physics
    mot = cfg.get("motion", dict(turn=0.0, tilt=0.0, freq=(0.05, 0.5)))
    e0, sines = _draw_path(motion_rng, mot["turn"], mot["tilt"], mot["freq"])
    window = cfg.get("window")
    envelope = (lambda tt: _plateau(tt, window[0], window[1], 1.0)) if window else None
    def path(tt):
        return _euler_path(tt, e0, sines, envelope)
    e, de = path(tau)
    q_phys = quat.from_euler(e)
    a_lin, field, b_dist = _seed_disturbances(cfg, dist_rng, path, tau)

    sensor = imu_model.IMU(spec, imu_rng, physics_rate_hz=physics)
    rec = sensor.simulate(tau, _body_rate(e, de), quat.rotate_inverse(q_phys, a_lin + [0.0, 0.0, G]),
                          quat.rotate_inverse(q_phys, field + b_dist))
    if len(rec) < n:       # cannot happen with a spare period and jitter clipped to 0.45 periods
        raise RuntimeError(f"IMU produced {len(rec)} samples, expected {n}")
    t, idx = rec.t[:n], rec.index[:n]

    # truth at the sample instants (analytic path); disturbances at the physics step read
    e_s, de_s = path(t)
    q_start = quat.from_euler(path(np.array([t[0] - 1.0 / fs]))[0][0])
    consts = sensor.constants
    params = dict(doc=cfg["doc"], physics_rate=physics, duration=n / fs, calibrated=calibrated,
                  imu_spec=spec.name, motion=mot, window=window, lever=cfg.get("lever", 0.0),
                  bursts=cfg.get("bursts"), sustained=cfg.get("sustained"), magnet=cfg.get("magnet"),
                  vibration=spec.vibration, imu_constants=consts, g=G)
    return Scenario(name=name, fs=fs, seed=seed, t=t, dt=rec.dt[:n], q_true=quat.from_euler(e_s),
                    q_start=q_start, omega=_body_rate(e_s, de_s), a_lin=a_lin[idx], gyr=rec.gyr[:n],
                    acc=rec.acc[:n], mag=rec.mag[:n], field=field, gyro_bias=consts["gyro_bias"],
                    params=params, preset=spec.name,
                    acc_disturbed=np.linalg.norm(a_lin[idx], axis=1) > ACC_DISTURBED,
                    mag_disturbed=np.linalg.norm(b_dist[idx], axis=1) > MAG_DISTURBED * np.linalg.norm(field))


# ---------------------------------------------------------------------------------------
# Failure scenarios (issue 19): one per failure category seen on real recordings, built on
# make_scenario's motion. The disturbances are added to the sensor readings; the truth is the
# motion's (a magnet does not turn the body, a linear vibration or a tap does not rotate it).

FAILURE_SCENARIOS = {
    "fast-rotation": dict(base="mixed", fs=286.0, motion=dict(tilt=60.0, turn=270.0, freq=(0.1, 0.8),
                                                              bursts_per_min=0.0, burst_acc=0.0),
                          doc="fast hand-held rotation (peaks of about 10 rad/s) sampled at 286 Hz"),
    "magnet-attached": dict(base="slow", fs=100.0, motion=dict(turn=120.0, freq=(0.05, 0.3)),
                            doc="a magnet fixed to the sensor from 20 to 50 s: a body-frame "
                                "offset of 0.8 x the field's norm (a new hard-iron offset)"),
    "magnet-stays": dict(base="slow", fs=100.0, motion=dict(turn=120.0, freq=(0.05, 0.3)),
                         doc="a strong magnet fixed to the sensor from 20 s to the end: a body-frame "
                             "offset of 10 x the field's norm (a small magnet a few cm away), which "
                             "turns with the sensor, so that no re-learnt reference is the earth's"),
    "magnet-passing": dict(base="slow", fs=100.0, motion=dict(turn=120.0, freq=(0.05, 0.3)),
                           doc="a magnet passed nearby: an earth-frame field of up to 0.7 x the "
                               "field's norm, Hann-shaped from 25 to 35 s"),
    "vibration": dict(base="slow", fs=286.0, motion=dict(turn=90.0),
                      doc="phone-like vibration: 2 s bursts every 8 s of 6 m/s^2 at 47 Hz on "
                          "the accelerometer"),
    "tapping": dict(base="slow", fs=286.0, motion=dict(turn=90.0),
                    doc="taps: 30 per minute, 20 ms spikes of 30 m/s^2 in random directions "
                        "on the accelerometer and 2 rad/s on the gyro"),
}


def failure_scenario(name: str, duration: float = 60.0, seed: int = 0) -> Scenario:
    """The failure scenario ``name`` (one of ``FAILURE_SCENARIOS``): a ``Scenario`` at the
    preset's rate whose readings carry the disturbance (``mag_disturbed`` / ``acc_disturbed``
    mark the samples)."""
    if name not in FAILURE_SCENARIOS:
        raise ValueError(f"unknown failure scenario {name!r}; available: {', '.join(FAILURE_SCENARIOS)}")
    spec = FAILURE_SCENARIOS[name]
    sc = make_scenario(spec["base"], fs=spec["fs"], duration=duration, seed=seed, **spec["motion"])
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
    t, n = sc.t, sc.n
    b = float(np.linalg.norm(sc.field))
    acc_dist = np.zeros(n, bool)
    mag_dist = np.zeros(n, bool)
    if name == "magnet-attached":
        on = (t >= 20.0) & (t < 50.0)
        sc.mag[on] += 0.8 * b * np.array([0.6, -0.48, 0.64])
        mag_dist = on
    elif name == "magnet-stays":
        on = t >= 20.0
        sc.mag[on] += 10.0 * b * np.array([0.6, -0.48, 0.64])
        mag_dist = on
    elif name == "magnet-passing":
        w = np.where((t >= 25.0) & (t < 35.0), np.sin(np.pi * (t - 25.0) / 10.0) ** 2, 0.0)
        d = 0.7 * b * np.array([0.6, -0.48, 0.64])
        sc.mag += quat.rotate_inverse(sc.q_true, w[:, None] * d)
        mag_dist = w > MAG_DISTURBED / 0.7
    elif name == "vibration":
        on = (t % 8.0) < 2.0
        axis = np.array([0.3, 0.9, -0.3]) / np.linalg.norm([0.3, 0.9, -0.3])
        sc.acc += (on * 6.0 * np.sin(2 * np.pi * 47.0 * t))[:, None] * axis
        acc_dist = on
    elif name == "tapping":
        starts = rng.uniform(0.0, max(duration - 0.1, 0.0), int(duration / 2.0))
        for s in starts:
            k = (t >= s) & (t < s + 0.02)
            u = rng.standard_normal(3)
            v = rng.standard_normal(3)
            sc.acc[k] += 30.0 * u / np.linalg.norm(u)
            sc.gyr[k] += 2.0 * v / np.linalg.norm(v)
            acc_dist |= k
    sc.name = name
    sc.acc_disturbed, sc.mag_disturbed = acc_dist, mag_dist
    sc.params = dict(sc.params, failure=name)
    return sc
