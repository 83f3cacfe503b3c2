"""The pendulum-driven spherical robot: documented parameters, the PyBullet model, the
drive motor and the steering servo.

Everything here is plain data and functions of a physics client id: nothing connects to
PyBullet at import. ``build_robot(client, params, ...)`` creates the multibody in a world
that ``resetSimulation`` has just emptied.

Structure (one PyBullet multibody, base = the inner frame)::

    base   inner frame (chassis, drive motor, electronics, IMU); its origin and centre of
           mass are on the drive axle at the shell's centre; x forward, y along the axle
           (left), z up when level
    link 0 shell, on the revolute drive joint (axis +y of the frame, through the centre):
           positive joint speed rolls the robot forward (+x)
    link 1 pendulum (batteries, ballast), on the revolute steering joint (axis +x of the
           frame, through the centre); its centre of mass hangs ``pendulum_length`` below
           the axle. Tilting it sideways tilts the axle and the robot turns.

Only the shell collides (with the floor); the frame and the pendulum sit inside it.
Sources and reasoning for each number: docs/envs/robot.md and the docstrings below.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any
from fusion.checks import integer, number
from fusion.constants import GRAVITY

__all__ = ["RobotParams", "DCMotor", "Servo", "build_robot", "spin_torque", "explicit_damping", "check_explicit_damping", "EXPLICIT_TERMS", "pendulum_dipole", "dipole_field", "DRIVE_JOINT", "STEER_JOINT", "REALISM"]

DRIVE_JOINT = 0
STEER_JOINT = 1


@dataclass(frozen=True)
class RobotParams:
    """Physical parameters of the robot (SI units). Defaults follow seed 000's robot.

    Shell: transparent acrylic, 25 cm across (seed 000); the issue gives about 0.4 kg (two
    hemispheres of about 1.7 mm wall: 4 pi r^2 t rho = 0.40 kg with rho = 1190 kg/m^3).
    Thin-shell inertia 2/3 m r^2.

    Inner frame: chassis, drive motor and gearbox, STM32 board, IMU, Bluetooth, axle and
    bearings: 0.35 kg (a 25 mm geared motor with encoder is about 100 g, the rest is
    chassis and boards), a box 12 x 20 x 5 cm (the axle spans the shell), centre of mass on
    the axle (the designers balance it so; only the pendulum gives the righting moment).

    Pendulum: four 18650 cells (4 x 46.5 g) + 24 aluminium blocks of 5 g (seed 000) + holder
    and servo: 0.40 kg, a box 8 x 7 x 4 cm whose centre hangs 7.5 cm below the axle; its
    farthest corner is then 10.9 cm from the centre, inside the shell's 12.3 cm inner
    radius at any drive or steering angle (rotations about axes through the centre).

    Drive motor (a 25 mm geared DC motor with Hall encoder, 4.32 W class as in seed 000),
    referred to the output shaft: supply ``motor_voltage`` 7.4 V (the four cells as 2S2P),
    ``motor_k`` 0.925 V s/rad = N m/A (no-load speed 8 rad/s at 7.4 V: 1 m/s of rolling),
    ``motor_resistance`` 12 ohm (stall 0.57 N m, 0.62 A at 7.4 V), ``motor_friction`` 2e-3
    N m s/rad viscous gearbox loss, and ``motor_torque_limit`` 0.15 N m, the driver's
    current limit (0.16 A). The pendulum's largest righting moment is m g L = 0.29 N m; a
    torque step tau swings an undamped pendulum over the top when tau / (m g L) > 2 / pi
    (energy: tau * pi > 2 m g L), and with the pendulum steered sideways by 30 deg only
    cos 30 deg of its moment acts in pitch: 0.64 * 0.29 * 0.87 = 0.16 N m. 0.15 N m keeps a
    full-voltage start or reversal from flipping the pendulum (measured: at most about
    105 deg of frame pitch for full reversals every 0.5 s, none past 72 deg for uniformly
    random actions). ``encoder_cpr`` 1496 counts per output revolution (11-pulse Hall disc,
    x4 quadrature, 1:34 gearbox).

    Steering servo (metal-gear micro servo class, e.g. MG92B: 0.3-0.5 N m, 0.13 s / 60 deg):
    ``steer_max`` 30 deg each way, ``steer_torque`` 0.5 N m (holding the pendulum at 30 deg
    takes m g L sin 30 deg = 0.15 N m; the margin covers the dynamic loads of a turn),
    ``steer_speed`` 6.2 rad/s.

    Contact: ``lateral_friction`` 0.6 (acrylic on wood or vinyl), never reached by the drive:
    the largest traction it can ask for is tau / r * m / (m + I / r^2) = 0.97 N against
    mu N = 6.8 N (the environments' ``slippery_patches`` lower it where the drive slips);
    ``rolling_resistance`` 0.004 (the dimensionless coefficient Crr of a hard plastic ball on a
    hard floor: resisting torque Crr N r; an assumption among the handbook values of hard
    rolling contacts, 0.001-0.005, "Rolling Resistance", The Engineering ToolBox: no figure
    for a plastic shell was found); ``spinning_friction`` 2e-4 m (torsional friction of the
    small contact patch, mu times a patch radius; docs/envs/robot.md).
    ``contact_stiffness`` 1e4 N/m, ``contact_damping`` 54 N s/m: the shell's compliant contact
    with the floor, bumps and ramps, a linear spring-damper on the whole robot (the frame and
    pendulum ride the axle, rigid vertically). Thin-shell theory bounds the shell's own
    stiffness at about 1.2e5 N/m (docs/envs/robot.md, "Contact"); bushings, chassis and floor
    covering in series soften it by an unmeasured amount, and 1e4 N/m is the stiffest the
    400 Hz step resolves (sqrt(k / m) dt = 0.23: an impact of pi sqrt(m / k) = 34 ms, 13 steps).
    Damping ratio 0.25 (restitution 0.44), assumed; with 0.5 the damper's force step at
    touch-down (c v) was as large as the spring's peak, and a bump's peak reading was that step.

    Drive vibration (``vib_*``, m/s^2 at top speed): assumptions of the right order, not
    measurements (no published acceleration at the IMU of such a robot was found); the tones
    are those of the sources measured on small DC motors (imbalance, commutation, gear mesh:
    "Characterizing Sources of Small DC Motor Noise and Vibration", Micromachines 2018), the
    level set to give a few tenths of m/s^2 of |acc| std in steady rolling (docs/envs/robot.md).
    ``rolling_damping`` is an assumption too (the decay time of the sideways rocking).
    """

    shell_radius: float = 0.125
    shell_mass: float = 0.40
    frame_mass: float = 0.35
    frame_size: tuple = (0.12, 0.20, 0.05)
    pendulum_mass: float = 0.40
    pendulum_length: float = 0.075
    pendulum_size: tuple = (0.08, 0.07, 0.04)
    motor_voltage: float = 7.4
    motor_k: float = 0.925
    motor_resistance: float = 12.0
    motor_friction: float = 2e-3
    motor_torque_limit: float = 0.15
    encoder_cpr: int = 1496
    steer_max: float = math.radians(30.0)
    steer_torque: float = 0.5
    steer_speed: float = 6.2
    lateral_friction: float = 0.6
    rolling_resistance: float = 0.004
    spinning_friction: float = 2e-4
    rolling_damping: float = 5e-3
    # --- the real robot's losses and imperfections (docs/envs/robot.md, "Realism"); every
    # one of them 0 in RobotParams.ideal()
    drive_coulomb: float = 0.02
    drive_stiction: float = 0.03
    motor_deadband: float = 0.02
    battery_resistance: float = 0.2
    steer_band: float = math.radians(4.0)
    steer_friction: float = 0.02
    steer_stop: float = math.radians(5.0)
    latency_s: float = 0.01
    contact_stiffness: float = 1.0e4
    contact_damping: float = 54.0
    vib_motor: float = 0.5
    vib_commutation: float = 0.3
    vib_gear: float = 0.3
    vib_seam: float = 1.0
    mag_steer: float = 8.0
    mag_current: float = 10.0
    gear_ratio: float = 34.0
    gear_teeth: float = 20.0

    def __post_init__(self):
        # name: (low, high, SI unit for the message; robot={...} takes these units, where
        # docs/envs/robot.md's table gives some in deg or cm)
        ranges = {
            "shell_radius": (0.03, 2.0, "m"), "shell_mass": (1e-3, 100.0, "kg"), "frame_mass": (1e-3, 100.0, "kg"),
            "pendulum_mass": (1e-3, 100.0, "kg"), "pendulum_length": (0.0, None, "m"),
            "motor_voltage": (1e-3, 1000.0, "V"), "motor_k": (1e-6, 100.0, "N m/A"), "motor_resistance": (1e-6, 1e4, "ohm"),
            "motor_friction": (0.0, 100.0, "N m s/rad"), "motor_torque_limit": (1e-6, 1e4, "N m"),
            "steer_max": (0.0, math.radians(80.0), "rad"), "steer_torque": (1e-6, 1e4, "N m"), "steer_speed": (1e-3, 1e3, "rad/s"),
            "lateral_friction": (0.0, 10.0, ""), "rolling_resistance": (0.0, 1.0, ""), "spinning_friction": (0.0, 1.0, "m"),
            "rolling_damping": (0.0, 1.0, "N m s/rad"), "drive_coulomb": (0.0, 10.0, "N m"), "drive_stiction": (0.0, 10.0, "N m"), "motor_deadband": (0.0, 0.5, ""),
            "battery_resistance": (0.0, 100.0, "ohm"), "steer_band": (0.0, math.radians(45.0), "rad"),
            "steer_friction": (0.0, 10.0, "N m"), "steer_stop": (0.0, math.radians(45.0), "rad"), "latency_s": (0.0, 0.1, "s"),
            "contact_stiffness": (0.0, 1e9, "N/m"), "contact_damping": (0.0, 1e7, "N s/m"),
            "vib_motor": (0.0, 100.0, "m/s^2"), "vib_commutation": (0.0, 100.0, "m/s^2"), "vib_gear": (0.0, 100.0, "m/s^2"),
            "vib_seam": (0.0, 100.0, "m/s^2"), "mag_steer": (0.0, 1000.0, "uT"), "mag_current": (0.0, 1000.0, "uT/A"), "gear_ratio": (1.0, 1000.0, ""), "gear_teeth": (1.0, 1000.0, ""),
        }
        for name, (lo, hi, unit) in ranges.items():     # shell_radius first: pendulum_length's bound
            hi = 0.9 * self.shell_radius if name == "pendulum_length" else hi
            object.__setattr__(self, name, number(f"robot.{name}", getattr(self, name), lo, hi,
                                                  unit=f" {unit}" if unit else ""))
        self._check_relations()
        object.__setattr__(self, "encoder_cpr", integer("robot.encoder_cpr", self.encoder_cpr, 1, 10 ** 7))
        for name in ("frame_size", "pendulum_size"):
            v = getattr(self, name)
            try:
                t = tuple(float(x) for x in v)
            except (TypeError, ValueError):
                t = ()
            if len(t) != 3 or not all(math.isfinite(x) and 0 < x <= 2 * self.shell_radius for x in t):
                raise ValueError(f"robot.{name} must be 3 lengths in (0, 2 * shell_radius = "
                                 f"{2 * self.shell_radius:g}] m, got {v!r}")
            object.__setattr__(self, name, t)
        # everything inside the shell
        fx, fy, fz = self.frame_size
        px, py, pz = self.pendulum_size
        inner = self.shell_radius * 0.98
        if math.sqrt((fx / 2) ** 2 + (fy / 2) ** 2 + (fz / 2) ** 2) > inner:
            raise ValueError(f"robot.frame_size {self.frame_size} does not fit inside the shell "
                             f"(half-diagonal must be <= {inner:g} m)")
        if math.sqrt((px / 2) ** 2 + (py / 2) ** 2 + (self.pendulum_length + pz / 2) ** 2) > inner:
            raise ValueError(f"robot.pendulum_length + pendulum_size put the pendulum outside the shell "
                             f"(farthest corner must be <= {inner:g} m from the centre)")


    def _check_relations(self):
        """The checks that tie fields together (after each is in its own range)."""
        if self.drive_stiction and self.drive_stiction < self.drive_coulomb:
            raise ValueError(f"robot.drive_stiction must be 0 or >= robot.drive_coulomb = {self.drive_coulomb:g} N m, "
                             f"got {self.drive_stiction!r}")
        if (self.contact_stiffness > 0) != (self.contact_damping > 0):
            raise ValueError("robot.contact_stiffness and robot.contact_damping must both be > 0 (compliant "
                             f"contact) or both 0 (PyBullet's rigid contact), got {self.contact_stiffness!r} "
                             f"and {self.contact_damping!r}")
        if self.contact_stiffness > 0 and self.total_mass * GRAVITY / self.contact_stiffness > 0.1 * self.shell_radius:
            # softer, and the robot sinks through the floor (it starts at its static compression)
            raise ValueError(f"robot.contact_stiffness must carry the robot's weight with a static sink of at most "
                             f"0.1 * shell_radius: >= {self.total_mass * GRAVITY / (0.1 * self.shell_radius):g} N/m, "
                             f"got {self.contact_stiffness!r}")
        if math.degrees(self.steer_max + self.steer_stop) > 85.0:
            raise ValueError(f"robot.steer_max + robot.steer_stop must be <= 85 deg, got "
                             f"{math.degrees(self.steer_max + self.steer_stop):g} deg")

    def replace(self, **changes: Any) -> RobotParams:
        return replace(self, **changes)

    @classmethod
    def ideal(cls, **changes: Any) -> RobotParams:
        """The idealised robot of the v0 environments: no gearbox or servo friction, no
        deadband, no battery sag, a stiff servo without end stops (steer_band 0: PyBullet's
        position servo), no latency, rigid contact."""
        return cls(**{**{name: 0.0 for name in _REAL_FIELDS}, **changes})

    @classmethod
    def from_any(cls, value: RobotParams | dict[str, Any] | None, ideal: bool = False) -> RobotParams:
        """None (defaults), a RobotParams (used as it is), or a dict of field overrides
        (of ``RobotParams.ideal()`` if ``ideal``)."""
        if value is None:
            return cls.ideal() if ideal else cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            names = {f.name for f in fields(cls)}
            bad = sorted(set(value) - names)
            if bad:
                raise ValueError(f"unknown robot parameter(s) {', '.join(bad)}; accepted: {', '.join(sorted(names))}")
            return cls.ideal(**value) if ideal else cls(**value)
        raise ValueError(f"robot must be None, a RobotParams or a dict, got {type(value).__name__}")

    # derived quantities
    @property
    def is_ideal(self):
        return all(getattr(self, name) == 0.0 for name in _REAL_FIELDS)

    @property
    def total_mass(self):
        return self.shell_mass + self.frame_mass + self.pendulum_mass

    @property
    def shell_inertia(self):
        return 2.0 / 3.0 * self.shell_mass * self.shell_radius ** 2

    @property
    def frame_inertia(self):
        x, y, z = self.frame_size
        m = self.frame_mass / 12.0
        return (m * (y * y + z * z), m * (x * x + z * z), m * (x * x + y * y))

    @property
    def pendulum_inertia(self):
        """About the pendulum's own centre of mass."""
        x, y, z = self.pendulum_size
        m = self.pendulum_mass / 12.0
        return (m * (y * y + z * z), m * (x * x + z * z), m * (x * x + y * y))

    @property
    def righting_moment(self):
        """N m: the pendulum's largest gravity moment about the axle, m g L."""
        return self.pendulum_mass * GRAVITY * self.pendulum_length

    @property
    def top_speed(self):
        """m/s: no-load rolling speed at full voltage (friction neglected)."""
        return self.motor_voltage / self.motor_k * self.shell_radius


#: the fields RobotParams.ideal() sets to 0
_REAL_FIELDS = ("rolling_damping", "drive_coulomb", "drive_stiction", "motor_deadband", "battery_resistance", "steer_band",
                "steer_friction", "steer_stop", "latency_s", "contact_stiffness", "contact_damping", "vib_motor", "vib_commutation", "vib_gear",
                "vib_seam", "mag_steer", "mag_current")
#: accepted values of the environments' ``realism=`` argument
REALISM = ("real", "ideal")


#: (A) the battery's other loads, for the sag: STM32 board, Bluetooth and IMU (idle), and
#: the servo's draw at stall (a micro servo at about 5 V draws about 0.7 A at stall; through
#: the regulator from the 7.4 V pack about 0.5 A)
IDLE_CURRENT = 0.1
SERVO_STALL_CURRENT = 0.5


class DCMotor:
    """Permanent-magnet DC motor with gearbox, referred to the output shaft; the armature
    inductance is neglected (L/R of about 1 ms, below the 2.5 ms physics step).

    ``torque(voltage, speed)``: the commanded voltage (at the nominal pack voltage) is zero
    inside the driver's deadband (``motor_deadband`` of full voltage) and scaled by the
    pack's sag (``battery_resistance`` times the current drawn at the previous step:
    motor, servo, electronics); current i = (V - k w) / R (back-EMF k w), motor torque k i
    limited to +-torque_limit (the driver's current limit), minus viscous gearbox friction.
    The gearbox's Coulomb friction and stiction act in PyBullet (a velocity motor held at 0,
    see ``build_robot``): they are constraints, so a stuck gearbox really sticks.
    """

    __slots__ = ("k", "r", "b", "limit", "vmax", "_k_over_r", "_k2_over_r", "deadband", "r_bat", "i_prev",
                 "i_other", "i_signed")

    def __init__(self, params: RobotParams) -> None:
        self.k = params.motor_k
        self.r = params.motor_resistance
        self.b = params.motor_friction
        self.limit = params.motor_torque_limit
        self.vmax = params.motor_voltage
        self._k_over_r = self.k / self.r
        self._k2_over_r = self.k * self.k / self.r
        self.deadband = params.motor_deadband * params.motor_voltage
        self.r_bat = params.battery_resistance / params.motor_voltage
        self.reset()

    def reset(self) -> None:
        self.i_prev = 0.0
        self.i_other = 0.0
        self.i_signed = 0.0

    def torque(self, voltage: float, speed: float) -> float:
        if -self.deadband < voltage < self.deadband:
            voltage = 0.0
        elif self.r_bat:
            # the pack sags under the previous step's load (explicit: R_bat i << V); a pack
            # whose resistance drops the whole voltage gives none, never a reversed one
            sag = 1.0 - self.r_bat * (self.i_prev + self.i_other + IDLE_CURRENT)
            voltage *= sag if sag > 0.0 else 0.0
        t = self._k_over_r * voltage - self._k2_over_r * speed
        lim = self.limit
        if t > lim:
            t = lim
        elif t < -lim:
            t = -lim
        self.i_prev = abs(t) / self.k
        self.i_signed = t / self.k
        return t - self.b * speed

    def current(self, voltage: float, speed: float) -> float:
        return (voltage - self.k * speed) / self.r


class Servo:
    """The steering servo as a DC motor behind a proportional position loop (hobby servo):
    torque = stall * (clip((target - angle) / band, -1, 1) - speed / no_load_speed), i.e.
    full torque beyond ``steer_band`` of error, the motor's back-EMF line (stall at rest,
    zero at ``steer_speed``) as its damping. Compliant: holding the pendulum at 30 deg from
    the vertical (0.15 N m) deflects it by 0.3 band. Its gear friction (``steer_friction``) acts in
    PyBullet as a velocity motor held at 0; the end stops are PyBullet joint limits at
    +-(steer_max + steer_stop)."""

    __slots__ = ("stall", "inv_band", "kd", "max")

    def __init__(self, params: RobotParams) -> None:
        self.stall = params.steer_torque
        self.inv_band = 1.0 / params.steer_band if params.steer_band > 0 else 0.0
        self.kd = params.steer_torque / params.steer_speed
        self.max = params.steer_max

    def torque(self, target: float, angle: float, speed: float) -> float:
        e = (target - angle) * self.inv_band
        e = 1.0 if e > 1.0 else (-1.0 if e < -1.0 else e)
        t = self.stall * e - self.kd * speed
        s = self.stall
        return s if t > s else (-s if t < -s else t)


def _robot_visuals(p, client, params):
    """The visual shapes of the shell, the frame with its axle and the pendulum."""
    r = params.shell_radius
    import pybullet_data
    data = pybullet_data.getDataPath()
    # TinyRenderer draws no transparency: the shell is an opaque textured sphere (its
    # rotation shows), the axle pokes out of it on both sides (heading and steering tilt)
    vis_shell = p.createVisualShape(p.GEOM_MESH, fileName=data + "/sphere_smooth.obj", meshScale=[r] * 3,
                                    rgbaColor=[0.75, 0.9, 1.0, 1.0], physicsClientId=client)
    vis_frame = p.createVisualShapeArray(
        shapeTypes=[p.GEOM_BOX, p.GEOM_CYLINDER],
        halfExtents=[[s / 2 for s in params.frame_size], [0, 0, 0]],
        radii=[0, 0.012], lengths=[0, 2 * r + 0.08],
        rgbaColors=[[0.25, 0.25, 0.3, 1.0], [0.85, 0.2, 0.15, 1.0]],
        visualFramePositions=[[0, 0, 0], [0, 0, 0]],
        visualFrameOrientations=[[0, 0, 0, 1], [math.sin(math.pi / 4), 0, 0, math.cos(math.pi / 4)]],
        physicsClientId=client)
    vis_pend = p.createVisualShape(p.GEOM_BOX, halfExtents=[s / 2 for s in params.pendulum_size],
                                   rgbaColor=[0.9, 0.45, 0.1, 1.0],
                                   visualFramePosition=[0, 0, -params.pendulum_length],
                                   physicsClientId=client)
    return vis_shell, vis_frame, vis_pend


def _robot_dynamics(p, client, body, params):
    """The robot's inertias, friction, contact, drive friction and steering servo."""
    r = params.shell_radius
    # inertias (PyBullet would take them from the collision shapes), no artificial damping
    p.changeDynamics(body, -1, localInertiaDiagonal=list(params.frame_inertia), linearDamping=0.0,
                     angularDamping=0.0, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,
                     physicsClientId=client)
    ishell = params.shell_inertia
    contact = {}
    if params.contact_stiffness > 0:
        # compliant contact: a spring-damper normal force instead of PyBullet's rigid
        # constraint, so that an impact lasts several physics steps (docs/envs/robot.md)
        contact = dict(contactStiffness=params.contact_stiffness, contactDamping=params.contact_damping)
    p.changeDynamics(body, DRIVE_JOINT, localInertiaDiagonal=[ishell] * 3, jointDamping=0.0,
                     lateralFriction=params.lateral_friction,
                     rollingFriction=params.rolling_resistance * r,
                     spinningFriction=0.0, restitution=0.0,
                     linearDamping=0.0, angularDamping=0.0, physicsClientId=client, **contact)
    p.changeDynamics(body, STEER_JOINT, localInertiaDiagonal=list(params.pendulum_inertia), jointDamping=0.0,
                     linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
    # the drive joint: torque from the motor model, plus the gearbox's Coulomb friction as a
    # velocity motor held at 0 (PyBullet's joint friction: a constraint, so it sticks)
    set_drive_friction(p, client, body, params.drive_coulomb)
    if params.steer_band > 0:
        # compliant servo (Servo, torque-controlled by the caller), gear friction, end stops
        p.setJointMotorControl2(body, STEER_JOINT, p.VELOCITY_CONTROL, targetVelocity=0.0,
                                force=params.steer_friction, physicsClientId=client)
        if params.steer_stop > 0:
            lim = params.steer_max + params.steer_stop
            p.changeDynamics(body, STEER_JOINT, jointLowerLimit=-lim, jointUpperLimit=lim, physicsClientId=client)
    else:
        set_steer(p, client, body, params, 0.0)


def build_robot(p: Any, client: int, params: RobotParams, position: Sequence[float], yaw: float,
                visual: bool = False, shell_shape: int | None = None) -> int:
    """Create the robot in ``client`` with the shell's centre at ``position`` (x, y) on the
    floor and heading ``yaw`` (rad, ENU: 0 = facing east). Returns the body id. Joint
    motors: the drive joint is torque-controlled by the caller every physics step; the
    steering joint is a position servo (``set_steer``). ``shell_shape``: the shell's
    collision shape (a sphere of ``shell_radius``) if the caller keeps one, else a new one."""
    r = params.shell_radius
    col = shell_shape if shell_shape is not None else p.createCollisionShape(p.GEOM_SPHERE, radius=r,
                                                                             physicsClientId=client)
    vis_shell = vis_frame = vis_pend = -1
    if visual:
        vis_shell, vis_frame, vis_pend = _robot_visuals(p, client, params)
    half = 0.5 * yaw
    orn = [0.0, 0.0, math.sin(half), math.cos(half)]
    # a compliant contact carries the weight at its static compression: start there
    sink = params.total_mass * GRAVITY / params.contact_stiffness if params.contact_stiffness > 0 else 0.0
    body = p.createMultiBody(
        baseMass=params.frame_mass, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vis_frame,
        basePosition=[float(position[0]), float(position[1]), r - sink], baseOrientation=orn,
        baseInertialFramePosition=[0, 0, 0], baseInertialFrameOrientation=[0, 0, 0, 1],
        linkMasses=[params.shell_mass, params.pendulum_mass],
        linkCollisionShapeIndices=[col, -1], linkVisualShapeIndices=[vis_shell, vis_pend],
        linkPositions=[[0, 0, 0], [0, 0, 0]], linkOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0], [0, 0, -params.pendulum_length]],
        linkInertialFrameOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkParentIndices=[0, 0], linkJointTypes=[p.JOINT_REVOLUTE, p.JOINT_REVOLUTE],
        linkJointAxis=[[0, 1, 0], [1, 0, 0]], physicsClientId=client)
    _robot_dynamics(p, client, body, params)
    if visual:
        import pybullet_data
        tex = p.loadTexture(pybullet_data.getDataPath() + "/checker_grid.jpg", physicsClientId=client)
        p.changeVisualShape(body, DRIVE_JOINT, textureUniqueId=tex, physicsClientId=client)
    return body


