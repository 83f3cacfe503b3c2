"""The spherical robot's physics, sensing and estimator: the base of the task environments
(envs/track.py, envs/waypoints.py), laid out like Gymnasium's MuJoCo environments (a base
with the simulation, one class per task with its rewards, observation and documentation).
Documentation: docs/envs/robot.md and the task classes' docstrings.

The physics client is created by the environment (at the first ``reset``), never at
import, so environments can be built in subprocesses; every ``reset`` empties the world
but its floor (every 64th, ``resetSimulation``: ``_build_world``) and rebuilds it, so that
an episode depends only on the seed.
"""
from __future__ import annotations

import math
import os
import sys

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
import gymnasium as gym
from gymnasium import spaces

import fusion
from fusion import imu as fimu
from fusion.checks import finite_vector, flag, integer, number
from fusion.constants import GRAVITY as G

from envs import _signals
from envs.robot import (DRIVE_JOINT, REALISM, SERVO_STALL_CURRENT, STEER_JOINT, DCMotor, RobotParams, Servo,
                        SPIN_EPS, STICK_RATE, build_robot, check_explicit_damping, dipole_field, pendulum_dipole,
                        spin_torque, set_drive_friction, set_steer)

__all__ = ["SphereRobotBase", "ESTIMATORS", "BASE_OBS", "obs_layout"]

#: the seam pulse's mean over one revolution of the shell (a raised cosine 0.15 rad wide,
#: mean 1/2 over its width): 0.15 / (4 pi) of its height
SEAM_MEAN = 0.15 / (4.0 * math.pi)

#: Earth field (uT, ENU) of the seeds' region (Nanjing, WMM: total 50.6 uT, inclination
#: 48 deg); declination set to 0 so that magnetic north is the world's +y and the estimated
#: heading has the same zero as the true one.
EARTH_FIELD = (0.0, 33.9, -37.6)
#: the observation's first ten values, common to every task: (name, bound)
BASE_OBS = (("q_w", 1.0), ("q_x", 1.0), ("q_y", 1.0), ("q_z", 1.0), ("rate_x", 20.0), ("rate_y", 20.0),
            ("rate_z", 20.0), ("encoder_speed", 50.0), ("last_drive", 1.0), ("last_steer", 1.0))
BUMP_LENGTH = 0.6        # (m) the bumps' cylinder length
RAMP_TOP, RAMP_WIDTH = 0.5, 0.8   # (m) a ramp's flat top and its width
START_CLEARANCE = 0.5    # (m) free floor between the start and every bump or ramp
MAX_SUBSTEPS = 10_000    # physics steps per step(): bounds the time one step() can take
# stuck (an episode end): slower than STUCK_SPEED (m/s) while driven harder than STUCK_ACTION
# (|action[0]|) for STUCK_TIME (s)
STUCK_SPEED, STUCK_ACTION, STUCK_TIME = 0.02, 0.5, 3.0
#: fusion.make's arguments that the environment sets itself, refused in estimator_params: why
ESTIMATOR_OWNED = {"name": "name is the estimator argument",
                   "fs": "fs is imu_hz",
                   "frame": "frame is 'ENU', the frame the observation and info read the quaternion in",
                   "on_invalid": "on_invalid is 'skip', so a bad IMU sample cannot end an episode"}
#: what step() says before the first reset() or after an episode ended
NEEDS_RESET = "call reset() before step() (and after an episode ended)"
PATCH_RADIUS = (0.5, 1.5)   # (m) the range of a slippery patch's radius (drawn uniformly)
REBUILD_EVERY = 64          # resets that keep the floor between two rebuilds of the world (_build_world)
_JOINTS = (DRIVE_JOINT, STEER_JOINT)
#: the methods of step() that the compiled step (envs/_signals.pyx, Loop.control_step) runs in C
_COMPILED_STEP = ("step", "_begin_step", "_end_step", "_check_action", "_advance", "_encoder_counts", "_odometry",
                  "_episode_end", "_observation", "_info", "_q_est_wxyz", "_est_bias", "_heading_est",
                  "_heading_true")


def ESTIMATORS() -> list[str]:
    """Names accepted by ``estimator=``: fusion's estimators and "truth"."""
    return list(fusion.available()) + ["truth"]


def obs_layout(parts: Sequence[tuple[str, float]]) -> dict[str, int]:
    """{name: index} of an observation assembled from ``parts`` ((name, bound), ...)."""
    return {name: i for i, (name, _) in enumerate(parts)}


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _vector3(name, value, what):
    return tuple(finite_vector(name, value, 3, f"{name} must be 3 finite numbers {what}").tolist())


def _multiple(a, b):
    """Whether a / b is a whole number (within rounding)."""
    n = round(a / b)
    return n >= 1 and abs(n * b - a) <= 1e-9 * a


def _imu_spec(imu, calibrated):
    if not isinstance(calibrated, (bool, np.bool_)):
        raise ValueError(f"imu_calibrated must be True or False, got {calibrated!r}")
    if isinstance(imu, fimu.IMUSpec):
        return imu
    if isinstance(imu, str) and imu in fimu.available():
        return fimu.preset(imu, calibrated=bool(calibrated))
    raise ValueError(f"unknown IMU preset {imu!r}; accepted: {', '.join(fimu.available())} "
                     "(or a fusion.imu.IMUSpec)")


def _mag_zone_spec(mag_zones):
    if mag_zones is None or (isinstance(mag_zones, str) and mag_zones == "random"):
        return mag_zones
    zs = []
    try:
        for z in mag_zones:
            if any(isinstance(v, (bool, np.bool_)) for v in z):
                raise ValueError
            x, y, f = (float(v) for v in z)
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(f) and 0 < f <= 1e4):
                raise ValueError
            zs.append((x, y, f))
    except (TypeError, ValueError):
        raise ValueError("mag_zones must be None, 'random' or a list of (x, y, field_uT) with "
                         f"field_uT in (0, 1e4], got {mag_zones!r}") from None
    return zs


def _x_display_answers() -> bool:
    """Whether the X server of $DISPLAY accepts a connection (PyBullet's GUI ends the process
    from C when it does not); True where libX11 cannot be loaded to ask (PyBullet then says)."""
    import ctypes
    import ctypes.util
    name = ctypes.util.find_library("X11")
    if name is None:
        return True
    try:
        x11 = ctypes.CDLL(name)
    except OSError:
        return True
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    d = x11.XOpenDisplay(None)
    if not d:
        return False
    x11.XCloseDisplay(d)
    return True


def heading_of(w: float, x: float, y: float, z: float) -> float:
    """The robot's heading (rad) of the attitude quaternion (w, x, y, z): the rolling direction,
    perpendicular to the axle (body y) in the horizontal plane, atan2(-R01, R11). Unlike the
    yaw of the body x axis it does not flip when the frame pitches past 90 deg (pendulum
    swung up by hard braking)."""
    return math.atan2(-2 * (x * y - w * z), 1 - 2 * (x * x + z * z))


