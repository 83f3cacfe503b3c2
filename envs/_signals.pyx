# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The environment's step in C: ``SphereRobotBase._advance`` (motor, servo, floor losses,
gearbox stiction, the PyBullet calls), ``SphereRobotBase._sense`` (the true IMU signals: body
rate, specific force at the IMU point, the field with the floor's dipole zones, the drive's
vibration and the robot's own field; then the IMU model's step and the estimator's update)
and the base's part of ``SphereRobotBase.step`` around them (action check, odometry, episode
end, observation, info; the task's rewards, observation values and info stay Python methods,
called from here, except the track task's, inlined too while a class keeps them: TRACK_METHODS).

The Python methods in envs/base.py are the reference: the same arithmetic in the same
order, compiled without fused multiply-adds, so the trajectories are the same to the last
bit (tests/test_env_kernel.py). ``Loop.load(env)`` takes the constants and state from the
environment at every reset; ``advance`` and ``sense`` read the state the environment may
change between calls and write back everything the Python code reads, so the two paths can
be mixed (the environment falls back to Python while a signal log is on).
"""
from libc.math cimport sqrt, sin, cos, fmod, copysign, atan2, acos, floor, isfinite, fabs
cimport numpy as cnp

from fusion._imu cimport StepKernel
from fusion._core cimport Estimator, _claim, _release

import math
import numpy as np

cnp.import_array()

cdef extern from *:
    """
    #if defined(__GNUC__) && !defined(__clang__)
    #pragma GCC optimize ("fp-contract=off")
    #endif
    #if defined(__clang__)
    #pragma clang fp contract(off)
    #endif
    """

from fusion._constants cimport GRAVITY as G     # envs.base.G
cdef double TWO_PI = 6.283185307179586
cdef double PI = 3.141592653589793
#: the track task's methods (envs/track.py) that _finish runs in C, for a class that keeps them all
TRACK_METHODS = ("_get_rew", "_task_obs", "_task_info", "_task_step_info", "_command", "_forward_speed",
                 "_heading_true", "_effort")
cdef tuple ZERO2 = (0.0, 0.0)        # the unused targets and gains of a torque command
cdef double RAD2DEG = 180.0 / 3.141592653589793     # math.degrees' factor
cdef object _hypot = math.hypot      # (its own algorithm, not libm's hypot: called, not copied)
cdef object _sum = sum
cdef object SKIPPED = Estimator.skipped      # the property, read from the kernel's counters here
cdef object KERNEL_BIAS = Estimator.bias    # the property every kernel's bias comes through (its _bias)


cdef inline double _pymod(double a, double m) noexcept nogil:
    """Python's float a % m (m > 0): the result has the sign of m."""
    cdef double r = fmod(a, m)
    if r != 0.0:
        if (m < 0) != (r < 0):
            r += m
    else:
        r = copysign(0.0, m)
    return r


cdef inline double _heading(double w, double x, double y, double z):
    """SphereRobotBase._heading_est's angle of the quaternion (w, x, y, z): math.atan2's,
    which for finite arguments is libm's."""
    cdef double s = -2.0 * (x * y - w * z), c = 1.0 - 2.0 * (x * x + z * z)
    if s != s or c != c:
        return math.atan2(s, c)             # (its NaN)
    return atan2(s, c)


cdef inline cnp.ndarray _f64(object seq, int n):
    """np.array(seq) of a tuple of n floats."""
    cdef cnp.npy_intp dim = n
    cdef cnp.ndarray a = cnp.PyArray_SimpleNew(1, &dim, cnp.NPY_DOUBLE)
    cdef double* d = <double*>cnp.PyArray_DATA(a)
    cdef int i
    for i in range(n):
        d[i] = seq[i]
    return a


cdef class Loop:
    # PyBullet
    cdef object p, getjs, setm, ext, step, getpo, getvel, joints, torque_mode, world
    cdef object set_steer, set_drive_friction, rp
    cdef int c, b
    # motor (envs.robot.DCMotor), servo (envs.robot.Servo)
    cdef double m_k, m_b, m_limit, m_k_over_r, m_k2_over_r, m_deadband, m_rbat, idle
    cdef bint has_servo
    cdef double s_stall, s_inv_band, s_kd, i_servo
    cdef int lat
    cdef double stiction, coulomb, spin, inv_eps, roll_c, stick_rate
    # slippery patches (x, y, squared radius), their friction, the floor's, the spin torque on them
    cdef double[:, ::1] patches
    cdef Py_ssize_t npatch
    cdef double patch_mu, lat_mu, spin_patch
    cdef bint patch_on
    # true signals
    cdef bint has_offset, vib, self_field
    cdef double ox, oy, oz, k_phys, ex, ey, ez, mag_current
    cdef double dip[5]                                    # envs.robot.pendulum_dipole
    cdef double dip_min                                   # envs.robot.DIPOLE_MIN_DISTANCE
    cdef double vk[8]
    cdef double seam_mean                                 # envs.base.SEAM_MEAN
    cdef double[:, ::1] zones
    cdef Py_ssize_t nz
    cdef StepKernel imu
    # state (copied in and out of the environment)
    cdef double v_prev[3]
    cdef double wb[3]
    cdef double axle[3]
    cdef double qd, wd_last, qs, i_prev, i_other, i_signed, tau
    cdef bint stuck_gear
    cdef object ang, pos, orn, lin
    cdef double gyr[3]
    cdef double acc[3]
    cdef double mag[3]
    cdef double gyr_last[3]
    cdef double q_est[4]
    cdef double q_true_s[4]
    cdef bint new_q, any_sample
    cdef double gyr_sum_y
    cdef long long gyr_n, n_samples
    cdef object est, motor
    cdef Estimator fast_est
    # the control step (SphereRobotBase.step): constants, the observation's bounds
    cdef object getj
    cdef int drive_joint, n_sub
    cdef double control_hz, cpr, shell_r, half_arena, volt, steer, fix_hz
    cdef double stuck_speed, stuck_action, stuck_time     # envs.base.STUCK_*
    cdef str needs_reset                                  # envs.base.NEEDS_RESET
    cdef long long max_steps
    cdef float[::1] obs_lo, obs_hi
    cdef Py_ssize_t n_obs
    # the joint states read after advance's last physics step, or None: they are the next
    # advance's first (nothing moves the robot between steps) and the step's encoder reading
    cdef object js_next
    # the environment is the track task with its methods (TRACK_METHODS): _finish inlines them
    cdef readonly bint track

    def __cinit__(self):
        from envs.base import NEEDS_RESET       # (step() may come before the first load)
        self.needs_reset = NEEDS_RESET

    def _load_signals(self, env, rp):
        """load's constants of the sensing: the IMU's place, the fields, the vibration."""
        from envs.base import SEAM_MEAN
        from envs.robot import DIPOLE_MIN_DISTANCE
        self.has_offset = env._has_offset
        self.ox, self.oy, self.oz = env.imu_offset
        self.k_phys = env.physics_hz
        self.ex, self.ey, self.ez = env.earth_field
        self.vib = env._vib
        for i in range(8):
            self.vk[i] = env._vib_k[i]
        self.seam_mean = SEAM_MEAN
        self.self_field = env._self_field
        self.mag_current = rp.mag_current
        for i in range(5):
            self.dip[i] = env._dipole[i]
        self.dip_min = DIPOLE_MIN_DISTANCE
        self.zones = np.array(env._zones, dtype=np.float64).reshape(-1, 7)
        self.nz = self.zones.shape[0]

    def load(self, env):
        """Constants of the episode (call after the world is built, before the first sense)."""
        import envs.robot as robot
        p = env._p
        self.p = p
        self.getjs, self.setm, self.ext = p.getJointStates, p.setJointMotorControlArray, p.applyExternalTorque
        self.step, self.getpo, self.getvel = p.stepSimulation, p.getBasePositionAndOrientation, p.getBaseVelocity
        self.joints = (robot.DRIVE_JOINT, robot.STEER_JOINT)
        self.torque_mode, self.world = p.TORQUE_CONTROL, p.WORLD_FRAME
        self.set_steer, self.set_drive_friction = robot.set_steer, robot.set_drive_friction
        self.c, self.b = env._client, env._body
        rp = env.robot
        self.rp = rp
        m = env._motor
        self.motor = m
        self.m_k, self.m_b, self.m_limit = m.k, m.b, m.limit
        self.m_k_over_r, self.m_k2_over_r = m._k_over_r, m._k2_over_r
        self.m_deadband, self.m_rbat, self.idle = m.deadband, m.r_bat, robot.IDLE_CURRENT
        s = env._servo
        self.has_servo = s is not None
        if s is not None:
            self.s_stall, self.s_inv_band, self.s_kd = s.stall, s.inv_band, s.kd
            self.i_servo = robot.SERVO_STALL_CURRENT / rp.steer_torque
        self.lat = env._lat_steps
        self.stiction, self.coulomb = rp.drive_stiction, rp.drive_coulomb
        self.spin, self.inv_eps, self.roll_c = robot.spin_torque(rp), 1.0 / robot.SPIN_EPS, rp.rolling_damping
        self.stick_rate = robot.STICK_RATE
        self.patches = np.array(env._patches, dtype=np.float64).reshape(-1, 3)
        self.npatch = self.patches.shape[0]
        self.patch_mu, self.lat_mu, self.spin_patch = env.patch_friction, rp.lateral_friction, env._spin_patch
        self._load_signals(env, rp)
        imu = env._imu
        self.imu = imu._kernel
        if self.imu is None:
            raise ValueError("the compiled loop needs an IMU with compiled=True")
        if not self.imu.live:
            self.imu.load(imu)
        self.getj, self.drive_joint = p.getJointState, robot.DRIVE_JOINT
        self.n_sub, self.control_hz, self.max_steps = env._n_sub, env.control_hz, env.max_steps
        self.cpr, self.shell_r = rp.encoder_cpr, rp.shell_radius
        self.half_arena, self.volt, self.steer = 0.5 * env.arena_size, rp.motor_voltage, rp.steer_max
        self.fix_hz = env.position_fix_hz
        from envs import base
        self.stuck_speed, self.stuck_action, self.stuck_time = base.STUCK_SPEED, base.STUCK_ACTION, base.STUCK_TIME
        self.obs_lo, self.obs_hi = env._obs_low, env._obs_high
        self.n_obs = self.obs_lo.shape[0]
        self.js_next = None
        from envs.track import SphereBotTrackEnv
        cls = type(env)
        self.track = all(getattr(cls, m) is getattr(SphereBotTrackEnv, m) for m in TRACK_METHODS)

    def forget(self):
        """The robot's joints may have moved outside advance (the Python path ran)."""
        self.js_next = None

    # -- state in and out ----------------------------------------------------------------
    cdef int _get(self, env, bint first=False, bint fresh=False) except -1:
        cdef int i
        if not first:               # (a first sense sets them)
            v = env._v_prev
            self.ang = env._wb
            a = env._axle
            for i in range(3):
                self.v_prev[i] = v[i]
                self.wb[i] = self.ang[i]
                self.axle[i] = a[i]
        self.qd, self.wd_last, self.qs = env._qd, env._wd_last, env._qs
        m = self.motor
        self.i_prev, self.i_other, self.i_signed = m.i_prev, m.i_other, m.i_signed
        self.stuck_gear = getattr(env, "_stuck_gear", False)     # (reset sets it after the first sense)
        self.patch_on = env._patch_on
        if self.npatch and not first:
            self.pos = env._true[0]             # the last sensed position (the Python path may have sensed)
        self._get_sums(env, fresh)
        return 0

    cdef int _get_sums(self, env, bint fresh=False) except -1:
        if fresh:                   # a new control step (SphereRobotBase._begin_step)
            self.gyr_sum_y, self.gyr_n = 0.0, 0
        else:
            self.gyr_sum_y, self.gyr_n = env._gyr_sum_y, env._gyr_n
        self.n_samples = env._n_samples
        est = env._est
        self.est = est
        self.fast_est = est if isinstance(est, Estimator) else None
        self.new_q = False
        self.any_sample = False
        return 0

    cdef int _put(self, env) except -1:
        env._v_prev = (self.v_prev[0], self.v_prev[1], self.v_prev[2])
        env._wb = self.ang
        env._axle = (self.axle[0], self.axle[1], self.axle[2])
        env._qd, env._wd_last, env._qs = self.qd, self.wd_last, self.qs
        m = self.motor
        m.i_prev, m.i_other, m.i_signed = self.i_prev, self.i_other, self.i_signed
        env._stuck_gear = self.stuck_gear
        env._patch_on = self.patch_on
        self._put_sums(env)
        return 0

    cdef int _put_sums(self, env) except -1:
        env._true = (self.pos, self.orn, self.lin, (self.gyr[0], self.gyr[1], self.gyr[2]),
                     (self.acc[0], self.acc[1], self.acc[2]), (self.mag[0], self.mag[1], self.mag[2]))
        env._gyr_sum_y, env._gyr_n, env._n_samples = self.gyr_sum_y, self.gyr_n, self.n_samples
        if self.any_sample:
            env._q_true_s = (self.q_true_s[0], self.q_true_s[1], self.q_true_s[2], self.q_true_s[3])
            env._gyr_last = (self.gyr_last[0], self.gyr_last[1], self.gyr_last[2])
        if self.new_q:
            # a tuple: SphereRobotEnv._q_est_wxyz reads it as floats, as it reads update()'s array
            env._q_est = (self.q_est[0], self.q_est[1], self.q_est[2], self.q_est[3])
        return 0

    # -- the true signals, the IMU, the estimator (SphereRobotEnv._sense) ----------------
    def sense(self, env, first=False):
        """SphereRobotEnv._sense on the kernel."""
        self._get(env, first)
        self._sense(first)
        self._put(env)

    cdef int _sense(self, bint first) except -1:
        cdef double x, y, z, w, x2, y2, z2, xx, yy, zz, xy_, xz, yz, wx, wy, wz
        cdef double r00, r01, r02, r10, r11, r12, r20, r21, r22
        cdef double wx_, wy_, wz_, vx, vy, vz, rx, ry, rz, ax, ay, az, bx, by, bz
        cdef double px, py, pz, dx, dy, dz, d2, d, ux, uy, uz, mr, s, k
        cdef double vbx = 0.0, vby = 0.0, vbz = 0.0
        cdef double qq[4]
        cdef Py_ssize_t i
        cdef double[:, ::1] zn = self.zones
        cdef Estimator e
        pos, orn = self.getpo(self.b, self.c)
        lin, ang = self.getvel(self.b, self.c)
        self.pos, self.orn, self.lin, self.ang = pos, orn, lin, ang
        x, y, z, w = orn
        x2, y2, z2 = x + x, y + y, z + z
        xx, yy, zz = x * x2, y * y2, z * z2
        xy_, xz, yz, wx, wy, wz = x * y2, x * z2, y * z2, w * x2, w * y2, w * z2
        r00, r01, r02 = 1.0 - (yy + zz), xy_ - wz, xz + wy
        r10, r11, r12 = xy_ + wz, 1.0 - (xx + zz), yz - wx
        r20, r21, r22 = xz - wy, yz + wx, 1.0 - (xx + yy)
        wx_, wy_, wz_ = ang
        vx, vy, vz = lin
        if self.has_offset:
            rx = r00 * self.ox + r01 * self.oy + r02 * self.oz
            ry = r10 * self.ox + r11 * self.oy + r12 * self.oz
            rz = r20 * self.ox + r21 * self.oy + r22 * self.oz
            vx += wy_ * rz - wz_ * ry
            vy += wz_ * rx - wx_ * rz
            vz += wx_ * ry - wy_ * rx
        else:
            rx = ry = rz = 0.0
        if first:
            ax = ay = 0.0
            az = G
        else:
            k = self.k_phys
            ax, ay, az = (vx - self.v_prev[0]) * k, (vy - self.v_prev[1]) * k, (vz - self.v_prev[2]) * k + G
        self.v_prev[0], self.v_prev[1], self.v_prev[2] = vx, vy, vz
        self.wb[0], self.wb[1], self.wb[2] = wx_, wy_, wz_
        self.axle[0], self.axle[1], self.axle[2] = r01, r11, r21
        bx, by, bz = self.ex, self.ey, self.ez
        if self.nz:
            px, py, pz = <double>pos[0] + rx, <double>pos[1] + ry, <double>pos[2] + rz
            for i in range(self.nz):
                dx, dy, dz = px - zn[i, 0], py - zn[i, 1], pz - zn[i, 2]
                d2 = dx * dx + dy * dy + dz * dz
                if d2 < zn[i, 6]:
                    d = sqrt(d2 if d2 > 1e-4 else 1e-4)
                    ux, uy, uz = dx / d, dy / d, dz / d
                    mr = zn[i, 3] * ux + zn[i, 4] * uy + zn[i, 5] * uz
                    s = 0.1 / (d * d * d)
                    bx += s * (3 * ux * mr - zn[i, 3])
                    by += s * (3 * uy * mr - zn[i, 4])
                    bz += s * (3 * uz * mr - zn[i, 5])
        self.gyr[0] = r00 * wx_ + r10 * wy_ + r20 * wz_
        self.gyr[1] = r01 * wx_ + r11 * wy_ + r21 * wz_
        self.gyr[2] = r02 * wx_ + r12 * wy_ + r22 * wz_
        if self.vib:
            self._vibration(&vbx, &vby, &vbz)
            self.acc[0] = r00 * ax + r10 * ay + r20 * az + vbx
            self.acc[1] = r01 * ax + r11 * ay + r21 * az + vby
            self.acc[2] = r02 * ax + r12 * ay + r22 * az + vbz
        else:
            self.acc[0] = r00 * ax + r10 * ay + r20 * az
            self.acc[1] = r01 * ax + r11 * ay + r21 * az
            self.acc[2] = r02 * ax + r12 * ay + r22 * az
        self.mag[0] = r00 * bx + r10 * by + r20 * bz
        self.mag[1] = r01 * bx + r11 * by + r21 * bz
        self.mag[2] = r02 * bx + r12 * by + r22 * bz
        if self.self_field:
            # SphereRobotEnv._add_self_field (envs.robot.dipole_field)
            self._dipole_field(&dx, &dy, &dz)
            dy += self.mag_current * self.i_signed
            self.mag[0] = self.mag[0] + dx
            self.mag[1] = self.mag[1] + dy
            self.mag[2] = self.mag[2] + dz
        if not self.imu.step_c(self.gyr, self.acc, self.mag, 0.0, False):
            return 0
        self.n_samples += 1
        self.any_sample = True
        self.q_true_s[0], self.q_true_s[1], self.q_true_s[2], self.q_true_s[3] = w, x, y, z
        if self.est is not None:
            e = self.fast_est
            if e is not None:
                # Estimator.update without its Python call: the same step (_run_batch, n = 1)
                _claim(e)
                e._run_batch(self.imu.out_g, self.imu.out_a, self.imu.out_m if self.imu.out_has_mag else NULL,
                             NULL, e.dt_nominal, qq, 1, False)
                _release(e)
                for i in range(4):
                    self.q_est[i] = qq[i]
            else:
                q = self.est.update(np.array([self.imu.out_g[0], self.imu.out_g[1], self.imu.out_g[2]]),
                                    np.array([self.imu.out_a[0], self.imu.out_a[1], self.imu.out_a[2]]),
                                    np.array([self.imu.out_m[0], self.imu.out_m[1], self.imu.out_m[2]])
                                    if self.imu.out_has_mag else None)
                for i in range(4):
                    self.q_est[i] = q[i]
            self.new_q = True
            for i in range(3):
                self.gyr_last[i] = self.imu.out_g[i]
        else:
            for i in range(3):
                self.gyr_last[i] = self.gyr[i]
        self.gyr_sum_y += self.gyr_last[1]
        self.gyr_n += 1
        return 0

    cdef void _dipole_field(self, double* bx, double* by, double* bz) noexcept:
        """envs.robot.dipole_field at the steering angle qs."""
        cdef double s = sin(self.qs), c = cos(self.qs), L = self.dip[1]
        cdef double dx = self.ox, dy = self.oy - L * s, dz = self.oz + L * c
        cdef double r = sqrt(dx * dx + dy * dy + dz * dz), ux, uy, uz, um, k
        if r > 0.0:
            ux, uy, uz = dx / r, dy / r, dz / r
        else:
            ux, uy, uz = 0.0, 0.0, 1.0
        if r < self.dip_min:
            r = self.dip_min
        um = uy * s - uz * c
        k = self.dip[0] / (r * r * r)
        bx[0] = k * (3.0 * ux * um) - self.dip[2]
        by[0] = k * (3.0 * uy * um - s) - self.dip[3]
        bz[0] = k * (3.0 * uz * um + c) - self.dip[4]

    cdef void _vibration(self, double* vx_, double* vy_, double* vz_) noexcept:
        """SphereRobotEnv._vibration."""
        cdef double n_m = self.vk[0], a_m = self.vk[1], a_c = self.vk[2], n_g = self.vk[3]
        cdef double a_g = self.vk[4], a_s = self.vk[5], inv_top = self.vk[6], lim = self.vk[7]
        cdef double q = self.qd, w = self.wd_last, s, vx = 0.0, vy = 0.0, vz = 0.0, ph, c, sn, a, u
        if w < 0.0:
            w = -w
        s = w * inv_top
        if n_m * w < lim:
            ph = n_m * q
            c, sn = cos(ph), sin(ph)
            a = a_m * s
            vx = a * c
            vz = a * sn
            vy = 0.3 * a * (0.5403023058681398 * c - 0.8414709848078965 * sn)
            if 2.0 * n_m * w < lim:
                vz += a_c * s * (c * c - sn * sn)
        if n_g * w < lim:
            ph = n_g * q
            a = a_g * s
            vx += a * sin(ph)
            vz += a * cos(ph)
        if a_s:
            u = _pymod(q, TWO_PI) * (1.0 / 0.15)
            vz += a_s * s * s * ((0.5 * (1.0 - cos(TWO_PI * u)) if u < 1.0 else 0.0) - self.seam_mean)
        vx_[0], vy_[0], vz_[0] = vx, vy, vz

    # -- the physics steps (SphereRobotEnv._advance) ----------------------------------------
    def advance(self, env, int n, double voltage, double target):
        """SphereRobotBase._advance on the kernel."""
        self._advance(env, n, voltage, target, False)

    cdef int _advance(self, env, int n, double voltage, double target, bint fresh) except -1:
        cdef double v_old, t_old, v, tgt, wd, t, lim, sag, ts = 0.0, tau = 0.0, e, s0, spin, px, py, dx, dy
        cdef int i
        cdef Py_ssize_t k
        cdef bint stuck, on
        cdef double[:, ::1] pt = self.patches
        self._get(env, False, fresh)
        v_old, t_old = env._cmd_prev
        b, c, joints = self.b, self.c, self.joints
        for i in range(n):
            if i < self.lat:
                v, tgt = v_old, t_old
            else:
                v, tgt = voltage, target
            if i == 0 and self.js_next is not None:
                js = self.js_next          # read after the last step's physics, nothing moved since
            else:
                js = self.getjs(b, joints, c)
            j0, j1 = js[0], js[1]
            self.qd = j0[0]
            wd = j0[1]
            self.qs = j1[0]
            self.wd_last = wd
            # DCMotor.torque
            if -self.m_deadband < v < self.m_deadband:
                v = 0.0
            elif self.m_rbat:
                sag = 1.0 - self.m_rbat * (self.i_prev + self.i_other + self.idle)
                v *= sag if sag > 0.0 else 0.0
            t = self.m_k_over_r * v - self.m_k2_over_r * wd
            lim = self.m_limit
            if t > lim:
                t = lim
            elif t < -lim:
                t = -lim
            self.i_prev = (t if t >= 0 else -t) / self.m_k
            self.i_signed = t / self.m_k
            tau = t - self.m_b * wd
            if self.has_servo:
                # Servo.torque
                e = (tgt - <double>j1[0]) * self.s_inv_band
                e = 1.0 if e > 1.0 else (-1.0 if e < -1.0 else e)
                ts = self.s_stall * e - self.s_kd * <double>j1[1]
                s0 = self.s_stall
                ts = s0 if ts > s0 else (-s0 if ts < -s0 else ts)
                self.i_other = self.i_servo * (ts if ts >= 0 else -ts)
            elif i == self.lat or (i == 0 and self.lat == self.n_sub):
                # (a latency of one control period: the last step's target, at this step's start)
                self.set_steer(self.p, c, b, self.rp, tgt)
            # positional (torque mode reads only the forces): PyBullet parses keywords 0.3 us slower
            self.setm(b, joints, self.torque_mode, ZERO2, ZERO2, (tau, ts), ZERO2, ZERO2, c)
            spin = self.spin
            if self.npatch:
                # SphereRobotBase._actuate: the friction under the shell's centre
                px, py = self.pos[0], self.pos[1]
                on = False
                for k in range(self.npatch):
                    dx, dy = px - pt[k, 0], py - pt[k, 1]
                    if dx * dx + dy * dy < pt[k, 2]:
                        on = True
                        break
                if on != self.patch_on:
                    self.patch_on = on
                    self.p.changeDynamics(b, 0, lateralFriction=self.patch_mu if on else self.lat_mu,
                                          physicsClientId=c)
                if on:
                    spin = self.spin_patch
            if spin or self.roll_c:
                e = (self.wb[2] + wd * self.axle[2]) * self.inv_eps
                self.ext(b, 0, (-self.roll_c * (self.wb[0] + wd * self.axle[0]),
                                -self.roll_c * (self.wb[1] + wd * self.axle[1]),
                                -spin * (1.0 if e > 1.0 else (-1.0 if e < -1.0 else e))),
                         self.world, c)             # (physicsClientId: positional is cheaper)
            if self.stiction:
                stuck = -self.stick_rate < wd < self.stick_rate
                if stuck != self.stuck_gear:
                    self.stuck_gear = stuck
                    self.set_drive_friction(self.p, c, b, self.stiction if stuck else self.coulomb)
            self.step(c)
            self._sense(False)
        if n > 0:
            self.js_next = self.getjs(b, joints, c)
        env._cmd_prev = (voltage, target)
        env._tau = tau
        self._put(env)
        return 0

    # -- the control step (SphereRobotBase.step) ------------------------------------------
    def control_step(self, env, action):
        """SphereRobotBase.step on the kernel: _begin_step, _advance, _end_step."""
        cdef double a0, a1
        if env._needs_reset:
            raise RuntimeError(self.needs_reset)
        if not self._action(env, action, &a0, &a1):
            a0, a1 = env._check_action(action)
        env._action = (a0, a1)
        self._advance(env, self.n_sub, a0 * self.volt, a1 * self.steer, True)
        return self._finish(env, a0, a1)

    def finish(self, env, double a0, double a1):
        """SphereRobotBase._end_step on the kernel (after either path's physics)."""
        return self._finish(env, a0, a1)

    cdef bint _action(self, env, action, double* a0, double* a1) except -1:
        """SphereRobotBase._check_action for a finite float32 or float64 array of shape (2,),
        False for anything else (the Python method checks it)."""
        cdef cnp.ndarray arr
        cdef char* d
        cdef cnp.npy_intp st
        cdef int t
        if type(action) is not cnp.ndarray:
            return False
        arr = <cnp.ndarray>action
        if cnp.PyArray_NDIM(arr) != 1 or cnp.PyArray_DIM(arr, 0) != 2 or not cnp.PyArray_ISNOTSWAPPED(arr) \
                or not cnp.PyArray_ISALIGNED(arr):
            return False
        t = cnp.PyArray_TYPE(arr)
        d, st = cnp.PyArray_BYTES(arr), cnp.PyArray_STRIDE(arr, 0)
        if t == cnp.NPY_FLOAT:
            a0[0], a1[0] = (<float*>d)[0], (<float*>(d + st))[0]
        elif t == cnp.NPY_DOUBLE:
            a0[0], a1[0] = (<double*>d)[0], (<double*>(d + st))[0]
        else:
            return False
        if not (isfinite(a0[0]) and isfinite(a1[0])):
            return False                    # (the Python method raises)
        if a0[0] > 1.0 or a0[0] < -1.0 or a1[0] > 1.0 or a1[0] < -1.0:
            env._clipped += 1
            a0[0] = 1.0 if a0[0] > 1.0 else (-1.0 if a0[0] < -1.0 else a0[0])
            a1[0] = 1.0 if a1[0] > 1.0 else (-1.0 if a1[0] < -1.0 else a1[0])
        return True

    cdef tuple _finish(self, env, double a0, double a1):
        """SphereRobotBase._end_step: the same operations in the same order (its methods
        _odometry, _episode_end, _observation and _info inlined), the task's methods called."""
        cdef double w, x, y, z, psi, b0 = 0.0, b1 = 0.0, b2 = 0.0, angle, c, enc_speed, rate_y, step_len
        cdef double t, qt0, qt1, qt2, qt3, dot, ox, oy, oz, ow, tilt, stuck_t, g0, g1, g2, psi_t, vc, hc, e_psi
        cdef bint has_bias = False, out, stuck, terminated, truncated
        cdef long long steps, counts, gyr_n
        cdef cnp.npy_intp n = self.n_obs
        cdef cnp.ndarray obs
        cdef float* o
        cdef float[::1] lo = self.obs_lo, hi = self.obs_hi
        cdef tuple task
        cdef Py_ssize_t i
        cdef Estimator fe
        cdef double bb[3]
        steps = env._steps + 1
        env._steps = steps
        t = steps / self.control_hz
        env._t = t
        # the estimated attitude and heading, the estimator's bias
        est = env._est
        q = env._q_est
        if est is None or q is None:
            q = env._q_true_s
        w, x, y, z = q
        psi = _heading(w, x, y, z)
        if est is not None:
            if isinstance(est, Estimator) and getattr(type(est), "bias", None) is KERNEL_BIAS:
                # est.bias's numbers without its array (0.6 us)
                fe = est
                if fe._bias(bb):
                    has_bias = True
                    b0, b1, b2 = bb[0], bb[1], bb[2]
            else:
                bias = est.bias
                if bias is not None:
                    has_bias = True
                    b0, b1, b2 = bias.tolist()
        # _odometry: the encoder (its reading the joint states after the physics when kept)
        js = self.js_next
        angle = js[0][0] if js is not None else self.getj(self.b, self.drive_joint, self.c)[0]
        c = angle * self.cpr / TWO_PI
        if not isfinite(c):
            math.floor(c)                   # (its error)
        counts = <long long>floor(c)
        enc_speed = <double>(counts - <long long>env._enc_counts) * (TWO_PI / self.cpr) * self.control_hz
        env._enc_speed = enc_speed
        env._enc_counts = counts
        gyr_n = env._gyr_n
        rate_y = <double>env._gyr_sum_y / <double>gyr_n if gyr_n else 0.0
        if has_bias:
            rate_y -= b1
        step_len = self.shell_r * (enc_speed + rate_y) / self.control_hz
        pe = env._pos_est
        pe[0] = <double>pe[0] + step_len * cos(psi)
        pe[1] = <double>pe[1] + step_len * sin(psi)
        if self.fix_hz > 0 and t >= <double>env._next_fix - 1e-9:
            env._position_fix()
        # the task's reward; _episode_end
        tr = env._true
        pos, orn, lin = tr[0], tr[1], tr[2]
        ox, oy, oz, ow = orn
        psi_t = _heading(ow, ox, oy, oz)
        if self.track:
            terms = self._track_rew(env, t, psi_t, lin, a0, a1)
            done = False
        else:
            terms, done = env._get_rew(a0, a1)
        reward = float(_sum(terms.values()))
        out = abs(<double>pos[0]) > self.half_arena or abs(<double>pos[1]) > self.half_arena
        if _hypot(lin[0], lin[1]) < self.stuck_speed and abs(a0) > self.stuck_action:
            stuck_t = <double>env._stuck_t + 1.0 / self.control_hz
        else:
            stuck_t = 0.0
        env._stuck_t = stuck_t
        stuck = stuck_t >= self.stuck_time
        terminated = bool(done) or out or stuck
        truncated = (not terminated) and steps >= self.max_steps
        if terminated or truncated:
            env._needs_reset = True
        # _observation
        if self.track:
            # SphereBotTrackEnv._task_obs
            cmd = env._cmd
            vc, hc = cmd[0], cmd[1]
            e_psi = _pymod(hc - psi + PI, TWO_PI) - PI
            task = (vc, vc - enc_speed * self.shell_r, sin(e_psi), cos(e_psi))
        else:
            task = env._task_obs(psi)
        if len(task) != n - 10:
            raise ValueError(f"the task's observation values must be {n - 10} numbers, got {len(task)}")
        gl = env._gyr_last
        g0, g1, g2 = gl[0], gl[1], gl[2]
        if has_bias:
            g0, g1, g2 = g0 - b0, g1 - b1, g2 - b2
        act = env._action
        obs = cnp.PyArray_SimpleNew(1, &n, cnp.NPY_FLOAT)
        o = <float*>cnp.PyArray_DATA(obs)
        if w < 0:
            o[0], o[1], o[2], o[3] = -w, -x, -y, -z
        else:
            o[0], o[1], o[2], o[3] = w, x, y, z
        o[4], o[5], o[6], o[7] = g0, g1, g2, enc_speed
        o[8], o[9] = <double>act[0], <double>act[1]
        for i in range(n - 10):
            o[10 + i] = <double>task[i]
        for i in range(n):                  # np.maximum, np.minimum (a NaN stays)
            if o[i] < lo[i]:
                o[i] = lo[i]
            if o[i] > hi[i]:
                o[i] = hi[i]
        # _info
        if est is None:
            skipped = {"gyr": 0, "acc": 0, "mag": 0}
        elif isinstance(est, Estimator) and type(est).skipped is SKIPPED:
            fe = est
            skipped = {"gyr": fe.n_skip_gyr, "acc": fe.n_skip_acc, "mag": fe.n_skip_mag}
        else:
            skipped = dict(est.skipped)
        qt = env._q_true_s
        qt0, qt1, qt2, qt3 = qt
        dot = abs(qt0 * w + qt1 * x + qt2 * y + qt3 * z)
        o0, o1 = orn[0], orn[1]
        tilt = 1.0 - 2.0 * <double>(o0 ** 2 + o1 ** 2)     # (Python's float power: libm's pow)
        tilt = tilt if tilt < 1.0 else 1.0
        tilt = tilt if tilt > -1.0 else -1.0
        info = {
            "q_true": _f64(qt, 4), "q_est": _f64(q, 4),
            "attitude_error_deg": (2.0 * acos(dot if dot < 1.0 else 1.0)) * RAD2DEG,
            "position": _f64(pos, 3), "velocity": _f64(lin, 3),
            "heading_true": psi_t, "heading_est": psi,
            "encoder_speed": enc_speed, "motor_torque": env._tau,
            "reward_terms": terms, "action_clipped": env._clipped,
            "estimator_skipped": skipped,
            "imu_samples": env._n_samples, "t": t,
            "frame_tilt_deg": acos(tilt) * RAD2DEG,
        }
        if self.track:
            info["command"] = env._cmd              # SphereBotTrackEnv._task_info
        else:
            env._task_info(info)
        info["out_of_arena"] = out
        info["stuck"] = stuck
        if not self.track:                          # (the track's: the base's, nothing)
            env._task_step_info(info, terminated and not out and not stuck)
        return obs, reward, terminated, truncated, info

    cdef dict _track_rew(self, env, double t, double psi_t, lin, double a0, double a1):
        """SphereBotTrackEnv._get_rew (its terms; it never ends the episode) at the time t,
        with the true heading psi_t and velocity lin."""
        cdef double vc, hc, v_fwd, e
        cdef Py_ssize_t i = env._cmd_i, n
        times = env._cmd_times
        n = len(times)
        if i + 1 < n and t >= <double>times[i + 1]:
            while i + 1 < n and t >= <double>times[i + 1]:
                i += 1
            env._cmd_i = i
            env._cmd = (env._cmd_speed[i], env._cmd_heading[i])
        cmd = env._cmd
        vc, hc = cmd[0], cmd[1]
        v_fwd = <double>lin[0] * cos(psi_t) + <double>lin[1] * sin(psi_t)
        e = _pymod(psi_t - hc + PI, TWO_PI) - PI
        return {"speed": -fabs(v_fwd - vc) / 0.5, "heading": -fabs(e) / PI, "effort": -0.01 * (a0 * a0 + a1 * a1)}
