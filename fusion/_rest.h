/* The rest detector's two time constants (fusion/_rest.pxd rest_detect), declared once for the
 * scalar kernel and the ekf bank's four-lane step (fusion/_ekfbank.h), and the rounding a
 * duration summed from sample steps is allowed. */
#ifndef FUSION_REST_H
#define FUSION_REST_H
/* s: the low-passes of the rate and the specific force (VQF's restFilterTau) */
#define FUSION_REST_TAU 0.5
/* s: the still tests' low-pass; at 100 Hz and below they judge the raw samples */
#define FUSION_REST_STILL_TAU 0.01
/* relative: a duration summed from sample steps has lasted T once the sum reaches
 * T (1 - this). Steps from time stamps that equal 1/fs to 1e-15 summed one sample short of
 * the nominal steps' sum; at the rest detector's knife edge (a still start of exactly
 * rest_time) that lost the first zero-rate update and doubled a recorded trial's error.
 * Every duration summed from steps that decides something uses it: the rest detector's,
 * the accelerometer low-pass's and ekf-lp's starts, the magnetic disturbance detector's
 * times, aekf's acc_pred_timeout. */
#define FUSION_STEP_SUM_TOL 1e-9
/* t has lasted d (reached it), t has outlasted d (gone beyond it), within that rounding */
#define FUSION_LASTED(t, d) ((t) >= (d) * (1.0 - FUSION_STEP_SUM_TOL))
#define FUSION_OUTLASTED(t, d) ((t) > (d) * (1.0 + FUSION_STEP_SUM_TOL))
#endif
