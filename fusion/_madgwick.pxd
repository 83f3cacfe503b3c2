from fusion._core cimport Estimator
from fusion._magdist cimport MagDetector
from fusion._acclp cimport AccLowpass
from fusion._rest cimport RestDetector

# its state besides the attitude, one struct (as the ekf's EKFState; fusion._core.struct_fields)
cdef struct MadgwickState:
    double bw[3]        # gyro bias learned with the zeta gain, rad/s
    double t_recover    # s of raised gain left after a saturated gyro (recovery_gain)

cdef class Madgwick(Estimator):
    cdef readonly double beta, zeta
    cdef MadgwickState s
    cdef readonly MagDetector magd    # magnetic disturbance detection (fusion/_magdist.pxd), time 0: off
    cdef bint mag_heading     # mag_update="heading": the field's gradient turns the heading only
    cdef readonly double acc_lowpass   # s, 0: off (fusion/_acclp.pxd)
    cdef AccLowpass acc_lp
    cdef readonly RestDetector rest   # rest detection (fusion/_rest.pxd), time 0: off
    cdef readonly double rest_tau      # s: the bias's time constant at rest
