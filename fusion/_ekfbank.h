/* A bank of `ekf` filters stepped four at a time (fusion/_bank.pyx): the structure-of-arrays
 * path of fusion.make_bank("ekf", ...).
 *
 * The state of all filters is field-major: field f of lane (filter) l is d[f * cap + l], cap a
 * multiple of 4. One step of four lanes loads each field as one four-lane vector, so every
 * operation of the ekf's step (fusion/_ekf.pyx ekf_step, fusion/_ekfcov.h) runs on four
 * filters at once: the same arithmetic, in the same order, as the scalar kernel, with one
 * filter per lane instead of one row of P per vector. The scalar kernel waits on its chain of
 * dependent multiply-adds from one sample's P to the next; here four independent chains fill
 * the pipeline, and the loads and stores are whole vectors.
 *
 * Only the usual sample runs here (ekfb_fast): initialised, every vector valid, the gyro
 * within its range, no time gap, the detectors and the low-pass started, and not the sample
 * that ends the low-pass's running-mean start (its tilt variance: ekf_start_ended). The caller steps any
 * other lane through its estimator object (the scalar kernel itself) and copies its state back.
 * Branches become masks: the zero-rate update at rest runs when a lane of the block is at rest
 * and is kept in those lanes only; the magnetometer update likewise where the disturbance
 * detector accepts the sample. The rare large rotation (the half-angle's series does not hold)
 * gets its cos / sin lane by lane, and the disturbance detector's state machine (with its
 * asin) runs lane by lane.
 *
 * Supported: acc_update="vector", mag_update="heading" (the defaults), every numeric parameter
 * per filter. GCC and Clang (vector extensions) with AVX (256-bit registers: make's native
 * build) only: without AVX (the portable build's SSE2) the four-lane vectors run as pairs and
 * the bank's run measured 0.87x of separate ekf.run calls, so there EKFB_AVAILABLE is 0 and the
 * bank keeps its array of estimator objects. */
#ifndef FUSION_EKFBANK_H
#define FUSION_EKFBANK_H
#include <math.h>
#include <string.h>
#include <float.h>
#include "_rest.h"
#include "_steps.h"

/* the fields, each an array of cap doubles (flags 0 / 1, counters exact below 2^53) */
enum {
    /* state */
    EB_Q = 0, EB_B = 4, EB_P = 7,            /* q[4], b[3], P's upper half by rows (28) */
    EB_TUN = 35,                              /* t_unmeasured */
    EB_RG = 36, EB_RA = 39, EB_RT = 42, EB_RN = 43, EB_RS = 44,     /* rest: gyr[3], acc[3], t, n, started */
    EB_MCUR = 45, EB_MREF = 47, EB_MCAND = 49, EB_MTU = 51, EB_MTC = 52, EB_MTR = 53,
    EB_MDIST = 54, EB_MREJ = 55, EB_MSET = 56, EB_MDIRC = 57, EB_MDIRS = 60, EB_MTF = 63,
    /* (magnetic disturbance) */
    EB_LP = 64, EB_LPS = 67, EB_LPT = 68,               /* acc low-pass */
    EB_INIT = 69,
    /* parameters */
    EB_GN = 70, EB_BN = 71, EB_AN = 72, EB_MN = 73, EB_GR = 74,
    EB_RTIME = 75, EB_RGTOL = 76, EB_RATOL = 77, EB_RNOISE = 78,
    EB_MTIME = 79, EB_MNTOL = 80, EB_MDTOL = 81, EB_MNEW = 82, EB_TAU = 83,
    /* the sample, transposed (ekfb_fast) */
    EB_IG = 84, EB_IA = 87, EB_IM = 90, EB_IDT = 93, EB_FAST = 94,
    /* rest's drift tests and running-mean start: gyr0[3], acc0[3], lp_time; the parameters */
    EB_RG0 = 95, EB_RA0 = 98, EB_RLPT = 101, EB_RGDTOL = 102, EB_RADTOL = 103,
    EB_RFG = 104, EB_RFA = 107,                 /* the still tests' samples: fgyr[3], facc[3] */
    EB_RGATE = 110, EB_RGATET = 111,            /* the zero-rate update's gate (rest_gate_open) */
    EB_RGS = 112, EB_RGST = 115,                /* the still run's gyro sum gsum[3], its time gsum_t */
    EB_RTAKEN = 116,                            /* an update has taken the sum (rest_rate) */
    EB_NFIELDS = 117
};

/* P[i, j]'s index in the upper half (i, j < 7) */
static inline int ekb_ix(int i, int j) {
    if (i > j) { int t = i; i = j; j = t; }
    return i * (13 - i) / 2 + j;
}

#if (defined(__GNUC__) || defined(__clang__)) && defined(__AVX__)
#define EKFB_AVAILABLE 1

typedef double ekb_v __attribute__((vector_size(32)));
typedef long long ekb_m __attribute__((vector_size(32)));

static inline ekb_v ekb_bc(double x) { ekb_v v = {x, x, x, x}; return v; }
static inline ekb_v ekb_ld(const double* p) { ekb_v v; memcpy(&v, p, sizeof v); return v; }
static inline void ekb_st(double* p, ekb_v v) { memcpy(p, &v, sizeof v); }
static inline ekb_v ekb_sel(ekb_m m, ekb_v a, ekb_v b) {
    return (ekb_v)(((ekb_m)a & m) | ((ekb_m)b & ~m));
}
static inline int ekb_any(ekb_m m) { return (m[0] | m[1] | m[2] | m[3]) != 0; }
/* an update's result (p2, q2, b2) kept in the lanes of m, the state before it elsewhere */
static inline void ekb_keep(ekb_m m, ekb_v* p, ekb_v* q, ekb_v* b, const ekb_v* p2,
                            const ekb_v* q2, const ekb_v* b2) {
    int i;
    for (i = 0; i < 49; i++)
        p[i] = ekb_sel(m, p2[i], p[i]);
    for (i = 0; i < 4; i++)
        q[i] = ekb_sel(m, q2[i], q[i]);
    for (i = 0; i < 3; i++)
        b[i] = ekb_sel(m, b2[i], b[i]);
}
static inline ekb_v ekb_sqrt(ekb_v v) {
    ekb_v r; int i;
    for (i = 0; i < 4; i++) r[i] = sqrt(v[i]);
    return r;
}
static inline ekb_v ekb_abs(ekb_v v) { return ekb_sel(v > 0.0, v, -v); }

