# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`cf-ekf`: the fusion of "Attitude-angle solution for a mobile robot" (Chinese patent, 2019)
(docs/cfekf.md): sliding-mean prefilter, an explicit
complementary filter (Mahony) whose quaternion is the measurement of the 7-state EKF."""

import numpy as np

from fusion._core cimport Estimator
from fusion._ekf cimport EKF
from fusion._mahony cimport Mahony
from fusion._prefilter cimport SlidingMean
from fusion._prefilter import check_window
from fusion._core import check_positive, check_param, check_rest_params, REST_PARAMS, MAGDIST_PARAMS, FLAG, TIMER
from fusion._ekf import check_recovery_params
from fusion._mahony import Mahony as _Mahony
from libc.math cimport sqrt, fabs
from fusion._qmath cimport quat_normalise, quat_measurement_update, saturated, vec3_finite

WINDOW_S = 0.02     # the seed's window: 10 samples at 500 Hz
MAHONY_KI = 0.005     # ki's default without bias_feedback (mahony's before issue 19)
# bias_feedback: the EKF learns the bias from the filter's quaternion only after LEARN_HOLD s
# with the (averaged) accelerometer within LEARN_ACC_TOL of g and the filter within
# 2 acos(LEARN_COS) = 2 deg of the EKF's prediction
cdef double G0 = 9.81
cdef double LEARN_ACC_TOL = 0.5             # m/s^2, the aekf's acc_norm_tol
cdef double LEARN_COS = 0.99984769515639127 # cos(1 deg): 2 deg between the quaternions
cdef double LEARN_HOLD = 0.5                # s


def default_window(fs):
    """Samples in the seed's 20 ms window at sample rate fs (at least 1)."""
    return max(1, int(round(WINDOW_S * fs)))


