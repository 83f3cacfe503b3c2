# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The base of the filters the accelerometer and magnetometer correct (fusion/_aided.pxd): the
rest and magnetic disturbance detectors and the accelerometer low-pass, held once for the
Kalman filters, mahony and madgwick, with their state fields, reset and properties."""
from fusion._core cimport Estimator
from fusion._core import struct_fields, ACC_LP_CHECKS
from fusion._rest import REST_PROPERTIES
from fusion._magdist import MAGDIST_PROPERTIES
from fusion._rest cimport rest_clear
from fusion._magdist cimport magd_clear
from fusion._acclp cimport acc_lowpass_clear


cdef class AidedFilter(Estimator):
    """Base of the filters that hold a rest detector (`est.rest`), a magnetic disturbance
    detector (`est.magd`) and an accelerometer low-pass (`acc_lowpass`): a subclass declares
    their parameters (fusion.params REST or REST_PULL, MAGDIST, MAG_UPDATE, ACC_LOWPASS where
    it has it), ends its _configure with configure(p), and extends _state_fields /
    _reset_state, which hold the parts', from this class's (docs/contributing.md)."""
    # the rest and disturbance parameters and counts, read from the detectors (fusion._rest,
    # fusion._magdist); rest_noise (REST_PROPERTIES[5]) only where there is a zero-rate
    # update (fusion._kalman)
    rest_time, rest_gyro_tol, rest_acc_tol, rest_gyro_drift_tol, rest_acc_drift_tol = REST_PROPERTIES[:5]
    at_rest, rest_samples = REST_PROPERTIES[6:]
    magdist_time, magdist_norm_tol, magdist_dip_tol, magdist_new_time, mag_rejected = MAGDIST_PROPERTIES

    cdef int configure(self, dict p) except -1:
        self.rest = RestDetector(p)
        self.magd = MagDetector(p)
        self.acc_lowpass = p["acc_lowpass"]
        self.mag_heading = p["mag_update"] == "heading"
        self.configured = True
        self._reset(None)
        return 0

    cdef list _state_fields(self):
        return (Estimator._state_fields(self)
                + struct_fields(<AccLowpass[:1]>&self.acc_lp, ACC_LP_CHECKS, "acc_")
                + self.rest.fields() + self.magd.fields())

    cdef void _reset_state(self) noexcept nogil:
        rest_clear(self.rest)
        magd_clear(self.magd)
        acc_lowpass_clear(&self.acc_lp)

    @property
    def mag_update(self):
        """"heading" (the magnetometer corrects the heading only) or "vector" (the filter's
        whole vector update)."""
        return "heading" if self.mag_heading else "vector"