#define EKB_F(f) (d + (size_t)(f) * cap + l)
#define EKB_LD(f) ekb_ld(EKB_F(f))
#define EKB_ST(f, v) ekb_st(EKB_F(f), v)

/* quat_normalise (fusion/_qmath.pxd): its series near unit norm, 1 / sqrt elsewhere */
static inline void ekb_normalise(ekb_v* q) {
    ekb_v n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    ekb_v dd = n2 - 1.0;
    ekb_m near = (-1e-6 < dd) & (dd < 1e-6);
    ekb_v f = ekb_sel(near, 1.0 - dd * (0.5 - 0.375 * dd), 1.0 / ekb_sqrt(n2));
    q[0] *= f; q[1] *= f; q[2] *= f; q[3] *= f;
}

/* phi_matrix (fusion/_qmath.pxd, half_angle_terms): A (16, row-major) for the rate w */
static inline void ekb_phi(ekb_v wx, ekb_v wy, ekb_v wz, ekb_v dt, ekb_v* A) {
    ekb_v n2 = wx * wx + wy * wy + wz * wz;
    ekb_v h2 = n2 * (0.25 * dt * dt);
    ekb_v h4 = h2 * h2;
    ekb_v c = (1.0 - 0.5 * h2) + h4 * ((1.0 / 24.0 - h2 * (1.0 / 720.0)) + h4 * (1.0 / 40320.0));
    ekb_v s = (0.5 * dt) * ((1.0 - h2 * (1.0 / 6.0))
                            + h4 * ((1.0 / 120.0 - h2 * (1.0 / 5040.0)) + h4 * (1.0 / 362880.0)));
    ekb_m big = h2 >= 0.0025;
    if (ekb_any(big)) {     /* theta/2 >= 0.05: the series does not hold, lane by lane */
        int i;
        for (i = 0; i < 4; i++)
            if (big[i]) {
                double n = sqrt(n2[i]);
                c[i] = cos(0.5 * n * dt[i]);
                s[i] = sin(0.5 * n * dt[i]) / n;
            }
    }
    wx *= s; wy *= s; wz *= s;
    A[0] = c;   A[1] = -wx; A[2] = -wy;  A[3] = -wz;
    A[4] = wx;  A[5] = c;   A[6] = wz;   A[7] = -wy;
    A[8] = wy;  A[9] = -wz; A[10] = c;   A[11] = wx;
    A[12] = wz; A[13] = wy; A[14] = -wx; A[15] = c;
}

/* sym3_adjugate (fusion/_qmath.pxd) */
static inline ekb_v ekb_adj(const ekb_v* S, ekb_v* Sa) {
    ekb_v det;
    Sa[0] = S[4] * S[8] - S[5] * S[7];
    Sa[1] = S[2] * S[7] - S[1] * S[8];
    Sa[2] = S[1] * S[5] - S[2] * S[4];
    det = 1.0 / (S[0] * Sa[0] + S[3] * Sa[1] + S[6] * Sa[2]);
    Sa[3] = Sa[1];
    Sa[4] = S[0] * S[8] - S[2] * S[6];
    Sa[5] = S[2] * S[3] - S[0] * S[5];
    Sa[6] = Sa[2];
    Sa[7] = Sa[5];
    Sa[8] = S[0] * S[4] - S[1] * S[3];
    return det;
}

/* ekfc_predict (fusion/_ekfcov.h), P the full 7x7 (p[7 i + j]) */
static inline void ekb_predict(ekb_v* p, ekb_v* q, const ekb_v* A, ekb_v dt, ekb_v gq, ekb_v qb) {
    ekb_v w = q[0], x = q[1], y = q[2], z = q[3];
    ekb_v hl = -0.5 * dt;
    ekb_v Xc[3][4], R[4][4], m[4][4], N[3][4], np[3][4], Rn[4][4], qn[4];
    int i, j;
    Xc[0][0] = -x; Xc[0][1] = w;  Xc[0][2] = z;  Xc[0][3] = -y;
    Xc[1][0] = -y; Xc[1][1] = -z; Xc[1][2] = w;  Xc[1][3] = x;
    Xc[2][0] = -z; Xc[2][1] = y;  Xc[2][2] = -x; Xc[2][3] = w;
    for (j = 0; j < 4; j++) {
        R[0][j] = p[28 + j] * (-x) - p[35 + j] * y - p[42 + j] * z;
        R[1][j] = p[28 + j] * w - p[35 + j] * z + p[42 + j] * y;
        R[2][j] = p[28 + j] * z + p[35 + j] * w - p[42 + j] * x;
        R[3][j] = p[35 + j] * x + p[28 + j] * (-y) + p[42 + j] * w;
    }
    for (i = 0; i < 4; i++)
        for (j = 0; j < 4; j++) {
            ekb_v s = p[j] * A[4 * i] + p[7 + j] * A[4 * i + 1];
            ekb_v u = p[14 + j] * A[4 * i + 2] + p[21 + j] * A[4 * i + 3];
            m[i][j] = (s + u) + R[i][j] * hl;
        }
    for (i = 0; i < 3; i++)
        for (j = 0; j < 4; j++) {
            ekb_v s = A[4 * j] * p[4 + i] + A[4 * j + 1] * p[11 + i];
            ekb_v u = A[4 * j + 2] * p[18 + i] + A[4 * j + 3] * p[25 + i];
            ekb_v t = Xc[0][j] * p[32 + i] + Xc[1][j] * p[39 + i] + Xc[2][j] * p[46 + i];
            N[i][j] = (s + u) + t * hl;
            np[i][j] = N[i][j] * hl + Xc[i][j] * gq;
        }
    for (i = 0; i < 4; i++)
        for (j = i; j < 4; j++) {
            ekb_v s = A[4 * j] * m[i][0] + A[4 * j + 1] * m[i][1];
            ekb_v u = A[4 * j + 2] * m[i][2] + A[4 * j + 3] * m[i][3];
            ekb_v t = Xc[0][j] * np[0][i] + Xc[1][j] * np[1][i] + Xc[2][j] * np[2][i];
            Rn[i][j] = (s + u) + t;
        }
    for (i = 0; i < 4; i++)
        qn[i] = A[4 * i] * w + A[4 * i + 1] * x + A[4 * i + 2] * y + A[4 * i + 3] * z;
    for (i = 0; i < 4; i++)
        for (j = i; j < 4; j++)
            p[7 * i + j] = p[7 * j + i] = Rn[i][j];
    for (i = 0; i < 3; i++)
        for (j = 0; j < 4; j++)
            p[7 * j + 4 + i] = p[7 * (4 + i) + j] = N[i][j];
    p[32] = p[32] + qb;
    p[40] = p[40] + qb;
    p[48] = p[48] + qb;
    for (i = 0; i < 4; i++)
        q[i] = qn[i];
}

