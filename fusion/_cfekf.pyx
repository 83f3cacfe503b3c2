# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`cf-ekf`: the fusion of "Attitude-angle solution for a mobile robot" (Chinese patent, 2019)
(docs/cfekf.md): sliding-mean prefilter, an explicit
complementary filter (Mahony) whose quaternion is the measurement of the 7-state EKF."""

import numpy as np

from libc.string cimport memcpy, memset

from fusion._core cimport Estimator
from fusion._ekf cimport EKF
from fusion._mahony cimport Mahony
from fusion._prefilter cimport SlidingMean
from fusion._prefilter import WINDOW_MAX
from fusion._core import struct_fields, TIMER
from fusion._ekf import EKF as _EKF
from fusion._mahony import Mahony as _Mahony
from fusion._rest import REST_PROPERTIES, REST_GATE_PROPERTIES
from fusion._magdist import MAGDIST_PROPERTIES
from fusion.params import Param, table, REST, MAGDIST, GYRO_RANGE, MOTION_RATE, MAG_UPDATE, ACC_LOWPASS
from libc.math cimport sqrt, fabs
from fusion._qmath cimport quat_normalise, quat_measurement_update, saturated, vec3_finite

WINDOW_S = 0.02     # the seed's window: 10 samples at 500 Hz (seed_window; not the default)
MAHONY_KI = 0.005     # ki's default without bias_feedback (mahony's before issue 19)
# bias_feedback: the EKF learns the bias from the filter's quaternion only after LEARN_HOLD s
# with the (averaged) accelerometer within LEARN_ACC_TOL of g and the filter within
# 2 acos(LEARN_COS) = 2 deg of the EKF's prediction
from fusion._constants cimport GRAVITY as G0, lasted
cdef double LEARN_ACC_TOL = 0.5             # m/s^2, the aekf's acc_norm_tol
cdef double LEARN_COS = 0.99984769515639127 # cos(1 deg): 2 deg between the quaternions
cdef double LEARN_HOLD = 0.5                # s


# the parameters its EKF core takes (the others are the complementary filter's or its own)
CORE_PARAMS = ("gyro_noise", "bias_noise", "q_init_std", "bias_init_std", "motion_rate",
               *(d.name for d in REST))


def seed_window(fs):
    """Samples in the seed's 20 ms window at sample rate fs (at least 1): its literal setting,
    ``window=seed_window(fs)``."""
    return max(1, int(round(WINDOW_S * fs)))


def _held(CFEKF e, part):
    """e's EKF core ("core") or complementary filter ("cf"), or a RuntimeError for an object
    whose __init__ did not run."""
    f = e.core if part == "core" else e.cf
    if f is None:
        raise RuntimeError("CFEKF object was not configured: call the class's __init__ or use fusion.make")
    return f


def _of(part, *names):
    """Read-only properties that read the attributes of the same names of the filter it holds
    as part ("core": the EKF, "cf": the complementary filter)."""
    what = "EKF core" if part == "core" else "complementary filter"
    return tuple(property(lambda e, n=n: getattr(_held(e, part), n), doc=f"The {what}'s {n}.")
                 for n in names)


cdef inline void cf_ekf_step(CFEKF e, EKF k, const double* gyr, const double* acc,
                             const double* mag, double dt) noexcept nogil:
    """CFEKF._step on its EKF core k (an argument: held in a register, not reloaded from
    e after every store)."""
    cdef double z[4]
    cdef double g[3]
    cdef int i
    cdef bint sat = gyr != NULL and e.s.sat_left > 0
    cdef bint learn
    cdef double na, c
    if not e.s.cf_started:         # the complementary filter starts where the EKF does
        e.cf._reset_state()
        for i in range(4):
            e.cf.q[i] = e.q[i]
        e.s.cf_started = True
    # the EKF's attitude is this estimator's (set by reset, the first sample, load_state)
    memcpy(k.q, e.q, 4 * sizeof(double))
    if gyr != NULL and e.bias_feedback:
        # the complementary filter integrates the gyro corrected by the EKF's bias (from
        # before this sample's update)
        for i in range(3):
            g[i] = gyr[i] - k.s.b[i]
        e.cf.step_flagged(g, acc, mag, dt, sat)
    else:
        e.cf.step_flagged(gyr, acc, mag, dt, sat)
    k.propagate(gyr, dt, sat)
    k.rest_update(gyr, acc, dt)
    if acc != NULL or mag != NULL:
        if e.cf.q[0] * k.q[0] + e.cf.q[1] * k.q[1] + e.cf.q[2] * k.q[2] + e.cf.q[3] * k.q[3] < 0.0:
            for i in range(4):
                z[i] = -e.cf.q[i]
        else:
            for i in range(4):
                z[i] = e.cf.q[i]
        learn = True
        if e.bias_feedback:
            # the bias is learned from the filter only while it is quiet (docs/cfekf.md):
            # not under linear acceleration (its correction then turns the wrong way),
            # nor while it corrects a large error (a start, a glitch), which would be
            # read as bias and, fed back, integrated
            na = G0 if acc == NULL else sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
            c = fabs(z[0] * k.q[0] + z[1] * k.q[1] + z[2] * k.q[2] + z[3] * k.q[3])
            if fabs(na - G0) > LEARN_ACC_TOL or c < LEARN_COS:
                e.s.t_quiet = 0.0
                learn = False
            else:
                e.s.t_quiet += dt
                learn = lasted(e.s.t_quiet, LEARN_HOLD)
        quat_measurement_update(k.q, k.s.b, k.s.P, z, e.cf_noise * e.cf_noise / dt, NULL, 0.0, learn)
    quat_normalise(k.q)
    memcpy(e.q, k.q, 4 * sizeof(double))


cdef class CFEKF(Estimator):
    """The fusion of "Attitude-angle solution for a mobile robot": gyro, accelerometer and
    magnetometer through a sliding mean (window samples, 1 by default: none); Mahony's
    complementary filter (kp, ki) turns the means into a quaternion; that quaternion is the
    4-D measurement (H = [I4 0], noise density cf_noise) of the quaternion + gyro-bias EKF,
    whose prediction integrates the averaged gyro. bias_feedback: the complementary filter
    integrates the averaged gyro minus the EKF's bias (ki then defaults to 0, else to
    mahony's 0.005). gyro_range, motion_rate: as the ekf's. It holds both filters (an `ekf`
    core and a `mahony`) and exposes its own parameters only."""
    name = "cf-ekf"
    PARAMS = table(
        # the ekf's noise declarations at the values cf-ekf's folds chose (docs/accuracy.md)
        _EKF.PARAMS["gyro_noise"].but(default=0.01), _EKF.PARAMS["bias_noise"], _EKF.PARAMS["q_init_std"],
        _EKF.PARAMS["bias_init_std"].but(default=0.02),
        # window 1 (no mean): every leave-one-set-out fold chose it over the seed's 20 ms, whose
        # delay of (window - 1)/2 samples the estimate follows (docs/accuracy.md, "Eleventh pass")
        Param("window", 1, "samples", 1, WINDOW_MAX, "sliding-mean length, step 1, on gyro, "
              "accelerometer and magnetometer; 1: no mean; the seed's 20 ms: round(0.02 fs)",
              integer=True),
        # kp: cf-ekf's own leave-one-set-out choice (docs/accuracy.md), not mahony's
        _Mahony.PARAMS["kp"].but(default=1.0, allow_zero=False, doc="the complementary filter's proportional gain"),
        _Mahony.PARAMS["ki"].but(default=None, doc="its integral gain; None: 0 with bias_feedback, "
                                 f"else {MAHONY_KI}"),
        _Mahony.PARAMS["mag_weight"].but(default=0.3),    # chosen as the ekf's mag_noise: docs/accuracy.md
        Param("cf_noise", 0.005, "1/√Hz", 1e-4, 10.0, "noise density of each component of the "
              "complementary filter's quaternion, as a measurement"),
        GYRO_RANGE, MOTION_RATE,
        Param("bias_feedback", True, "", doc="the complementary filter integrates the averaged gyro "
              "minus the EKF's bias, which the EKF learns from the filter only while it is quiet"),
        MAG_UPDATE, ACC_LOWPASS.but(default=0.5), *REST,
        # the gate does not help its slowest turn about the vertical (docs/accuracy.md, fifteenth pass)
        _EKF.PARAMS["rest_bias_gate"].but(default=0.0), *MAGDIST)
    # the rest parameters and counts, read from the core's detector (fusion._rest)
    (rest_time, rest_gyro_tol, rest_acc_tol, rest_gyro_drift_tol, rest_acc_drift_tol, rest_noise, at_rest,
     rest_samples) = REST_PROPERTIES
    rest_bias_gate, rest_gate_time = REST_GATE_PROPERTIES
    # the disturbance parameters and count, read from the complementary filter's (its magd)
    magdist_time, magdist_norm_tol, magdist_dip_tol, magdist_new_time, mag_rejected = MAGDIST_PROPERTIES
    # its EKF parameters, the gyro bias and the 7x7 covariance of [q (in the estimator's frame),
    # bias] are the core's
    gyro_noise, bias_noise, q_init_std, bias_init_std, motion_rate, covariance = _of(
        "core", "gyro_noise", "bias_noise", "q_init_std", "bias_init_std", "motion_rate", "covariance")
    # its complementary filter's gains and the parts of it that take the accelerometer and
    # magnetometer (acc_lowpass: fusion/_acclp.pxd; magd: its disturbance detector)
    kp, ki, mag_weight, mag_update, acc_lowpass, magd = _of("cf", "kp", "ki", "mag_weight", "mag_update",
                                                            "acc_lowpass", "magd")

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked before the base takes anything
        self._take_base(fs, frame, on_invalid, p)
        # the EKF core: cf-ekf's noise, recovery and rest detection; its accelerometer
        # low-pass and magnetic detection off (the complementary filter takes those sensors).
        # A saturated gyro (tested on the raw samples: _process) restarts the complementary
        # filter's gain ramp, and the core's attitude covariance grows (motion_rate) as the
        # ekf's does, so that it takes the filter's recovered attitude as the ekf takes the
        # accelerometer's
        self.core = _EKF(self.fs, frame, on_invalid, acc_lowpass=0.0, magdist_time=0.0,
                         **{k: p[k] for k in CORE_PARAMS})
        self.rest = self.core.rest
        self.cf_noise = p["cf_noise"]
        self.bias_feedback = p["bias_feedback"]
        # with the EKF's bias fed back the complementary filter needs no integral of its own
        # (docs/cfekf.md, "bias_feedback"); without it, mahony's default
        ki = p["ki"]
        if ki is None:
            ki = 0.0 if self.bias_feedback else MAHONY_KI
        w = p["window"]
        self._take_prefilters(SlidingMean(w), SlidingMean(w), SlidingMean(w))
        # the complementary filter takes the magnetometer: its heading-only correction and
        # disturbance detection are the cf-ekf's
        self.cf = _Mahony(self.fs, kp=p["kp"], ki=ki, mag_weight=p["mag_weight"], gyro_range=p["gyro_range"],
                          mag_update=p["mag_update"],
                          acc_lowpass=p["acc_lowpass"], rest_time=0.0,
                          **{d.name: p[d.name] for d in MAGDIST})
        self.configured = True
        self._reset(None)

    cdef list _state_fields(self):
        # the core's b, P, recovery timer and rest detector under the ekf's names (its
        # attitude is q); the inner complementary filter's whole state, under "cf."
        return (Estimator._state_fields(self) + self.core._filter_fields() + self.rest.fields()
                + struct_fields(<CFEKFState[:1]>&self.s, {"sat_left": (0, self.window), "t_quiet": TIMER})
                + [("cf." + n, v, c) for n, v, c in self.cf._state_fields()])

    cdef bint _bias(self, double* out) noexcept nogil:
        # the core's (None before __init__ configured it: no bias)
        return self.core is not None and self.core._bias(out)

    cdef void _reset_state(self) noexcept nogil:
        self.core._reset_state()
        memset(&self.s, 0, sizeof(CFEKFState))

    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil:
        # saturation is a property of the raw sample (the window's mean of rail samples is
        # not on the rail): flagged while the window holds one
        cdef bint entered = vec3_finite(gyr)     # the prefilter sees valid samples only
        if entered and saturated(gyr, self.gyro_range_):
            self.s.sat_left = (<SlidingMean>self.pre_gyr).window
        Estimator._process(self, gyr, acc, mag, dt)
        if entered and self.s.sat_left > 0:
            self.s.sat_left -= 1

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        cf_ekf_step(self, self.core, gyr, acc, mag, dt)

    @property
    def window(self):
        """Sliding-mean window, samples."""
        return (<object>self.pre_gyr).window

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
