"""IMU sensor model: true motion at the physics rate in, what a real IMU reports out.

    import numpy as np
    from fusion import imu

    sensor = imu.IMU("icm20602+qmc5883l", np.random.default_rng(0))
    rec = sensor.simulate(t, gyr_true, acc_true, mag_true)   # arrays at the physics rate
    rec.t, rec.gyr, rec.acc, rec.mag, rec.dt                  # at the IMU rate

    sensor.reset()
    for ...:                                                  # inside a physics loop
        s = sensor.step(gyr_true, acc_true, mag_true, dt)     # None unless a sample is due
        if s is not None:
            q = est.update(s.gyr, s.acc, s.mag)

Inputs, body frame: angular velocity (rad/s), specific force (m/s^2: acceleration minus
gravity, so +9.81 on z when flat and still), the local magnetic field (uT by default, see
``mag_unit``; disturbances are the caller's, ``dipole_field`` helps to make them). The
per-axis error model, the presets and the datasheet source of every number are in
docs/imu.md. Numpy only; every random draw comes from the generator the caller passes.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import Any, NamedTuple, Optional, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike

from fusion._imu import StepKernel as _StepKernel
from fusion.checks import finite_vector, flag, integer, number
from fusion.constants import STANDARD_GRAVITY

__all__ = [
    "SensorSpec", "MagSpec", "Vibration", "IMUSpec", "IMU", "IMURecord", "IMUSample",
    "PRESETS", "preset", "available", "VIBRATION_SEED003",
    "allan_deviation", "allan_summary", "dipole_field", "dipole_moment_for",
    "DEG", "G0", "MG", "UG", "DPH", "GAUSS", "ALLAN_FLOOR",
]

# ---------------------------------------------------------------------------------------
# Units (SI in code): multiply a datasheet figure by these to get SI.
DEG = math.pi / 180.0          # rad per degree
G0 = STANDARD_GRAVITY          # m/s^2 per g (the datasheets' g)
MG = 1e-3 * G0                 # m/s^2 per milli-g
UG = 1e-6 * G0                 # m/s^2 per micro-g
DPH = DEG / 3600.0             # rad/s per deg/h
GAUSS = 100.0                  # uT per gauss
#: Allan-deviation floor of flicker (bias-instability) noise per unit of the IEEE-952
#: bias-instability coefficient B: floor = sqrt(2 ln 2 / pi) B = 0.664 B.
ALLAN_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

# Bias instability is realised as three first-order Gauss-Markov processes with correlation
# times T, T/10, T/100 (T = bias_corr_time_s) and variances _GM_WEIGHTS * floor^2: a single
# Gauss-Markov process gives an Allan hump, not a floor; these weights (least squares on the
# analytic Allan variance) make the Allan deviation flat at the floor within +-1.3 % for
# tau from T/50 to 2 T.
_GM_FRACTIONS = (1.0, 0.1, 0.01)
_GM_WEIGHTS = (2.1150, 1.5115, 2.0526)

_MAG_UNITS = {"uT": 1.0, "nT": 1e-3, "mT": 1e3, "T": 1e6, "G": 100.0, "mG": 0.1}
_SAMPLING = ("hold", "average")
_TOL = 1e-9                    # s: time comparisons (a sample at t and a step at t coincide)
_BLOCK = 512                   # noise rows drawn per block
_CHUNK = 1 << 17               # physics samples per internal batch step


def _check_number(owner, name, value, *, positive=False, allow_inf=False, allow_none=False):
    """fusion.checks.number of a field >= 0 (> 0 with positive), named owner.name."""
    return number(f"{owner}.{name}", value, 0.0, open_low=positive, allow_inf=allow_inf, allow_none=allow_none)


def _check_axes(owner, name, value):
    """A scalar or 3 per-axis values (x, y, z), all finite and >= 0; returned as a float or a tuple."""
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        return _check_number(owner, name, value)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{owner}.{name} must be finite and >= 0, or 3 such numbers (x, y, z), got {value!r}")
    return tuple(float(v) for v in arr)


# ---------------------------------------------------------------------------------------
# Specifications


@dataclass(frozen=True)
class SensorSpec:
    """Error model of one 3-axis inertial sensor, every figure per axis and 1 sigma.

    Units: the sensor's SI unit ``u`` is rad/s for a gyroscope and m/s^2 for an
    accelerometer (``DEG``, ``MG``, ``UG``, ``DPH`` convert datasheet figures).

    noise_density: u/sqrt(Hz), the datasheet's (one-sided) white-noise density. The output
        samples carry white noise of this density whatever the rate: per-sample standard
        deviation ``noise_density * sqrt(rate_hz / 2)`` without low-pass, less with one
        (first-order shaped, see docs/imu.md). Angle (velocity) random walk, the Allan
        deviation at tau = 1 s, is ``arw = noise_density / sqrt(2)``.
    bias_instability: u, the IEEE-952 bias-instability coefficient B: the Allan deviation
        has a floor of ``ALLAN_FLOOR * B = 0.664 B`` for tau from about
        ``bias_corr_time_s / 50`` to ``2 * bias_corr_time_s``.
    bias_corr_time_s: s, the longest correlation time of the bias-instability process.
    bias_random_walk: u/sqrt(s), rate random walk K: Allan deviation ``K sqrt(tau / 3)``.
    bias_turn_on: u, standard deviation of the constant bias drawn at every reset (a number
        or one per axis (x, y, z)); ``bias_turn_on_calibrated`` is the residual after a
        power-on calibration, used by ``IMUSpec.calibrated()``.
    scale_error: 1, standard deviation of each diagonal element of the fixed 3x3 gain
        matrix ``I + E`` drawn at reset (scale-factor tolerance).
    misalignment: 1 (rad), standard deviation of each off-diagonal element of ``E``
        (cross-axis sensitivity plus package misalignment).
    range: u, full scale (+-range); outputs saturate there.
    lsb: u, quantisation step (output = nearest whole number of LSB); 0: not quantised.
    adc_bits: output word length: codes are also limited to [-2^(bits-1), 2^(bits-1) - 1];
        None: symmetric limit at the largest whole LSB within the range.
    lpf_hz: Hz, -3 dB bandwidth of the first-order output low-pass (the chip's DLPF),
        applied at the physics rate before sampling; None: no low-pass.
    noise_bw_hz: Hz, the datasheet's noise bandwidth (NBW) of that DLPF setting, or None.
        Given, the white noise is that of a continuous process of density
        ``noise_density`` and bandwidth NBW point-sampled at the output rate, as the chip's
        output register is: per-sample standard deviation ``noise_density * sqrt(NBW)``,
        correlation exp(-4 NBW / rate_hz) between samples; an NBW above rate_hz / 2
        aliases, and the output's density (``density_at``) exceeds ``noise_density``.
        None: the noise is shaped as if anti-aliased (density ``noise_density`` at any rate).
    scale_error_calibrated, misalignment_calibrated: the residual scale and cross-axis
        errors after a calibration (used by ``IMUSpec.calibrated()``); None: unchanged.
    """

    noise_density: float = 0.0
    bias_instability: float = 0.0
    bias_corr_time_s: float = 100.0
    bias_random_walk: float = 0.0
    bias_turn_on: Union[float, Tuple[float, float, float]] = 0.0
    bias_turn_on_calibrated: Union[float, Tuple[float, float, float]] = 0.0
    scale_error: float = 0.0
    misalignment: float = 0.0
    range: float = math.inf
    lsb: float = 0.0
    adc_bits: Optional[int] = None
    lpf_hz: Optional[float] = None
    noise_bw_hz: Optional[float] = None
    scale_error_calibrated: Optional[float] = None
    misalignment_calibrated: Optional[float] = None

    def __post_init__(self):
        own = type(self).__name__
        object.__setattr__(self, "noise_bw_hz", _check_number(own, "noise_bw_hz", self.noise_bw_hz, positive=True,
                                                              allow_none=True))
        for name in ("scale_error_calibrated", "misalignment_calibrated"):
            object.__setattr__(self, name, _check_number(own, name, getattr(self, name), allow_none=True))
        for name in ("noise_density", "bias_instability", "bias_random_walk", "scale_error",
                     "misalignment", "lsb"):
            object.__setattr__(self, name, _check_number(own, name, getattr(self, name)))
        object.__setattr__(self, "bias_corr_time_s",
                           _check_number(own, "bias_corr_time_s", self.bias_corr_time_s, positive=True))
        object.__setattr__(self, "range", _check_number(own, "range", self.range, positive=True, allow_inf=True))
        object.__setattr__(self, "lpf_hz", _check_number(own, "lpf_hz", self.lpf_hz, positive=True,
                                                         allow_none=True))
        for name in ("bias_turn_on", "bias_turn_on_calibrated"):
            object.__setattr__(self, name, _check_axes(own, name, getattr(self, name)))
        integer(f"{own}.adc_bits", self.adc_bits, 2, 32, allow_none=True)

    @property
    def arw(self):
        """Angle (gyro) or velocity (accelerometer) random walk, u/sqrt(Hz) = u sqrt(s):
        the Allan deviation of the white noise at tau = 1 s, ``noise_density / sqrt(2)``."""
        return self.noise_density / math.sqrt(2.0)

    def density_at(self, rate_hz: float) -> float:
        """u/sqrt(Hz): the one-sided white-noise density of the output at ``rate_hz``
        (``noise_density`` unless an NBW above about rate_hz / 4 aliases into it)."""
        if self.noise_bw_hz is None:
            return self.noise_density
        b = self.noise_bw_hz
        rho = math.exp(-4.0 * b / rate_hz)
        return self.noise_density * math.sqrt(2.0 * b / rate_hz * (1.0 + rho) / (1.0 - rho))

    @property
    def allan_floor(self):
        """u: the Allan-deviation floor of the bias instability, 0.664 * bias_instability."""
        return ALLAN_FLOOR * self.bias_instability

    def code_limits(self) -> tuple[float, float] | None:
        """(most negative, most positive) output code, or None when not quantised."""
        if not self.lsb > 0:
            return None
        n = math.floor(self.range / self.lsb * (1 + 1e-12)) if math.isfinite(self.range) else math.inf
        lo = hi = n
        if self.adc_bits is not None:
            lo = min(n, 2 ** (self.adc_bits - 1))
            hi = min(n, 2 ** (self.adc_bits - 1) - 1)
        return -float(lo), float(hi)

    def allan(self, tau: ArrayLike, rate_hz: float | None = None) -> np.ndarray:
        """Model Allan deviation (u) at averaging times ``tau`` (s) of a static record.

        White noise, bias instability and bias random walk; with ``rate_hz`` the white noise
        at that rate (``density_at``, aliasing included) and the quantisation error as white noise (LSB^2/12 per sample, valid when the noise
        dithers it, i.e. per-sample noise above about LSB/2). The low-pass colouring of the
        white noise (tau of a few samples) is left out.
        """
        tau = np.asarray(tau, dtype=float)
        arw = self.arw if rate_hz is None else self.density_at(rate_hz) / math.sqrt(2.0)
        av = arw ** 2 / tau + self.bias_random_walk ** 2 * tau / 3.0
        floor = self.allan_floor
        if floor > 0:
            for frac, w in zip(_GM_FRACTIONS, _GM_WEIGHTS):
                tc = frac * self.bias_corr_time_s
                x = tau / tc
                av = av + w * floor ** 2 * (tc / tau) ** 2 * (2 * x - 3 + 4 * np.exp(-x) - np.exp(-2 * x))
        if rate_hz is not None and self.lsb > 0:
            av = av + self.lsb ** 2 / 12.0 / (rate_hz * tau)
        return np.sqrt(av)


@dataclass(frozen=True)
class MagSpec:
    """Error model of the 3-axis magnetometer, in uT (the IMU converts from ``mag_unit``).

    Output ``S m + h + noise``, quantised and saturated, read at the IMU rate and refreshed
    at the magnetometer's own output rate (held in between).

    noise_rms: uT, white noise per magnetometer sample (datasheets give rms noise at an ODR).
    range: uT, full scale (+-range).   lsb: uT, quantisation step; 0: not quantised.
    adc_bits: as ``SensorSpec.adc_bits``.
    rate_hz: Hz, magnetometer output data rate; None (or above the IMU rate): every IMU sample.
    hard_iron: uT, standard deviation of the constant offset ``h`` drawn at reset (the
        chip's zero-field offset; a robot's own hard iron belongs in the field the caller
        passes). soft_iron: 1, standard deviation of the symmetric deviation of ``S`` from
        the identity (sensitivity tolerance and soft iron). ``*_calibrated``: the residuals
        after an ellipsoid fit, used by ``IMUSpec.calibrated()``.
    """

    noise_rms: float = 0.0
    range: float = math.inf
    lsb: float = 0.0
    adc_bits: Optional[int] = None
    rate_hz: Optional[float] = None
    hard_iron: float = 0.0
    soft_iron: float = 0.0
    hard_iron_calibrated: float = 0.0
    soft_iron_calibrated: float = 0.0

    def __post_init__(self):
        own = type(self).__name__
        for name in ("noise_rms", "lsb", "hard_iron", "soft_iron", "hard_iron_calibrated",
                     "soft_iron_calibrated"):
            object.__setattr__(self, name, _check_number(own, name, getattr(self, name)))
        object.__setattr__(self, "range", _check_number(own, "range", self.range, positive=True, allow_inf=True))
        object.__setattr__(self, "rate_hz", _check_number(own, "rate_hz", self.rate_hz, positive=True,
                                                          allow_none=True))
        integer(f"{own}.adc_bits", self.adc_bits, 2, 32, allow_none=True)

    code_limits = SensorSpec.code_limits


@dataclass(frozen=True)
class Vibration:
    """Narrow-band motor vibration added to the true motion at the physics rate.

    Per axis, ``n_tones`` sinusoids with frequencies drawn uniformly in [f_low_hz,
    f_high_hz] and random phases (drawn at reset), scaled so that each axis has the given rms:
    ``acc_rms`` (m/s^2) on the accelerometer, ``gyr_rms`` (rad/s) on the gyroscope. Simulated
    before the low-pass and the sampling, so that it aliases as on a real chip (170 Hz read at
    200 Hz appears at 30 Hz); only the low-pass (or ``sampling="average"``) attenuates it.
    Needs a physics rate above twice ``f_high_hz``.
    """

    f_low_hz: float
    f_high_hz: float
    acc_rms: float = 0.0
    gyr_rms: float = 0.0
    n_tones: int = 8

    def __post_init__(self):
        own = type(self).__name__
        lo = _check_number(own, "f_low_hz", self.f_low_hz, positive=True)
        hi = _check_number(own, "f_high_hz", self.f_high_hz, positive=True)
        if hi < lo:
            raise ValueError(f"{own}.f_high_hz must be >= f_low_hz ({lo}), got {hi}")
        object.__setattr__(self, "f_low_hz", lo)
        object.__setattr__(self, "f_high_hz", hi)
        object.__setattr__(self, "acc_rms", _check_number(own, "acc_rms", self.acc_rms))
        object.__setattr__(self, "gyr_rms", _check_number(own, "gyr_rms", self.gyr_rms))
        integer(f"{own}.n_tones", self.n_tones, 1)


#: Motor vibration of the platform of "IIR-EKF, IMU dynamic error suppression" (seed 003): its
#: spectra show the noise in 130-200 Hz. The amplitudes are not in the paper; these (0.2 g, 3 deg/s rms per axis) are assumed, of the
#: order of small brushed/brushless drives on a light frame.
VIBRATION_SEED003 = Vibration(130.0, 200.0, acc_rms=0.2 * G0, gyr_rms=3.0 * DEG)


@dataclass(frozen=True)
class IMUSpec:
    """A whole IMU: gyroscope, accelerometer, optional magnetometer, and how it samples.

    rate_hz: Hz, output data rate.  jitter_s: s, standard deviation of each sample instant
    about its nominal time k / rate_hz (not accumulating; clipped to +-0.45 periods).
    vibration: motor vibration (``Vibration``) or None.  sampling: "hold" (the low-passed
    signal is sampled and held, as InvenSense chips do: content above the Nyquist rate
    aliases) or "average" (each output is the mean over its period, as an IMU that
    integrates internally, e.g. Xsens' strapdown integration, reports).
    """

    name: str
    gyro: SensorSpec
    acc: SensorSpec
    mag: Optional[MagSpec]
    rate_hz: float
    jitter_s: float = 0.0
    vibration: Optional[Vibration] = None
    sampling: str = "hold"

    def __post_init__(self):
        own = type(self).__name__
        if not isinstance(self.gyro, SensorSpec):
            raise ValueError(f"{own}.gyro must be a SensorSpec, got {type(self.gyro).__name__}")
        if not isinstance(self.acc, SensorSpec):
            raise ValueError(f"{own}.acc must be a SensorSpec, got {type(self.acc).__name__}")
        if self.mag is not None and not isinstance(self.mag, MagSpec):
            raise ValueError(f"{own}.mag must be a MagSpec or None, got {type(self.mag).__name__}")
        if self.vibration is not None and not isinstance(self.vibration, Vibration):
            raise ValueError(f"{own}.vibration must be a Vibration or None, got {type(self.vibration).__name__}")
        rate = _check_number(own, "rate_hz", self.rate_hz, positive=True)
        object.__setattr__(self, "rate_hz", rate)
        jit = _check_number(own, "jitter_s", self.jitter_s)
        if jit > 0.2 / rate:
            raise ValueError(f"{own}.jitter_s must be <= 0.2 / rate_hz = {0.2 / rate:g} s, got {jit!r}")
        object.__setattr__(self, "jitter_s", jit)
        if self.sampling not in _SAMPLING:
            raise ValueError(f"{own}.sampling must be one of {', '.join(_SAMPLING)}, got {self.sampling!r}")

    def replace(self, **changes: Any) -> IMUSpec:
        """A copy with some fields changed, e.g. ``spec.replace(rate_hz=100.0)``."""
        return replace(self, **changes)

    def calibrated(self) -> IMUSpec:
        """A copy with the residuals of a power-on calibration in place of the raw part's
        turn-on biases (gyro static average, accelerometer six-position calibration) and of
        the magnetometer's hard and soft iron (ellipsoid fit), and the scale and cross-axis
        residuals where the spec gives them (``scale_error_calibrated``,
        ``misalignment_calibrated``; else the factory tolerances stay)."""
        def cal(sp):
            ch = {"bias_turn_on": sp.bias_turn_on_calibrated}
            if sp.scale_error_calibrated is not None:
                ch["scale_error"] = sp.scale_error_calibrated
            if sp.misalignment_calibrated is not None:
                ch["misalignment"] = sp.misalignment_calibrated
            return replace(sp, **ch)
        g, a = cal(self.gyro), cal(self.acc)
        m = self.mag
        if m is not None:
            m = replace(m, hard_iron=m.hard_iron_calibrated, soft_iron=m.soft_iron_calibrated)
        name = self.name if self.name.endswith("(calibrated)") else f"{self.name} (calibrated)"
        return replace(self, name=name, gyro=g, acc=a, mag=m)


# ---------------------------------------------------------------------------------------
# Presets (sources and assumptions: docs/imu.md, one table per preset)


def _rrw(bias_instability, corr_time_s):
    """Assumed rate random walk: its Allan line K sqrt(tau / 3) reaches the bias floor at
    tau = 10 corr_time_s, five times past the end of the flat floor."""
    return ALLAN_FLOOR * bias_instability * math.sqrt(3.0 / (10.0 * corr_time_s))


# The MTi 10-series datasheet's in-run bias stability (gyro 18 deg/h, accelerometer 40 ug) is,
# as datasheets quote it, the minimum of the Allan deviation: the coefficient B is that / 0.664
_MTI_GYRO_BI = 18.0 * DPH / ALLAN_FLOOR
_MTI_ACC_BI = 40.0 * UG / ALLAN_FLOOR
_INV_GYRO_BI = 10.0 * DPH       # assumed bias instability of InvenSense consumer gyros
_INV_ACC_BI = 0.1 * MG          # assumed bias instability of InvenSense consumer accelerometers
# Noise bandwidths of the register-default DLPF (gyro DLPF_CFG = 0: 250 Hz 3-dB, accelerometer
# A_DLPF_CFG = 0: 218.1 Hz 3-dB): ICM-20602 data sheet's DLPF tables (NBW 306.6 Hz and
# 235.0 Hz); the MPU-9250's register map gives the same 3-dB bandwidths and delays, no NBW.
_INV_GYRO_NBW = 306.6
_INV_ACC_NBW = 235.0
# DLPF_CFG = 6 (5 Hz 3-dB) has no NBW in the MPU-6050's documents: a first-order filter's,
# (pi / 2) x 5 Hz. The register holds point samples of the filtered signal (read at 10 Hz),
# so the per-sample noise is noise_density sqrt(NBW), aliasing included, as the NBW presets'
_MPU6050_DLPF6_NBW = 0.5 * math.pi * 5.0
# Residual scale and cross-axis errors after a user calibration of a consumer MEMS IMU
# (accelerometer: multi-position fit of gains and non-orthogonality; gyro: rotations against
# the calibrated accelerometer), after Tedaldi, Pretto and Menegatti, "A robust and easy to
# implement method for IMU calibration without external equipments" (ICRA 2014): a few
# 0.1 % of scale and about 0.1 deg of axis error remain. docs/imu.md.
_CAL_ACC = dict(scale_error_calibrated=0.003, misalignment_calibrated=0.002)
_CAL_GYRO = dict(scale_error_calibrated=0.005, misalignment_calibrated=0.003)

def _invensense_gyro(**kw):
    """An InvenSense MEMS gyro of the presets: the family's bias instability and its random walk
    (300 s correlation), a 16-bit ADC, the calibration residuals; ``kw`` the part's own values."""
    return SensorSpec(bias_instability=_INV_GYRO_BI, bias_corr_time_s=300.0, bias_random_walk=_rrw(_INV_GYRO_BI, 300.0),
                      adc_bits=16, **_CAL_GYRO, **kw)


def _invensense_acc(**kw):
    """An InvenSense MEMS accelerometer of the presets, as ``_invensense_gyro``."""
    return SensorSpec(bias_instability=_INV_ACC_BI, bias_corr_time_s=300.0, bias_random_walk=_rrw(_INV_ACC_BI, 300.0),
                      adc_bits=16, **_CAL_ACC, **kw)


PRESETS = {
    # A perfect sensor: returns the true signals sampled at the IMU rate.
    "ideal": IMUSpec("ideal", gyro=SensorSpec(), acc=SensorSpec(), mag=MagSpec(), rate_hz=100.0),

    # "EKF attitude estimation for a spherical robot" (seed 000): MPU6050 + MAG3110, the robot's
    # 10 Hz experiment. MPU-6000/6050 PS rev 3.4, register defaults FS_SEL = AFS_SEL = 0;
    # DLPF_CFG = 6 (5 Hz) assumed for 10 Hz output.
    "mpu6050+mag3110": IMUSpec(
        "mpu6050+mag3110",
        gyro=_invensense_gyro(noise_density=0.005 * DEG, bias_turn_on=20.0 * DEG, bias_turn_on_calibrated=0.8 * DEG,
                              scale_error=0.03, misalignment=0.02, range=250.0 * DEG, lsb=DEG / 131.0, lpf_hz=5.0,
                              noise_bw_hz=_MPU6050_DLPF6_NBW),
        acc=_invensense_acc(noise_density=400.0 * UG, bias_turn_on=(50.0 * MG, 50.0 * MG, 80.0 * MG),
                            bias_turn_on_calibrated=(2.5 * MG, 2.5 * MG, 4.3 * MG), scale_error=0.03,
                            misalignment=0.02, range=2.0 * G0, lsb=G0 / 16384.0, lpf_hz=5.0,
                            noise_bw_hz=_MPU6050_DLPF6_NBW),
        mag=MagSpec(noise_rms=0.25, range=1000.0, lsb=0.1, adc_bits=16, rate_hz=80.0, hard_iron=100.0,
                    soft_iron=0.02, hard_iron_calibrated=1.0, soft_iron_calibrated=0.01),
        rate_hz=10.0, jitter_s=20e-6),

    # "Adaptive EKF from predicted measurements, for arm attitude" (seed 001): Xsens MTi-10 at
    # 256 Hz (MTi 10-series datasheet; MTi-300 datasheet of the same generation for bandwidths
    # and magnetometer). Outputs are floats (no ADC words);
    # strapdown integration inside: "average" sampling.
    "mti10": IMUSpec(
        "mti10",
        gyro=SensorSpec(noise_density=0.03 * DEG, bias_instability=_MTI_GYRO_BI, bias_corr_time_s=1000.0,
                        bias_random_walk=_rrw(_MTI_GYRO_BI, 1000.0), bias_turn_on=0.5 * DEG,
                        bias_turn_on_calibrated=0.05 * DEG, scale_error=0.001, misalignment=0.1 * DEG,
                        range=450.0 * DEG),
        acc=SensorSpec(noise_density=80.0 * UG, bias_instability=_MTI_ACC_BI, bias_corr_time_s=1000.0,
                       bias_random_walk=_rrw(_MTI_ACC_BI, 1000.0), bias_turn_on=5.0 * MG,
                       bias_turn_on_calibrated=0.5 * MG,
                       scale_error=0.001, misalignment=0.1 * DEG, range=20.0 * G0),
        mag=MagSpec(noise_rms=0.05, range=8.0 * GAUSS, lsb=0.025, hard_iron=0.5, soft_iron=0.005,
                    hard_iron_calibrated=0.5, soft_iron_calibrated=0.005),
        rate_hz=256.0, jitter_s=10e-6, sampling="average"),

    # "IIR-EKF, IMU dynamic error suppression" (seed 003): ICM20602 (4096 LSB/g, +-8 g;
    # 16.4 LSB/(deg/s), +-2000 deg/s, as the paper's table 1) + QMC5883L, 200 Hz. ICM-20602
    # DS-000176 v1.0; DLPF register defaults (gyro 250 Hz, accelerometer 218.1 Hz): the paper
    # gives no setting.
    "icm20602+qmc5883l": IMUSpec(
        "icm20602+qmc5883l",
        gyro=_invensense_gyro(noise_density=0.004 * DEG, bias_turn_on=1.0 * DEG, bias_turn_on_calibrated=0.05 * DEG,
                              scale_error=0.01, misalignment=0.02, range=2000.0 * DEG, lsb=DEG / 16.4, lpf_hz=250.0,
                              noise_bw_hz=_INV_GYRO_NBW),
        acc=_invensense_acc(noise_density=100.0 * UG, bias_turn_on=40.0 * MG,
                            bias_turn_on_calibrated=(2.5 * MG, 2.5 * MG, 5.0 * MG), scale_error=0.01,
                            misalignment=0.02, range=8.0 * G0, lsb=G0 / 4096.0, lpf_hz=218.1, noise_bw_hz=_INV_ACC_NBW),
        mag=MagSpec(noise_rms=0.2, range=8.0 * GAUSS, lsb=GAUSS / 3000.0, adc_bits=16, rate_hz=200.0,
                    hard_iron=10.0, soft_iron=0.03, hard_iron_calibrated=1.0, soft_iron_calibrated=0.01),
        rate_hz=200.0, jitter_s=20e-6),

    # "Attitude-angle solution for a mobile robot" (seed 004): MPU9250 (with its AK8963), 500 Hz.
    # MPU-9250 PS rev 1.0/1.1, register defaults: +-250 deg/s, +-2 g, DLPF gyro 250 Hz /
    # accelerometer 218.1 Hz, AK8963 14-bit (0.6 uT/LSB) at its 100 Hz continuous mode.
    "mpu9250": IMUSpec(
        "mpu9250",
        gyro=_invensense_gyro(noise_density=0.01 * DEG, bias_turn_on=5.0 * DEG, bias_turn_on_calibrated=0.3 * DEG,
                              scale_error=0.03, misalignment=0.02, range=250.0 * DEG, lsb=DEG / 131.0, lpf_hz=250.0,
                              noise_bw_hz=_INV_GYRO_NBW),
        acc=_invensense_acc(noise_density=300.0 * UG, bias_turn_on=(60.0 * MG, 60.0 * MG, 80.0 * MG),
                            bias_turn_on_calibrated=3.0 * MG, scale_error=0.03, misalignment=0.02,
                            range=2.0 * G0, lsb=G0 / 16384.0, lpf_hz=218.1, noise_bw_hz=_INV_ACC_NBW),
        mag=MagSpec(noise_rms=0.6, range=4800.0, lsb=0.6, adc_bits=14, rate_hz=100.0, hard_iron=75.0,
                    soft_iron=0.03, hard_iron_calibrated=1.0, soft_iron_calibrated=0.01),
        rate_hz=500.0, jitter_s=20e-6),
}


def available() -> list[str]:
    """Preset names accepted by ``preset()`` and ``IMU()``, in a stable order."""
    return list(PRESETS)


def preset(name: str, calibrated: bool = False) -> IMUSpec:
    """The ``IMUSpec`` called ``name`` (see ``available()``); ``calibrated=True`` gives
    ``spec.calibrated()``: residual biases and iron after a power-on calibration."""
    try:
        spec = PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown IMU preset {name!r}; available: {', '.join(available())}") from None
    return spec.calibrated() if flag("calibrated", calibrated) else spec


# ---------------------------------------------------------------------------------------
# Records


class IMUSample(NamedTuple):
    """One IMU sample from ``IMU.step``: time (s, since the first step after reset), gyro
    (rad/s), accelerometer (m/s^2), magnetometer (``mag_unit``, or None), dt (s, since the
    previous sample; 1/rate for the first), index (the physics step it was read at)."""

    t: float
    gyr: np.ndarray
    acc: np.ndarray
    mag: Optional[np.ndarray]
    dt: float
    index: int


@dataclass
class IMURecord:
    """IMU output of ``IMU.simulate``, at the IMU rate.

    t (M,): sample instants (s, same clock as the input ``t``, jitter included);
    gyr, acc (M, 3): rad/s, m/s^2; mag (M, 3) in ``mag_unit``, or None;
    dt (M,): seconds since the previous sample (1/fs for the very first after reset);
    index (M,): row of the input arrays each sample was read at (for aligning a reference);
    fs: nominal rate (Hz).
    """

    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: Optional[np.ndarray]
    dt: np.ndarray
    index: np.ndarray
    fs: float

    def __len__(self):
        return len(self.t)


# ---------------------------------------------------------------------------------------
# Linear recurrences y[k] = a y[k-1] + b[k] along axis 0, vectorised


def _ar1(a, b, y0):
    """y[k] = a * y[k-1] + b[k] (k = 0..n-1, y[-1] = y0), constant 0 <= a < 1; b is (n, m)."""
    n = b.shape[0]
    if n == 0 or a == 0.0:
        return np.array(b, dtype=float, copy=True)
    span = int(math.log(1e4) / -math.log(a))          # a^-span <= 1e4: closed form stays accurate
    if span >= 32:                                    # a near 1: closed form in blocks
        y = np.empty_like(b, dtype=float)
        prev = np.asarray(y0, dtype=float)
        span = min(span, n)
        i = np.arange(span, dtype=float)
        up, down = a ** -i, a ** i
        for s in range(0, n, span):
            m = min(span, n - s)
            c = np.cumsum(b[s:s + m] * up[:m, None], axis=0)
            y[s:s + m] = (a * prev + c) * down[:m, None]
            prev = y[s + m - 1]
        return y
    y = np.array(b, dtype=float, copy=True)           # a small: doubling (Kogge-Stone) scan
    y[0] = a * y0 + y[0]
    p, s = a, 1
    while s < n and p > 1e-30:
        y[s:] += p * y[:-s]
        p *= p
        s *= 2
    return y


def _ar1_var(a, b, y0):
    """As _ar1 with a per-row coefficient a (n,) in [0, 1)."""
    n = b.shape[0]
    y = np.array(b, dtype=float, copy=True)
    if n == 0:
        return y
    y[0] = a[0] * y0 + y[0]
    A = np.array(a, dtype=float, copy=True)[:, None]
    s = 1
    while s < n:
        y[s:] += A[s:] * y[:-s]
        A[s:] *= A[:-s]
        if A[s:].max(initial=0.0) < 1e-30:
            break
        s *= 2
    return y


# ---------------------------------------------------------------------------------------
# The sensor


def _channel_params(spec, fs):
    """Per-axis process parameters of one inertial sensor at output rate fs (see SensorSpec)."""
    dt = 1.0 / fs
    floor = spec.allan_floor
    gm_rho = [math.exp(-dt / (f * spec.bias_corr_time_s)) for f in _GM_FRACTIONS]
    gm_sig = [math.sqrt(w) * floor for w in _GM_WEIGHTS]
    gm_c = [s_ * math.sqrt(1.0 - r * r) for s_, r in zip(gm_sig, gm_rho)]
    # White noise: one-sided density noise_density at the output whatever the rate; a low-pass
    # of (equivalent noise) bandwidth B shapes it as an AR(1) with rho = exp(-4 B / fs), the
    # sampled first-order process whose noise bandwidth is B (docs/imu.md); given its 3-dB
    # corner fc alone, B = (pi / 2) fc, rho = exp(-2 pi fc / fs), the signal path's own pole.
    if spec.noise_bw_hz is not None:
        # the datasheet's NBW: the point-sampled first-order process (aliasing included)
        wn_rho = math.exp(-4.0 * spec.noise_bw_hz / fs)
        wn_sig = spec.noise_density * math.sqrt(spec.noise_bw_hz)
    else:
        wn_rho = math.exp(-2.0 * math.pi * spec.lpf_hz / fs) if spec.lpf_hz is not None else 0.0
        wn_sig = spec.noise_density * math.sqrt(0.5 * fs * (1.0 - wn_rho) / (1.0 + wn_rho))
    return dict(gm_rho=gm_rho, gm_sig=gm_sig, gm_c=gm_c, rw_c=spec.bias_random_walk * math.sqrt(dt),
                wn_rho=wn_rho, wn_sig=wn_sig, wn_c=wn_sig * math.sqrt(1.0 - wn_rho * wn_rho))


def _quantiser(spec):
    """(lsb, lo, hi, active): output step and limits; lsb 0 means clip only (if active)."""
    lim = spec.code_limits()
    if lim is not None:
        return spec.lsb, lim[0], lim[1], True
    return 0.0, -spec.range, spec.range, math.isfinite(spec.range)


class IMU:
    """The sensor model: ``IMU(spec_or_preset_name, rng, physics_rate_hz=None, mag_unit="uT")``.

    spec_or_preset_name: an ``IMUSpec`` or a preset name (``available()``).
    rng: a ``numpy.random.Generator``; the IMU draws one seed from it at construction (so the
    caller's generator advances by the same amount however the IMU is used) and all its
    randomness from generators seeded by it: the same generator state gives the same output.
    physics_rate_hz: rate of the true motion (Hz); the default ``dt`` of ``step`` and a check on
    the ``t`` of ``simulate``; None: taken from the input.
    mag_unit: unit of the magnetic field in and out: "uT", "nT", "mT", "T", "G" or "mG".
    compiled: True (default): ``step`` runs on the C kernel (fusion/_imu.pyx), the same
    numbers as this module's Python ``step``, which False selects (the reference).

    ``simulate`` (batch) and ``step`` (streaming) share one state and give the same numbers
    (to floating-point rounding) for the same generator: a record can be produced in chunks,
    or by any mix of the two. ``reset()`` starts a new record and redraws the constants.
    """

    def __init__(self, spec_or_preset_name: IMUSpec | str, rng: np.random.Generator,
                 physics_rate_hz: float | None = None, mag_unit: str = "uT", compiled: bool = True) -> None:
        if isinstance(spec_or_preset_name, IMUSpec):
            spec = spec_or_preset_name
        elif isinstance(spec_or_preset_name, str):
            spec = preset(spec_or_preset_name)
        else:
            raise ValueError("spec_or_preset_name must be an IMUSpec or one of the preset names "
                             f"{', '.join(available())}; got {type(spec_or_preset_name).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise ValueError("rng must be a numpy.random.Generator (e.g. numpy.random.default_rng(seed)), "
                             f"got {type(rng).__name__}")
        if physics_rate_hz is not None:
            physics_rate_hz = _check_number("IMU", "physics_rate_hz", physics_rate_hz, positive=True)
            if physics_rate_hz < spec.rate_hz * (1 - 1e-9):
                raise ValueError(f"physics_rate_hz must be >= the IMU rate ({spec.rate_hz} Hz), "
                                 f"got {physics_rate_hz}")
        if mag_unit not in _MAG_UNITS:
            raise ValueError(f"mag_unit must be one of {', '.join(_MAG_UNITS)}, got {mag_unit!r}")
        if not isinstance(compiled, (bool, np.bool_)):
            raise ValueError(f"compiled must be True or False, got {compiled!r}")
        self._kernel = _StepKernel() if compiled else None
        self._spec = spec
        self._fs = spec.rate_hz
        self._physics_rate = physics_rate_hz
        self._mag_unit = mag_unit
        self._mag_scale = _MAG_UNITS[mag_unit]
        self._hold = spec.sampling == "hold"
        pg, pa = _channel_params(spec.gyro, self._fs), _channel_params(spec.acc, self._fs)
        # Process state, 30 numbers: bias-instability GM j = 0, 1, 2 (6 each: gyro x y z, acc
        # x y z), bias random walk (6), white noise (6). Each is updated per sample as
        # s <- R s + C e with the standard normal e of the same column (+1) of the noise row.
        R, C, sig = [], [], []
        for j in range(3):
            R += [pg["gm_rho"][j]] * 3 + [pa["gm_rho"][j]] * 3
            C += [pg["gm_c"][j]] * 3 + [pa["gm_c"][j]] * 3
            sig += [pg["gm_sig"][j]] * 3 + [pa["gm_sig"][j]] * 3
        R += [1.0] * 6
        C += [pg["rw_c"]] * 3 + [pa["rw_c"]] * 3
        sig += [0.0] * 6
        R += [pg["wn_rho"]] * 3 + [pa["wn_rho"]] * 3
        C += [pg["wn_c"]] * 3 + [pa["wn_c"]] * 3
        sig += [pg["wn_sig"]] * 3 + [pa["wn_sig"]] * 3
        self._R, self._C, self._sig0 = R, C, np.array(sig)
        self._quant = (_quantiser(spec.gyro), _quantiser(spec.acc))
        self._quant6 = [q for q in self._quant for _ in range(3)]    # per channel, for _output_one
        ms = spec.mag
        if ms is not None:
            lim = ms.code_limits()
            self._mlsb = ms.lsb if lim is not None else 0.0
            self._mlo, self._mhi = lim if lim is not None else (-ms.range, ms.range)
            self._mclip = lim is not None or math.isfinite(ms.range)
            self._mrate = ms.rate_hz if (ms.rate_hz is not None and ms.rate_hz < self._fs) else None
        self._vib = spec.vibration
        self._ncols = 34                   # jitter, GM 3 x 6, RW 6, white 6, mag noise 3
        self._seed(rng)
        self.reset()

    def __getstate__(self):
        """Copy and pickle: the streaming state back from the kernel, and a fresh kernel
        (loaded from that state at the next step)."""
        k = self._kernel
        if k is not None and k.live:
            k.store(self)
        state = self.__dict__.copy()
        state["_kernel"] = k is not None
        return state

    def __setstate__(self, state):
        state = dict(state)
        compiled = state.pop("_kernel")
        self.__dict__.update(state)
        self._kernel = _StepKernel() if compiled else None

    # -- randomness ---------------------------------------------------------------------
    def _seed(self, rng):
        seed = rng.integers(0, 2 ** 63 - 1, size=4, dtype=np.int64)
        ss = np.random.SeedSequence([int(s) for s in seed])
        main, vib, records = ss.spawn(3)
        self._generators(main, vib)
        # a reset without rng after the first record draws from generators of its own,
        # spawned per record: what the record before consumed (batch peeks whole noise
        # blocks beyond its end, streaming does not) cannot change the next one's draws
        self._records = records
        self._fresh = True

    def _generators(self, main, vib):
        """The noise and vibration generators from their seed sequences."""
        self._gen = np.random.Generator(np.random.PCG64(main))
        self._gen_vib = np.random.Generator(np.random.PCG64(vib))

    def _peek(self, n):
        """The next n noise rows (n, ncols) without consuming them."""
        need = self._pos + n
        if need > self._buf.shape[0]:
            extra = -(-(need - self._buf.shape[0]) // _BLOCK)
            # whole blocks of _BLOCK rows: one draw of several blocks gives the same numbers as
            # several draws of one, so batch and streaming consume the generator alike
            new = self._gen.standard_normal((extra * _BLOCK, self._ncols))
            self._buf = np.concatenate([self._buf[self._pos:], new], axis=0) if self._pos < self._buf.shape[0] else new
            self._pos = 0
        return self._buf[self._pos:self._pos + n]

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Start a new record: redraw the turn-on biases, gain matrices, hard and soft iron,
        vibration tones and initial bias states; the next ``step`` is time 0. With ``rng``
        (a Generator) the IMU is reseeded from it first, as at construction."""
        if rng is not None:
            if not isinstance(rng, np.random.Generator):
                raise ValueError(f"rng must be a numpy.random.Generator or None, got {type(rng).__name__}")
            self._seed(rng)
        elif not self._fresh:
            self._generators(*self._records.spawn(1)[0].spawn(2))
        self._fresh = False
        if self._kernel is not None:
            self._kernel.live = False       # reloaded from the state below at the next step
        c = self._gen.standard_normal(61)
        self._draw_constants(c)
        self._buf = np.empty((0, self._ncols))
        self._pos = 0
        if self._vib is not None:
            self._draw_vibration()
        self._reset_clock(c[0])

    def _draw_constants(self, c):
        """The record's constants from the normal draws c (61,): gain matrices, turn-on biases,
        the bias processes' stationary start, hard and soft iron."""
        self._M, self._ident = [], []
        for i, sp in enumerate((self._spec.gyro, self._spec.acc)):
            z = c[1 + 9 * i:10 + 9 * i].reshape(3, 3)
            E = z * sp.misalignment
            E[np.diag_indices(3)] = z.diagonal() * sp.scale_error
            self._M.append(np.eye(3) + E)
            self._ident.append(not E.any())
        self._Ml = [m.tolist() for m in self._M]
        self._b0 = c[19:25] * np.concatenate([np.broadcast_to(np.asarray(self._spec.gyro.bias_turn_on, float), 3),
                                              np.broadcast_to(np.asarray(self._spec.acc.bias_turn_on, float), 3)])
        self._b0l = self._b0.tolist()
        st = np.zeros(30)
        st[0:18] = c[25:43] * self._sig0[0:18]       # stationary start of the GM processes
        st[24:30] = c[43:49] * self._sig0[24:30]     # and of the (possibly low-passed) white noise
        self._S = st.tolist()
        if self._spec.mag is not None:
            ms = self._spec.mag
            self._mag_h = c[49:52] * ms.hard_iron
            e = c[52:61].reshape(3, 3)
            self._mag_S = np.eye(3) + ms.soft_iron * 0.5 * (e + e.T)
            self._mag_ident = ms.soft_iron == 0.0
            self._mag_Sl = self._mag_S.tolist()
            self._mag_hl = self._mag_h.tolist()

    def _draw_vibration(self):
        """The vibration tones' frequencies, phases and amplitudes (rows gyro x y z, acc x y z)."""
        v = self._vib
        n = 1 if v.f_high_hz == v.f_low_hz else v.n_tones
        u = self._gen_vib.random((2, 6, n))
        self._vib_w = 2 * math.pi * (v.f_low_hz + (v.f_high_hz - v.f_low_hz) * u[0])   # (6, n) rad/s
        self._vib_phi = 2 * math.pi * u[1]
        amp = math.sqrt(2.0 / n)
        self._vib_amp = np.array([v.gyr_rms * amp] * 3 + [v.acc_rms * amp] * 3)
        self._vib_buf = np.empty((6, n))
        self._vib_out = np.empty(6)

    def _reset_clock(self, jitter0):
        """The sampling and filter state of a new record (its first sample's jitter draw)."""
        self._k = 0                                  # index of the next sample
        self._T_next = self._jitter(0, jitter0)      # its instant (s, since origin)
        self._T_prev = None                          # instant of the last sample
        self._origin = None                          # clock origin (input t of the first step)
        self._steps = 0                              # physics steps since reset
        self._tau_last = None                        # time of the last physics step
        self._y_last = np.zeros(9)                   # low-passed signal at the last step
        self._y_prev = np.zeros(9)                   # (streaming scratch)
        self._x = np.zeros(9)
        self._tmp = np.zeros(9)
        self._sum = np.zeros(9)                      # "average" sampling: running sum ...
        self._cnt = 0                                # ... and count since the last sample
        self._mag_held = None                        # last magnetometer reading (uT)
        self._mag_on = None                          # whether this record has a magnetometer input
        self._lpf_dt = None
        self._lpf_a = np.zeros(9)
        self._lpf_b = np.ones(9)
        self._mag_slot_last = None

    def _jitter(self, k, z):
        j = self._spec.jitter_s * z
        lim = 0.45 / self._fs
        j = -lim if j < -lim else (lim if j > lim else j)
        return k / self._fs + j

    # -- properties ---------------------------------------------------------------------
    @property
    def spec(self):
        """The ``IMUSpec`` this IMU simulates."""
        return self._spec

    @property
    def fs(self):
        """Nominal output rate (Hz)."""
        return self._fs

    @property
    def mag_unit(self):
        return self._mag_unit

    @property
    def constants(self):
        """The constants drawn at the last reset: gain matrices (I + scale + misalignment),
        turn-on biases, magnetometer soft-iron matrix and hard-iron offset (in ``mag_unit``),
        vibration tone frequencies (Hz, rows gyro x y z, acc x y z)."""
        out = {"gyro_matrix": self._M[0].copy(), "gyro_bias": self._b0[0:3].copy(),
               "acc_matrix": self._M[1].copy(), "acc_bias": self._b0[3:6].copy()}
        if self._spec.mag is not None:
            out["mag_soft_iron"] = self._mag_S.copy()
            out["mag_hard_iron"] = self._mag_h / self._mag_scale
        if self._vib is not None:
            out["vibration_hz"] = self._vib_w / (2 * math.pi)
        return out

    # -- low-pass coefficients -------------------------------------------------------------
    def _lpf_coeffs(self, dt):
        """(a, b) per channel for a step dt: gyro and accelerometer low-pass, magnetometer none."""
        a = np.zeros(9)
        for i, sp in enumerate((self._spec.gyro, self._spec.acc)):
            f = sp.lpf_hz
            if f is not None:
                a[3 * i:3 * i + 3] = math.exp(-2.0 * math.pi * f * dt)
        return a, 1.0 - a

    # -- the output stage, shared by simulate and step -----------------------------------------
    def _output(self, v, rows):
        """Gyro and accelerometer outputs (n, 6) for sampled values v (n, 6), noise rows (n, ncols)."""
        out = np.empty_like(v)
        for i in (0, 1):
            x = v[:, 3 * i:3 * i + 3]
            if self._ident[i]:
                out[:, 3 * i:3 * i + 3] = x
            else:
                m = self._Ml[i]
                for r in range(3):
                    out[:, 3 * i + r] = m[r][0] * x[:, 0] + m[r][1] * x[:, 1] + m[r][2] * x[:, 2]
        S0 = np.array(self._S)
        last = np.empty(30)
        for i in (0, 1):
            parts = []
            for c0 in (3 * i, 6 + 3 * i, 12 + 3 * i, 18 + 3 * i, 24 + 3 * i):    # GM 0 1 2, RW, white
                cols = slice(c0, c0 + 3)
                b = rows[:, 1 + c0:4 + c0] * np.array(self._C[cols])
                if self._R[c0] == 1.0:
                    p = S0[cols] + np.cumsum(b, axis=0)
                else:
                    p = _ar1(self._R[c0], b, S0[cols])
                last[cols] = p[-1]
                parts.append(p)
            g0, g1, g2, rw, wn = parts
            bias = self._b0[3 * i:3 * i + 3] + g0 + g1 + g2
            out[:, 3 * i:3 * i + 3] = out[:, 3 * i:3 * i + 3] + (bias + rw) + wn
        self._S = last.tolist()
        for i, (lsb, lo, hi, active) in enumerate(self._quant):
            sl = slice(3 * i, 3 * i + 3)
            if lsb > 0:
                out[:, sl] = np.clip(np.rint(out[:, sl] / lsb), lo, hi) * lsb
            elif active:
                out[:, sl] = np.clip(out[:, sl], lo, hi)
        return out

    def _output_one(self, v, row):
        """As _output for one sample (v, row: lists of floats), with the same arithmetic in
        plain floats: returns a list of 6."""
        S, R, C = self._S, self._R, self._C
        for i in range(30):
            S[i] = R[i] * S[i] + row[1 + i] * C[i]
        res = [0.0] * 6
        b0, quant = self._b0l, self._quant6
        for i in (0, 1):
            k = 3 * i
            x0, x1, x2 = v[k], v[k + 1], v[k + 2]
            if self._ident[i]:
                out = (x0, x1, x2)
            else:
                m = self._Ml[i]
                out = (m[0][0] * x0 + m[0][1] * x1 + m[0][2] * x2, m[1][0] * x0 + m[1][1] * x1 + m[1][2] * x2,
                       m[2][0] * x0 + m[2][1] * x1 + m[2][2] * x2)
            for r in range(3):
                c = k + r
                y = out[r] + ((b0[c] + S[c] + S[6 + c] + S[12 + c]) + S[18 + c]) + S[24 + c]
                lsb, lo, hi, active = quant[c]
                if lsb > 0:
                    y = round(y / lsb)
                    y = (lo if y < lo else (hi if y > hi else y)) * lsb
                elif active:
                    y = lo if y < lo else (hi if y > hi else y)
                res[c] = y
        return res

    def _mag_output(self, v, rows):
        """Magnetometer readings (uT) for true fields v (n, 3) and noise rows (n, 3)."""
        ms = self._spec.mag
        if self._mag_ident:
            out = v
        else:
            m = self._mag_Sl
            out = np.stack([m[r][0] * v[:, 0] + m[r][1] * v[:, 1] + m[r][2] * v[:, 2] for r in range(3)], axis=1)
        out = out + self._mag_h + rows * ms.noise_rms
        if self._mlsb > 0:
            out = np.clip(np.rint(out / self._mlsb), self._mlo, self._mhi) * self._mlsb
        elif self._mclip:
            out = np.clip(out, self._mlo, self._mhi)
        return out

    def _mag_output_one(self, v, row):
        """As _mag_output for one sample (lists of 3 floats, v in uT); returns a list."""
        x0, x1, x2 = v
        if self._mag_ident:
            out = (x0, x1, x2)
        else:
            m = self._mag_Sl
            out = (m[0][0] * x0 + m[0][1] * x1 + m[0][2] * x2, m[1][0] * x0 + m[1][1] * x1 + m[1][2] * x2,
                   m[2][0] * x0 + m[2][1] * x1 + m[2][2] * x2)
        h, sd, lsb, lo, hi = self._mag_hl, self._spec.mag.noise_rms, self._mlsb, self._mlo, self._mhi
        res = []
        for r in range(3):
            y = out[r] + h[r] + row[r] * sd
            if lsb > 0:
                y = round(y / lsb)
                y = (lo if y < lo else (hi if y > hi else y)) * lsb
            elif self._mclip:
                y = lo if y < lo else (hi if y > hi else y)
            res.append(y)
        return res

    def _mag_slots(self, T):
        """Index of the magnetometer output period each sample instant falls in."""
        return np.floor(np.asarray(T) * self._mrate + _TOL)

    def _emit(self, T, vals, rows):
        """Outputs for samples at instants T (n,) with sampled values vals (n, 9), rows (n, ncols).
        Returns gyr, acc, mag (uT or None) and updates the sample bookkeeping."""
        ga = self._output(vals[:, 0:6], rows)
        gyr, acc = ga[:, 0:3], ga[:, 3:6]
        mag = None
        if self._mag_on and self._spec.mag is not None:
            m = self._mag_output(vals[:, 6:9] * self._mag_scale, rows[:, 31:34])
            if self._mrate is not None:
                slot = self._mag_slots(T)
                prev = np.concatenate([[np.nan if self._mag_slot_last is None else self._mag_slot_last], slot[:-1]])
                new = slot != prev
                idx = np.maximum.accumulate(np.where(new, np.arange(len(T)), -1))
                held = self._mag_held if self._mag_held is not None else m[0]
                m = np.where((idx >= 0)[:, None], m[np.maximum(idx, 0)], held)
                self._mag_slot_last = slot[-1]
            self._mag_held = m[-1].copy()
            mag = m / self._mag_scale
        return gyr, acc, mag

    # -- batch -------------------------------------------------------------------------
    def simulate(self, t: ArrayLike, gyr_true: ArrayLike, acc_true: ArrayLike,
                 mag_true: ArrayLike | None = None) -> IMURecord:
        """IMU output for true motion sampled at the physics rate.

        t (N,): strictly increasing times (s); gyr_true (N, 3): body rate (rad/s); acc_true
        (N, 3): specific force (m/s^2); mag_true (N, 3) or None: local field in the body frame
        (``mag_unit``). Returns an ``IMURecord`` at the IMU rate. Continues the current record:
        a second call must start after the first ended (``reset()`` for a new record).
        """
        if self._kernel is not None and self._kernel.live:
            self._kernel.store(self)        # the streaming state, for the batch code below
        t = np.asarray(t)
        if t.ndim != 1 or t.dtype.kind not in "fiu":
            raise ValueError(f"t must be a 1-D array of times (s), got shape {t.shape} dtype {t.dtype}")
        n = t.shape[0]
        if n == 0:
            raise ValueError("t must hold at least one time, got an empty array")
        t = t.astype(float)
        arrays = [self._samples(gyr_true, "gyr_true", n), self._samples(acc_true, "acc_true", n)]
        has_mag = mag_true is not None
        if has_mag:
            arrays.append(self._samples(mag_true, "mag_true", n))
        if not np.all(np.isfinite(t)):
            raise ValueError("t must be finite")
        dts = np.diff(t)
        if n > 1 and not np.all(dts > 0):
            bad = int(np.argmin(dts > 0)) + 1
            raise ValueError(f"t must be strictly increasing; t[{bad}] is not after the previous time")
        if self._mag_on is not None and self._mag_on != has_mag:
            raise ValueError("mag_true must be given in every call of a record or in none "
                             f"(this record {'has' if self._mag_on else 'has no'} magnetometer input)")
        origin = float(t[0]) if self._origin is None else self._origin
        if self._steps and not t[0] - origin > self._tau_last + _TOL:
            raise ValueError("t must continue the current record: t[0] must be after the last time "
                             f"given ({self._tau_last + origin!r}); call reset() to start a new one")
        if self._steps:
            self._check_physics_dt(np.concatenate([[t[0] - origin - self._tau_last], dts]))
        else:
            self._check_physics_dt(dts)
        self._mag_on = has_mag
        self._origin = origin
        parts = []
        for c0 in range(0, n, _CHUNK):          # bounded memory for long records
            c1 = min(n, c0 + _CHUNK)
            rec = self._simulate(t[c0:c1] - origin, [a[c0:c1] for a in arrays], has_mag)
            rec.index += c0
            parts.append(rec)
        if len(parts) == 1:
            return parts[0]
        cat = lambda f: np.concatenate([getattr(r, f) for r in parts])
        return IMURecord(t=cat("t"), gyr=cat("gyr"), acc=cat("acc"), mag=cat("mag") if has_mag and
                         parts[0].mag is not None else None, dt=cat("dt"), index=cat("index"), fs=self._fs)

    def _simulate(self, tau, arrays, has_mag):
        """simulate() on one validated chunk; tau is time since the origin."""
        n = tau.shape[0]
        dts = np.diff(tau)
        first = self._steps == 0
        if not first:
            step_dt = np.concatenate([[tau[0] - self._tau_last], dts])
        else:
            step_dt = np.concatenate([[dts[0] if n > 1 else 1.0 / self._fs], dts])
        y = self._physics_signal(tau, arrays, has_mag, step_dt, first)
        T, idx, rows, rows_all, M = self._sample_instants(tau)
        vals = self._sample_values(y, tau, T, idx, M, first)

        if M:
            gyr, acc, mag = self._emit(T, vals, rows)
            self._pos += M
            Tprev = self._T_prev if self._T_prev is not None else T[0] - 1.0 / self._fs
            dt_out = np.diff(np.concatenate([[Tprev], T]))
            self._T_prev = float(T[-1])
            self._k += M
            self._T_next = self._jitter(self._k, rows_all[M - 1, 0])
        else:
            gyr = acc = np.zeros((0, 3))
            mag = np.zeros((0, 3)) if (has_mag and self._spec.mag is not None) else None
            dt_out = np.zeros(0)
        self._steps += n
        self._tau_last = float(tau[-1])
        self._y_last = y[-1].copy()
        return IMURecord(t=T + self._origin, gyr=gyr, acc=acc, mag=mag, dt=dt_out, index=idx.astype(np.int64),
                         fs=self._fs)

    def _physics_signal(self, tau, arrays, has_mag, step_dt, first):
        """The physics-rate signal (n, 9) of one chunk: true motion + vibration, low-passed."""
        n = tau.shape[0]
        x = np.zeros((n, 9))
        x[:, 0:3] = arrays[0]
        x[:, 3:6] = arrays[1]
        if has_mag:
            x[:, 6:9] = arrays[2]
        if self._vib is not None:
            v = np.zeros((n, 6))
            for j in range(self._vib_w.shape[1]):
                v += np.sin(tau[:, None] * self._vib_w[:, j] + self._vib_phi[:, j])
            x[:, 0:6] += v * self._vib_amp
        y0 = x[0] if first else self._y_last
        med = float(np.median(step_dt))
        uniform = np.all(np.abs(step_dt - med) <= 1e-9 * med)
        a0, b0 = self._lpf_coeffs(med)
        if uniform:
            if a0.any():
                y = np.empty_like(x)
                for c0 in (0, 3):
                    a = a0[c0]
                    y[:, c0:c0 + 3] = _ar1(a, x[:, c0:c0 + 3] * b0[c0], y0[c0:c0 + 3]) if a > 0 else x[:, c0:c0 + 3]
                y[:, 6:9] = x[:, 6:9]
            else:
                y = x
        else:
            y = x.copy()
            for c0, sp in ((0, self._spec.gyro), (3, self._spec.acc)):
                f = sp.lpf_hz
                if f is not None:
                    a = np.exp(-2.0 * math.pi * f * step_dt)
                    y[:, c0:c0 + 3] = _ar1_var(a, x[:, c0:c0 + 3] * (1.0 - a)[:, None], y0[c0:c0 + 3])
        if first:   # the filter starts settled on the first input
            y[0] = x[0]
        return y

    def _sample_instants(self, tau):
        """Which samples fall in this stretch of physics steps, and at which step: (instants T,
        step indices, their noise rows, the rows peeked, the number of samples M)."""
        n = tau.shape[0]
        span = float(tau[-1] - self._T_next)
        cand = max(0, int(span * self._fs) + 2) if span >= -_TOL else 0
        rows_all = self._peek(cand) if cand else np.empty((0, self._ncols))
        T = np.empty(cand + 1)
        T[0] = self._T_next
        lim = 0.45 / self._fs
        T[1:] = np.arange(self._k + 1, self._k + 1 + cand, dtype=float) / self._fs + \
            np.clip(self._spec.jitter_s * rows_all[:, 0], -lim, lim)
        s = np.searchsorted(tau, T - _TOL, side="left")
        ar = np.arange(cand + 1)
        idx = np.maximum.accumulate(s - ar) + ar
        M = int(np.count_nonzero(idx < n))
        return T[:M], idx[:M], rows_all[:M], rows_all, M

    def _sample_values(self, y, tau, T, idx, M, first):
        """The sampled values (M, 9) of the low-passed signal y: interpolated at the instants
        ("hold") or averaged since the last sample ("average", whose running sum carries over)."""
        n = tau.shape[0]
        if self._hold:
            ip = idx - 1
            at0 = ip < 0
            ip[at0] = 0
            yp = y[ip]
            tp = tau[ip]
            if at0.any():       # the step before this call's first: the last of the previous call
                yp[at0] = y[0] if first else self._y_last
                tp[at0] = tau[0] if first else self._tau_last
            yi, ti = y[idx], tau[idx]
            with np.errstate(invalid="ignore", divide="ignore"):
                w = np.clip((T - tp) / (ti - tp), 0.0, 1.0)
            w[(T >= ti - _TOL) | (ti == tp)] = 1.0
            vals = (1.0 - w)[:, None] * yp + w[:, None] * yi
        else:
            starts = np.concatenate([[0], idx[:-1] + 1]) if M else np.zeros(0, dtype=int)
            if M:
                sums = np.add.reduceat(y[:idx[-1] + 1], starts, axis=0)
                cnts = np.diff(np.concatenate([starts, [0]]))
                cnts[-1] = idx[-1] + 1 - starts[-1]
                sums[0] += self._sum
                cnts = cnts.astype(float)
                cnts[0] += self._cnt
                vals = sums / cnts[:, None]
                rest = y[idx[-1] + 1:]
                self._sum = rest.sum(axis=0) if len(rest) else np.zeros(9)
                self._cnt = len(rest)
            else:
                vals = np.zeros((0, 9))
                self._sum = self._sum + y.sum(axis=0)
                self._cnt += n
        return vals

    @staticmethod
    def _samples(x, name, n):
        arr = np.asarray(x)
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
        if arr.shape != (n, 3):
            raise ValueError(f"{name} must have shape (N, 3) with N = len(t) = {n}, got {arr.shape}")
        arr = arr.astype(float)
        if not np.all(np.isfinite(arr)):
            bad = int(np.argmax(~np.all(np.isfinite(arr), axis=1)))
            raise ValueError(f"{name} must be finite; row {bad} is not")
        return arr

    def _check_physics_dt(self, dts):
        if len(dts) == 0:
            return
        if dts.max() > (1.0 + 1e-6) / self._fs:
            raise ValueError(f"the physics step must not exceed the IMU period 1/{self._fs:g} s; "
                             f"got a step of {dts.max():g} s (give the true motion at a rate >= rate_hz)")
        if self._physics_rate is not None:
            med = float(np.median(dts))
            if abs(med * self._physics_rate - 1.0) > 0.01:
                raise ValueError(f"t must be sampled at physics_rate_hz = {self._physics_rate:g} Hz, "
                                 f"got a median step of {med:g} s")

    # -- streaming ---------------------------------------------------------------------
    def step(self, gyr_true: ArrayLike, acc_true: ArrayLike, mag_true: ArrayLike | None = None,
             dt: float | None = None) -> IMUSample | None:
        """Advance the physics clock by one step and return an ``IMUSample`` if one is due,
        else None. The first call after ``reset()`` is time 0 (its dt is not used); later
        calls advance by ``dt`` (s), default 1/physics_rate_hz. Arguments as one row of
        ``simulate``'s (3 numbers each)."""
        if dt is not None:
            dt = number("dt", dt, unit=" s")
        k = self._kernel
        if k is not None:
            if not k.live:
                k.load(self)
            return k.step(gyr_true, acc_true, mag_true, dt, IMUSample)
        x = self._step_input(gyr_true, acc_true, mag_true)
        y, tau, tau_prev, first = self._step_filter(x, dt)
        step_index = self._steps
        self._steps += 1
        if not self._hold:
            self._sum += y
            self._cnt += 1
        T = self._T_next
        if tau < T - _TOL:
            return None
        return self._step_sample(y, T, tau, tau_prev, first, step_index)

    def _step_input(self, gyr_true, acc_true, mag_true):
        """One step's true motion, checked, into the scratch row x (9,)."""
        x = self._x
        # (each checked on its own step, as _imu.pyx's _read3: a NaN on a step without a sample
        # would enter the low-pass and fail a later sample)
        x[0:3] = finite_vector("gyr_true", gyr_true, 3, "gyr_true must be 3 finite real numbers (rad/s)")
        x[3:6] = finite_vector("acc_true", acc_true, 3, "acc_true must be 3 finite real numbers (m/s^2)")
        has_mag = mag_true is not None
        if has_mag:
            x[6:9] = finite_vector("mag_true", mag_true, 3, "mag_true must be 3 finite real numbers or None")
        if self._mag_on is None:
            self._mag_on = has_mag
        elif self._mag_on != has_mag:
            raise ValueError("mag_true must be given in every step of a record or in none")
        return x

    def _step_filter(self, x, dt):
        """Advance the physics clock by dt and low-pass x (vibration added): (the filtered
        signal, its time, the previous step's time, whether this is the record's first step)."""
        if self._steps == 0:
            if self._origin is None:
                self._origin = 0.0
            tau = 0.0
            if self._vib is not None:
                self._add_vibration(x, tau)
            y = self._y_last
            y[:] = x
            first = True
        else:
            if dt is None:
                if self._physics_rate is None:
                    raise ValueError("dt must be given (s) when the IMU has no physics_rate_hz")
                dt = 1.0 / self._physics_rate
            elif not (dt > 0) or dt > (1.0 + 1e-6) / self._fs:
                raise ValueError(f"dt must be > 0 and <= the IMU period 1/{self._fs:g} s, got {dt!r}")
            tau = self._tau_last + dt
            if self._vib is not None:
                self._add_vibration(x, tau)
            if dt != self._lpf_dt:
                self._lpf_a, self._lpf_b = self._lpf_coeffs(dt)
                self._lpf_dt = dt
            # swap: y_prev <- last, y <- a * last + b * x
            self._y_prev, self._y_last = self._y_last, self._y_prev
            y = self._y_last
            np.multiply(self._y_prev, self._lpf_a, out=y)
            np.multiply(x, self._lpf_b, out=self._tmp)
            np.add(y, self._tmp, out=y)
            first = False
        tau_prev = self._tau_last
        self._tau_last = tau
        return y, tau, tau_prev, first

    def _step_sample(self, y, T, tau, tau_prev, first, step_index):
        """The sample due at instant T (within the last physics step): an ``IMUSample``."""
        if self._hold:
            if first or T >= tau - _TOL or tau == tau_prev:
                vals = y
            else:
                w = (T - tau_prev) / (tau - tau_prev)
                w = 0.0 if w < 0.0 else (1.0 if w > 1.0 else w)
                vals = (1.0 - w) * self._y_prev + w * y
        else:
            vals = self._sum / float(self._cnt)
            self._sum = np.zeros(9)
            self._cnt = 0
        row = self._peek(1)[0].tolist()
        vl = vals.tolist()
        try:
            ga = self._output_one(vl, row)
            mag = None
            if self._mag_on and self._spec.mag is not None:
                if self._mrate is not None:
                    slot = math.floor(T * self._mrate + _TOL)
                    fresh = slot != self._mag_slot_last
                    self._mag_slot_last = slot
                else:
                    fresh = True
                if fresh or self._mag_held is None:
                    sc = self._mag_scale
                    self._mag_held = np.array(self._mag_output_one([vl[6] * sc, vl[7] * sc, vl[8] * sc], row[31:34]))
                mag = self._mag_held / self._mag_scale
        except (ValueError, OverflowError):
            raise ValueError("gyr_true, acc_true and mag_true must be finite") from None
        self._pos += 1
        dt_out = T - self._T_prev if self._T_prev is not None else 1.0 / self._fs
        self._T_prev = T
        self._k += 1
        self._T_next = self._jitter(self._k, row[0])
        return IMUSample(T + self._origin, np.array(ga[0:3]), np.array(ga[3:6]), mag, dt_out, step_index)

    def _add_vibration(self, x, tau):
        buf = self._vib_buf
        np.multiply(self._vib_w, tau, out=buf)
        np.add(buf, self._vib_phi, out=buf)
        np.sin(buf, out=buf)
        v = self._vib_out
        np.sum(buf, axis=1, out=v)
        v *= self._vib_amp
        x[0:6] += v


# ---------------------------------------------------------------------------------------
# Allan deviation


def allan_deviation(x: ArrayLike, fs: float, taus: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of rate samples.

    x (N,) or (N, k): e.g. a static gyro record (rad/s) or accelerometer record (m/s^2);
    fs: sample rate (Hz); taus: averaging times (s), rounded to whole samples, default about
    ten per decade from 1/fs to N/(3 fs). Returns (taus (n,), adev (n,) or (n, k)), the
    deviation in the unit of x. Uses the integrated signal, O(N) per tau.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2) or x.shape[0] < 3:
        raise ValueError(f"x must have shape (N,) or (N, k) with N >= 3, got {x.shape}")
    fs = _check_number("allan_deviation", "fs", fs, positive=True)
    n = x.shape[0]
    if taus is None:
        top = max(1, n // 3)
        m = np.unique(np.round(np.logspace(0, math.log10(top), max(2, int(10 * math.log10(top)) + 1))).astype(int))
    else:
        m = np.unique(np.round(np.atleast_1d(np.asarray(taus, dtype=float)) * fs).astype(int))
        if m.size == 0 or m[0] < 1 or m[-1] > (n - 1) // 2:
            raise ValueError(f"taus must lie between 1/fs and (N-1)/(2 fs) = {(n - 1) // 2 / fs:g} s")
    theta = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x - x.mean(axis=0), axis=0)]) / fs
    out = np.empty((len(m),) + x.shape[1:])
    for i, mi in enumerate(m):
        d = theta[2 * mi:] - 2.0 * theta[mi:-mi] + theta[:-2 * mi]
        tau = mi / fs
        out[i] = np.sqrt(np.mean(d * d, axis=0) / (2.0 * tau * tau))
    return m / fs, out


def allan_summary(taus: ArrayLike, adev: ArrayLike, fs: float | None = None,
                  max_tau: float | None = None) -> dict[str, float]:
    """Read the usual figures off an Allan-deviation curve (one column).

    Returns a dict: ``arw`` (the -1/2-slope line through the short-tau points, read at
    tau = 1 s: median of adev * sqrt(tau) for tau from 2 to 20 samples, at most 1 s; fs
    gives the sample period, else taus[0] is taken for it), ``adev_1s`` (the curve itself at
    1 s, interpolated in log-log; includes whatever else is there at 1 s),
    ``bias_instability`` (the curve's minimum / 0.664) and ``tau_floor`` (where it is). The
    minimum is searched up to ``max_tau`` (s), default taus[-1] / 3: the last points rest on
    a few clusters only and scatter low.
    """
    taus = np.asarray(taus, dtype=float)
    adev = np.asarray(adev, dtype=float)
    if adev.shape != taus.shape or taus.ndim != 1 or taus.size < 2:
        raise ValueError(f"taus and adev must be 1-D of the same length >= 2, got {taus.shape}, {adev.shape}")
    tmin = taus[0] if fs is None else 1.0 / _check_number("allan_summary", "fs", fs, positive=True)
    sel = (taus >= 2 * tmin * (1 - 1e-9)) & (taus <= min(20 * tmin, 1.0) * (1 + 1e-9))
    if not sel.any():
        sel = taus <= max(1.0, taus[0])
    arw = float(np.median(adev[sel] * np.sqrt(taus[sel])))
    adev_1s = float(np.exp(np.interp(0.0, np.log(taus), np.log(adev)))) if taus[0] <= 1.0 <= taus[-1] else math.nan
    top = taus[-1] / 3.0 if max_tau is None else float(max_tau)
    cand = np.flatnonzero(taus <= top)
    if cand.size == 0:
        cand = np.arange(taus.size)
    i = int(cand[np.argmin(adev[cand])])
    return {"arw": arw, "adev_1s": adev_1s, "bias_instability": float(adev[i] / ALLAN_FLOOR),
            "tau_floor": float(taus[i])}


# ---------------------------------------------------------------------------------------
# Magnetic disturbances


def dipole_field(points: ArrayLike, center: ArrayLike, moment: ArrayLike,
                 min_distance: float = 0.01) -> np.ndarray:
    """Field (uT) of a magnetic dipole of ``moment`` (A m^2, (3,)) at ``center`` (m, (3,)), at
    ``points`` (m, (3,) or (N, 3)), in the frame the positions are given in (e.g. ENU):
    ``B = mu0/(4 pi) (3 r (m . r) / |r|^5 - m / |r|^3)``. Distances below ``min_distance`` (m)
    are raised to it (the field of a real magnet stays finite). Add it to the earth field,
    rotate into the body frame, and pass it as ``mag_true``: a motor, a battery or a steel
    structure near a point of the course."""
    p = np.asarray(points, dtype=float)
    c = np.asarray(center, dtype=float)
    m = np.asarray(moment, dtype=float)
    if p.shape[-1:] != (3,) or p.ndim not in (1, 2):
        raise ValueError(f"points must have shape (3,) or (N, 3), got {p.shape}")
    if c.shape != (3,):
        raise ValueError(f"center must have shape (3,), got {c.shape}")
    if m.shape != (3,):
        raise ValueError(f"moment must have shape (3,), got {m.shape}")
    min_distance = _check_number("dipole_field", "min_distance", min_distance, positive=True)
    r = p - c
    d = np.linalg.norm(r, axis=-1, keepdims=True)
    rhat = np.divide(r, d, out=np.zeros_like(r), where=d > 0)
    rhat = np.where(d > 0, rhat, m / max(np.linalg.norm(m), 1e-300))
    d = np.maximum(d, min_distance)
    mr = np.sum(rhat * m, axis=-1, keepdims=True)
    return 1e-7 * (3.0 * rhat * mr - m) / d ** 3 * 1e6


def dipole_moment_for(field_ut: float, distance_m: float) -> float:
    """Dipole moment (A m^2) whose field on its axis at ``distance_m`` is ``field_ut`` (uT):
    ``|m| = field * d^3 / (2e-7 * 1e6)`` (e.g. 20 uT at 0.1 m: 0.1 A m^2)."""
    b = _check_number("dipole_moment_for", "field_ut", field_ut)
    d = _check_number("dipole_moment_for", "distance_m", distance_m, positive=True)
    return b * d ** 3 / 0.2