/* ekfc_pht: U[m][i] = (P Hᵀ)[i, m], S = H U + r I */
static inline void ekb_pht(const ekb_v* p, const ekb_v* H, ekb_v r, ekb_v U[3][7], ekb_v* S) {
    int m, i;
    for (m = 0; m < 3; m++)
        for (i = 0; i < 7; i++)
            U[m][i] = p[i] * H[4 * m] + p[7 + i] * H[4 * m + 1] + p[14 + i] * H[4 * m + 2]
                      + p[21 + i] * H[4 * m + 3];
#define EKB_S(m, j) (H[4 * (m)] * U[j][0] + H[4 * (m) + 1] * U[j][1] \
                     + H[4 * (m) + 2] * U[j][2] + H[4 * (m) + 3] * U[j][3])
    S[0] = EKB_S(0, 0) + r;
    S[1] = S[3] = EKB_S(0, 1);
    S[2] = S[6] = EKB_S(0, 2);
    S[4] = EKB_S(1, 1) + r;
    S[5] = S[7] = EKB_S(1, 2);
    S[8] = EKB_S(2, 2) + r;
#undef EKB_S
}

/* ekfc_optimal then quat_normalise */
static inline void ekb_optimal(ekb_v* p, ekb_v* q, ekb_v* b, ekb_v U[3][7], const ekb_v* Si,
                               ekb_v det, const ekb_v* y) {
    ekb_v K[7][3], R[7][7];
    int i, j, m;
    for (j = 0; j < 3; j++)
        for (i = 0; i < 7; i++)
            K[i][j] = (U[0][i] * Si[j] + U[1][i] * Si[3 + j] + U[2][i] * Si[6 + j]) * det;
    for (i = 0; i < 4; i++)
        q[i] = q[i] + (K[i][0] * y[0] + K[i][1] * y[1] + K[i][2] * y[2]);
    for (i = 0; i < 3; i++)
        b[i] = b[i] + (K[4 + i][0] * y[0] + K[4 + i][1] * y[1] + K[4 + i][2] * y[2]);
    for (i = 0; i < 4; i++)
        for (j = i; j < 4; j++)
            R[i][j] = p[7 * i + j] - U[0][j] * K[i][0] - U[1][j] * K[i][1] - U[2][j] * K[i][2];
    for (j = 0; j < 3; j++)
        for (i = 0; i < 4; i++)
            R[i][4 + j] = p[7 * (4 + j) + i] - K[i][0] * U[0][4 + j] - K[i][1] * U[1][4 + j]
                          - K[i][2] * U[2][4 + j];
    for (i = 0; i < 3; i++)
        for (j = i; j < 3; j++) {
            ekb_v s = p[7 * (4 + i) + 4 + j];
            for (m = 0; m < 3; m++)
                s = s - U[m][4 + j] * K[4 + i][m];
            R[4 + i][4 + j] = s;
        }
    for (i = 0; i < 7; i++)
        for (j = i; j < 7; j++)
            p[7 * i + j] = p[7 * j + i] = R[i][j];
    ekb_normalise(q);
}

static inline void ekb_up(const ekb_v* q, ekb_v* out) {
    ekb_v w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = 2.0 * (x*z - w*y);
    out[1] = 2.0 * (y*z + w*x);
    out[2] = w*w - x*x - y*y + z*z;
}

static inline void ekb_unit3(const ekb_v* v, ekb_v* out) {
    ekb_v n = 1.0 / ekb_sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    out[0] = v[0] * n;
    out[1] = v[1] * n;
    out[2] = v[2] * n;
}

/* ekf_acc_update with acc_update="vector" */
static inline void ekb_acc_update(ekb_v* p, ekb_v* q, ekb_v* b, const ekb_v* acc, ekb_v r) {
    ekb_v z[3], h[3], H[12], U[3][7], S[9], Si[9], y[3], det;
    ekb_v w = 2.0 * q[0], x = 2.0 * q[1], yy = 2.0 * q[2], zz = 2.0 * q[3];
    int i;
    ekb_unit3(acc, z);
    ekb_up(q, h);
    H[0] = -yy; H[1] = zz; H[2] = -w;  H[3] = x;
    H[4] = x;   H[5] = w;  H[6] = zz;  H[7] = yy;
    H[8] = w;   H[9] = -x; H[10] = -yy; H[11] = zz;
    ekb_pht(p, H, r, U, S);
    for (i = 0; i < 3; i++)
        y[i] = z[i] - h[i];
    det = ekb_adj(S, Si);
    ekb_optimal(p, q, b, U, Si, det, y);
}