cdef class CFEKF(EKF):
    """The fusion of "Attitude-angle solution for a mobile robot": gyro, accelerometer and
    magnetometer through a sliding mean; Mahony's
    complementary filter (kp, ki) turns the means into a quaternion; that quaternion is the
    4-D measurement (H = [I4 0], noise density cf_noise) of the quaternion + gyro-bias EKF,
    whose prediction integrates the averaged gyro. bias_feedback: the complementary filter
    integrates the averaged gyro minus the EKF's bias (ki then defaults to 0, else to
    mahony's 0.005). gyro_range, motion_rate: as the ekf's."""
    name = "cf-ekf"
    PARAMS = {"gyro_noise": 0.01, "bias_noise": 1e-4, "q_init_std": 0.05, "bias_init_std": 0.02,
              "window": None, "kp": 1.0, "ki": None, "cf_noise": 0.005, "gyro_range": None,
              "motion_rate": 1.0, "bias_feedback": True, "mag_update": "heading", "acc_lowpass": 0.5,
              **REST_PARAMS, **MAGDIST_PARAMS}

    def __init__(self, fs, frame="ENU", on_invalid="raise", **params):
        Estimator.__init__(self, fs, frame, on_invalid)
        p = self._take_params(params)
        self.gyro_noise = check_param("gyro_noise", p["gyro_noise"])
        self.bias_noise = check_param("bias_noise", p["bias_noise"], allow_zero=True)
        self.q_init_std = check_param("q_init_std", p["q_init_std"])
        self.bias_init_std = check_param("bias_init_std", p["bias_init_std"], allow_zero=True)
        self.cf_noise = check_param("cf_noise", p["cf_noise"])
        self.rest.time, self.rest.gyro_tol, self.rest.acc_tol, self.rest.noise = check_rest_params(p)
        kp = check_param("kp", p["kp"])
        if p["bias_feedback"] not in (True, False):
            raise ValueError(f"bias_feedback must be True or False, got {p['bias_feedback']!r}")
        self.bias_feedback = bool(p["bias_feedback"])
        # with the EKF's bias fed back the complementary filter needs no integral of its own
        # (docs/cfekf.md, "bias_feedback"); without it, mahony's default
        ki = p["ki"]
        if ki is None:
            ki = 0.0 if self.bias_feedback else MAHONY_KI
        ki = check_param("ki", ki, allow_zero=True)
        w = p["window"]
        w = check_window(default_window(self.fs) if w is None else w, " or None (round(0.02 fs))")
        self.pre_gyr = SlidingMean(int(w))
        self.pre_acc = SlidingMean(int(w))
        self.pre_mag = SlidingMean(int(w))
        # a saturated gyro (tested on the raw samples: _process) restarts the complementary
        # filter's gain ramp, and the EKF's attitude covariance grows as the ekf's does, so
        # that it takes the filter's recovered attitude as the ekf takes the accelerometer's
        self.gyro_range_, self.motion_rate = check_recovery_params(p)
        # the complementary filter takes the magnetometer: its heading-only correction and
        # disturbance detection are the cf-ekf's
        self.cf = _Mahony(self.fs, kp=kp, ki=ki, gyro_range=p["gyro_range"], mag_update=p["mag_update"],
                          acc_lowpass=p["acc_lowpass"], **{k: p[k] for k in MAGDIST_PARAMS})
        self.configured = True     # before reset(), which refuses an unconfigured object
        self.reset()

    cdef list _state_fields(self):
        # the inner complementary filter's whole state, under "cf."
        return (EKF._state_fields(self) + [("cf_started", <int[:1]><int*>&self.cf_started, FLAG),
                                           ("sat_left", <int[:1]>&self.sat_left, (0, self.window)),
                                           ("t_quiet", <double[:1]>&self.t_quiet, TIMER)]
                + [("cf." + n, v, c) for n, v, c in self.cf._state_fields()])

    cdef void _reset_state(self) noexcept nogil:
        EKF._reset_state(self)
        self.cf_started = False
        self.sat_left = 0
        self.t_quiet = 0.0

    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil:
        # saturation is a property of the raw sample (the window's mean of rail samples is
        # not on the rail): flagged while the window holds one
        cdef bint entered = vec3_finite(gyr)     # the prefilter sees valid samples only
        if entered and saturated(gyr, self.gyro_range_):
            self.sat_left = (<SlidingMean>self.pre_gyr).window
        Estimator._process(self, gyr, acc, mag, dt)
        if entered and self.sat_left > 0:
            self.sat_left -= 1

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        cdef double z[4]
        cdef double g[3]
        cdef int i
        cdef bint sat = gyr != NULL and self.sat_left > 0
        cdef bint learn
        cdef double na, c
        if not self.cf_started:         # the complementary filter starts where the EKF does
            self.cf._reset_state()
            for i in range(4):
                self.cf.q[i] = self.q[i]
            self.cf_started = True
        if gyr != NULL and self.bias_feedback:
            # the complementary filter integrates the gyro corrected by the EKF's bias (from
            # before this sample's update)
            for i in range(3):
                g[i] = gyr[i] - self.b[i]
            self.cf.step_flagged(g, acc, mag, dt, sat)
        else:
            self.cf.step_flagged(gyr, acc, mag, dt, sat)
        self.propagate(gyr, dt, sat)
        self.rest_update(gyr, acc, dt)
        if acc != NULL or mag != NULL:
            if (self.cf.q[0] * self.q[0] + self.cf.q[1] * self.q[1] + self.cf.q[2] * self.q[2]
                    + self.cf.q[3] * self.q[3]) < 0.0:
                for i in range(4):
                    z[i] = -self.cf.q[i]
            else:
                for i in range(4):
                    z[i] = self.cf.q[i]
            learn = True
            if self.bias_feedback:
                # the bias is learned from the filter only while it is quiet (docs/cfekf.md):
                # not under linear acceleration (its correction then turns the wrong way),
                # nor while it corrects a large error (a start, a glitch), which would be
                # read as bias and, fed back, integrated
                na = G0 if acc == NULL else sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
                c = fabs(z[0] * self.q[0] + z[1] * self.q[1] + z[2] * self.q[2] + z[3] * self.q[3])
                if fabs(na - G0) > LEARN_ACC_TOL or c < LEARN_COS:
                    self.t_quiet = 0.0
                    learn = False
                else:
                    self.t_quiet += dt
                    learn = self.t_quiet >= LEARN_HOLD
            quat_measurement_update(self.q, self.b, self.P, z, self.cf_noise * self.cf_noise / dt,
                                    NULL, 0.0, learn)
        quat_normalise(self.q)

    @property
    def window(self):
        """Sliding-mean window, samples."""
        return (<object>self.pre_gyr).window

    @property
    def mag_rejected(self):
        """Magnetometer samples the complementary filter rejected as disturbed."""
        return self.cf.mag_rejected

    @property
    def mag_update(self):
        return self.cf.mag_update

    @property
    def acc_lowpass(self):
        """s: the complementary filter's accelerometer low-pass (fusion/_acclp.pxd; 0: off)."""
        return self.cf.acc_lowpass

    @property
    def magdist_time(self):
        return self.cf.magdist_time

    @property
    def magdist_norm_tol(self):
        return self.cf.magdist_norm_tol

    @property
    def magdist_dip_tol(self):
        return self.cf.magdist_dip_tol

    @property
    def magdist_new_time(self):
        return self.cf.magdist_new_time

    @property
    def kp(self):
        return None if self.cf is None else self.cf.kp     # None: not configured

    @property
    def ki(self):
        return None if self.cf is None else self.cf.ki

    @property
    def cf_quaternion(self):
        """The complementary filter's own attitude (the last measurement), in the estimator's
        frame."""
        cdef double out[4]
        if self.cf is None:
            raise RuntimeError("CFEKF object was not configured: call the class's __init__ or use fusion.make")
        cdef Estimator e = self.cf
        e.ned = self.ned
        e._output_q(out)
        return np.array([out[0], out[1], out[2], out[3]])
