# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`madgwick`: Madgwick's gradient-descent orientation filter (docs/madgwick.md)."""
import numpy as np
from libc.math cimport fmax, fmin, sqrt
from libc.string cimport memset

from fusion._constants cimport BIAS_MAX
from fusion._core import struct_fields, BIAS, RECOVERY
from fusion.params import Param, table, GYRO_RANGE, MAG_UPDATE, ACC_LOWPASS, MAGDIST, REST_PULL
from fusion._qmath cimport (quat_propagate, quat_normalise, rot_to_body, rot_to_nav,
                            jac_rot_to_body, up_in_body, jac_up_in_body, unit3, recovery_gain,
                            saturated)
from fusion._aided cimport AidedFilter, rest_now, mag_accepted, acc_input
from fusion._rest cimport rest_rate
from fusion._acclp cimport acc_lowpass_lost
from fusion._rest import REST_TAU_PROPERTY

# |grad f| at or below this is round-off, not a direction: no step (docs/madgwick.md)
cdef double DEAD_ZONE2 = 1e-20
# while recovering, the raised step is recovery_gain's factor on at least Madgwick's report's
# beta (rad/s): a step lost by the gyro can leave an error of 90 deg, which the ramp must
# correct whatever the (smaller) default beta is (docs/robustness.md, "Recovery")
cdef double BETA_RECOVERY = 0.041


cdef inline void add_gradient(const double* H, const double* v, const double* s,
                              double* g) noexcept nogil:
    """g += H^T (v - s), H 3x4 row-major."""
    cdef double f0 = v[0] - s[0], f1 = v[1] - s[1], f2 = v[2] - s[2]
    cdef int k
    for k in range(4):
        g[k] += H[k] * f0 + H[4 + k] * f1 + H[8 + k] * f2