def _reduced(i_a: float, i_b: float) -> float:
    """The inertia of two bodies' relative rotation about one axis: i_a i_b / (i_a + i_b)."""
    return i_a * i_b / (i_a + i_b)


#: the explicit damping terms (explicit_damping's keys) and the parameters that set each
EXPLICIT_TERMS = {
    "drive": "motor_friction + motor_k² / motor_resistance (the gearbox loss and the back-EMF)",
    "servo": "steer_torque / steer_speed and steer_torque / steer_band (the servo's damping and stiffness)",
    "rolling": "rolling_damping",
    "spin": "spinning_friction (over SPIN_EPS = 1 rad/s)",
}


def explicit_damping(params: RobotParams, physics_hz: float) -> dict[str, float]:
    """c dt / I of every damping the environment applies as an explicit torque (computed
    from the state at the step's start, not solved by PyBullet's constraints; keys as
    EXPLICIT_TERMS): an explicit step removes c dt / I of the rate it acts on, so above 1 it
    reverses that rate, and above 2 the oscillation grows every step until a torque limit
    clips it (the robot left the floor at 35 m/s with ``motor_friction`` 3.0 at 400 Hz,
    and at 21 m/s with ``steer_torque`` 100). I is the smallest inertia the torque can act
    on: the relative rotation of the shell alone against the frame and pendulum (drive; the
    shell off the floor, the pendulum steered to its end stop), of the pendulum against the
    frame and shell (servo), the shell alone (the floor's losses). The servo's stiffness k enters as k dt² / (2 I): a
    semi-implicit step of I x'' = -k x - c x' is stable when 2 c dt / I + k dt² / I < 4, and
    a sum of 1 keeps half of that. The ideal robot's servo (``steer_band`` 0) is PyBullet's
    and is not listed."""
    dt = 1.0 / physics_hz
    fi, pi_ = params.frame_inertia, params.pendulum_inertia
    ml2 = params.pendulum_mass * params.pendulum_length ** 2
    ish = params.shell_inertia
    c_drive = params.motor_k ** 2 / params.motor_resistance + params.motor_friction
    # the pendulum steered to its end stop is nearer the axle: m (L cos(steer))^2 about it
    ml2_steered = ml2 * math.cos(params.steer_max + params.steer_stop) ** 2
    out = {"drive": c_drive * dt / _reduced(fi[1] + pi_[1] + ml2_steered, ish)}
    if params.steer_band > 0:
        kd = params.steer_torque / params.steer_speed
        kp = params.steer_torque / params.steer_band
        out["servo"] = (kd * dt + 0.5 * kp * dt * dt) / _reduced(pi_[0] + ml2, fi[0] + ish)
    out["rolling"] = params.rolling_damping * dt / ish
    out["spin"] = spin_torque(params) / SPIN_EPS * dt / ish
    return out


