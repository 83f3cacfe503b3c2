from fusion._aided cimport AidedFilter

cdef void mahony_error(const double* q, const double* acc, const double* mag,
                       double* e) noexcept nogil

# its state besides the attitude, one struct (as the ekf's EKFState; fusion._core.struct_fields)
cdef struct MahonyState:
    double eint[3]      # integral of the correction error
    double t_recover    # s of raised gain left after a saturated gyro (recovery_gain)

cdef class Mahony(AidedFilter):
    cdef readonly double kp, ki, mag_weight
    cdef MahonyState s
    cdef void step_flagged(self, const double* gyr, const double* acc, const double* mag,
                           double dt, bint sat) noexcept nogil