/* ekfc_mag_model: h, H; ok false where rho < 1e-9 (no heading information) */
static inline ekb_m ekb_mag_model(const ekb_v* q, const ekb_v* zv, ekb_v* h, ekb_v* H) {
    ekb_v w = q[0], x = q[1], y = q[2], z = q[3];
    ekb_v a = zv[0], b = zv[1], c = zv[2];
    ekb_v r00 = w * w + x * x - y * y - z * z, r01 = 2.0 * (x * y - w * z), r02 = 2.0 * (x * z + w * y);
    ekb_v ry0 = 2.0 * (x * y + w * z), ry1 = w * w - x * x + y * y - z * z, ry2 = 2.0 * (y * z - w * x);
    ekb_v rz0 = 2.0 * (x * z - w * y), rz1 = 2.0 * (y * z + w * x), rz2 = w * w - x * x - y * y + z * z;
    ekb_v n0 = r00 * a + r01 * b + r02 * c;
    ekb_v n1 = ry0 * a + ry1 * b + ry2 * c;
    ekb_v n2 = rz0 * a + rz1 * b + rz2 * c;
    ekb_v rho = ekb_sqrt(n0 * n0 + n1 * n1);
    ekb_v pv[9][4] = {{w, x, -y, -z}, {-z, y, x, -w}, {y, z, w, x}, {z, y, x, w}, {w, -x, y, -z},
                      {-x, -w, z, y}, {-y, z, -w, x}, {x, w, z, y}, {w, -x, -y, z}};
    ekb_v J0[4], J1[4], J2[4], Dy[4], ux, uy;
    int t;
    for (t = 0; t < 4; t++) {
        J0[t] = pv[0][t] * (2.0 * a) + pv[1][t] * (2.0 * b) + pv[2][t] * (2.0 * c);
        J1[t] = pv[3][t] * (2.0 * a) + pv[4][t] * (2.0 * b) + pv[5][t] * (2.0 * c);
        J2[t] = pv[6][t] * (2.0 * a) + pv[7][t] * (2.0 * b) + pv[8][t] * (2.0 * c);
    }
    ux = n0 / rho;
    uy = n1 / rho;
    for (t = 0; t < 4; t++)
        Dy[t] = J0[t] * ux + J1[t] * uy;
    h[0] = ry0 * rho + rz0 * n2;
    h[1] = ry1 * rho + rz1 * n2;
    h[2] = ry2 * rho + rz2 * n2;
    for (t = 0; t < 4; t++) {
        H[t] = pv[3][t] * (2.0 * rho) + pv[6][t] * (2.0 * n2) + Dy[t] * ry0 + J2[t] * rz0;
        H[4 + t] = pv[4][t] * (2.0 * rho) + pv[7][t] * (2.0 * n2) + Dy[t] * ry1 + J2[t] * rz1;
        H[8 + t] = pv[5][t] * (2.0 * rho) + pv[8][t] * (2.0 * n2) + Dy[t] * ry2 + J2[t] * rz2;
    }
    return ~(rho < 1e-9);
}

/* ekf_mag_update with mag_update="heading" (heading_gain, ekfc_heading) */
static inline ekb_m ekb_mag_update(ekb_v* p, ekb_v* q, ekb_v* b, const ekb_v* mag, ekb_v r) {
    ekb_v z[3], h[3], H[12], U[3][7], S[9], Sa[9], y[3], det, u[4], w[3], av[3], cv[3], ka[3], kc[3];
    ekb_v dq, db, t[3], al, be, ga, gq[4], gb[3], hq[4], hb[3], R[7][7];
    ekb_m ok;
    int i, j;
    ekb_unit3(mag, z);
    ok = ekb_mag_model(q, z, h, H);
    ekb_pht(p, H, r, U, S);
    for (i = 0; i < 3; i++)
        y[i] = z[i] - h[i];
    det = ekb_adj(S, Sa);
    /* heading_gain */
    u[0] = -q[3]; u[1] = -q[2]; u[2] = q[1]; u[3] = q[0];
    ekb_up(q, w);
    for (j = 0; j < 3; j++) {
        av[j] = u[0] * U[j][0] + u[1] * U[j][1] + u[2] * U[j][2] + u[3] * U[j][3];
        cv[j] = w[0] * U[j][4] + w[1] * U[j][5] + w[2] * U[j][6];
    }
    for (j = 0; j < 3; j++) {
        ka[j] = (av[0] * Sa[j] + av[1] * Sa[3 + j] + av[2] * Sa[6 + j]) * det;
        kc[j] = (cv[0] * Sa[j] + cv[1] * Sa[3 + j] + cv[2] * Sa[6 + j]) * det;
    }
    dq = ka[0] * y[0] + ka[1] * y[1] + ka[2] * y[2];
    db = kc[0] * y[0] + kc[1] * y[1] + kc[2] * y[2];
    for (i = 0; i < 4; i++)
        q[i] = q[i] + u[i] * dq;
    for (i = 0; i < 3; i++)
        b[i] = b[i] + w[i] * db;
    ekb_normalise(q);
    /* ekfc_heading */
    for (i = 0; i < 4; i++) {
        gq[i] = U[0][i] * ka[0] + U[1][i] * ka[1] + U[2][i] * ka[2];
        hq[i] = U[0][i] * kc[0] + U[1][i] * kc[1] + U[2][i] * kc[2];
    }
    for (i = 0; i < 3; i++) {
        gb[i] = U[0][4 + i] * ka[0] + U[1][4 + i] * ka[1] + U[2][4 + i] * ka[2];
        hb[i] = U[0][4 + i] * kc[0] + U[1][4 + i] * kc[1] + U[2][4 + i] * kc[2];
    }
    for (i = 0; i < 3; i++)
        t[i] = S[3 * i] * ka[0] + S[3 * i + 1] * ka[1] + S[3 * i + 2] * ka[2];
    al = ka[0] * t[0] + ka[1] * t[1] + ka[2] * t[2];
    be = kc[0] * t[0] + kc[1] * t[1] + kc[2] * t[2];
    for (i = 0; i < 3; i++)
        t[i] = S[3 * i] * kc[0] + S[3 * i + 1] * kc[1] + S[3 * i + 2] * kc[2];
    ga = kc[0] * t[0] + kc[1] * t[1] + kc[2] * t[2];
    for (i = 0; i < 4; i++)
        gq[i] = gq[i] - u[i] * (0.5 * al);
    for (i = 0; i < 3; i++) {
        gb[i] = gb[i] - w[i] * be;
        hb[i] = hb[i] - w[i] * (0.5 * ga);
    }
    for (i = 0; i < 4; i++)
        for (j = i; j < 4; j++)
            R[i][j] = p[7 * i + j] - gq[j] * u[i] - u[j] * gq[i];
    for (j = 0; j < 3; j++)
        for (i = 0; i < 4; i++)
            R[i][4 + j] = p[7 * (4 + j) + i] - u[i] * gb[j] - hq[i] * w[j];
    for (i = 0; i < 3; i++)
        for (j = i; j < 3; j++)
            R[4 + i][4 + j] = p[7 * (4 + i) + 4 + j] - hb[j] * w[i] - w[j] * hb[i];
    for (i = 0; i < 7; i++)
        for (j = i; j < 7; j++)
            p[7 * i + j] = p[7 * j + i] = R[i][j];
    return ok;
}

