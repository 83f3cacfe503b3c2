# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The base of the Kalman filters (fusion/_kalman.pxd): the noise parameters (one struct) the
`ekf` family and the `ukf` both have, and the rest detector's zero-rate noise, on the parts of
fusion._aided.AidedFilter."""
from fusion._aided cimport AidedFilter
from fusion._core import BIAS, COV, TIMER
from fusion._rest import REST_PROPERTIES, REST_GATE_PROPERTIES

NOISE = ("gyro_noise", "bias_noise", "acc_noise", "mag_noise", "q_init_std", "bias_init_std",
         "motion_rate")

# struct_fields' checks of their state structs (the ekf's EKFState, the ukf's UKFState)
STATE_CHECKS = {"b": BIAS, "P": COV, "t_unmeasured": TIMER}


def _of_kalman(name):
    return property(lambda e: e.kalman[name], doc=f"The {name} parameter (PARAMS[{name!r}]).")


NOISE_PROPERTIES = tuple(_of_kalman(n) for n in NOISE)


cdef class KalmanFilter(AidedFilter):
    """Base of the Kalman filters: a subclass declares the parameters (NOISE's, fusion.params
    REST, MAGDIST, MAG_UPDATE, ACC_LOWPASS where it has it) and ends its _configure with
    configure(p) (the noise struct, then AidedFilter's parts)."""
    gyro_noise, bias_noise, acc_noise, mag_noise, q_init_std, bias_init_std, motion_rate = NOISE_PROPERTIES
    rest_noise = REST_PROPERTIES[5]     # the zero-rate update's noise (its rest detector's)
    rest_bias_gate, rest_gate_time = REST_GATE_PROPERTIES   # and its gate

    cdef int configure(self, dict p) except -1:
        self.kalman = p     # before the reset, which reads the initial stds
        return AidedFilter.configure(self, p)
