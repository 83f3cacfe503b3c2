# The base of the filters that correct the gyro's attitude with the accelerometer and the
# magnetometer (the Kalman filters of fusion/_kalman.pxd, mahony, madgwick): the three parts
# they all hold, built from the checked parameters (hold_parts), with their state fields
# (_state_fields), their reset (_reset_state) and their properties, the mag_update choice they
# all have, and the one call of each part a step makes (below). cf-ekf is none of them: it
# holds an EKF core and a mahony.
from fusion._core cimport Estimator
from fusion._rest cimport RestDetector, rest_detect
from fusion._magdist cimport MagDetector, magd_check
from fusion._acclp cimport AccLowpass, acc_lowpassed

cdef class AidedFilter(Estimator):
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly MagDetector magd    # magnetic disturbance detection (fusion/_magdist.pxd), time 0: off
    cdef readonly double acc_lowpass  # s, 0: off (fusion/_acclp.pxd)
    cdef AccLowpass acc_lp
    cdef bint mag_heading             # mag_update="heading": the magnetometer turns the heading only
    # the last line of a subclass's _configure: the parts from the checked parameters
    # (Estimator._take_params), then the object configured and reset
    cdef int configure(self, dict p) except -1


# --- the parts in a step, on the filter's own parts ---------------------------------------

cdef inline bint rest_now(AidedFilter e, const double* gyr, const double* acc,
                          double dt) noexcept nogil:
    """rest_detect on e's detector: True when e makes its zero-rate update this sample."""
    return rest_detect(e.rest, gyr, acc, dt)

cdef inline bint mag_accepted(AidedFilter e, const double* q, const double* mag, const double* gyr,
                              double dt) noexcept nogil:
    """A magnetometer sample (mag not NULL) that e's disturbance detector accepts."""
    return mag != NULL and magd_check(e.magd, q, mag, gyr, dt)

cdef inline const double* acc_input(AidedFilter e, const double* gyr, bint sat, const double* b,
                                    const double* acc, double dt, double* out) noexcept nogil:
    """acc_lowpassed on e's low-pass: the accelerometer sample e corrects with (b: its bias
    estimate; sat: the gyro sample is saturated)."""
    return acc_lowpassed(e.acc_lowpass, &e.acc_lp, gyr, sat, b, acc, dt, e.dt_nominal, out)