/* ekf_rest's zero-rate update (kalman_apply with the bias-only gain): the gain's attitude
 * rows are zero, so q is only normalised and P's attitude block is unchanged */
static inline void ekb_rest_update(ekb_v* p, ekb_v* q, ekb_v* b, const ekb_v* g, ekb_v r) {
    ekb_v U[7][3], S[9], Si[9], y[3], K[7][3], V[7][3], det, R[7][7];
    int i, j;
    for (i = 0; i < 7; i++)
        for (j = 0; j < 3; j++)
            U[i][j] = p[7 * i + 4 + j];
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++)
            S[3 * i + j] = p[7 * (4 + i) + 4 + j];
        S[4 * i] = S[4 * i] + r;
        y[i] = g[i] - b[i];
    }
    det = ekb_adj(S, Si);
    for (i = 4; i < 7; i++)
        for (j = 0; j < 3; j++)
            K[i][j] = (U[i][0] * Si[j] + U[i][1] * Si[3 + j] + U[i][2] * Si[6 + j]) * det;
    for (i = 0; i < 3; i++)
        b[i] = b[i] + (K[4 + i][0] * y[0] + K[4 + i][1] * y[1] + K[4 + i][2] * y[2]);
    ekb_normalise(q);
    for (i = 4; i < 7; i++)
        for (j = 0; j < 3; j++)
            V[i][j] = U[i][j] - (K[i][0] * S[j] + K[i][1] * S[3 + j] + K[i][2] * S[6 + j]);
    for (i = 0; i < 4; i++)
        for (j = 4; j < 7; j++)     /* K's row i is zero: V's is U's */
            R[i][j] = p[7 * i + j] - (U[i][0] * K[j][0] + U[i][1] * K[j][1] + U[i][2] * K[j][2]);
    for (i = 4; i < 7; i++)
        for (j = i; j < 7; j++)
            R[i][j] = p[7 * i + j] - ((K[i][0] * U[j][0] + K[i][1] * U[j][1] + K[i][2] * U[j][2])
                                      + (V[i][0] * K[j][0] + V[i][1] * K[j][1] + V[i][2] * K[j][2]));
    for (i = 0; i < 7; i++)
        for (j = (i < 4 ? 4 : i); j < 7; j++)
            p[7 * i + j] = p[7 * j + i] = R[i][j];
}

/* magd_check (fusion/_magdist.pxd) on lane l: 1 if the filter may use the sample */
/* its constants FUSION_MAGD_*: fusion/_magdist.pxd's, defined before this header in the
 * generated module */
#define EKB_S(f) d[(size_t)(f) * cap + l]

static inline int ekb_magd_close(const double* a, const double* r, double norm_tol, double dip_tol) {
    double dn = a[0] - r[0], dd = a[1] - r[1];
    return (dn > 0.0 ? dn : -dn) < norm_tol * r[0] && (dd > 0.0 ? dd : -dd) < dip_tol;
}

static inline int ekb_magd(double* d, size_t cap, size_t l, const double* q, const double* mag,
                           const double* gyr, double dt) {
    double nrm, nz, s, k, ks, g2, x[2], cur[2], ref[2], cand[2], u[3], r2;
    double ntol = EKB_S(EB_MNTOL), dtol = EKB_S(EB_MDTOL);
    int i, disturbed, turned;
    if (EKB_S(EB_MTIME) <= 0.0)
        return 1;
    nrm = sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2]);
    nz = (2.0 * (q[1] * q[3] - q[0] * q[2]) * mag[0] + 2.0 * (q[2] * q[3] + q[0] * q[1]) * mag[1]
          + (q[0] * q[0] - q[1] * q[1] - q[2] * q[2] + q[3] * q[3]) * mag[2]);
    s = nz / nrm;
    u[0] = ((q[0] * q[0] + q[1] * q[1] - q[2] * q[2] - q[3] * q[3]) * mag[0]
            + 2.0 * (q[1] * q[2] - q[0] * q[3]) * mag[1] + 2.0 * (q[1] * q[3] + q[0] * q[2]) * mag[2]) / nrm;
    u[1] = (2.0 * (q[1] * q[2] + q[0] * q[3]) * mag[0] + (q[0] * q[0] - q[1] * q[1] + q[2] * q[2] - q[3] * q[3]) * mag[1]
            + 2.0 * (q[2] * q[3] - q[0] * q[1]) * mag[2]) / nrm;
    u[2] = s;
    s = s > 1.0 ? 1.0 : (s < -1.0 ? -1.0 : s);
    x[0] = nrm;
    x[1] = -asin(s);
    for (i = 0; i < 2; i++) {
        cur[i] = EKB_S(EB_MCUR + i);
        ref[i] = EKB_S(EB_MREF + i);
        cand[i] = EKB_S(EB_MCAND + i);
    }
    disturbed = EKB_S(EB_MDIST) != 0.0;
    /* (past the first sample: ekfb_fast) */
    k = dt / (FUSION_MAGD_CUR_TAU + dt);
    ks = dt / (FUSION_MAGD_DIR_TAU + dt);
    r2 = 0.0;
    for (i = 0; i < 3; i++) {
        EKB_S(EB_MDIRC + i) += k * (u[i] - EKB_S(EB_MDIRC + i));
        EKB_S(EB_MDIRS + i) += ks * (EKB_S(EB_MDIRC + i) - EKB_S(EB_MDIRS + i));
        u[i] = EKB_S(EB_MDIRC + i) - EKB_S(EB_MDIRS + i);
        r2 += u[i] * u[i];
    }
    turned = FUSION_LASTED(EKB_S(EB_MSET), FUSION_MAGD_FIRST_TIME) && r2 > FUSION_MAGD_DIR_TOL * FUSION_MAGD_DIR_TOL;
    EKB_S(EB_MTF) = turned ? 0.0 : EKB_S(EB_MTF) + dt;
    k = dt / (FUSION_MAGD_CUR_TAU + dt);
    for (i = 0; i < 2; i++)
        cur[i] += k * (x[i] - cur[i]);
    if (!FUSION_LASTED(EKB_S(EB_MSET), FUSION_MAGD_FIRST_TIME)) {     /* settling: the reference's dip is the current one */
        ref[1] = cur[1];
        cand[1] = cur[1];
        EKB_S(EB_MSET) += dt;
    }
    k = dt / (FUSION_MAGD_REF_TAU + dt);
    if (ekb_magd_close(cur, ref, ntol, dtol)) {
        EKB_S(EB_MTU) += dt;
        if (FUSION_LASTED(EKB_S(EB_MTU), FUSION_MAGD_MIN_UNDIST)) {
            disturbed = 0;
            for (i = 0; i < 2; i++)
                ref[i] += k * (cur[i] - ref[i]);
        }
    } else {
        EKB_S(EB_MTU) = 0.0;
        disturbed = 1;
    }
    if (ekb_magd_close(cur, cand, ntol, dtol) && !turned) {
        g2 = gyr[0] * gyr[0] + gyr[1] * gyr[1] + gyr[2] * gyr[2];
        if (g2 >= FUSION_MAGD_NEW_MIN_GYR * FUSION_MAGD_NEW_MIN_GYR)
            EKB_S(EB_MTC) += dt;
        for (i = 0; i < 2; i++)
            cand[i] += k * (cur[i] - cand[i]);
        if (disturbed && FUSION_LASTED(EKB_S(EB_MTC), EKB_S(EB_MNEW))
            && FUSION_LASTED(EKB_S(EB_MTF), FUSION_MAGD_FIXED_HOLD)) {     /* magd_relearn(cand) */
            ref[0] = cand[0];
            ref[1] = cand[1];
            disturbed = 0;
            EKB_S(EB_MTU) = FUSION_MAGD_MIN_UNDIST;
        }
    } else {
        EKB_S(EB_MTC) = 0.0;
        cand[0] = cur[0];
        cand[1] = cur[1];
    }
    for (i = 0; i < 2; i++) {
        EKB_S(EB_MCUR + i) = cur[i];
        EKB_S(EB_MCAND + i) = cand[i];
    }
    if (!disturbed) {
        EKB_S(EB_MTR) -= FUSION_MAGD_DECAY * dt;
        if (EKB_S(EB_MTR) < 0.0)
            EKB_S(EB_MTR) = 0.0;
        EKB_S(EB_MREF) = ref[0];
        EKB_S(EB_MREF + 1) = ref[1];
        EKB_S(EB_MDIST) = 0.0;
        return 1;
    }
    EKB_S(EB_MTR) += dt;
    if (FUSION_OUTLASTED(EKB_S(EB_MTR), EKB_S(EB_MTIME)) && FUSION_LASTED(EKB_S(EB_MTF), FUSION_MAGD_FIXED_HOLD)) {      /* magd_relearn(cur) */
        EKB_S(EB_MREF) = cur[0];
        EKB_S(EB_MREF + 1) = cur[1];
        EKB_S(EB_MDIST) = 0.0;
        EKB_S(EB_MTU) = FUSION_MAGD_MIN_UNDIST;
        EKB_S(EB_MTR) = 0.0;
        return 1;
    }
    EKB_S(EB_MREF) = ref[0];
    EKB_S(EB_MREF + 1) = ref[1];
    EKB_S(EB_MDIST) = 1.0;
    EKB_S(EB_MREJ) += 1.0;
    return 0;
}

