# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""`triad`: the attitude from each sample's accelerometer and magnetometer alone, no gyro
(docs/estimators.md, "triad"). The floor on the other side from `gyro`: no drift, all the
accelerometer's and magnetometer's noise and disturbance."""
from fusion._core cimport Estimator
from fusion._prefilter cimport Butterworth
from fusion._qmath cimport quat_from_acc_mag
from fusion.params import Param, table


cdef class Triad(Estimator):
    """TRIAD from each sample (Black 1964), the accelerometer the primary vector: up from the
    accelerometer, north from the magnetometer's component across it; without a magnetometer
    the heading is 0. The gyro is not used. With cutoff_hz the accelerometer and magnetometer
    pass a second-order Butterworth low-pass first."""
    name = "triad"
    PARAMS = table(
        Param("cutoff_hz", None, "Hz", 0.0, None, "cutoff of the Butterworth low-pass in front of "
              "the accelerometer and magnetometer, from 1e-7 fs to below fs / 2; None: raw samples", open_low=True))

    def _configure(self, fs, frame, on_invalid, params):
        fs = self._check_init(fs, frame, on_invalid)       # before the prefilters are replaced
        p = self._take_params(params)
        pre_acc = None if p["cutoff_hz"] is None else Butterworth(fs, p["cutoff_hz"])
        pre_mag = None if p["cutoff_hz"] is None else Butterworth(fs, p["cutoff_hz"])
        self._take_prefilters(None, pre_acc, pre_mag)
        self._take_base(fs, frame, on_invalid, p)
        self.configured = True
        self._reset(None)

    cdef void _step(self, const double* gyr, const double* acc, const double* mag,
                    double dt) noexcept nogil:
        if acc != NULL:     # an invalid accelerometer sample: the last attitude is held
            quat_from_acc_mag(acc, mag, self.q)

    @property
    def cutoff_hz(self):
        return None if self.pre_acc is None else self.pre_acc.cutoff_hz
