/* Durations summed from sample steps (fusion/_constants.pxd binds these for the kernels; the
 * ekf bank's four-lane step, fusion/_ekfbank.h, includes this file). */
#ifndef FUSION_STEPS_H
#define FUSION_STEPS_H
/* relative: a duration summed from sample steps has lasted T once the sum reaches
 * T (1 - this). Steps from time stamps that equal 1/fs to 1e-15 summed one sample short of
 * the nominal steps' sum; at the rest detector's knife edge (a still start of exactly
 * rest_time) that lost the first zero-rate update and doubled a recorded trial's error.
 * Every duration summed from steps that decides something uses it: the rest detector's,
 * the accelerometer low-pass's and ekf-lp's starts, the magnetic disturbance detector's
 * times, aekf's acc_pred_timeout, cf-ekf's quiet time, the complementary filters' recovery. */
#define FUSION_STEP_SUM_TOL 1e-9
/* t has lasted d (reached it), t has outlasted d (gone beyond it), within that rounding */
#define FUSION_LASTED(t, d) ((t) >= (d) * (1.0 - FUSION_STEP_SUM_TOL))
#define FUSION_OUTLASTED(t, d) ((t) > (d) * (1.0 + FUSION_STEP_SUM_TOL))
#endif
