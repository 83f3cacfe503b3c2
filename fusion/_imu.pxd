# The IMU model's streaming step in C (fusion/_imu.pyx); cimported by the environment's
# per-physics-step kernel (envs/_signals.pyx).
cdef class StepKernel:
    cdef public bint live               # loaded from the Python IMU, which is then stale
    # constants
    cdef double fs, jitter_s, lim, prate, lpf_g, lpf_acc, mag_scale
    cdef bint hold, has_prate, has_magspec, mag_ident, mclip, has_mrate, vib
    cdef double R[30]
    cdef double C[30]
    cdef double M[2][9]
    cdef bint ident[2]
    cdef double b0[6]
    cdef double qlsb[6]
    cdef double qlo[6]
    cdef double qhi[6]
    cdef bint qact[6]
    cdef double magS[9]
    cdef double magh[3]
    cdef double mnoise, mlsb, mlo, mhi, mrate
    cdef double[:, ::1] vib_w, vib_phi, vib_buf
    cdef double vib_amp[6]
    # state
    cdef object gen
    cdef double[:, ::1] buf
    cdef Py_ssize_t pos
    cdef long long k, steps, cnt
    cdef double S[30]
    cdef double T_next, T_prev, origin, tau_last, lpf_dt, slot_last
    cdef bint has_T_prev, has_origin, has_mag_held, has_lpf_dt, has_slot
    cdef int mag_on                     # -1: not yet known
    cdef double y_last[9]
    cdef double y_prev[9]
    cdef double x[9]
    cdef double sum_[9]
    cdef double lpf_a[9]
    cdef double lpf_b[9]
    cdef double mag_held[3]
    # the last sample (step_c returned 1)
    cdef double out_g[3]
    cdef double out_a[3]
    cdef double out_m[3]
    cdef bint out_has_mag
    cdef double out_t, out_dt
    cdef long long out_index

    cdef int _refill(self) except -1
    cdef void _vibrate(self, double tau) noexcept
    cdef int step_c(self, const double* g, const double* a, const double* m, double dt, bint has_dt) except -1
    cdef object sample(self, sample_type)