def parse_action(action: ArrayLike) -> tuple[float, float, bool]:
    """(a0, a1, clipped): the action as two floats clipped to [-1, 1], and whether it was
    clipped; ValueError if it is not 2 finite real numbers."""
    if type(action) is np.ndarray and action.shape == (2,) and action.dtype.kind == "f":
        a0, a1 = float(action[0]), float(action[1])       # (the common case, without a copy)
    else:
        try:
            a = None if isinstance(action, np.ma.MaskedArray) else np.asarray(action)   # (a mask would be dropped)
        except (TypeError, ValueError):
            a = None
        # real numbers only: a cast would drop a complex action's imaginary part and read
        # True as 1.0 (and parse strings)
        if a is None or a.dtype.kind not in "iuf":
            raise ValueError(f"action must be 2 finite real numbers in [-1, 1] (float or int), "
                             f"got {action!r}")
        a = a.astype(np.float64)
        if a.shape != (2,):
            raise ValueError(f"action must have shape (2,) (drive voltage, steering), got shape {a.shape}")
        a0, a1 = float(a[0]), float(a[1])
    if not (math.isfinite(a0) and math.isfinite(a1)):
        raise ValueError(f"action must be finite, got {action!r}")
    if a0 > 1.0 or a0 < -1.0 or a1 > 1.0 or a1 < -1.0:
        a0 = 1.0 if a0 > 1.0 else (-1.0 if a0 < -1.0 else a0)
        a1 = 1.0 if a1 > 1.0 else (-1.0 if a1 < -1.0 else a1)
        return a0, a1, True
    return a0, a1, False


