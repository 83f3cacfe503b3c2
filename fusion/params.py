"""`fusion.Param`: the one declaration of an estimator's parameter (name, default, unit,
accepted range, meaning). An estimator class's `PARAMS` is a table of them (name -> Param);
validation (Estimator._take_params), the docs' and README's parameter tables
(docs/api_tables.py) and `type(est).PARAMS` all read it.

The declarations that several estimators share (the parts they hold in common: rest
detection, magnetic disturbance detection, saturation recovery, the accelerometer
low-pass, the magnetometer's update) stand here once; an estimator whose value or range
differs takes the shared one with `.but(...)`.

The ranges of the numbers are wide enough for any real sensor and tuning (datasheet noise
densities are about 1e-4 rad/s/sqrt(Hz) and 2e-3 m/s^2/sqrt(Hz)) and narrow enough that no
combination with a time step in [DT_MIN, DT_MAX] and any valid sample over- or underflows to
NaN or leaves a covariance indefinite (tests/test_fuzz.py)."""
import dataclasses
from typing import Any

from fusion import checks

__all__ = ["Param", "table", "REST", "REST_PULL", "MAGDIST", "GYRO_RANGE", "MOTION_RATE", "MAG_UPDATE", "ACC_LOWPASS"]


@dataclasses.dataclass(frozen=True)
class Param:
    """One parameter. Numbers are accepted in [low, high] (open at an end with open_low /
    open_high; None: unbounded), 0 too with allow_zero; integer=True for whole numbers;
    choices for strings; a bool default makes a flag (True or False); a None default means
    None is accepted too (the estimator works it out: doc says how)."""
    name: str
    default: Any
    unit: str = ""
    low: float | None = None
    high: float | None = None
    doc: str = ""
    allow_zero: bool = False
    choices: tuple | None = None
    integer: bool = False
    open_low: bool = False
    open_high: bool = False

    def check(self, value: Any) -> Any:
        """value in its canonical type (float, int, bool, str or None), or a ValueError
        naming the parameter and the accepted range."""
        none_ok = self.default is None
        if self.choices is not None:
            return checks.choice(self.name, value, self.choices)
        if isinstance(self.default, bool):
            return checks.flag(self.name, value)
        if self.integer:
            return checks.integer(self.name, value, self.low, self.high, allow_none=none_ok,
                                  unit=f" ({self.unit})" if self.unit else "")
        return checks.number(self.name, value, self.low, self.high, open_low=self.open_low,
                             open_high=self.open_high, allow_zero=self.allow_zero, allow_none=none_ok)

    def but(self, **changes: Any) -> "Param":
        """This declaration with some fields changed (another estimator's default, range or doc)."""
        return dataclasses.replace(self, **changes)

    @property
    def accepted(self) -> str:
        """The accepted values, as the docs' tables print them."""
        if self.choices is not None:
            return " or ".join(f'`"{c}"`' for c in self.choices)
        if isinstance(self.default, bool):
            return "True or False"
        rng = checks.interval(self.low, self.high, self.open_low, self.open_high)
        if self.low == 0 and self.high is None and not self.allow_zero:
            rng = "> 0"
        extra = [s for s, on in (("0", self.allow_zero), ("None", self.default is None)) if on]
        return (("integer " if self.integer else "") + rng + "".join(f", {s}" for s in extra)).replace("inf", "∞")

    def __post_init__(self):
        if self.choices is None and not isinstance(self.default, (bool, str)):
            if self.default is not None:        # the default must pass its own check
                self.check(self.default)
            if self.low is not None and self.high is not None and not self.low <= self.high:
                raise ValueError(f"Param {self.name}: low {self.low} > high {self.high}")
        elif self.choices is not None and self.default not in self.choices:
            raise ValueError(f"Param {self.name}: default {self.default!r} not in {self.choices}")


def table(*params: Param) -> dict[str, Param]:
    """An estimator's PARAMS: name -> Param in the order given; a later Param of the same
    name replaces an earlier one (in its place)."""
    out: dict[str, Param] = {}
    for p in params:
        out[p.name] = p
    return out


# --- the declarations several estimators share ------------------------------------------

