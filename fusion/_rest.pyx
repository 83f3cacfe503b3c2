# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Rest detection, the component (fusion/_rest.pxd; docs/estimators.md, "Rest"): a filter that
learns the gyro bias at rest declares `fusion.params.REST` in its PARAMS and holds a
RestDetector (docs/contributing.md); the rest properties below then read it."""
from operator import attrgetter

from fusion._core import FLAG, COUNT, TIMER


cdef class RestDetector:
    """The thresholds and state of the rest detector a filter holds as `est.rest`: time,
    gyro_tol, acc_tol, gyro_drift_tol, acc_drift_tol, and noise (a Kalman filter's zero-rate
    update) or tau (the bias pull of mahony and madgwick): the rest_* parameters; at_rest,
    samples."""

    def __init__(self, p):
        """p: the holder's checked parameters (Estimator._take_params), REST's among them."""
        self.time, self.gyro_tol = p["rest_time"], p["rest_gyro_tol"]
        self.acc_tol = p["rest_acc_tol"]
        self.gyro_drift_tol, self.acc_drift_tol = p["rest_gyro_drift_tol"], p["rest_acc_drift_tol"]
        # what the holder does at rest: REST's zero-rate update (rest_noise) or REST_PULL's
        # pull of the bias (rest_tau); the one it does not declare is 0
        self.noise, self.tau = p.get("rest_noise", 0.0), p.get("rest_tau", 0.0)
        self.gate, self.gate_time = p.get("rest_bias_gate", 0.0), p.get("rest_gate_time", 0.0)
        rest_clear(self)

    cdef list fields(self):
        return [("rest_gyr", <double[:3]>self.gyr, None), ("rest_acc", <double[:3]>self.acc, None),
                ("rest_gyr0", <double[:3]>self.gyr0, None), ("rest_acc0", <double[:3]>self.acc0, None),
                ("rest_fgyr", <double[:3]>self.fgyr, None), ("rest_facc", <double[:3]>self.facc, None),
                ("rest_gsum", <double[:3]>self.gsum, None), ("rest_gsum_t", <double[:1]>&self.gsum_t, TIMER),
                ("rest_taken", <int[:1]><int*>&self.taken, FLAG),
                ("t_rest", <double[:1]>&self.t, TIMER),
                ("rest_lp_time", <double[:1]>&self.lp_time, TIMER),
                ("rest_started", <int[:1]><int*>&self.started, FLAG),
                ("rest_samples", <long long[:1]>&self.n, COUNT)]

    @property
    def at_rest(self):
        """True while the detector holds (the last sample was at rest: a zero-rate update, unless
        a Kalman filter's rest_bias_gate held it)."""
        return self.time > 0.0 and lasted(self.t, self.time)

    @property
    def samples(self):
        """Samples detected at rest since the last reset (a Kalman filter's zero-rate updates, and
        the ones its rest_bias_gate held)."""
        return self.n


def _of_rest(attr, doc):
    return property(attrgetter("rest." + attr), doc=doc)


#: The holder's rest properties, read from its `rest`: in its class body,
#: ``rest_time, rest_gyro_tol, rest_acc_tol, rest_gyro_drift_tol, rest_acc_drift_tol, rest_noise,
#: at_rest, rest_samples = REST_PROPERTIES``
REST_PROPERTIES = (
    _of_rest("time", "s of rest before the gyro measures its bias; 0: rest detection off. "
             "rest_gyro_tol, rest_acc_tol, rest_gyro_drift_tol, rest_acc_drift_tol, rest_noise: "
             "docs/estimators.md, \"Rest\"."),
    _of_rest("gyro_tol", "rad/s: at rest the gyro is within this of its low-pass, the low-pass "
             "within this of zero."),
    _of_rest("acc_tol", "m/s^2: at rest the accelerometer is within this of its low-pass."),
    _of_rest("gyro_drift_tol", "rad/s: a still run ends when the gyro's low-pass moves this far "
             "from its value at the run's start; 0: never."),
    _of_rest("acc_drift_tol", "m/s^2: a still run ends when the accelerometer's low-pass moves "
             "this far from its value at the run's start; 0: never."),
    _of_rest("noise", "rad/s/sqrt(Hz): the zero-rate measurement's noise density."),
    _of_rest("at_rest", "True while the rest detector holds (the last sample was at rest: a zero-rate "
             "update, unless rest_bias_gate held it)."),
    _of_rest("samples", "Samples detected at rest since the last reset (the zero-rate updates, and the "
             "ones rest_bias_gate held)."))

#: rest_bias_gate and rest_gate_time, the zero-rate update's gate, of the holders that declare
#: REST (the Kalman filters: rest_gate_open)
REST_GATE_PROPERTIES = (
    _of_rest("gate", "bias standard deviations: the zero-rate update waits while the gyro's "
             "low-pass is further than this (plus rest_gyro_drift_tol) from the bias estimate; 0: off."),
    _of_rest("gate_time", "s: a still run this long updates the bias whatever the gate says."))

#: rest_tau, the bias pull's time constant, of the holders that declare REST_PULL (mahony, madgwick)
REST_TAU_PROPERTY = _of_rest("tau", "s: at rest the gyro bias is pulled toward the measured rate with "
                             "this time constant.")