def check_explicit_damping(params: RobotParams, physics_hz: float) -> None:
    """Refuse robot parameters whose explicit damping a physics step of 1 / physics_hz
    cannot integrate (an explicit_damping term above 1), naming the parameters that set it,
    the ratio, and the physics rate at which it would be accepted."""
    for term, ratio in explicit_damping(params, physics_hz).items():
        if ratio > 1.0:
            raise ValueError(
                f"the robot's {term} damping, {EXPLICIT_TERMS[term]}, is {ratio:.3g} x what a physics step "
                f"of 1 / {physics_hz:g} Hz integrates (c dt / I must be <= 1; docs/envs/robot.md, "
                f"\"Explicit terms\"): lower it, or raise physics_hz to at least {physics_hz * ratio:.4g} Hz")


#: (m) the pendulum dipole's distance from the IMU is held at least this (a point dipole's
#: field diverges at it; the zones' dipoles use the same floor)
DIPOLE_MIN_DISTANCE = 0.01


def pendulum_dipole(params: RobotParams, imu_offset: Sequence[float]) -> tuple[float, ...]:
    """The pendulum's magnetic field as a point dipole at its centre of mass, its moment along
    the pendulum (away from the axle), turning with it about the frame's x axis; scaled so
    that its field at the IMU (``imu_offset``, frame axes) with the pendulum centred has the
    magnitude ``mag_steer``. Returns (k, L, bx0, by0, bz0): k = (mu0 / 4 pi) M in uT m^3, L the
    pendulum length, b0 that centred field (uT), which a calibration at rest removes
    (dipole_field)."""
    L = params.pendulum_length
    f, r = _dipole_shape(imu_offset, L, 0.0)
    norm = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
    k = params.mag_steer * r ** 3 / norm
    return (k, L) + tuple(k * c / r ** 3 for c in f)