cdef class Madgwick(AidedFilter):
    """Madgwick's gradient-descent filter: a fixed-rate step (beta, rad/s) along the
    normalised gradient of the gravity and north-folded field residuals; optional gyro-bias
    learning with gain zeta (rad/s^2). After a step the gyro did not measure (a saturated
    sample with gyro_range, rad/s; a dropped gyro sample; a gap in time) beta is raised and
    the bias learning held for 3 s (recovery_gain). mag_update="heading": the
    field's gradient projected onto a turn about the vertical; magdist_*: disturbed fields
    skipped (fusion/_magdist.pxd); acc_lowpass (s): the gradient's accelerometer low-passed
    in a gyro-integrated frame (fusion/_acclp.pxd); rest_* (fusion/_rest.pxd): at rest the
    bias is pulled toward the measured rate with the time constant rest_tau."""
    name = "madgwick"
    PARAMS = table(
        # beta, zeta and acc_lowpass chosen leave-one-set-out on the recorded sets
        # (docs/accuracy.md, sixth pass): a small fixed step needs the bias learned in motion
        Param("beta", 0.0075, "rad/s", 1e-6, 1e3, "step of the quaternion along the normalised "
              "gradient, per second (the attitude turns by up to 2 beta rad/s toward the vectors; "
              "Madgwick's report: 0.041)"),
        Param("zeta", 5e-4, "rad/s²", 1e-9, 1e3, "gain of Madgwick's gyro-bias compensation (the bias "
              "changes by up to 2 zeta rad/s per second; 0: off, as in MadgwickAHRS.c and ahrs)",
              allow_zero=True),
        GYRO_RANGE.but(doc=GYRO_RANGE.doc + "; for 3 s after a saturated sample beta is raised and the "
                       "bias learning held"),
        MAG_UPDATE, ACC_LOWPASS.but(default=2.0), *MAGDIST, *REST_PULL)
    rest_tau = REST_TAU_PROPERTY        # REST_PULL's, read from its rest detector

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked before the base takes anything
        self._take_base(fs, frame, on_invalid, p)
        self.beta = p["beta"]
        self.zeta = p["zeta"]
        self.configure(p)                   # rest and disturbance detectors, low-pass; reset

    cdef list _state_fields(self):
        return AidedFilter._state_fields(self) + struct_fields(<MadgwickState[:1]>&self.s,
                                                              {"bw": BIAS, "t_recover": RECOVERY})

    cdef void _reset_state(self) noexcept nogil:
        AidedFilter._reset_state(self)
        memset(&self.s, 0, sizeof(MadgwickState))

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        cdef double* q = self.q
        cdef double s[3]
        cdef double v[3]
        cdef double h[3]
        cdef double H[12]
        cdef double g[4]
        cdef double gm[4]
        cdef double u[4]
        cdef double af[3]
        cdef double n2, k, T
        cdef double z[3]
        cdef int i
        cdef bint sat = gyr != NULL and saturated(gyr, self.gyro_range_)
        # a step the gyro did not measure (saturated, dropped, or a gap) leaves an attitude
        # error of unknown size, which the small fixed step of beta would take long to
        # correct: raise it as after a saturated sample
        cdef double f = recovery_gain(&self.s.t_recover,
                                      acc_lowpass_lost(gyr, sat, dt, self.dt_nominal), dt)
        if not mag_accepted(self, q, mag, gyr, dt):
            mag = NULL
        if self.rest.time > 0.0 and rest_now(self, gyr, acc, dt):
            T = rest_rate(self.rest, gyr, dt, z)      # the rate measured, over the time T
            k = T / (self.rest.tau + T)
            for i in range(3):
                self.s.bw[i] += k * (z[i] - self.s.bw[i])
        acc = acc_input(self, gyr, sat, self.s.bw, acc, dt, af)
        if gyr != NULL:
            quat_propagate(q, gyr[0] - self.s.bw[0], gyr[1] - self.s.bw[1], gyr[2] - self.s.bw[2], dt)
        g[0] = 0.0
        g[1] = 0.0
        g[2] = 0.0
        g[3] = 0.0
        if acc != NULL:
            unit3(acc, s)
            up_in_body(q, v)
            jac_up_in_body(q, H)
            add_gradient(H, v, s, g)
        if mag != NULL:
            unit3(mag, s)
            rot_to_nav(q, s, h)
            h[1] = sqrt(h[0] * h[0] + h[1] * h[1])     # the field turned about z onto north
            h[0] = 0.0
            rot_to_body(q, h, v)
            jac_rot_to_body(q, h, H)                   # reference direction held fixed
            if not self.mag_heading:
                add_gradient(H, v, s, g)
            else:
                # only its component along a turn about the vertical, u = e_z ⊗ q: the
                # field corrects the heading, never the tilt (as in VQF and x-io Fusion)
                gm[0] = 0.0
                gm[1] = 0.0
                gm[2] = 0.0
                gm[3] = 0.0
                add_gradient(H, v, s, gm)
                u[0] = -q[3]
                u[1] = -q[2]
                u[2] = q[1]
                u[3] = q[0]
                k = (u[0] * gm[0] + u[1] * gm[1] + u[2] * gm[2] + u[3] * gm[3]) / (
                    u[0] * u[0] + u[1] * u[1] + u[2] * u[2] + u[3] * u[3])
                g[0] += k * u[0]
                g[1] += k * u[1]
                g[2] += k * u[2]
                g[3] += k * u[3]
        n2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2] + g[3] * g[3]
        if n2 > DEAD_ZONE2:
            k = 1.0 / sqrt(n2)
            g[0] *= k
            g[1] *= k
            g[2] *= k
            g[3] *= k
            if self.zeta > 0.0 and f == 1.0:     # (held while recovering) w_eps = 2 vec(q* ⊗ g) = 2 Xi(q)^T g
                k = 2.0 * self.zeta * dt
                self.s.bw[0] += k * (-q[1] * g[0] + q[0] * g[1] + q[3] * g[2] - q[2] * g[3])
                self.s.bw[1] += k * (-q[2] * g[0] - q[3] * g[1] + q[0] * g[2] + q[1] * g[3])
                self.s.bw[2] += k * (-q[3] * g[0] + q[2] * g[1] - q[1] * g[2] + q[0] * g[3])
                # a zeta that makes the loop unstable winds the bias up without bound: held
                # at BIAS_MAX
                for i in range(3):
                    self.s.bw[i] = fmin(fmax(self.s.bw[i], -BIAS_MAX), BIAS_MAX)
            k = self.beta * dt if f == 1.0 else f * max(self.beta, BETA_RECOVERY) * dt
            q[0] -= k * g[0]
            q[1] -= k * g[1]
            q[2] -= k * g[2]
            q[3] -= k * g[3]
        quat_normalise(q)

    cdef bint _bias(self, double* out) noexcept nogil:
        # the gyro bias learned at rest and with the zeta gain
        out[0], out[1], out[2] = self.s.bw[0], self.s.bw[1], self.s.bw[2]
        return True
