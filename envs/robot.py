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
import numbers
from dataclasses import dataclass, fields, replace

__all__ = ["RobotParams", "DCMotor", "build_robot", "DRIVE_JOINT", "STEER_JOINT"]

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

    Contact: ``lateral_friction`` 0.6 (acrylic on wood or vinyl); ``rolling_resistance`` 0.004
    (the dimensionless coefficient Crr of a hard plastic ball on a hard floor: resisting
    torque Crr N r); ``spinning_friction`` 1e-3 m (torsional friction of the small contact
    patch, mu times a patch radius of about 2 mm).
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
    spinning_friction: float = 1e-3

    def __post_init__(self):
        ranges = {
            "shell_radius": (0.03, 2.0), "shell_mass": (1e-3, 100.0), "frame_mass": (1e-3, 100.0),
            "pendulum_mass": (1e-3, 100.0), "pendulum_length": (0.0, None),
            "motor_voltage": (1e-3, 1000.0), "motor_k": (1e-6, 100.0), "motor_resistance": (1e-6, 1e4),
            "motor_friction": (0.0, 100.0), "motor_torque_limit": (1e-6, 1e4),
            "steer_max": (0.0, math.radians(80.0)), "steer_torque": (1e-6, 1e4), "steer_speed": (1e-3, 1e3),
            "lateral_friction": (0.0, 10.0), "rolling_resistance": (0.0, 1.0), "spinning_friction": (0.0, 1.0),
        }
        for name, (lo, hi) in ranges.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise ValueError(f"robot.{name} must be a finite number in [{lo}, {hi}], got {v!r}")
            object.__setattr__(self, name, float(v))
        for name, (lo, hi) in ranges.items():
            v = getattr(self, name)
            if name == "pendulum_length":
                hi = 0.9 * self.shell_radius
            if v < lo or v > hi:
                raise ValueError(f"robot.{name} must be in [{lo:g}, {hi:g}], got {v!r}")
        c = self.encoder_cpr
        if isinstance(c, bool) or not isinstance(c, numbers.Integral) or not 1 <= c <= 10 ** 7:
            raise ValueError(f"robot.encoder_cpr must be an integer in [1, 10000000], got {c!r}")
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

    def replace(self, **changes):
        return replace(self, **changes)

    @classmethod
    def from_any(cls, value):
        """None (defaults), a RobotParams, or a dict of field overrides."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            names = {f.name for f in fields(cls)}
            bad = sorted(set(value) - names)
            if bad:
                raise ValueError(f"unknown robot parameter(s) {', '.join(bad)}; accepted: {', '.join(sorted(names))}")
            return cls(**value)
        raise ValueError(f"robot must be None, a RobotParams or a dict, got {type(value).__name__}")

    # derived quantities
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
        return self.pendulum_mass * 9.81 * self.pendulum_length

    @property
    def top_speed(self):
        """m/s: no-load rolling speed at full voltage (friction neglected)."""
        return self.motor_voltage / self.motor_k * self.shell_radius


class DCMotor:
    """Permanent-magnet DC motor with gearbox, referred to the output shaft; the armature
    inductance is neglected (L/R of about 1 ms, below the 2.5 ms physics step).

    ``torque(voltage, speed)``: current i = (V - k w) / R (back-EMF k w), motor torque k i
    limited to +-torque_limit (the driver's current limit), minus viscous gearbox friction.
    """

    __slots__ = ("k", "r", "b", "limit", "vmax", "_k_over_r", "_k2_over_r")

    def __init__(self, params: RobotParams):
        self.k = params.motor_k
        self.r = params.motor_resistance
        self.b = params.motor_friction
        self.limit = params.motor_torque_limit
        self.vmax = params.motor_voltage
        self._k_over_r = self.k / self.r
        self._k2_over_r = self.k * self.k / self.r

    def torque(self, voltage, speed):
        t = self._k_over_r * voltage - self._k2_over_r * speed
        lim = self.limit
        if t > lim:
            t = lim
        elif t < -lim:
            t = -lim
        return t - self.b * speed

    def current(self, voltage, speed):
        return (voltage - self.k * speed) / self.r


def build_robot(p, client, params: RobotParams, position, yaw, visual=False):
    """Create the robot in ``client`` with the shell's centre at ``position`` (x, y) on the
    floor and heading ``yaw`` (rad, ENU: 0 = facing east). Returns the body id. Joint
    motors: the drive joint is torque-controlled by the caller every physics step; the
    steering joint is a position servo (``set_steer``)."""
    r = params.shell_radius
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=r, physicsClientId=client)
    vis_shell = vis_frame = vis_pend = -1
    if visual:
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
    half = 0.5 * yaw
    orn = [0.0, 0.0, math.sin(half), math.cos(half)]
    body = p.createMultiBody(
        baseMass=params.frame_mass, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vis_frame,
        basePosition=[float(position[0]), float(position[1]), r], baseOrientation=orn,
        baseInertialFramePosition=[0, 0, 0], baseInertialFrameOrientation=[0, 0, 0, 1],
        linkMasses=[params.shell_mass, params.pendulum_mass],
        linkCollisionShapeIndices=[col, -1], linkVisualShapeIndices=[vis_shell, vis_pend],
        linkPositions=[[0, 0, 0], [0, 0, 0]], linkOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0], [0, 0, -params.pendulum_length]],
        linkInertialFrameOrientations=[[0, 0, 0, 1], [0, 0, 0, 1]],
        linkParentIndices=[0, 0], linkJointTypes=[p.JOINT_REVOLUTE, p.JOINT_REVOLUTE],
        linkJointAxis=[[0, 1, 0], [1, 0, 0]], physicsClientId=client)
    # inertias (PyBullet would take them from the collision shapes), no artificial damping
    p.changeDynamics(body, -1, localInertiaDiagonal=list(params.frame_inertia), linearDamping=0.0,
                     angularDamping=0.0, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,
                     physicsClientId=client)
    ishell = params.shell_inertia
    p.changeDynamics(body, DRIVE_JOINT, localInertiaDiagonal=[ishell] * 3, jointDamping=0.0,
                     lateralFriction=params.lateral_friction,
                     rollingFriction=params.rolling_resistance * r,
                     spinningFriction=params.spinning_friction, restitution=0.0,
                     linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
    p.changeDynamics(body, STEER_JOINT, localInertiaDiagonal=list(params.pendulum_inertia), jointDamping=0.0,
                     linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
    # the drive joint: free (torque from the motor model); the steering joint: servo
    p.setJointMotorControl2(body, DRIVE_JOINT, p.VELOCITY_CONTROL, targetVelocity=0.0, force=0.0,
                            physicsClientId=client)
    set_steer(p, client, body, params, 0.0)
    if visual:
        tex = p.loadTexture(data + "/checker_grid.jpg", physicsClientId=client)
        p.changeVisualShape(body, DRIVE_JOINT, textureUniqueId=tex, physicsClientId=client)
    return body


def set_steer(p, client, body, params, target):
    """Command the steering servo to ``target`` rad (clipped to +-steer_max): a position
    servo with torque limit ``steer_torque`` and slew limit ``steer_speed``."""
    m = params.steer_max
    target = m if target > m else (-m if target < -m else target)
    p.setJointMotorControl2(body, STEER_JOINT, p.POSITION_CONTROL, targetPosition=target,
                            force=params.steer_torque, maxVelocity=params.steer_speed,
                            positionGain=0.2, velocityGain=1.0, physicsClientId=client)