def _dipole_shape(o: Sequence[float], L: float, steer: float) -> tuple[tuple[float, float, float], float]:
    """3 u (u . m) - m for a unit moment m along the pendulum at ``steer`` (rad) and u the
    unit vector from the pendulum's centre of mass to the point o; and that distance."""
    s, c = math.sin(steer), math.cos(steer)
    dx, dy, dz = o[0], o[1] - L * s, o[2] + L * c
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    # u a unit vector whatever the distance (straight up from the pendulum at 0); only the
    # 1 / r^3 is held at DIPOLE_MIN_DISTANCE
    ux, uy, uz = (dx / d, dy / d, dz / d) if d > 0.0 else (0.0, 0.0, 1.0)
    um = uy * s - uz * c
    return (3.0 * ux * um, 3.0 * uy * um - s, 3.0 * uz * um + c), max(d, DIPOLE_MIN_DISTANCE)


def dipole_field(dipole: tuple[float, ...], imu_offset: Sequence[float], steer: float) -> tuple[float, float, float]:
    """(uT, frame axes) the change of the pendulum dipole's field at the IMU from its centred
    value at steering angle ``steer`` (rad): what remains after a calibration with the
    pendulum centred (pendulum_dipole)."""
    k, L, bx0, by0, bz0 = dipole
    f, r = _dipole_shape(imu_offset, L, steer)
    s = k / (r * r * r)
    return s * f[0] - bx0, s * f[1] - by0, s * f[2] - bz0