static inline int ekb_valid3(const double* v) {
    double n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    return isfinite(n2) && n2 >= DBL_MIN;
}

/* The sample of the first n lanes (g, a, m rows of 3, m NULL: 6-axis; h the (n,) steps or
 * NULL: dt) transposed into the fields EB_IG.., and EB_FAST per lane: 1 if the lane's sample
 * may take the four-lane step (ekf_step's usual path: nothing the scalar kernel does
 * differently), 0 if the caller must step it through its estimator. Lanes n..cap get a benign
 * sample. Returns the number of lanes that are not fast. */
static inline size_t ekfb_fast(double* d, size_t cap, size_t n, const double* g, const double* a,
                               const double* m, const double* h, double dt, double dtn) {
    size_t l, slow = 0;
    int k;
    for (l = 0; l < cap; l++) {
        int fast;
        double gr, r, hl;
        const double *gl, *al, *ml;
        if (l >= n) {
            for (k = 0; k < 3; k++) {
                EKB_S(EB_IG + k) = 0.0;
                EKB_S(EB_IA + k) = k == 2 ? 9.81 : 0.0;
                EKB_S(EB_IM + k) = k == 0 ? 0.4 : (k == 2 ? -0.3 : 0.0);
            }
            EKB_S(EB_IDT) = dtn;
            EKB_S(EB_FAST) = 0.0;
            continue;
        }
        gl = g + 3 * l;
        al = a + 3 * l;
        ml = m != NULL ? m + 3 * l : NULL;
        hl = h != NULL ? h[l] : dt;
        for (k = 0; k < 3; k++) {
            EKB_S(EB_IG + k) = gl[k];
            EKB_S(EB_IA + k) = al[k];
            EKB_S(EB_IM + k) = ml != NULL ? ml[k] : 0.0;
        }
        EKB_S(EB_IDT) = hl;
        gr = EKB_S(EB_GR);
        r = 0.98 * gr;
        fast = EKB_S(EB_INIT) != 0.0
               && isfinite(gl[0] * gl[0] + gl[1] * gl[1] + gl[2] * gl[2]) && ekb_valid3(al)
               && (ml == NULL || ekb_valid3(ml))
               /* not saturated (so not out of range either) */
               && (gr <= 0.0 || (gl[0] < r && gl[0] > -r && gl[1] < r && gl[1] > -r
                                 && gl[2] < r && gl[2] > -r))
               /* no gap: no unmeasured time, the low-pass's gyro frame kept */
               && !(hl > 1.5 * dtn)
               && (EKB_S(EB_RTIME) <= 0.0 || EKB_S(EB_RS) != 0.0)
               /* the low-pass started, and this sample does not end its running-mean start
                * (acc_lowpass_settles; the tilt variance that adds, ekf_start_ended, runs in
                * the scalar kernel) */
               && (EKB_S(EB_TAU) <= 0.0 || (EKB_S(EB_LPS) != 0.0
                                            && !(EKB_S(EB_LPT) < EKB_S(EB_TAU)
                                                 && FUSION_LASTED(EKB_S(EB_LPT) + hl, EKB_S(EB_TAU)))))
               && (ml == NULL || EKB_S(EB_MTIME) <= 0.0 || EKB_S(EB_MSET) > 0.0);
        EKB_S(EB_FAST) = fast ? 1.0 : 0.0;
        slow += !fast;
    }
    return slow;
}

