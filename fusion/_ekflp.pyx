# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`ekf-lp`: the `ekf`'s gyro bias and heading, with the inclination of the accelerometer
low-passed in a frame that turns with the bias-corrected gyro alone by a second-order
Butterworth, the inclination filter of VQF (Laidig & Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", 2023) (docs/estimators.md)."""
from libc.math cimport tan, sqrt, atan2, sin, cos, fmax, M_SQRT2, M_PI
from libc.string cimport memset

from fusion._core cimport quat_out
from fusion._core import struct_fields, TIMER
from fusion._ekf cimport EKF
from fusion._acclp cimport acc_lowpass_lost
from fusion._constants cimport lasted
from fusion._prefilter cimport Biquad, butterworth2_design, biquad_prime, biquad_step, C_CUTOFF_MIN
from fusion.params import Param, table
from fusion._qmath cimport half_angle_terms, rot_to_body, rot_to_nav, quat_mul, quat_normalise, \
    norm3, saturated, out_of_range


cdef struct InclLowpass:
    double y[3]         # the low-passed accelerometer (body frame): the running mean during the start
    double s0[3]        # the Butterworth's two states (transposed direct form II), body frame
    double s1[3]
    double t            # s of samples in the running mean, held at incl_lowpass once it settles
    bint started        # y holds a sample


cdef inline void turn3(const double* dq, double* v) noexcept nogil:
    cdef double t[3]
    rot_to_body(dq, v, t)
    v[0] = t[0]
    v[1] = t[1]
    v[2] = t[2]


cdef void butterworth_coefficients(EKFLP e, double dt) noexcept nogil:
    """The Butterworth's coefficients for a step dt (fusion/_prefilter.pxd), the cutoff
    √2 / (2π incl_lowpass): its time constant is incl_lowpass in time, whatever the samples'
    spacing (VQF designs it once, at its fixed sample time). Computed again only when dt
    changes."""
    if dt != e.coef_dt:
        # tan(π fc dt), held at the Butterworth's floor (fusion/_prefilter.pxd; π fc dt there, whose
        # tangent differs by 3e-14 of it) for a step much shorter than the nominal period, which
        # incl_lowpass's range was checked against
        butterworth2_design(fmax(tan(dt / (M_SQRT2 * e.incl_lowpass)), M_PI * C_CUTOFF_MIN), &e.c)
        e.coef_dt = dt


cdef void incl_step(EKFLP e, const double* gyr, const double* acc, double dt) noexcept nogil:
    """One sample of the inclination low-pass. The gyro frame is lost (a restart from the next
    accelerometer sample, as acc_lowpass's) where the gyro did not measure the step: no
    sample, one out of range or saturated, or a gap of more than two nominal periods.
    Otherwise the states turn into this sample's body frame by the bias-corrected gyro's turn
    (the filter run in the gyro frame, written in the body frame: fusion/_acclp.pxd), then the
    sample enters: the running mean of the samples so far (the first weighs one nominal
    period, the others their dt) until they span incl_lowpass, then the Butterworth started
    at rest on that mean (VQF's start, which counts samples of the nominal period)."""
    cdef InclLowpass* s = &e.il
    cdef double dq[4]
    cdef double c, sn, wx, wy, wz
    cdef int i
    cdef bint settled = s.t >= e.incl_lowpass
    if gyr != NULL and out_of_range(gyr, e.gyro_range_):
        gyr = NULL      # not a measurement, as the ekf takes it
    if acc_lowpass_lost(gyr, gyr != NULL and saturated(gyr, e.gyro_range_), dt, e.dt_nominal):
        s.started = False
    elif s.started:
        wx = gyr[0] - e.s.b[0]
        wy = gyr[1] - e.s.b[1]
        wz = gyr[2] - e.s.b[2]
        half_angle_terms(wx, wy, wz, dt, &c, &sn)
        dq[0] = c
        dq[1] = wx * sn
        dq[2] = wy * sn
        dq[3] = wz * sn
        if settled:
            turn3(dq, s.s0)
            turn3(dq, s.s1)
        if not settled or acc == NULL:      # (settled, a sample overwrites y below)
            turn3(dq, s.y)
    if acc == NULL:
        return
    if not s.started:
        memset(s, 0, sizeof(InclLowpass))
        s.y[0], s.y[1], s.y[2] = acc[0], acc[1], acc[2]
        s.t = e.dt_nominal      # one sample's weight, also after a gap (its dt spans the gap)
        s.started = True
    elif s.t < e.incl_lowpass:
        s.t += dt
        for i in range(3):
            s.y[i] += dt / s.t * (acc[i] - s.y[i])
    else:
        butterworth_coefficients(e, dt)
        for i in range(3):
            s.y[i] = biquad_step(&e.c, acc[i], &s.s0[i], &s.s1[i])
        return
    # the start ends (the steps summed may fall short of a whole multiple by round-off): the
    # Butterworth's steady state on the mean
    if lasted(s.t, e.incl_lowpass):
        s.t = e.incl_lowpass
        butterworth_coefficients(e, dt)
        for i in range(3):
            biquad_prime(&e.c, s.y[i], &s.s0[i], &s.s1[i])


cdef inline void incl_output(const double* q, const double* y, double frac, double* out) noexcept nogil:
    """q turned about a horizontal axis towards y's direction as its body-frame vertical (VQF's
    inclination correction; the heading about the new vertical kept): c ⊗ q with c the
    shortest turn of u = R(q) y / |y| onto the vertical, its angle scaled by frac (0 to 1:
    the part of the turn made). q itself where u points down (no shortest turn) or y is zero."""
    cdef double u[3]
    cdef double c[4]
    cdef double n = norm3(y)
    cdef double w, h, k
    out[0], out[1], out[2], out[3] = q[0], q[1], q[2], q[3]
    if not n > 0.0:
        return
    rot_to_nav(q, y, u)
    w = (u[2] / n + 1.0) * 0.5
    if not w > 1e-12:
        return
    w = sqrt(w)
    c[0] = w
    c[1] = 0.5 * u[1] / n / w
    c[2] = -0.5 * u[0] / n / w
    c[3] = 0.0
    if frac < 1.0:
        h = atan2(sqrt(c[1] * c[1] + c[2] * c[2]), w)       # half the turn's angle
        if h > 0.0:
            k = sin(frac * h) / sin(h)
            c[0] = cos(frac * h)
            c[1] *= k
            c[2] *= k
    quat_mul(c, q, out)
    quat_normalise(out)


cdef class EKFLP(EKF):
    """The `ekf` (its gyro bias, heading, rest and magnetic disturbance handling) reporting the
    inclination of the accelerometer low-passed in the gyro frame by a second-order
    Butterworth of time constant incl_lowpass (VQF's inclination filter, with the `ekf`'s
    bias in place of VQF's). The filter's own state, and so its bias and heading, are the
    `ekf`'s: the low-pass only changes what is reported."""
    name = "ekf-lp"
    PARAMS = table(*EKF.PARAMS.values(),
                   Param("incl_lowpass", 3.0, "s", 1e-3, 1e4, "time constant of the reported "
                         "inclination's second-order Butterworth (VQF's tauAcc convention: cutoff "
                         "√2 / (2π incl_lowpass) Hz; 3 s is VQF's published default, not fitted here); "
                         "at least 1.1 sample periods and at most 2.25e6 / fs s (cutoff 1e-7 fs); not given: "
                         "held within those"))
    cdef InclLowpass il
    cdef readonly double incl_lowpass
    cdef Biquad c                   # the Butterworth's coefficients for the step coef_dt
    cdef double coef_dt

    def _configure(self, fs, frame, on_invalid, params):
        cdef double tau
        fs = self._check_init(fs, frame, on_invalid)
        tau = self._take_params(params)["incl_lowpass"]
        # the cutoff √2 / (2π tau) between CUTOFF_MIN fs (fusion._prefilter) and a third of fs,
        # where the bilinear map holds
        tau_min, tau_max = 1.1 / fs, M_SQRT2 / (2.0 * M_PI * C_CUTOFF_MIN * fs)
        if "incl_lowpass" not in params:    # the default at a rate too low (below 0.37 Hz) or too high for it
            tau = min(max(tau, tau_min), tau_max)
        low, high = f"{tau_min:.3g}", f"{tau_max:.6g}"     # as the messages print them: accepted too
        if tau < min(tau_min, float(low)):
            raise ValueError(f"incl_lowpass must be at least 1.1 sample periods (1.1 / fs = "
                             f"{low} s at fs={fs:g} Hz), got {tau!r}")
        if tau > max(tau_max, float(high)):
            raise ValueError(f"incl_lowpass must be at most {high} s at fs={fs:g} Hz (its cutoff "
                             f"at least {C_CUTOFF_MIN:g} fs: below it the Butterworth's rounding moves "
                             f"its poles), got {tau!r}")
        EKF._configure(self, fs, frame, on_invalid, params)
        # after the base's checks, so that a refused re-__init__ leaves it as it was
        self.incl_lowpass = tau
        self.coef_dt = 0.0          # no coefficients yet (a step is > 0)

    cdef list _state_fields(self):
        return EKF._state_fields(self) + struct_fields(<InclLowpass[:1]>&self.il, {"t": TIMER}, "incl_")

    cdef void _reset_state(self) noexcept nogil:
        EKF._reset_state(self)
        memset(&self.il, 0, sizeof(InclLowpass))

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        EKF._step(self, gyr, acc, mag, dt)
        incl_step(self, gyr, acc, dt)

    cdef void _output_q(self, double* out) noexcept nogil:
        """During the low-pass's start the reported inclination moves from the `ekf`'s to the
        running mean's in proportion to the part of incl_lowpass the mean spans: a mean of a
        few samples is not yet the low-pass's average (VQF reports it from the first sample,
        which assumes a sensor at rest)."""
        cdef double q[4]
        if self.il.started:
            incl_output(self.q, self.il.y, self.il.t / self.incl_lowpass, q)
            quat_out(q, self.ned, out)
        else:
            quat_out(self.q, self.ned, out)
