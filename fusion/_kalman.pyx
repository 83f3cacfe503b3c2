# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The base of the Kalman filters (fusion/_kalman.pxd): the noise parameters (one struct) and
the parts both the `ekf` family and the `ukf` hold, the rest and magnetic disturbance
detectors and the accelerometer low-pass, with their properties and state fields."""
from fusion._core import struct_fields, ACC_LP_CHECKS, BIAS, COV, TIMER
from fusion._rest import REST_PROPERTIES
from fusion._magdist import MAGDIST_PROPERTIES
from fusion._rest cimport rest_clear
from fusion._magdist cimport magd_clear
from fusion._acclp cimport acc_lowpass_clear

NOISE = ("gyro_noise", "bias_noise", "acc_noise", "mag_noise", "q_init_std", "bias_init_std",
         "motion_rate")

# struct_fields' checks of their state structs (the ekf's EKFState, the ukf's UKFState)
STATE_CHECKS = {"b": BIAS, "P": COV, "t_unmeasured": TIMER}


def _of_kalman(name):
    return property(lambda e: e.kalman[name], doc=f"The {name} parameter (PARAMS[{name!r}]).")



NOISE_PROPERTIES = tuple(_of_kalman(n) for n in NOISE)


cdef class KalmanFilter(Estimator):
    """Base of the Kalman filters: a subclass declares the parameters (fusion.params REST,
    MAGDIST, ACC_LOWPASS where it has it, and NOISE's), calls hold_parts(p) in its __init__,
    clear_parts() in _reset_state and adds parts_fields() to its _state_fields."""
    # the rest and disturbance parameters and counts, read from the detectors (fusion._rest,
    # fusion._magdist); the noise parameters, from the kalman struct
    rest_time, rest_gyro_tol, rest_acc_tol, rest_noise, at_rest, rest_samples = REST_PROPERTIES
    magdist_time, magdist_norm_tol, magdist_dip_tol, magdist_new_time, mag_rejected = MAGDIST_PROPERTIES
    gyro_noise, bias_noise, acc_noise, mag_noise, q_init_std, bias_init_std, motion_rate = NOISE_PROPERTIES

    cdef int hold_parts(self, dict p) except -1:
        self.kalman = p
        self.rest = RestDetector(p)
        self.magd = MagDetector(p)
        self.acc_lowpass = p.get("acc_lowpass", 0.0)    # aekf declares none
        return 0

    cdef list parts_fields(self):
        return (struct_fields(<AccLowpass[:1]>&self.acc_lp, ACC_LP_CHECKS, "acc_")
                + self.rest.fields() + self.magd.fields())

    cdef void clear_parts(self) noexcept nogil:
        rest_clear(self.rest)
        magd_clear(self.magd)
        acc_lowpass_clear(&self.acc_lp)