def spin_torque(params: RobotParams) -> float:
    """(N m) the spinning friction's torque, applied by the caller as an explicit torque on
    the shell about the vertical: PyBullet's own spinningFriction constraint pumps the
    sideways rocking in a turn (roll peak to peak grows to 60-80 deg with 3e-4 m even at
    1600 Hz; with none it decays). Normal force: the robot's weight."""
    return params.spinning_friction * params.total_mass * GRAVITY


#: (rad/s) the spin rate over which the spinning friction ramps to its full value. A rolling
#: contact's spin moment is linear in the spin creepage and saturates at full slip (Kalker,
#: "Three-Dimensional Elastic Bodies in Rolling Contact"); with a sharp (0.05 rad/s) Coulomb
#: law the sideways rocking after a turn grew instead of decaying (measured: 17 deg peak to
#: peak sustained after 20 s; with 1 rad/s it decays to 2.4 deg)
SPIN_EPS = 1.0

#: (rad/s) below this drive-joint rate the gearbox holds with its stiction (drive_stiction),
#: above it it slides with its Coulomb friction (drive_coulomb)
STICK_RATE = 0.05


def set_drive_friction(p, client, body, force):
    """The gearbox's friction torque (N m) on the drive joint: a velocity motor held at 0."""
    p.setJointMotorControl2(body, DRIVE_JOINT, p.VELOCITY_CONTROL, targetVelocity=0.0, force=force,
                            physicsClientId=client)


def set_steer(p, client, body, params, target):
    """The ideal robot's (steer_band = 0) servo: command the steering servo to ``target`` rad (clipped to +-steer_max): a position
    servo with torque limit ``steer_torque`` and slew limit ``steer_speed``."""
    m = params.steer_max
    target = m if target > m else (-m if target < -m else target)
    p.setJointMotorControl2(body, STEER_JOINT, p.POSITION_CONTROL, targetPosition=target,
                            force=params.steer_torque, maxVelocity=params.steer_speed,
                            positionGain=0.2, velocityGain=1.0, physicsClientId=client)