class SphereRobotBase(gym.Env):
    """Pendulum-driven spherical robot, IMU and estimator in the loop: the physics, sensing
    and estimation common to the tasks. A task subclass sets ``task``, ``TASK_OBS`` (its
    observation's last values: (name, bound), ...), ``default_episode_s`` and implements
    ``_draw_task``, ``_reset_task``, ``_task_obs``, ``_get_rew`` and ``_task_info``.

    Arguments common to the tasks (all keyword; ranges are checked, ``ValueError`` names the
    argument); the tasks' docstrings list them with their defaults:

    estimator: a name of ``fusion.available()`` or "truth" (the true attitude and rate).
    estimator_params: dict passed to ``fusion.make`` (the estimator's own parameters; fs,
        frame and on_invalid are the environment's: ``ESTIMATOR_OWNED``).
    imu: a preset of ``fusion.imu.available()`` (default "mpu9250") or an ``IMUSpec``.
    imu_calibrated: use the preset's residuals after a power-on calibration (default True).
    imu_hz: IMU output rate (Hz, default 200, in [1, 10000]); physics_hz: physics rate, a
        whole multiple of imu_hz and of control_hz (default 400, in [100, 20000]); control_hz:
        agent rate (default 50, in [0.1, 1000], <= imu_hz, >= physics_hz / MAX_SUBSTEPS).
    imu_offset: (m) the IMU's position on the inner frame, from the axle centre.
    episode_s: episode length (s), default the task's ``default_episode_s``.
    robot: ``RobotParams``, or a dict of overrides of its fields.
    realism: "real" (default: the v1 robot's losses, compliance, latency, deadband, battery
        sag, vibration and own magnetic field) or "ideal" (``RobotParams.ideal()``: all of
        them off; a ``robot`` dict then overrides fields of the ideal robot, a
        ``RobotParams`` is used as it is). docs/envs/robot.md, "Realism".
    arena_size: side of the square arena (m) centred on the origin; leaving it ends the episode.
    bumps: number of low cylindrical bumps (height ``bump_height``) laid on the floor.
    ramps: number of ramps (slope ``ramp_deg``, height ``ramp_height``) on the floor.
    slippery_patches: number of low-friction discs on the floor (polished or wet tiles, dust:
        radius U(0.5, 1.5) m, placed by the seed); while the shell's centre is over one, the
        shell-floor friction coefficient is ``patch_friction`` (default 0.05) instead of
        ``robot.lateral_friction``, and the spinning friction scales with it. The drive can
        then slip, which the encoder's dead reckoning does not see. docs/envs/robot.md.
    mag_zones: None, "random" (``n_mag_zones`` dipoles placed by the seed) or a list of
        (x, y, field_uT): a magnetic dipole in the floor at (x, y) whose field at the
        IMU's height above it is field_uT (a steel plate, a motor).
    earth_field: (uT, ENU) the undisturbed field.
    render_mode: None, "rgb_array" (TinyRenderer, headless) or "human" (PyBullet window).
    render_size: (width, height) of rgb_array frames.
    compiled: True (default): the per-physics-step path (motor, servo, floor losses, true
        IMU signals, IMU model, estimator update) and the base's part of each step (action
        check, odometry, episode end, observation, info; the task's methods are called from
        it) run in C (envs/_signals.pyx, fusion/_imu.pyx), the same numbers as the Python
        methods here, which False selects (the reference).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}
    task = None                 # the subclass's task name
    TASK_OBS = ()               # the subclass's task values: (name, bound), ...
    default_episode_s = 30.0
    #: {name: index} of the observation (set for each subclass from BASE_OBS + TASK_OBS)
    OBS = obs_layout(BASE_OBS)

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        cls.OBS = obs_layout(BASE_OBS + cls.TASK_OBS)

    def __init__(self, estimator: str = "ekf", imu: str | fimu.IMUSpec = "mpu9250", *,
                 estimator_params: dict[str, Any] | None = None, imu_calibrated: bool = True,
                 imu_hz: float = 200.0, physics_hz: float = 400.0, control_hz: float = 50.0,
                 imu_offset: Sequence[float] = (0.02, 0.0, 0.03), episode_s: float | None = None,
                 robot: RobotParams | dict[str, Any] | None = None, arena_size: float = 20.0,
                 bumps: int = 0, bump_height: float = 0.012, ramps: int = 0, ramp_deg: float = 8.0,
                 ramp_height: float = 0.05, slippery_patches: int = 0, patch_friction: float = 0.05,
                 mag_zones: Sequence[Any] | None = None, n_mag_zones: int = 3,
                 earth_field: Sequence[float] = EARTH_FIELD, realism: str = "real",
                 render_mode: str | None = None, render_size: tuple[int, int] = (320, 240),
                 compiled: bool = True) -> None:
        super().__init__()
        if estimator not in ESTIMATORS():
            raise ValueError(f"unknown estimator {estimator!r}; accepted: {', '.join(ESTIMATORS())}")
        spec = _imu_spec(imu, imu_calibrated)
        self._check_render(render_mode, render_size)
        self.estimator_name = estimator
        self._check_rates(imu_hz, physics_hz, control_hz)
        if realism not in REALISM:
            raise ValueError(f"realism must be one of {', '.join(map(repr, REALISM))}, got {realism!r}")
        self.realism = realism
        self.robot = RobotParams.from_any(robot, ideal=realism == "ideal")
        check_explicit_damping(self.robot, self.physics_hz)
        if self.robot.latency_s > 1.0 / self.control_hz + 1e-12:
            raise ValueError(f"robot.latency_s must be in [0, 1 / control_hz = {1.0 / self.control_hz:g}] s, "
                             f"got {self.robot.latency_s!r}")
        self.arena_size = number("arena_size", arena_size, 2.0, 1000.0)
        eps = self.default_episode_s if episode_s is None else episode_s
        self.episode_s = number("episode_s", eps, 0.0, 1e6, open_low=True)
        self.max_steps = max(1, int(round(self.episode_s * self.control_hz)))
        # a recorded video plays at the control rate (one frame a step)
        self.metadata = {**type(self).metadata, "render_fps": self.control_hz}
        self._check_world(imu_offset, bumps, bump_height, ramps, ramp_deg, ramp_height, n_mag_zones, earth_field)
        self.slippery_patches = integer("slippery_patches", slippery_patches, 0, 1000)
        self.patch_friction = number("patch_friction", patch_friction, 0.0, 1.0)
        self._mag_zone_spec = _mag_zone_spec(mag_zones)
        self._compiled = flag("compiled", compiled)
        #: the per-physics-step path in C (envs/_signals.pyx), or None: the Python methods below
        self._loop = _signals.Loop() if self._compiled else None
        #: the rest of step() in C too, unless a subclass overrides one of the methods it inlines
        self._compiled_step = self._loop is not None and all(
            getattr(type(self), m) is getattr(SphereRobotBase, m) for m in _COMPILED_STEP)
        self.imu_spec = spec.replace(rate_hz=self.imu_hz)
        self._make_estimator(estimator, estimator_params)
        self._make_models()
        self._make_spaces()
        self._p = None
        self._client = None
        self._body = None
        self._bodies = []
        #: None, or the PyBullet client of a world shared with other robots (envs/vector.py)
        self._shared = None
        self._needs_reset = True
        #: None, or a list that receives one tuple per physics step (see enable_signal_log)
        self.signal_log = None

    def _check_render(self, render_mode, render_size):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"unknown render_mode {render_mode!r}; accepted: None, "
                             f"{', '.join(self.metadata['render_modes'])}")
        self.render_mode = render_mode
        try:
            rw, rh = render_size
            rw, rh = integer("render_size[0]", rw, 16, 4096), integer("render_size[1]", rh, 16, 4096)
        except (TypeError, ValueError):
            raise ValueError(f"render_size must be (width, height), two integers in [16, 4096], "
                             f"got {render_size!r}") from None
        self.render_size = (rw, rh)

    def _check_rates(self, imu_hz, physics_hz, control_hz):
        # lower bounds: the estimator's fs range starts at 1 Hz here (slower is no IMU), and one
        # step() runs at most MAX_SUBSTEPS physics steps (~50 us each: about half a second)
        self.imu_hz = number("imu_hz", imu_hz, 1.0, 10000.0)
        self.physics_hz = number("physics_hz", physics_hz, 0.0, 20000.0, open_low=True)
        self.control_hz = number("control_hz", control_hz, 0.1, 1000.0)
        if self.control_hz > self.imu_hz:
            raise ValueError(f"control_hz must be <= imu_hz = {self.imu_hz:g} Hz (one IMU sample or more per "
                             f"action), got {control_hz!r}")
        if self.physics_hz / self.control_hz > MAX_SUBSTEPS:
            raise ValueError(f"control_hz must be >= physics_hz / {MAX_SUBSTEPS} = "
                             f"{self.physics_hz / MAX_SUBSTEPS:g} Hz (at most {MAX_SUBSTEPS} physics steps "
                             f"per step()), got {control_hz!r}")
        if not _multiple(self.physics_hz, self.imu_hz):
            raise ValueError(f"physics_hz must be a whole multiple of imu_hz = {self.imu_hz:g} Hz "
                             f"(range: k * {self.imu_hz:g}, k = 1, 2, ...), got {physics_hz!r}")
        if not _multiple(self.physics_hz, self.control_hz):
            raise ValueError(f"physics_hz must be a whole multiple of control_hz = {self.control_hz:g} Hz "
                             f"(range: k * {self.control_hz:g}, k = 1, 2, ...), got {physics_hz!r}")
        if self.physics_hz < 100.0:
            raise ValueError(f"physics_hz must be >= 100 Hz for stable contact, got {physics_hz!r}")

    def _check_world(self, imu_offset, bumps, bump_height, ramps, ramp_deg, ramp_height, n_mag_zones,
                     earth_field):
        lim = 0.9 * self.robot.shell_radius
        what = f"(m) within 0.9 * shell_radius = {lim:g} m of the centre"
        off = _vector3("imu_offset", imu_offset, what)
        if math.sqrt(sum(v * v for v in off)) > lim:
            raise ValueError(f"imu_offset must be 3 finite numbers {what}, got {imu_offset!r}")
        self.imu_offset = off
        self._has_offset = any(v != 0.0 for v in off)
        self.bumps, self.ramps = integer("bumps", bumps, 0, 1000), integer("ramps", ramps, 0, 1000)
        self.n_mag_zones = integer("n_mag_zones", n_mag_zones, 0, 1000)
        self.bump_height = number("bump_height", bump_height, 0.001, 0.5 * self.robot.shell_radius)
        self.ramp_deg = number("ramp_deg", ramp_deg, 0.5, 30.0)
        self.ramp_height = number("ramp_height", ramp_height, 0.005, 1.0)
        what = "(uT, ENU) with a norm in (0, 1e4)"
        ef = _vector3("earth_field", earth_field, what)
        if not 0 < math.sqrt(sum(v * v for v in ef)) < 1e4:
            raise ValueError(f"earth_field must be 3 finite numbers {what}, got {earth_field!r}")
        self.earth_field = ef

    def _make_estimator(self, estimator, estimator_params):
        if estimator_params is not None and not isinstance(estimator_params, Mapping):
            raise ValueError(f"estimator_params must be None or a dict of the estimator's parameters "
                             f"(fusion.make's **params), got {estimator_params!r}")
        self._est_params = dict(estimator_params or {})
        if not all(isinstance(k, str) for k in self._est_params):
            raise ValueError(f"estimator_params' keys must be parameter names (str), got {estimator_params!r}")
        owned = [k for k in ESTIMATOR_OWNED if k in self._est_params]
        if owned:
            raise ValueError(f"estimator_params must not set {', '.join(owned)}: the environment sets them "
                             f"({'; '.join(ESTIMATOR_OWNED[k] for k in owned)})")
        if estimator != "truth":
            # build once here so that bad parameters fail at construction
            try:
                self._est = fusion.make(estimator, self.imu_hz, on_invalid="skip", **self._est_params)
            except (TypeError, ValueError) as e:
                if not self._est_params:
                    raise
                raise type(e)(f"estimator_params: {e}") from None
        else:
            if self._est_params:
                raise ValueError("estimator_params must be empty for estimator='truth'")
            self._est = None
        self._imu = None

    def _make_models(self):
        rp = self.robot
        self._motor = DCMotor(rp)
        self._servo = Servo(rp) if rp.steer_band > 0 else None
        self._lat_steps = int(round(rp.latency_s * self.physics_hz))
        self._vib = bool(rp.vib_motor or rp.vib_commutation or rp.vib_gear or rp.vib_seam)
        self._w_top = rp.motor_voltage / rp.motor_k
        # (motor tone's multiple of the drive angle, its amplitude, commutation's, gear mesh's
        # multiple and amplitude, seam's, 1 / top speed, the highest tone kept (rad/s))
        self._vib_k = (rp.gear_ratio, rp.vib_motor, rp.vib_commutation, rp.gear_teeth, rp.vib_gear, rp.vib_seam,
                       1.0 / self._w_top, 0.8 * math.pi * self.physics_hz)
        self._qd = self._wd_last = self._qs = 0.0
        self._self_field = bool(rp.mag_steer or rp.mag_current)
        self._dipole = pendulum_dipole(rp, self.imu_offset)
        self._n_sub = int(round(self.physics_hz / self.control_hz))
        self._dt = 1.0 / self.physics_hz
        self._settle_steps = int(round(0.1 * self.physics_hz))
        self._spin = spin_torque(rp)
        # the spinning friction is a friction (mu times a contact-patch radius): it scales with
        # the friction coefficient on a slippery patch
        self._spin_patch = self._spin * (self.patch_friction / rp.lateral_friction if rp.lateral_friction > 0 else 1.0)
        self._i_servo = SERVO_STALL_CURRENT / rp.steer_torque if self._servo is not None else 0.0

    def _make_spaces(self):
        parts = BASE_OBS + self.TASK_OBS
        high = np.array([b for _, b in parts], dtype=np.float32)
        self._obs_high = high
        self._obs_low = -high
        self.observation_space = spaces.Box(-high, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.obs_names = tuple(name for name, _ in parts)

    # ------------------------------------------------------------------------------------
    # physics client and world

    def _connect(self):
        import pybullet as p
        self._p = p
        self._shapes = {}           # the world's collision shapes ({name: id}, _shape)
        self._kept = 0              # resets since the world was last rebuilt (_build_world)
        if self._shared is not None:
            self._client = self._shared
            return
        if self.render_mode == "human":
            # without a display PyBullet's GUI ends the whole process from C; fail in Python
            headless = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
            if sys.platform.startswith("linux") and headless:
                raise RuntimeError("render_mode='human' opens PyBullet's window and needs a display "
                                   "(DISPLAY is not set); use render_mode='rgb_array' for headless frames")
            if sys.platform.startswith("linux") and os.environ.get("DISPLAY") and not _x_display_answers():
                raise RuntimeError(f"render_mode='human' opens PyBullet's window, and the X display "
                                   f"{os.environ['DISPLAY']!r} does not answer; use render_mode='rgb_array' "
                                   f"for headless frames")
            self._client = p.connect(p.GUI)
        else:
            self._client = p.connect(p.DIRECT)
        if self._client < 0:
            raise RuntimeError("could not connect to PyBullet")

    def _ramp_run(self):
        """(m) the horizontal length of a ramp's slope."""
        return self.ramp_height / math.tan(math.radians(self.ramp_deg))

    @property
    def _ramp_verts(self):
        """The ramp's mesh vertices, one list built once: PyBullet keeps every new vertex list
        passed to createCollisionShape (memory grew 10 MB per 1,000 resets with ramps)."""
        v = getattr(self, "_ramp_verts_cache", None)
        if v is None:
            h, run = self.ramp_height, self._ramp_run()
            top, w = RAMP_TOP, RAMP_WIDTH
            xs = (-(top / 2 + run), -top / 2, top / 2, top / 2 + run)
            v = []
            for yy in (-w / 2, w / 2):
                v += [[xs[0], yy, 0.0], [xs[1], yy, h], [xs[2], yy, h], [xs[3], yy, 0.0]]
            self._ramp_verts_cache = v
        return v

    def _build_world(self, start_xy, start_yaw, bumps, ramps):
        p, c = self._p, self._client
        visual = self.render_mode is not None
        # The floor kept and the other bodies removed: the same episode as in a new world
        # (tests/test_envs.py), 1.3 ms sooner than resetSimulation and a new floor. PyBullet
        # frees part of a removed body's memory only in resetSimulation (1-7 kB per reset),
        # so every REBUILD_EVERY-th reset rebuilds the world. A robot of envs/vector.py's
        # shared world removes only its own bodies (the one floor is envs/vector.py's).
        keep = []
        if self._shared is None and self._bodies and not visual and self._kept < REBUILD_EVERY:
            keep = self._bodies[:1]
        if self._shared is None and not keep:
            p.resetSimulation(physicsClientId=c)
            self._shapes = {}
            self._kept = 0
            self._world_settings()
        else:
            self._kept += 1
            for body in self._bodies[len(keep):]:
                p.removeBody(body, physicsClientId=c)
        statics = keep if keep else ([self._make_floor()] if self._shared is None else [])
        for (x, y, yaw) in bumps:
            h = self.bump_height
            col = self._shape("bump", p.GEOM_CAPSULE, radius=h, height=BUMP_LENGTH)
            vis = p.createVisualShape(p.GEOM_CAPSULE, radius=h, length=BUMP_LENGTH, rgbaColor=[0.5, 0.35, 0.2, 1],
                                      physicsClientId=c) if visual else -1
            # capsule axis z turned horizontal (about x by 90 deg), then yawed
            qa = (math.sin(math.pi / 4), 0.0, 0.0, math.cos(math.pi / 4))
            qy = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            orn = p.multiplyTransforms([0, 0, 0], qy, [0, 0, 0], qa)[1]
            statics.append(p.createMultiBody(0, col, vis, [x, y, 0.0], orn, physicsClientId=c))
        for (x, y, yaw) in ramps:
            verts = self._ramp_verts
            col = self._shape("ramp", p.GEOM_MESH, vertices=verts)
            vis = -1
            if visual:
                idx = [0, 1, 2, 0, 2, 3, 4, 6, 5, 4, 7, 6, 0, 4, 5, 0, 5, 1, 1, 5, 6, 1, 6, 2, 2, 6, 7, 2, 7, 3]
                vis = p.createVisualShape(p.GEOM_MESH, vertices=verts, indices=idx, rgbaColor=[0.6, 0.6, 0.55, 1],
                                          physicsClientId=c)
            orn = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            statics.append(p.createMultiBody(0, col, vis, [x, y, 0.0], orn, physicsClientId=c))
        self._bodies = statics
        for b in statics:
            p.changeDynamics(b, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0,
                             restitution=0.0, physicsClientId=c)
        if visual:
            self._add_floor_visual()
        self._body = build_robot(p, c, self.robot, start_xy, start_yaw, visual=visual,
                                 shell_shape=self._shape("shell", p.GEOM_SPHERE, radius=self.robot.shell_radius))
        self._bodies.append(self._body)

    def _shape(self, key, geom, **kw):
        """The world's collision shape ``key``, made once per world: shapes outlive the bodies
        removed between episodes (they grew memory 30 kB per reset)."""
        col = self._shapes.get(key)
        if col is None:
            col = self._shapes[key] = self._p.createCollisionShape(geom, physicsClientId=self._client, **kw)
        return col

    def _make_floor(self):
        p, c = self._p, self._client
        floor = p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=c), physicsClientId=c)
        p.changeDynamics(floor, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0,
                         restitution=0.0, physicsClientId=c)
        return floor

    def _world_settings(self):
        p, c = self._p, self._client
        p.setGravity(0.0, 0.0, -G, physicsClientId=c)
        p.setPhysicsEngineParameter(fixedTimeStep=self._dt, numSubSteps=0, deterministicOverlappingPairs=1,
                                    physicsClientId=c)

    def _add_floor_visual(self):
        import pybullet_data
        p, c = self._p, self._client
        vis = p.createVisualShape(p.GEOM_MESH, fileName=pybullet_data.getDataPath() + "/plane100.obj",
                                  meshScale=[0.2, 0.2, 1.0], rgbaColor=[1, 1, 1, 1], physicsClientId=c)
        b = p.createMultiBody(0, -1, vis, [0, 0, -0.0005], physicsClientId=c)
        tex = p.loadTexture(pybullet_data.getDataPath() + "/checker_blue.png", physicsClientId=c)
        p.changeVisualShape(b, -1, textureUniqueId=tex, physicsClientId=c)
        self._mag_markers()

    def _mag_markers(self):
        p, c = self._p, self._client
        for (cx, cy, r2) in self._patches:
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=math.sqrt(r2), length=0.002,
                                      rgbaColor=[0.85, 0.95, 1.0, 1], physicsClientId=c)
            p.createMultiBody(0, -1, vis, [cx, cy, 0.001], physicsClientId=c)
        for (cx, cy, _cz, _mx, _my, _mz, _r2) in self._zones:
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=0.15, length=0.004, rgbaColor=[0.8, 0.1, 0.1, 1],
                                      physicsClientId=c)
            p.createMultiBody(0, -1, vis, [cx, cy, 0.002], physicsClientId=c)

    # ------------------------------------------------------------------------------------
    # random draws of an episode (all from self.np_random, in a fixed order)

    def _draw_layout(self, start=None):
        """(start_xy, start_yaw, bumps, ramps): the start drawn, or ``start`` (x, y) in its
        place (drawn all the same, so that the rest of the layout is the same)."""
        rng = self.np_random
        start_xy = rng.uniform(-0.5, 0.5, size=2)
        if start is not None:
            start_xy = start
        start_yaw = float(rng.uniform(-math.pi, math.pi))
        half = 0.5 * self.arena_size

        def away(n, extent):
            # extent: the obstacle's radius about its centre. One moved too close is pushed
            # straight away from the start until START_CLEARANCE of floor lies between
            # the start and the obstacle (no extra random draw, so the rest of the
            # layout stays the same).
            out = []
            keep = START_CLEARANCE + extent
            for _ in range(n):
                xy = rng.uniform(-half + 1.0, half - 1.0, size=2)
                yaw = float(rng.uniform(-math.pi, math.pi))
                d = xy - start_xy
                dist = math.hypot(d[0], d[1])
                if dist < keep:
                    u = d / dist if dist > 1e-9 else np.array([1.0, 0.0])
                    xy = start_xy + u * keep
                out.append((float(xy[0]), float(xy[1]), yaw))
            return out

        bumps = away(self.bumps, 0.5 * BUMP_LENGTH + self.bump_height)
        ramps = away(self.ramps, math.hypot(0.5 * RAMP_TOP + self._ramp_run(), 0.5 * RAMP_WIDTH))
        self._zones = self._draw_zones()
        return start_xy, start_yaw, bumps, ramps

    def _draw_patches(self):
        """The slippery patches: (x, y, squared radius), anywhere in the arena."""
        rng = self.np_random
        half = 0.5 * self.arena_size
        out = []
        for _ in range(self.slippery_patches):
            xy = rng.uniform(-half + 1.0, half - 1.0, size=2)
            r = float(rng.uniform(*PATCH_RADIUS))
            out.append((float(xy[0]), float(xy[1]), r * r))
        return out

    def _draw_zones(self):
        """The magnetic zones: (x, y, z, moment (A m^2, 3), squared radius of influence)."""
        rng = self.np_random
        half = 0.5 * self.arena_size
        zones = []
        r_imu = self.robot.shell_radius + self.imu_offset[2]
        spec = self._mag_zone_spec
        if spec == "random":
            for _ in range(self.n_mag_zones):
                xy = rng.uniform(-half + 1.0, half - 1.0, size=2)
                f = float(rng.uniform(10.0, 60.0))
                d = rng.normal(size=3)
                d /= np.linalg.norm(d)
                zones.append((float(xy[0]), float(xy[1]), f, tuple(float(v) for v in d)))
        elif spec:
            zones = [(x, y, f, (0.0, 0.0, 1.0)) for (x, y, f) in spec]
        out = []
        for (x, y, f, d) in zones:
            m = fimu.dipole_moment_for(f, r_imu)
            # zone radius: where the on-axis field has fallen to 0.05 uT (below any preset's LSB)
            cut = (0.2 * m / 0.05) ** (1.0 / 3.0)
            out.append((x, y, 0.0, m * d[0], m * d[1], m * d[2], cut * cut))
        return out

    # ------------------------------------------------------------------------------------
    # the physics loop

    def _sense(self, first=False):
        """One physics step's sensing: the true signals -> the IMU model -> the estimator.

        The compiled loop (envs/_signals.pyx) runs the same numbers; these Python methods are
        its reference, and run while a signal log is on."""
        loop = self._loop
        if loop is not None:
            if first:
                loop.load(self)             # the episode's world, zones and IMU
            if self.signal_log is None:
                loop.sense(self, first)
                return
        s = self._measure(first)
        if s is not None:
            self._on_sample(s, self._est.update(s.gyr, s.acc, s.mag) if self._est is not None else None)

    def _measure(self, first=False):
        """The true signals -> the IMU model: its sample if one is due, else None."""
        gyr, acc, mag = self._true_signals(first)
        s = self._imu.step(gyr, acc, mag)
        if self.signal_log is not None:
            pos, orn, lin = self._true[0], self._true[1], self._true[2]
            self.signal_log.append((pos, orn, lin, self._wb, gyr, acc, mag, s))
        return s

    def _on_sample(self, s, q):
        """An IMU sample ``s`` and the estimator's quaternion ``q`` after it (None for "truth")."""
        self._n_samples += 1
        x, y, z, w = self._true[1]
        self._q_true_s = (w, x, y, z)
        if self._est is not None:
            self._q_est = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))    # as the compiled loop's
            g = s.gyr
        else:
            g = self._true[3]
        self._gyr_last = g
        self._gyr_sum_y += g[1]
        self._gyr_n += 1

    def _true_signals(self, first=False):
        """The true IMU signals at the current physics step: (gyro (rad/s), specific force
        (m/s^2), field (uT)), body frame, at the IMU's point; also sets ``self._true``
        (position, orientation, velocity, gyro, specific force, field) and the state the
        next step needs (the IMU point's velocity, the frame's rate and axle).

        Plain float arithmetic (no numpy): this runs at the physics rate."""
        p, c, b = self._p, self._client, self._body
        pos, orn = p.getBasePositionAndOrientation(b, c)
        lin, ang = p.getBaseVelocity(b, c)
        x, y, z, w = orn
        # body -> world rotation matrix R
        x2, y2, z2 = x + x, y + y, z + z
        xx, yy, zz = x * x2, y * y2, z * z2
        xy_, xz, yz, wx, wy, wz = x * y2, x * z2, y * z2, w * x2, w * y2, w * z2
        r00, r01, r02 = 1.0 - (yy + zz), xy_ - wz, xz + wy
        r10, r11, r12 = xy_ + wz, 1.0 - (xx + zz), yz - wx
        r20, r21, r22 = xz - wy, yz + wx, 1.0 - (xx + yy)
        wx_, wy_, wz_ = ang
        vx, vy, vz = lin
        if self._has_offset:
            # IMU point: v + w x (R r)
            ox, oy, oz = self.imu_offset
            rx = r00 * ox + r01 * oy + r02 * oz
            ry = r10 * ox + r11 * oy + r12 * oz
            rz = r20 * ox + r21 * oy + r22 * oz
            vx += wy_ * rz - wz_ * ry
            vy += wz_ * rx - wx_ * rz
            vz += wx_ * ry - wy_ * rx
        else:
            rx = ry = rz = 0.0
        if first:
            ax = ay = 0.0
            az = G
        else:
            k = self.physics_hz
            pv = self._v_prev
            ax, ay, az = (vx - pv[0]) * k, (vy - pv[1]) * k, (vz - pv[2]) * k + G   # a - g, g = (0, 0, -G)
        self._v_prev = (vx, vy, vz)
        self._wb, self._axle = ang, (r01, r11, r21)
        bx, by, bz = self.earth_field
        if self._zones:
            bx, by, bz = self._zone_field(pos[0] + rx, pos[1] + ry, pos[2] + rz, bx, by, bz)
        # world -> body: R^T v
        gyr = (r00 * wx_ + r10 * wy_ + r20 * wz_, r01 * wx_ + r11 * wy_ + r21 * wz_, r02 * wx_ + r12 * wy_ + r22 * wz_)
        if self._vib:                       # body frame
            vx_, vy_, vz_ = self._vibration()
            acc = (r00 * ax + r10 * ay + r20 * az + vx_, r01 * ax + r11 * ay + r21 * az + vy_,
                   r02 * ax + r12 * ay + r22 * az + vz_)
        else:
            acc = (r00 * ax + r10 * ay + r20 * az, r01 * ax + r11 * ay + r21 * az, r02 * ax + r12 * ay + r22 * az)
        mag = (r00 * bx + r10 * by + r20 * bz, r01 * bx + r11 * by + r21 * bz, r02 * bx + r12 * by + r22 * bz)
        if self._self_field:
            mag = self._add_self_field(mag)
        self._true = (pos, orn, lin, gyr, acc, mag)
        return gyr, acc, mag

    def _zone_field(self, px, py, pz, bx, by, bz):
        """(uT, world) the field (bx, by, bz) plus the zones' dipoles at the point (px, py, pz)."""
        for (cx, cy, cz, mx, my, mz, r2) in self._zones:
            dx, dy, dz = px - cx, py - cy, pz - cz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < r2:
                d = math.sqrt(max(d2, 1e-4))
                ux, uy, uz = dx / d, dy / d, dz / d
                mr = mx * ux + my * uy + mz * uz
                s = 0.1 / (d * d * d)           # mu0 / 4 pi in uT m^3 / (A m^2)
                bx += s * (3 * ux * mr - mx)
                by += s * (3 * uy * mr - my)
                bz += s * (3 * uz * mr - mz)
        return bx, by, bz

    def _add_self_field(self, mag):
        """(uT, body frame) the robot's own field at the IMU on top of ``mag``: what a
        calibration at rest with the pendulum centred and the motor off leaves. The
        pendulum's field (steel cans of the cells, the servo's magnet; magnitude
        ``mag_steer`` at the IMU when centred) is a point dipole at its centre of mass that
        turns with the steering angle (envs.robot.dipole_field), so its change from the
        centred value remains; the drive current's field (unshielded leads and the motor's
        armature; ``mag_current`` uT per A) lies along the axle and changes sign with the
        current. docs/envs/robot.md."""
        dx, dy, dz = dipole_field(self._dipole, self.imu_offset, self._qs)
        dy += self.robot.mag_current * self._motor.i_signed
        return (mag[0] + dx, mag[1] + dy, mag[2] + dz)

    def _vibration(self):
        """(m/s^2, body frame) the drive's vibration at the IMU, phase-locked to the drive
        joint's angle (so the same at any physics rate) and scaled with its speed: the motor's
        imbalance (a vector rotating in the x-z plane at the motor's speed, gear_ratio x the
        output), its commutation (2x, along z), the output stage's gear mesh (gear_teeth x
        the output, x-z) and the shell's seam (a raised-cosine pulse along z once per
        revolution, 0.15 rad of shell rotation wide, less its mean over the revolution,
        SEAM_MEAN: the shell rises over the seam and comes down again, so the pulse moves no
        mean acceleration; the bare pulse read 0.009 m/s^2 above g in steady rolling at full
        drive). Tones above 0.4 physics_hz are left out
        (they would alias in the physics itself). Amplitudes: docs/envs/robot.md."""
        n_m, a_m, a_c, n_g, a_g, a_s, inv_top, lim = self._vib_k
        q, w = self._qd, self._wd_last
        if w < 0.0:
            w = -w
        s = w * inv_top
        vx = vy = vz = 0.0
        if n_m * w < lim:
            ph = n_m * q
            c, sn = math.cos(ph), math.sin(ph)
            a = a_m * s
            vx = a * c
            vz = a * sn
            vy = 0.3 * a * (0.5403023058681398 * c - 0.8414709848078965 * sn)      # cos(ph + 1)
            if 2.0 * n_m * w < lim:
                vz += a_c * s * (c * c - sn * sn)                                  # cos(2 ph)
        if n_g * w < lim:
            ph = n_g * q
            a = a_g * s
            vx += a * math.sin(ph)
            vz += a * math.cos(ph)
        if a_s:
            u = (q % 6.283185307179586) * (1.0 / 0.15)
            vz += a_s * s * s * ((0.5 * (1.0 - math.cos(6.283185307179586 * u)) if u < 1.0 else 0.0) - SEAM_MEAN)
        return vx, vy, vz

    def _advance(self, n, voltage, target):
        """n physics steps with the drive ``voltage`` (V at the nominal pack voltage) and the
        steering ``target`` (rad); the previous command holds for the first
        ``latency_s`` of them (actuation latency). The compiled loop runs the same."""
        if self._loop is not None:
            if self.signal_log is None:
                self._loop.advance(self, n, voltage, target)
                return
            self._loop.forget()         # (the joints it read last are moving)
        step, c, actuate, sense = self._p.stepSimulation, self._client, self._actuate, self._sense
        for i in range(n):
            actuate(i, voltage, target)
            step(c)
            sense()
        self._cmd_prev = (voltage, target)

    def _actuate(self, i, voltage, target):
        """Before physics step ``i`` of ``_advance``: read the joints, command the drive's and
        the servo's torques and apply the floor's losses on the shell."""
        p, c, b = self._p, self._client, self._body
        rp = self.robot
        motor, servo = self._motor, self._servo
        lat = self._lat_steps
        v, tgt = self._cmd_prev if i < lat else (voltage, target)
        js = p.getJointStates(b, _JOINTS, c)
        self._qd, wd = js[0][0], js[0][1]
        self._qs = js[1][0]
        self._wd_last = wd
        self._tau = tau = motor.torque(v, wd)
        ts = 0.0
        if servo is not None:
            ts = servo.torque(tgt, js[1][0], js[1][1])
            motor.i_other = self._i_servo * abs(ts)
        elif i == lat or (i == 0 and lat == self._n_sub):
            # the ideal robot's PyBullet position servo; a latency of one control period: the
            # last step's target, at this step's start
            set_steer(p, c, b, rp, tgt)
        p.setJointMotorControlArray(b, _JOINTS, p.TORQUE_CONTROL, forces=(tau, ts), physicsClientId=c)
        spin, roll_c = self._spin, rp.rolling_damping
        if self._patches:
            # the contact lies under the shell's centre: over a patch, its friction
            pos = self._true[0]
            on = False
            for (cx, cy, r2) in self._patches:
                dx, dy = pos[0] - cx, pos[1] - cy
                if dx * dx + dy * dy < r2:
                    on = True
                    break
            if on != self._patch_on:
                self._patch_on = on
                p.changeDynamics(b, DRIVE_JOINT, lateralFriction=self.patch_friction if on else rp.lateral_friction,
                                 physicsClientId=c)
            if on:
                spin = self._spin_patch
        if spin or roll_c:
            # the floor's losses on the shell (its rate: the frame's + wd x axle): viscous
            # rolling damping about x and y, spinning friction about z
            w, a = self._wb, self._axle
            e = (w[2] + wd * a[2]) * (1.0 / SPIN_EPS)
            p.applyExternalTorque(b, DRIVE_JOINT, (-roll_c * (w[0] + wd * a[0]), -roll_c * (w[1] + wd * a[1]),
                                                   -spin * (1.0 if e > 1.0 else (-1.0 if e < -1.0 else e))),
                                  p.WORLD_FRAME, physicsClientId=c)
        stiction = rp.drive_stiction
        if stiction:
            stuck = -STICK_RATE < wd < STICK_RATE
            if stuck != self._stuck_gear:
                self._stuck_gear = stuck
                set_drive_friction(p, c, b, stiction if stuck else rp.drive_coulomb)

    # ------------------------------------------------------------------------------------
    # Gymnasium API

    # ------------------------------------------------------------------------------------
    # Gymnasium API

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        self._reset_begin(seed, options)
        self._advance(self._settle_steps, 0.0, 0.0)
        return self._reset_end()

    def _reset_begin(self, seed, options):
        """A reset up to the settling: the episode's draws, the new world, the first sensing."""
        super().reset(seed=seed)
        if self._client is None:
            self._connect()
        start = self._checked_options(options)
        # the bumps and ramps keep clear of the start used, the drawn one or the option's
        self._xy0, self._yaw0, bumps, ramps = self._draw_layout(start.get("start_xy"))
        self._yaw0 = start.get("start_yaw", self._yaw0)
        self._draw_task()
        if self._imu is None:
            self._imu = fimu.IMU(self.imu_spec, self.np_random, physics_rate_hz=self.physics_hz,
                                 compiled=self._compiled)
        else:
            self._imu.reset(rng=self.np_random)
        # drawn after everything else of the reset, so that with patches the episode's other
        # draws (layout, task, IMU) are those of the flat floor
        self._patches = self._draw_patches()
        self._patch_on = False
        self._build_world(self._xy0, self._yaw0, bumps, ramps)
        if self._est is not None:
            self._est.reset()
        self._q_est = None
        self._q_true_s = None
        self._gyr_last = [0.0, 0.0, 0.0]
        self._last_sample = None
        self._n_samples = 0
        self._gyr_sum_y, self._gyr_n = 0.0, 0
        self._qd = self._wd_last = self._qs = 0.0
        self._motor.reset()
        self._sense(first=True)
        self._cmd_prev = (0.0, 0.0)
        self._stuck_gear = False

    def _reset_end(self):
        """A reset after the settling: the episode's state, the first observation and info."""
        self._t = 0.0
        self._steps = 0
        self._action = (0.0, 0.0)
        self._clipped = 0
        self._stuck_t = 0.0
        self._enc_counts = self._encoder_counts()
        self._enc_speed = 0.0
        self._pos_est = [float(self._xy0[0]), float(self._xy0[1])]
        self._gyr_sum_y, self._gyr_n = 0.0, 0
        self._reset_task()
        self._needs_reset = False
        psi = self._heading_est()
        info = self._info(dict.fromkeys(self.REWARD_TERMS, 0.0), psi)
        # the step's keys too, so that a vector env's autoreset step has every key
        info["out_of_arena"] = info["stuck"] = False
        self._task_step_info(info, False)
        return self._observation(psi, self._est_bias()), info

    def _checked_options(self, options):
        """reset()'s options as {"start_xy": (2,) floats, "start_yaw": float}, each if given."""
        out = {}
        if options is None:
            return out
        if not isinstance(options, Mapping):
            raise ValueError(f"options must be None or a dict with start_xy and/or start_yaw, got {options!r}")
        bad = sorted(map(str, set(options) - {"start_xy", "start_yaw"}))
        if bad:
            raise ValueError(f"unknown reset option(s) {', '.join(bad)}; accepted: start_xy, start_yaw")
        if "start_xy" in options:
            try:
                xy = np.asarray(options["start_xy"])
            except (TypeError, ValueError):
                xy = np.array(())
            if (xy.dtype.kind not in "iuf" or xy.shape != (2,) or not np.all(np.isfinite(xy))
                    or np.any(np.abs(xy) > 0.5 * self.arena_size)):
                raise ValueError(f"options['start_xy'] must be 2 real numbers (x, y) inside the arena "
                                 f"(|x|, |y| <= {0.5 * self.arena_size:g} m), got {options['start_xy']!r}")
            out["start_xy"] = xy.astype(float)
        if "start_yaw" in options:
            out["start_yaw"] = number("options['start_yaw']", options["start_yaw"])
        return out

    def step(self, action: ArrayLike) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._compiled_step and self.signal_log is None:
            return self._loop.control_step(self, action)    # the three calls below, in C
        a0, a1 = self._begin_step(action)
        rp = self.robot
        self._advance(self._n_sub, a0 * rp.motor_voltage, a1 * rp.steer_max)
        return self._end_step(a0, a1)

    def _begin_step(self, action):
        """The checked action (a0, a1) of a step, before its physics."""
        if self._needs_reset:
            raise RuntimeError(NEEDS_RESET)
        a0, a1 = self._check_action(action)
        self._action = (a0, a1)
        self._gyr_sum_y, self._gyr_n = 0.0, 0
        return a0, a1

    def _end_step(self, a0, a1):
        """(obs, reward, terminated, truncated, info) of a step, after its physics."""
        if self._compiled_step:
            return self._loop.finish(self, a0, a1)      # the same as below, in C
        self._steps += 1
        self._t = self._steps / self.control_hz
        # the estimated heading and bias, read once: the estimator does not move until the next step
        psi, bias = self._heading_est(), self._est_bias()
        self._odometry(psi, bias)
        # reward, termination (the referee uses the true state)
        terms, done = self._get_rew(a0, a1)
        reward = float(sum(terms.values()))
        terminated, out, stuck = self._episode_end(done, a0)
        truncated = (not terminated) and self._steps >= self.max_steps
        if terminated or truncated:
            self._needs_reset = True
        obs = self._observation(psi, bias)
        info = self._info(terms, psi)
        info["out_of_arena"] = out
        info["stuck"] = stuck
        self._task_step_info(info, terminated and not out and not stuck)
        return obs, reward, terminated, truncated, info

    def _check_action(self, action):
        """The action as two floats in [-1, 1] (clipped, counted); ValueError if not 2 finite numbers."""
        a0, a1, clipped = parse_action(action)
        if clipped:
            self._clipped += 1
        return a0, a1

    def _encoder_counts(self):
        cpr = self.robot.encoder_cpr
        return math.floor(self._p.getJointState(self._body, DRIVE_JOINT, self._client)[0] * cpr / (2 * math.pi))

    def _odometry(self, psi, bias):
        """The robot's own estimates after a control period: the Hall encoder's speed over it,
        and the dead-reckoned position (with the optional position fix) along the estimated
        heading ``psi``, with the gyro's ``bias`` (3 floats or None) removed from its rate."""
        rp = self.robot
        counts = self._encoder_counts()
        self._enc_speed = (counts - self._enc_counts) * (2 * math.pi / rp.encoder_cpr) * self.control_hz
        self._enc_counts = counts
        rate_y = self._gyr_sum_y / self._gyr_n if self._gyr_n else 0.0
        if bias is not None:
            rate_y -= bias[1]
        v_est = rp.shell_radius * (self._enc_speed + rate_y)
        step_len = v_est / self.control_hz
        self._pos_est[0] += step_len * math.cos(psi)
        self._pos_est[1] += step_len * math.sin(psi)
        if self.position_fix_hz > 0 and self._t >= self._next_fix - 1e-9:
            self._position_fix()

    def _position_fix(self):
        """The dead reckoning replaced by the true position with the fix's noise."""
        pos = self._true[0]
        n = self.np_random.normal(size=2) * self.position_fix_std
        self._pos_est = [pos[0] + float(n[0]), pos[1] + float(n[1])]
        self._next_fix += 1.0 / self.position_fix_hz

    def _episode_end(self, done, a0):
        """(terminated, out of the arena, stuck) after a step; ``done``: the task's own end."""
        pos, lin = self._true[0], self._true[2]
        half = 0.5 * self.arena_size
        out = abs(pos[0]) > half or abs(pos[1]) > half
        speed = math.hypot(lin[0], lin[1])
        if speed < STUCK_SPEED and abs(a0) > STUCK_ACTION:
            self._stuck_t += 1.0 / self.control_hz
        else:
            self._stuck_t = 0.0
        stuck = self._stuck_t >= STUCK_TIME
        return bool(done or out or stuck), out, stuck

    def _forward_speed(self, psi=None):
        """(m/s) the true velocity along the true heading (``psi``: it, if already computed)."""
        lin = self._true[2]
        if psi is None:
            psi = self._heading_true()
        return lin[0] * math.cos(psi) + lin[1] * math.sin(psi)

    # ------------------------------------------------------------------------------------
    # the task's part (subclasses)

    #: the names of ``_get_rew``'s terms (``info["reward_terms"]``)
    REWARD_TERMS = ()
    #: a slow, noisy position fix of the dead reckoning: none in the base
    position_fix_hz = 0.0
    position_fix_std = 0.0

    def _draw_task(self):
        """Draw the episode's task from ``self.np_random`` (after the layout)."""
        raise NotImplementedError

    def _reset_task(self):
        """The task's state at the start of an episode (after settling)."""
        self._next_fix = 0.0

    def _task_obs(self, psi):
        """The observation's task values (``TASK_OBS``), given the estimated heading ``psi``."""
        raise NotImplementedError

    def _get_rew(self, a0, a1):
        """({term: value}, whether the task ended) after a step with the action (a0, a1)."""
        raise NotImplementedError

    def _task_info(self, info):
        """Add the task's entries to ``info``."""

    def _task_step_info(self, info, success):
        """Add the task's per-step entries (``success``: terminated by the task itself)."""

    @staticmethod
    def _effort(a0, a1):
        return -0.01 * (a0 * a0 + a1 * a1)

    # ------------------------------------------------------------------------------------

    def enable_signal_log(self) -> None:
        """Diagnostics: from now on append, at every physics step, a tuple (position,
        orientation [x, y, z, w] (PyBullet order), linear velocity, angular velocity (world),
        true gyro, true specific force, true field (body frame), IMU sample or None) to
        ``self.signal_log`` (a new list, returned). ``disable_signal_log()`` stops it."""
        self.signal_log = []
        return self.signal_log

    def disable_signal_log(self) -> None:
        self.signal_log = None

    def true_state(self) -> dict[str, Any]:
        """The simulator's state now: dict of position (m), orientation (the inner frame's
        quaternion [w, x, y, z]), velocity (m/s), body_rate (rad/s, frame axes), shell_rate
        (rad/s, world frame), drive_angle and steer_angle (rad), drive_speed (rad/s)."""
        if self._client is None:
            raise RuntimeError("call reset() first")
        p, c, b = self._p, self._client, self._body
        pos, orn = p.getBasePositionAndOrientation(b, c)
        lin, ang = p.getBaseVelocity(b, c)
        shell = p.getLinkState(b, DRIVE_JOINT, computeLinkVelocity=1, physicsClientId=c)
        js = p.getJointStates(b, [DRIVE_JOINT, STEER_JOINT], physicsClientId=c)
        x, y, z, w = orn
        R = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        return {"position": np.array(pos), "orientation": np.array([w, x, y, z]), "velocity": np.array(lin),
                "body_rate": R.T @ np.array(ang), "shell_rate": np.array(shell[7]),
                "drive_angle": js[0][0], "drive_speed": js[0][1], "steer_angle": js[1][0],
                "rotation": R}

    def _q_est_wxyz(self):
        """The estimated attitude (4 floats, the true one for "truth" or before a sample)."""
        if self._est is None or self._q_est is None:
            return self._q_true_s
        return self._q_est

    def _est_bias(self):
        """The estimator's gyro bias (3 floats), or None."""
        b = self._est.bias if self._est is not None else None
        return None if b is None else tuple(b.tolist())

    def _heading_est(self):
        return heading_of(*self._q_est_wxyz())

    def _heading_true(self):
        x, y, z, w = self._true[1]
        return heading_of(w, x, y, z)

    def _observation(self, psi, bias):
        """The observation, given the estimated heading ``psi`` and gyro ``bias`` (or None)."""
        w, x, y, z = self._q_est_wxyz()
        if w < 0:
            w, x, y, z = -w, -x, -y, -z
        g = self._gyr_last
        if bias is not None:
            g = (g[0] - bias[0], g[1] - bias[1], g[2] - bias[2])
        task = self._task_obs(psi)
        obs = np.array((w, x, y, z, g[0], g[1], g[2], self._enc_speed, self._action[0], self._action[1]) + task,
                       dtype=np.float32)
        np.maximum(obs, self._obs_low, out=obs)       # np.clip's numbers, without its Python wrapper
        np.minimum(obs, self._obs_high, out=obs)
        return obs

    def _info(self, terms, psi):
        pos, orn, lin = self._true[0], self._true[1], self._true[2]
        qt = self._q_true_s
        qe = self._q_est_wxyz()
        dot = abs(qt[0] * qe[0] + qt[1] * qe[1] + qt[2] * qe[2] + qt[3] * qe[3])
        err = math.degrees(2.0 * math.acos(min(1.0, dot)))
        info = {
            "q_true": np.array(qt), "q_est": np.array(qe), "attitude_error_deg": err,
            "position": np.array(pos), "velocity": np.array(lin),
            "heading_true": self._heading_true(), "heading_est": psi,
            "encoder_speed": self._enc_speed, "motor_torque": self._tau,
            "reward_terms": terms, "action_clipped": self._clipped,
            "estimator_skipped": dict(self._est.skipped) if self._est is not None else {"gyr": 0, "acc": 0, "mag": 0},
            "imu_samples": self._n_samples, "t": self._t,
            # angle of the inner frame's z axis from the vertical: > 90 deg means the pendulum
            # has swung over the top (hard braking or violent steering)
            "frame_tilt_deg": math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (orn[0] ** 2 + orn[1] ** 2))))),
        }
        self._task_info(info)
        return info

    # ------------------------------------------------------------------------------------

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self._client is None:
            return None
        p, c = self._p, self._client
        pos = self._true[0]
        if self.render_mode == "human":
            p.resetDebugVisualizerCamera(1.2, 45.0, -30.0, pos, physicsClientId=c)
            return None
        w, h = self.render_size
        view = p.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=pos, distance=0.9,
                                                   yaw=self._heading_true() * 180.0 / math.pi - 60.0, pitch=-20.0,
                                                   roll=0.0, upAxisIndex=2, physicsClientId=c)
        proj = p.computeProjectionMatrixFOV(fov=60.0, aspect=w / h, nearVal=0.02, farVal=50.0, physicsClientId=c)
        img = p.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER, shadow=1,
                               lightDirection=[0.4, 0.3, 1.0], physicsClientId=c)
        rgba = np.asarray(img[2], dtype=np.uint8).reshape(h, w, 4)
        return np.ascontiguousarray(rgba[:, :, :3])

    def close(self) -> None:
        if self._client is not None and self._p is not None and self._shared is None:
            try:
                self._p.disconnect(physicsClientId=self._client)
            except Exception:   # already gone (e.g. the GUI window was closed)
                pass
        self._client = None
        self._body = None
        self._bodies = []
        self._needs_reset = True

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
