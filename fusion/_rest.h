/* The rest detector's two time constants (fusion/_rest.pxd rest_detect), declared once for the
 * scalar kernel and the ekf bank's four-lane step (fusion/_ekfbank.h). */
#ifndef FUSION_REST_H
#define FUSION_REST_H
/* s: the low-passes of the rate and the specific force (VQF's restFilterTau) */
#define FUSION_REST_TAU 0.5
/* s: the still tests' low-pass; at 100 Hz and below they judge the raw samples */
#define FUSION_REST_STILL_TAU 0.01
#endif
