from fusion._aided cimport AidedFilter

# its state besides the attitude, one struct (as the ekf's EKFState; fusion._core.struct_fields)
cdef struct MadgwickState:
    double bw[3]        # gyro bias learned with the zeta gain, rad/s
    double t_recover    # s of raised gain left after a saturated gyro (recovery_gain)

cdef class Madgwick(AidedFilter):
    cdef readonly double beta, zeta
    cdef MadgwickState s