# rest detection (docs/estimators.md, "Rest"): 2 deg/s and 0.5 m/s^2 are VQF's thresholds; the
# detector every filter that learns its bias at rest has
_REST_DETECTION = (
    Param("rest_time", 0.4, "s", 1e-3, 1e4, "rest detection: after this long at rest the gyro "
          "measures its bias (a zero-rate update); 0: off", allow_zero=True),
    Param("rest_gyro_tol", 0.034906585039886591, "rad/s", 1e-6, 10.0, "at rest: the gyro within "
          "this of its 0.5 s low-pass, and the low-pass within this of zero on every axis (2 deg/s)"),
    Param("rest_acc_tol", 0.5, "m/s²", 1e-6, 100.0, "at rest: the accelerometer within this of its "
          "0.5 s low-pass"),
    # a still run's low-passes must stay where it began: the turning point of a slow oscillation
    # passes the tests above for a moment (docs/accuracy.md, thirteenth pass)
    Param("rest_gyro_drift_tol", 0.0034906585039886591, "rad/s", 1e-6, 10.0, "a still run ends "
          "when the gyro's 0.5 s low-pass moves this far from its value at the run's start "
          "(0.2 deg/s); 0: off", allow_zero=True),
    Param("rest_acc_drift_tol", 0.1, "m/s²", 1e-6, 100.0, "a still run ends when the "
          "accelerometer's 0.5 s low-pass moves this far from its value at the run's start "
          "(about 0.6 deg of tilt); 0: off", allow_zero=True),
)

# the Kalman filters' rest: the detector and the zero-rate update
REST = (
    *_REST_DETECTION,
    Param("rest_noise", 1e-3, "rad/s/√Hz", 1e-7, 1.0, "the gyro's white-noise density as the "
          "zero-rate measurement's noise"),
    # a slow turn about the vertical passes every test above for a second or so; the filter's own
    # bias uncertainty tells it from rest. On at 2 since the first update takes the still run
    # (fusion._rest.rest_rate), which made that turn worse without it; it delays a turn-on bias
    # beyond it and costs a little under linear acceleration (docs/accuracy.md, fourteenth and
    # fifteenth passes); off in aekf and cf-ekf, which it does not help
    Param("rest_bias_gate", 2.0, "1", 0.5, 100.0, "the zero-rate update waits while the gyro's "
          "0.5 s low-pass is more than this many bias standard deviations (plus "
          "rest_gyro_drift_tol) from the bias estimate on some axis (2: slow turns about the "
          "vertical without a magnetometer); 0: off", allow_zero=True),
    Param("rest_gate_time", 2.0, "s", 1e-3, 1e4, "a still run this long updates the bias whatever "
          "rest_bias_gate says (a turn-on bias beyond the gate is learned after it; at or below "
          "rest_time the gate never acts)"),
)

# the complementary filters' rest learning (no zero-rate update there, so neither its noise nor
# its gate): at rest their gyro bias is pulled toward the measured rate
REST_PULL = (*_REST_DETECTION,
             Param("rest_tau", 1.0, "s", 1e-3, 1e4, "at rest: the time constant with which the gyro "
                   "bias is pulled toward the measured rate"))

# magnetic disturbance rejection (docs/estimators.md, "Magnetic disturbances"): VQF's
# thresholds and times
MAGDIST = (
    Param("magdist_time", 60.0, "s", 1e-3, 1e5, "magnetic disturbance detection: after this long "
          "rejecting (decaying twice as fast while undisturbed) the current field becomes the "
          "reference; 0: detection off", allow_zero=True),
    Param("magdist_norm_tol", 0.1, "1", 1e-4, 10.0, "a field whose norm differs from the "
          "reference's by more than this share is disturbed"),
    # 5 deg, not VQF's 10: leave-one-set-out, docs/accuracy.md "Seventh pass: the magnetic dip tolerance"
    Param("magdist_dip_tol", 5.0, "deg", 1e-3, 90.0, "a field whose dip differs from the "
          "reference's by more than this is disturbed"),
    Param("magdist_new_time", 20.0, "s", 1e-3, 1e5, "a field other than the reference that stays "
          "steady this long while the sensor turns (|ω| >= 20 °/s) becomes the reference"),
)

# saturation and gap recovery (docs/robustness.md, "Recovery")
GYRO_RANGE = Param("gyro_range", None, "rad/s", 0.0, 1e6, "gyro samples at or beyond 98 % of this "
                   "(the part's full scale) count as saturated; None: unknown", open_low=True)
MOTION_RATE = Param("motion_rate", 1.0, "rad/s", 1e-6, 100.0, "rate std over time the gyro did not "
                    "measure (dropouts, gaps, saturation): the attitude variance grows by "
                    "(motion_rate t)², capped at π²; 0: off", allow_zero=True)

MAG_UPDATE = Param("mag_update", "heading", "", doc='"heading": the magnetometer corrects the '
                   'heading (and the bias along the vertical) only; "vector": the whole 3-D field, folded onto '
                   'north, as the measurement model of "IIR-EKF, IMU dynamic error suppression" '
                   '(docs/estimators.md)', choices=("heading", "vector"))
ACC_LOWPASS = Param("acc_lowpass", 1.0, "s", 1e-3, 1e4, "time constant of the accelerometer's "
                    "low-pass in a frame that turns with the gyro alone (VQF's; docs/estimators.md); "
                    "0: off", allow_zero=True)