/* ekf_step's usual path on lanes l..l+3 (the sample from ekfb_fast), the attitudes (ENU) into
 * qo[4][4] (qo[k][lane]). nine: the magnetometer's sample is there. */
static inline void ekfb_block(double* d, size_t cap, size_t l, int nine, double qo[4][4]) {
    ekb_v p[49], q[4], b[3], g[3], a[3], mg[3], A[16], dt;
    int i, j, lane;
    ekb_m on;
    for (i = 0; i < 7; i++)
        for (j = i; j < 7; j++)
            p[7 * i + j] = p[7 * j + i] = EKB_LD(EB_P + ekb_ix(i, j));
    for (i = 0; i < 4; i++)
        q[i] = EKB_LD(EB_Q + i);
    for (i = 0; i < 3; i++) {
        b[i] = EKB_LD(EB_B + i);
        g[i] = EKB_LD(EB_IG + i);
        a[i] = EKB_LD(EB_IA + i);
        mg[i] = EKB_LD(EB_IM + i);
    }
    dt = EKB_LD(EB_IDT);
    /* ekf_propagate: measured, no gap: no unmeasured time */
    EKB_ST(EB_TUN, ekb_bc(0.0));
    {
        ekb_v gn = EKB_LD(EB_GN), bn = EKB_LD(EB_BN);
        ekb_phi(g[0] - b[0], g[1] - b[1], g[2] - b[2], dt, A);
        ekb_predict(p, q, A, dt, 0.25 * dt * gn * gn, bn * bn * dt);
    }
    /* ekf_rest: rest_detect (started), then the zero-rate update where at rest */
    on = EKB_LD(EB_RTIME) > 0.0;
    if (ekb_any(on)) {
        ekb_v lpt = EKB_LD(EB_RLPT) + dt, k, dg = ekb_bc(0.0), da = ekb_bc(0.0), gtol = EKB_LD(EB_RGTOL);
        ekb_v atol = EKB_LD(EB_RATOL), gdtol = EKB_LD(EB_RGDTOL), adtol = EKB_LD(EB_RADTOL);
        ekb_v rg[3], ra[3], t, dd, drift_g, drift_a, fg, fa, gs[3], gst = ekb_bc(0.0);
        ekb_m still = on, rest, start, raw, summing = {0, 0, 0, 0}, pending, taken = {0, 0, 0, 0};
        ekb_v kf = dt / FUSION_REST_STILL_TAU;
        lpt = ekb_sel(lpt > FUSION_REST_TAU, ekb_bc(FUSION_REST_TAU), lpt);
        k = dt / (lpt + dt);
        raw = kf >= 1.0;
        EKB_ST(EB_RLPT, ekb_sel(on, lpt, EKB_LD(EB_RLPT)));
        for (i = 0; i < 3; i++) {
            rg[i] = EKB_LD(EB_RG + i);
            ra[i] = EKB_LD(EB_RA + i);
            rg[i] = rg[i] + k * (g[i] - rg[i]);
            ra[i] = ra[i] + k * (a[i] - ra[i]);
            fg = EKB_LD(EB_RFG + i);
            fa = EKB_LD(EB_RFA + i);
            fg = ekb_sel(raw, g[i], fg + kf * (g[i] - fg));
            fa = ekb_sel(raw, a[i], fa + kf * (a[i] - fa));
            EKB_ST(EB_RFG + i, ekb_sel(on, fg, EKB_LD(EB_RFG + i)));
            EKB_ST(EB_RFA + i, ekb_sel(on, fa, EKB_LD(EB_RFA + i)));
            dd = fg - rg[i];
            dg = dg + dd * dd;
            dd = fa - ra[i];
            da = da + dd * dd;
            still = still & (ekb_abs(rg[i]) < gtol);
            EKB_ST(EB_RG + i, ekb_sel(on, rg[i], EKB_LD(EB_RG + i)));
            EKB_ST(EB_RA + i, ekb_sel(on, ra[i], EKB_LD(EB_RA + i)));
        }
        still = still & (dg < gtol * gtol) & (da < atol * atol);
        /* rest_detect's drift tests: a still run's start holds the low-passes (gyr0, acc0);
         * later samples stay still while the low-passes are within the tolerances of them */
        start = still & (EKB_LD(EB_RT) == 0.0);
        drift_g = ekb_bc(0.0);
        drift_a = ekb_bc(0.0);
        for (i = 0; i < 3; i++) {
            ekb_v g0 = EKB_LD(EB_RG0 + i), a0 = EKB_LD(EB_RA0 + i);
            EKB_ST(EB_RG0 + i, ekb_sel(on & start, rg[i], g0));
            EKB_ST(EB_RA0 + i, ekb_sel(on & start, ra[i], a0));
            dd = rg[i] - g0;
            drift_g = drift_g + dd * dd;
            dd = ra[i] - a0;
            drift_a = drift_a + dd * dd;
        }
        still = still & (start | (((gdtol <= 0.0) | (drift_g <= gdtol * gdtol))
                                  & ((adtol <= 0.0) | (drift_a <= adtol * adtol))));
        /* rest_count: the run's samples summed until an update takes them; a start clears them
         * (nothing to do, and nothing loaded, while no lane is still) */
        if (ekb_any(still)) {
            taken = (EKB_LD(EB_RTAKEN) != 0.0) & ~(on & start);
            summing = on & still & ~taken;
            for (i = 0; i < 3; i++) {
                gs[i] = ekb_sel(on & start, ekb_bc(0.0), EKB_LD(EB_RGS + i));
                gs[i] = ekb_sel(summing, gs[i] + g[i] * dt, gs[i]);
                EKB_ST(EB_RGS + i, gs[i]);
            }
            gst = ekb_sel(on & start, ekb_bc(0.0), EKB_LD(EB_RGST));
            gst = ekb_sel(summing, gst + dt, gst);
            EKB_ST(EB_RGST, gst);
        }
        t = ekb_sel(still, EKB_LD(EB_RT) + dt, ekb_bc(0.0));
        t = ekb_sel(on, t, EKB_LD(EB_RT));
        EKB_ST(EB_RT, t);
        rest = on & FUSION_LASTED(t, EKB_LD(EB_RTIME));
        pending = summing & rest;
        if (ekb_any(rest)) {
            ekb_v gk = EKB_LD(EB_RGATE), lim;
            /* rest_gate_open: a short still run whose low-pass is far from the bias waits */
            ekb_m gated = (gk > 0.0) & ~FUSION_LASTED(t, EKB_LD(EB_RGATET)), far = {0, 0, 0, 0};
            EKB_ST(EB_RN, EKB_LD(EB_RN) + ekb_sel(rest, ekb_bc(1.0), ekb_bc(0.0)));
            for (i = 0; i < 3; i++) {
                dd = rg[i] - b[i];
                lim = gk * ekb_sqrt(p[8 * (4 + i)]) + gdtol;
                far = far | (dd * dd > lim * lim);
            }
            rest = rest & ~(gated & far);
        }
        if (ekb_any(rest)) {
            ekb_v p2[49], q2[4], b2[3], z[3], rn = EKB_LD(EB_RNOISE);
            /* rest_rate: the run's mean over its time (held within BIAS_MAX) where its sum is
             * pending; else the sample */
            ekb_v T = ekb_sel(pending, gst, dt), m;
            for (i = 0; i < 3; i++) {
                m = gs[i] / T;
                m = ekb_sel(m > FUSION_BIAS_MAX, ekb_bc(FUSION_BIAS_MAX), m);
                m = ekb_sel(m < -FUSION_BIAS_MAX, ekb_bc(-FUSION_BIAS_MAX), m);
                z[i] = ekb_sel(pending, m, g[i]);
            }
            memcpy(p2, p, sizeof p2);
            memcpy(q2, q, sizeof q2);
            memcpy(b2, b, sizeof b2);
            ekb_rest_update(p2, q2, b2, z, rn * rn / T);
            ekb_keep(rest, p, q, b, p2, q2, b2);
            taken = taken | (pending & rest);
        }
        if (ekb_any(still))       /* a lane at rest is still */
            EKB_ST(EB_RTAKEN, ekb_sel(taken, ekb_bc(1.0), ekb_bc(0.0)));
    }
    /* acc_lowpassed (started, not lost) where tau > 0, in the body frame as acc_gyro_lowpass:
     * lp <- R(dq)ᵀ lp + k (a - R(dq)ᵀ lp), dq = A's first column */
    on = EKB_LD(EB_TAU) > 0.0;
    if (ekb_any(on)) {
        ekb_v lp[3], t[3], tau = EKB_LD(EB_TAU), lpt, k;
        ekb_v w, x, y, z;
        ekb_phi(g[0] - b[0], g[1] - b[1], g[2] - b[2], dt, A);
        w = A[0]; x = A[4]; y = A[8]; z = A[12];
        for (i = 0; i < 3; i++)
            lp[i] = EKB_LD(EB_LP + i);
        t[0] = (w*w + x*x - y*y - z*z) * lp[0] + 2.0 * (x*y + w*z) * lp[1] + 2.0 * (x*z - w*y) * lp[2];
        t[1] = 2.0 * (x*y - w*z) * lp[0] + (w*w - x*x + y*y - z*z) * lp[1] + 2.0 * (y*z + w*x) * lp[2];
        t[2] = 2.0 * (x*z + w*y) * lp[0] + 2.0 * (y*z - w*x) * lp[1] + (w*w - x*x - y*y + z*z) * lp[2];
        lpt = EKB_LD(EB_LPT) + dt;
        lpt = ekb_sel(FUSION_LASTED(lpt, tau), tau, lpt);
        k = dt / (lpt + dt);
        for (i = 0; i < 3; i++) {
            lp[i] = t[i] + k * (a[i] - t[i]);
            EKB_ST(EB_LP + i, ekb_sel(on, lp[i], EKB_LD(EB_LP + i)));
            a[i] = ekb_sel(on, lp[i], a[i]);
        }
        EKB_ST(EB_LPT, ekb_sel(on, lpt, EKB_LD(EB_LPT)));
    }
    {
        ekb_v sa = EKB_LD(EB_AN) / 9.81;
        ekb_acc_update(p, q, b, a, sa * sa / dt);
    }
    if (nine) {
        ekb_m acc;
        ekb_v mn = EKB_LD(EB_MN), p2[49], q2[4], b2[3];
        double qs[4], ms[3], gs[3];
        for (lane = 0; lane < 4; lane++) {
            for (i = 0; i < 4; i++)
                qs[i] = q[i][lane];
            for (i = 0; i < 3; i++) {
                ms[i] = mg[i][lane];
                gs[i] = g[i][lane];
            }
            acc[lane] = ekb_magd(d, cap, l + lane, qs, ms, gs, dt[lane]) ? -1 : 0;
        }
        if (ekb_any(acc)) {
            memcpy(p2, p, sizeof p2);
            memcpy(q2, q, sizeof q2);
            memcpy(b2, b, sizeof b2);
            acc &= ekb_mag_update(p2, q2, b2, mg, mn * mn / dt);
            ekb_keep(acc, p, q, b, p2, q2, b2);
        }
    }
    for (i = 0; i < 7; i++)
        for (j = i; j < 7; j++)
            EKB_ST(EB_P + ekb_ix(i, j), p[7 * i + j]);
    for (i = 0; i < 4; i++) {
        EKB_ST(EB_Q + i, q[i]);
        for (lane = 0; lane < 4; lane++)
            qo[i][lane] = q[i][lane];
    }
    for (i = 0; i < 3; i++)
        EKB_ST(EB_B + i, b[i]);
}
#undef EKB_S
#undef EKB_F
#undef EKB_LD
#undef EKB_ST

#else
#define EKFB_AVAILABLE 0
/* never called (soa_supported is False): declared for fusion/_bank.pyx */
static inline size_t ekfb_fast(double* d, size_t cap, size_t n, const double* g, const double* a,
                               const double* m, const double* h, double dt, double dtn) {
    (void)d; (void)cap; (void)n; (void)g; (void)a; (void)m; (void)h; (void)dt; (void)dtn;
    return 0;
}
static inline void ekfb_block(double* d, size_t cap, size_t l, int nine, double qo[4][4]) {
    (void)d; (void)cap; (void)l; (void)nine; (void)qo;
}
#endif
#endif
