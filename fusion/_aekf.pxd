from fusion._ekf cimport EKF

# its state besides the ekf's, one struct (as EKFState; fusion._core.struct_fields)
cdef struct AEKFState:
    double t_dir            # s the direction test has failed alone
    long long n_learned     # samples the magnetic reference has been learned from
    double norm_sum, dip_sum        # their sums (norm; dip, rad)
    double norm_ref, dip_ref        # the reference: field norm, dip (rad)
    double ref_field[3]     # unit reference field, ENU: [0, cos dip, -sin dip]
    bint have_ref           # the reference is known (given, or learned from one sample at least)
    # the switching record
    long long n_acc_tested, n_acc_rej, n_mag_tested, n_mag_rej, n_quest
    int last_code           # the last sample's decision (bits, as est.decisions)
    double g_ref            # m/s^2: g for the tests (9.81, then learned at rest)

cdef class AEKF(EKF):
    # thresholds (e_a1, e_a2 in m/s^2; e_m1 relative; e_m2 in degrees) and the rejection factor
    cdef readonly double acc_norm_tol, acc_pred_tol, mag_norm_tol, mag_dip_tol
    cdef readonly double acc_pred_timeout   # s: a longer disagreement is the estimate's fault
    cdef readonly double reject_factor, learn_time, quest_mag_weight
    cdef double dip_tol_rad
    cdef bint use_quest              # measurement == "quest"
    # magnetic reference: given (mag_norm / mag_dip) or learned from the first samples
    cdef readonly object mag_norm, mag_dip     # the parameters (None: learned)
    cdef bint learn_norm, learn_dip
    cdef double norm_given, dip_given   # mag_norm, mag_dip (degrees) when given
    cdef long long n_learn              # samples to learn it from
    cdef AEKFState ad
    cdef bint logging
    cdef unsigned char* log
    cdef Py_ssize_t log_n, log_cap

