# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`aekf`: the adaptive EKF of "Adaptive EKF from predicted measurements, for arm attitude",
on the 7-state `ekf` (docs/aekf.md). Also `quest()`, a Python entry to the inline QUEST of
fusion/_wahba.pxd."""
import numpy as np
cimport numpy as cnp
from libc.math cimport sqrt, fabs, asin, sin, cos, M_PI, isfinite
from libc.stdlib cimport realloc, free
from libc.string cimport memset

from fusion._core cimport Estimator, _claim, _release
from fusion._ekf cimport EKF
from fusion._aided cimport mag_accepted
from fusion._constants cimport outlasted
from fusion._core import struct_fields, TIMER, VALUE_MAX
from fusion.checks import number
from fusion.params import Param, table
from fusion._qmath cimport quat_normalise, xi_matrix, up_in_body, unit3, norm3, quat_measurement_update, saturated, out_of_range
from fusion._wahba cimport quest2

cnp.import_array()

from fusion._constants cimport GRAVITY as G0
cdef double DEG = M_PI / 180.0
cdef double UP[3]
UP[:] = [0.0, 0.0, 1.0]

# codes of est.decisions / est.last_decision (bits), for the kernel and for Python
cdef enum:
    DEC_ACC_REJECTED = 1
    DEC_MAG_REJECTED = 2
    DEC_QUEST_USED = 4
ACC_REJECTED, MAG_REJECTED, QUEST_USED = DEC_ACC_REJECTED, DEC_MAG_REJECTED, DEC_QUEST_USED

# struct_fields' checks of AEKFState: those other than a double's magnitude bound, a bint's
# flag and a long long's count
AEKF_STATE_CHECKS = {"t_dir": TIMER, "norm_ref": (0.0, VALUE_MAX), "dip_ref": (-M_PI / 2, M_PI / 2),
                     "ref_field": "unit",
                     "last_code": (0, DEC_ACC_REJECTED | DEC_MAG_REJECTED | DEC_QUEST_USED),
                     "g_ref": (1.0, 100.0)}     # m/s^2: the norm a still sensor reads


def quest(b1, b2, r1, r2, w1=1.0, w2=1.0):
    """QUEST solution of Wahba's problem for two vector pairs: the unit quaternion [w, x, y, z]
    (w >= 0) minimising w1 |r1 - R(q) b1|² + w2 |r2 - R(q) b2|² (b: body vectors, r: reference
    vectors, normalised here), or None when b1 ∥ b2 or r1 ∥ r2. The kernels call the inline
    fusion._wahba.quest2 directly."""
    cdef double v[4][3]
    cdef double q[4]
    cdef double n
    cdef int i, j
    for i, x in enumerate((b1, b2, r1, r2)):
        a = np.asarray(x, dtype=np.float64)
        if a.shape != (3,):
            raise ValueError(f"{('b1', 'b2', 'r1', 'r2')[i]} must have shape (3,), got {a.shape}")
        n = float(np.sqrt(a @ a))
        if not (np.isfinite(n) and n > 0):
            raise ValueError(f"{('b1', 'b2', 'r1', 'r2')[i]} must be finite and non-zero")
        for j in range(3):
            v[i][j] = a[j] / n
    cdef double c1 = number("w1", w1, 0.0, open_low=True)
    cdef double c2 = number("w2", w2, 0.0, open_low=True)
    if not quest2(v[0], v[1], v[2], v[3], c1, c2, q):
        return None
    return np.array([q[0], q[1], q[2], q[3]])


cdef class AEKF(EKF):
    """The adaptive EKF of "Adaptive EKF from predicted measurements, for arm attitude": the
    `ekf` whose accelerometer / magnetometer variances switch to reject_factor times their
    values when the readings disagree with what the predicted
    attitude expects (linear acceleration, magnetic disturbance); with measurement="quest" a
    QUEST quaternion is the measurement while both sensors are accepted."""
    name = "aekf"
    # the ekf's parameters; the accelerometer corrects the inclination only (docs/aekf.md,
    # "Rest and tilt"); its tests judge the sample the update takes, low-passed by acc_lowpass,
    # and acc_norm_tol, chosen with it leave-one-set-out (docs/accuracy.md, fifth pass)
    PARAMS = table(
        *EKF.PARAMS.values(),
        EKF.PARAMS["acc_update"].but(default="tilt"),
        EKF.PARAMS["bias_init_std"].but(default=0.02),
        # the gate makes its slowest turn about the vertical worse (docs/accuracy.md, fifteenth pass)
        EKF.PARAMS["rest_bias_gate"].but(default=0.0),
        Param("acc_norm_tol", 2.0, "m/s²", 0.0, None, "accelerometer rejected if | |a| - g | > this, a "
              "the sample the update takes (low-passed by acc_lowpass); g is 9.81 until the first rest, "
              "then the accelerometer's low-passed norm at rest (the paper's e_a1)", open_low=True),
        Param("acc_pred_tol", 2.0, "m/s²", 0.0, None, "accelerometer rejected if |a - g u| > this, u "
              "the predicted vertical (e_a2)", open_low=True),
        Param("acc_pred_timeout", 2.0, "s", 0.0, 1e4, "a distance-test failure lasting longer than "
              "this is the estimate's fault", open_low=True),
        Param("mag_norm_tol", 0.1, "1", 0.0, None, "magnetometer rejected if | |m| / B_ref - 1 | > "
              "this (e_m1)", open_low=True),
        Param("mag_dip_tol", 5.0, "deg", 0.0, 180.0, "magnetometer rejected if the dip is off by more "
              "than this (e_m2)", open_low=True),
        Param("reject_factor", 1e4, "1", 1.0, 1e12, "a rejected sensor's variance is this times its own"),
        Param("mag_norm", None, "mag. unit", 0.0, None, "reference field norm; None: learned",
              open_low=True),
        Param("mag_dip", None, "deg", -90.0, 90.0, "reference dip angle (positive: the field points "
              "down, north hemisphere); None: learned", open_low=True, open_high=True),
        Param("learn_time", 1.0, "s", 1e-6, 1e4, "the references are learned over the first "
              "max(1, round(learn_time fs)) samples", allow_zero=True),
        Param("measurement", "vectors", "", doc='"vectors": the two vector updates; "quest": the '
              "QUEST quaternion when both sensors are accepted", choices=("vectors", "quest")),
        Param("quest_mag_weight", 0.01, "1", 0.0, 1.0, "the magnetometer's Wahba weight (the "
              "accelerometer's is 1 - quest_mag_weight)", open_low=True, open_high=True))

    def _configure(self, fs, frame, on_invalid, params):
        own = set(self.PARAMS) - set(EKF.PARAMS)
        fs = self._check_init(fs, frame, on_invalid)
        p = self._take_params(params)       # checked (EKF._configure takes the ekf's part)
        self.acc_norm_tol = p["acc_norm_tol"]
        self.acc_pred_tol = p["acc_pred_tol"]
        self.acc_pred_timeout = p["acc_pred_timeout"]
        self.mag_norm_tol = p["mag_norm_tol"]
        self.mag_dip_tol = p["mag_dip_tol"]
        self.dip_tol_rad = self.mag_dip_tol * DEG
        self.reject_factor = p["reject_factor"]
        self.learn_time = p["learn_time"]
        self.quest_mag_weight = p["quest_mag_weight"]
        self.use_quest = p["measurement"] == "quest"
        self.mag_norm = p["mag_norm"]
        self.mag_dip = p["mag_dip"]
        self.learn_norm = self.mag_norm is None
        self.learn_dip = self.mag_dip is None
        self.norm_given = 0.0 if self.learn_norm else self.mag_norm
        self.dip_given = 0.0 if self.learn_dip else self.mag_dip
        self.n_learn = (max(1, int(round(self.learn_time * fs)))
                        if (self.learn_norm or self.learn_dip) else 0)
        EKF._configure(self, fs, frame, on_invalid, {k: v for k, v in params.items() if k not in own})

    def __dealloc__(self):
        free(self.log)

    cdef list _state_fields(self):
        # the decision log (record_decisions) is a recording, not state
        return EKF._state_fields(self) + struct_fields(<AEKFState[:1]>&self.ad, AEKF_STATE_CHECKS)

    cdef void _reset_state(self) noexcept nogil:
        EKF._reset_state(self)
        memset(&self.ad, 0, sizeof(AEKFState))
        self.ad.g_ref = G0
        self.ad.have_ref = not (self.learn_norm or self.learn_dip)
        self.ad.norm_ref = 0.0 if self.learn_norm else self.norm_given
        self.ad.dip_ref = 0.0 if self.learn_dip else self.dip_given * DEG
        self.ad.ref_field[1] = cos(self.ad.dip_ref)
        self.ad.ref_field[2] = -sin(self.ad.dip_ref)
        self.log_n = 0

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        cdef double u[3]
        cdef double ah[3]
        cdef double mh[3]
        cdef double qm[4]
        cdef double v[4]
        cdef double X[12]
        cdef int i
        cdef double na = 0.0, nm, c, dx, dy, dz, sa, sm
        cdef bint acc_rej = False, mag_rej = False, mag_tested = False, off_g
        cdef long long n_rest = self.rest.n
        cdef double g
        cdef double af[3]
        cdef const double* raw
        cdef double nr
        cdef bint sat
        cdef bint magd_run = False
        cdef bint magd_ok = False
        if gyr != NULL and out_of_range(gyr, self.gyro_range_):
            gyr = NULL      # not a measurement: held as a dropped sample (ekf_step)
        sat = gyr != NULL and saturated(gyr, self.gyro_range_)
        self.propagate(gyr, dt, sat)
        self.rest_update(gyr, acc, dt)
        # the sample the tests judge and the update takes: low-passed in the gyro's frame, so
        # that a shaken or fast-turning body's linear acceleration is averaged out before it
        # is tested (the raw samples of such a body fail the tests nearly all the time)
        raw = acc           # the reference's dip is learned from the raw samples
        acc = self.acc_sample(gyr, sat, acc, dt, af)
        if self.rest.n > n_rest:
            # at rest the accelerometer's low-passed norm is this sensor's g (a scale error of
            # a few % would otherwise fail the norm test on every sample of a still sensor)
            self.ad.g_ref = sqrt(self.rest.acc[0] * self.rest.acc[0] + self.rest.acc[1] * self.rest.acc[1]
                                 + self.rest.acc[2] * self.rest.acc[2])
        g = self.ad.g_ref
        # the tests: measured readings against those the predicted attitude expects
        up_in_body(self.q, u)
        if acc != NULL:
            na = sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
            dx = acc[0] - g * u[0]
            dy = acc[1] - g * u[1]
            dz = acc[2] - g * u[2]
            off_g = fabs(na - g) > self.acc_norm_tol
            if off_g and self.acc_lowpass <= 0.0:
                acc_rej = True          # a raw sample off g: the body accelerates
                self.ad.t_dir = 0.0
            elif off_g or sqrt(dx * dx + dy * dy + dz * dz) > self.acc_pred_tol:
                # not where the attitude expects it (or, low-passed, off g: its gyro frame
                # drifts with a wrong bias, which only accepted samples correct): a linear
                # acceleration, unless this lasts so long that the estimate must be wrong
                self.ad.t_dir += dt
                acc_rej = not outlasted(self.ad.t_dir, self.acc_pred_timeout)
            else:
                self.ad.t_dir = 0.0
            self.ad.n_acc_tested += 1
            if acc_rej:
                self.ad.n_acc_rej += 1
                self.ad.last_code |= DEC_ACC_REJECTED
        if mag != NULL:
            nm = sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
            if acc != NULL and self.ad.n_learned < self.n_learn:
                # learning the reference: running means over the first samples
                self.ad.n_learned += 1
                if self.learn_norm:
                    self.ad.norm_sum += nm
                    self.ad.norm_ref = self.ad.norm_sum / self.ad.n_learned
                if self.learn_dip:
                    nr = norm3(raw)
                    c = -(mag[0] * raw[0] + mag[1] * raw[1] + mag[2] * raw[2]) / (nm * nr)
                    if not isfinite(c):     # |m| |a| over- or underflowed: from unit vectors
                        c = -((mag[0] / nm) * (raw[0] / nr) + (mag[1] / nm) * (raw[1] / nr)
                              + (mag[2] / nm) * (raw[2] / nr))
                    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
                    self.ad.dip_sum += asin(c)
                    self.ad.dip_ref = self.ad.dip_sum / self.ad.n_learned
                    self.ad.ref_field[1] = cos(self.ad.dip_ref)
                    self.ad.ref_field[2] = -sin(self.ad.dip_ref)
                self.ad.have_ref = True
            if self.ad.have_ref:
                mag_tested = True
                c = -(mag[0] * u[0] + mag[1] * u[1] + mag[2] * u[2]) / nm
                c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
                mag_rej = (fabs(nm / self.ad.norm_ref - 1.0) > self.mag_norm_tol
                           or fabs(asin(c) - self.ad.dip_ref) > self.dip_tol_rad)
                self.ad.n_mag_tested += 1
                if mag_rej:
                    self.ad.n_mag_rej += 1
                    self.ad.last_code |= DEC_MAG_REJECTED
        # QUEST takes the magnetometer only where the shared disturbance detector accepts it
        # too, as the vector updates do (run once a sample: it keeps time)
        if self.use_quest and acc != NULL and mag_tested and not acc_rej and not mag_rej:
            magd_run = True
            magd_ok = mag_accepted(self, self.q, mag, gyr, dt)
        if magd_ok:
            unit3(acc, ah)
            unit3(mag, mh)
            # |u × m̂|²: the horizontal share of the field seen from the predicted attitude
            c = ((u[1] * mh[2] - u[2] * mh[1]) ** 2 + (u[2] * mh[0] - u[0] * mh[2]) ** 2
                 + (u[0] * mh[1] - u[1] * mh[0]) ** 2)
            if c > 1e-18 and quest2(ah, mh, UP, self.ad.ref_field, 1.0 - self.quest_mag_weight,
                                    self.quest_mag_weight, qm):
                if qm[0] * self.q[0] + qm[1] * self.q[1] + qm[2] * self.q[2] + qm[3] * self.q[3] < 0.0:
                    qm[0] = -qm[0]; qm[1] = -qm[1]; qm[2] = -qm[2]; qm[3] = -qm[3]
                # Rm: tilt as the accelerometer's, heading (rotation about the predicted up
                # axis u) as the magnetometer's horizontal part: σa² (I4 - v vᵀ)/4 + σh² v vᵀ/4,
                # v = Ξ(q) u, σh² = σm² / |u × m̂|²
                sa = self.kalman.acc_noise * self.kalman.acc_noise / (G0 * G0 * dt)
                sm = self.kalman.mag_noise * self.kalman.mag_noise / (dt * c)
                xi_matrix(self.q, X)
                for i in range(4):
                    v[i] = X[3 * i] * u[0] + X[3 * i + 1] * u[1] + X[3 * i + 2] * u[2]
                quat_measurement_update(self.q, self.s.b, self.s.P, qm, 0.25 * sa, v, 0.25 * (sm - sa))
                self.ad.n_quest += 1
                self.ad.last_code |= DEC_QUEST_USED
                quat_normalise(self.q)
                return
        # the ekf's updates; its variance is σ²/dt, so dt / factor gives factor × the variance
        if acc != NULL:
            self._acc_correct(acc, dt / self.reject_factor if acc_rej else dt)
        # the shared disturbance detector as well (fusion/_magdist.pxd): its reference is
        # re-learned, the document's gate's is not
        if magd_ok if magd_run else mag_accepted(self, self.q, mag, gyr, dt):
            self._mag_correct(mag, dt / self.reject_factor if mag_rej else dt)
        quat_normalise(self.q)

    cdef void _process(self, const double* gyr, const double* acc, const double* mag,
                       double dt) noexcept nogil:
        cdef unsigned char* p
        cdef Py_ssize_t cap
        self.ad.last_code = 0
        Estimator._process(self, gyr, acc, mag, dt)
        if self.logging:
            if self.log_n == self.log_cap:
                cap = 2 * self.log_cap if self.log_cap > 0 else 4096
                p = <unsigned char*>realloc(self.log, cap)
                if p == NULL:       # out of memory: stop recording, keep what there is
                    self.logging = False
                    return
                self.log = p
                self.log_cap = cap
            self.log[self.log_n] = <unsigned char>self.ad.last_code
            self.log_n += 1

    def _run(self, gyr, acc, mag, dt):
        # a refused batch (on_invalid="raise" past FUSED_CHECK_MIN: the state is put back)
        # takes back the codes it logged too
        cdef Py_ssize_t n0 = self.log_n
        cdef bint on = self.logging
        try:
            return Estimator._run(self, gyr, acc, mag, dt)
        except BaseException:
            self.log_n = n0
            self.logging = on
            raise

    # --- the switching, for figures ------------------------------------------------------
    def record_decisions(self, on=True):
        """Start (on=True) or stop recording one decision code per sample (est.decisions);
        starting forgets what was recorded before."""
        if on not in (True, False):
            raise ValueError(f"on must be True or False, got {on!r}")
        _claim(self)
        self.logging = bool(on)
        if on:
            self.log_n = 0
        _release(self)

    @property
    def decisions(self):
        """Per-sample codes recorded since record_decisions() (uint8 array): bit 0 (1)
        accelerometer rejected, bit 1 (2) magnetometer rejected, bit 2 (4) QUEST measurement
        used; 0 where the sensors were accepted or absent/invalid."""
        out = np.empty(self.log_n, dtype=np.uint8)
        cdef unsigned char[::1] o = out
        cdef Py_ssize_t i
        _claim(self)        # a run in another thread may move the log (realloc)
        for i in range(min(self.log_n, o.shape[0])):
            o[i] = self.log[i]
        _release(self)
        return out

    @property
    def last_decision(self):
        """The code (as in est.decisions) of the last sample processed."""
        return int(self.ad.last_code)

    @property
    def rejected(self):
        """Counts of accelerometer / magnetometer samples rejected since the last reset."""
        return {"acc": self.ad.n_acc_rej, "mag": self.ad.n_mag_rej}

    @property
    def tested(self):
        """Counts of accelerometer / magnetometer samples tested since the last reset."""
        return {"acc": self.ad.n_acc_tested, "mag": self.ad.n_mag_tested}

    @property
    def quest_updates(self):
        """Samples whose measurement was the QUEST quaternion since the last reset."""
        return self.ad.n_quest

    @property
    def mag_reference(self):
        """(field norm, dip angle in degrees) the magnetometer is tested against, or None
        before it is known (learned from the first samples unless mag_norm / mag_dip given)."""
        if not self.ad.have_ref:
            return None
        return (self.ad.norm_ref, self.ad.dip_ref / DEG)

    @property
    def measurement(self):
        return "quest" if self.use_quest else "vectors"
