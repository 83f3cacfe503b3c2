/* The ekf's covariance arithmetic (fusion/_ekf.pyx) four lanes wide.
 *
 * P is the 7x7 covariance of [q, b], row-major. Its rows' quaternion parts P[r, 0:4] are four
 * contiguous doubles: one vector each. Written entry by entry in Cython, the compiler's own
 * vectoriser packs this code two lanes wide and spends about as many shuffles as it saves
 * products (benchmarks/README.md, "Where a sample's time goes"); here every product runs on
 * whole rows or columns of the 4x4 attitude block: F P Fᵀ in about 100 vector multiply-adds
 * where the scalar code took 300, the updates' P Hᵀ, gain and covariance update alike.
 *
 * Symmetry: an entry computed twice (P[i, j] and P[j, i]) in floating point may differ in its
 * last bit. Every function here computes each entry of the upper half once and writes it to
 * both places, so P stays exactly symmetric (tests/test_health.py checks it bit for bit).
 *
 * The vectors are GCC / Clang vector extensions (any target: SSE2 gets them as pairs, AVX as
 * one register); other compilers get a plain four-element struct with the same arithmetic.
 * memcpy moves them to and from memory (unaligned loads and stores). */
#ifndef FUSION_EKFCOV_H
#define FUSION_EKFCOV_H
#include <string.h>

#if defined(__GNUC__) || defined(__clang__)
typedef double ekf_v4 __attribute__((vector_size(32)));
static inline ekf_v4 ekf_bc(double x) { ekf_v4 v = {x, x, x, x}; return v; }
static inline ekf_v4 ekf_set(double a, double b, double c, double d) { ekf_v4 v = {a, b, c, d}; return v; }
static inline ekf_v4 ekf_mul(ekf_v4 a, double s) { return a * ekf_bc(s); }
/* acc + a s, acc - a s: one fused multiply-add each where the target has it */
static inline ekf_v4 ekf_madd(ekf_v4 acc, ekf_v4 a, double s) { return acc + a * ekf_bc(s); }
static inline ekf_v4 ekf_msub(ekf_v4 acc, ekf_v4 a, double s) { return acc - a * ekf_bc(s); }
static inline double ekf_lane(ekf_v4 v, int i) { return v[i]; }
#else
typedef struct { double v[4]; } ekf_v4;
static inline ekf_v4 ekf_bc(double x) { ekf_v4 r = {{x, x, x, x}}; return r; }
static inline ekf_v4 ekf_set(double a, double b, double c, double d) { ekf_v4 r = {{a, b, c, d}}; return r; }
static inline ekf_v4 ekf_mul(ekf_v4 a, double s) {
    ekf_v4 r; int i; for (i = 0; i < 4; i++) r.v[i] = a.v[i] * s; return r; }
static inline ekf_v4 ekf_madd(ekf_v4 acc, ekf_v4 a, double s) {
    ekf_v4 r; int i; for (i = 0; i < 4; i++) r.v[i] = acc.v[i] + a.v[i] * s; return r; }
static inline ekf_v4 ekf_msub(ekf_v4 acc, ekf_v4 a, double s) {
    ekf_v4 r; int i; for (i = 0; i < 4; i++) r.v[i] = acc.v[i] - a.v[i] * s; return r; }
static inline double ekf_lane(ekf_v4 v, int i) { return v.v[i]; }
#endif

static inline ekf_v4 ekf_ld(const double* p) { ekf_v4 v; memcpy(&v, p, sizeof v); return v; }
static inline void ekf_st(double* p, ekf_v4 v) { memcpy(p, &v, sizeof v); }

/* P[i, j] = P[j, i] = x for the attitude block's lower half, from its upper half */
static inline void ekf_mirror_qq(double* P) {
    P[7] = P[1]; P[14] = P[2]; P[21] = P[3];
    P[15] = P[9]; P[22] = P[10];
    P[23] = P[17];
}

/* The attitude-bias block from its columns: c[j] = P[0:4, 4 + j], written to row 4 + j
 * (contiguous) and to column 4 + j of rows 0..3, the same values in both places. */
static inline void ekf_store_qb(double* P, const ekf_v4* c) {
    int i, j;
    for (j = 0; j < 3; j++) {
        ekf_st(P + 7 * (4 + j), c[j]);
        for (i = 0; i < 4; i++)
            P[7 * i + 4 + j] = ekf_lane(c[j], i);
    }
}

/* The time update's covariance and quaternion, F = [[A, L], [0, I]], L = -(dt/2) X,
 * X = Xi(q) (4x3), A (4x4) row-major: P <- F P Fᵀ + Q, Q = diag(gq X Xᵀ, qb I3); q <- A q.
 * With M = A Pqq + L Pbq (rows) and N = A Pqb + L Pbb (columns): Pqq <- M Aᵀ + N Lᵀ + gq X Xᵀ,
 * Pqb <- N, Pbb <- Pbb + qb I3. */
static inline void ekfc_predict(double* P, double* q, const double* A, const double* X,
                                double dt, double gq, double qb) {
    ekf_v4 Ac[4], Lc[3], Xc[3], Pq[7], N[3], R[4], qn;
    double L[12], m[16], n[12];
    double hl = -0.5 * dt;
    int i, k;
    for (i = 0; i < 12; i++)
        L[i] = hl * X[i];
    for (k = 0; k < 4; k++)
        Ac[k] = ekf_set(A[k], A[4 + k], A[8 + k], A[12 + k]);    /* columns of A */
    for (k = 0; k < 3; k++) {
        Lc[k] = ekf_set(L[k], L[3 + k], L[6 + k], L[9 + k]);
        Xc[k] = ekf_set(X[k], X[3 + k], X[6 + k], X[9 + k]);
    }
    for (k = 0; k < 7; k++)
        Pq[k] = ekf_ld(P + 7 * k);                                 /* P[k, 0:4] */
    /* rows of M: M[i, :] = sum_k A[i, k] P[k, 0:4] + sum_k L[i, k] P[4 + k, 0:4]; here and
     * below the sums in two or three independent parts, which shortens the chain from one
     * sample's P to the next (seven and ten dependent multiply-adds, 4 cycles each) */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_mul(Pq[0], A[4 * i]);
        ekf_v4 t = ekf_mul(Pq[4], L[3 * i]);
        s = ekf_madd(s, Pq[1], A[4 * i + 1]);
        t = ekf_madd(t, Pq[5], L[3 * i + 1]);
        s = ekf_madd(s, Pq[2], A[4 * i + 2]);
        t = ekf_madd(t, Pq[6], L[3 * i + 2]);
        s = ekf_madd(s, Pq[3], A[4 * i + 3]);
        ekf_st(m + 4 * i, s + t);
    }
    /* columns of N: N[:, j] = sum_k A[:, k] P[k, 4 + j] + sum_k L[:, k] P[4 + k, 4 + j] */
    for (i = 0; i < 3; i++) {
        ekf_v4 s = ekf_mul(Ac[0], P[4 + i]);
        ekf_v4 t = ekf_mul(Lc[0], P[32 + i]);
        s = ekf_madd(s, Ac[1], P[11 + i]);
        t = ekf_madd(t, Lc[1], P[39 + i]);
        s = ekf_madd(s, Ac[2], P[18 + i]);
        t = ekf_madd(t, Lc[2], P[46 + i]);
        s = ekf_madd(s, Ac[3], P[25 + i]);
        N[i] = s + t;
        ekf_st(n + 4 * i, N[i]);
    }
    /* rows of the new attitude block: sum_k M[i, k] A[:, k] + sum_k N[i, k] L[:, k]
     * + gq sum_k X[i, k] X[:, k] (Aᵀ's rows are A's columns) */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_mul(Ac[0], m[4 * i]);
        ekf_v4 t = ekf_mul(Lc[0], n[i]);
        ekf_v4 u = ekf_mul(Xc[0], gq * X[3 * i]);
        s = ekf_madd(s, Ac[1], m[4 * i + 1]);
        t = ekf_madd(t, Lc[1], n[4 + i]);
        u = ekf_madd(u, Xc[1], gq * X[3 * i + 1]);
        s = ekf_madd(s, Ac[2], m[4 * i + 2]);
        t = ekf_madd(t, Lc[2], n[8 + i]);
        u = ekf_madd(u, Xc[2], gq * X[3 * i + 2]);
        s = ekf_madd(s, Ac[3], m[4 * i + 3]);
        R[i] = s + (t + u);
    }
    qn = ekf_mul(Ac[0], q[0]);
    qn = ekf_madd(qn, Ac[1], q[1]);
    qn = ekf_madd(qn, Ac[2], q[2]);
    qn = ekf_madd(qn, Ac[3], q[3]);
    for (i = 0; i < 4; i++)
        ekf_st(P + 7 * i, R[i]);
    ekf_mirror_qq(P);
    ekf_store_qb(P, N);
    P[32] += qb;
    P[40] += qb;
    P[48] += qb;
    ekf_st(q, qn);
}

/* U = P Hᵀ for H = [Hq, 0] (Hq 3x4 row-major) as three columns of eight, U[8 m + i] =
 * (P Hᵀ)[i, m] for i < 7 (U[8 m + 7] is not used), and S = Hq U[0:4] + r I3 (3x3,
 * row-major, the upper half mirrored). */
static inline void ekfc_pht(const double* P, const double* H, double r, double* U, double* S) {
    int m, l, j;
    for (m = 0; m < 3; m++) {
        /* by symmetry, column i of P is row i: U[:, m] = sum_l P[l, :] H[m, l]; the load
         * of P[l, 4:8] reads P[l + 1, 0] into the unused lane */
        ekf_v4 uq = ekf_mul(ekf_ld(P), H[4 * m]);
        ekf_v4 ub = ekf_mul(ekf_ld(P + 4), H[4 * m]);
        for (l = 1; l < 4; l++) {
            uq = ekf_madd(uq, ekf_ld(P + 7 * l), H[4 * m + l]);
            ub = ekf_madd(ub, ekf_ld(P + 7 * l + 4), H[4 * m + l]);
        }
        ekf_st(U + 8 * m, uq);
        ekf_st(U + 8 * m + 4, ub);
    }
    for (m = 0; m < 3; m++)
        for (j = m; j < 3; j++) {
            double s = (H[4 * m] * U[8 * j] + H[4 * m + 1] * U[8 * j + 1]
                        + H[4 * m + 2] * U[8 * j + 2] + H[4 * m + 3] * U[8 * j + 3]);
            S[3 * m + j] = s;
            S[3 * j + m] = s;
        }
    S[0] += r;
    S[4] += r;
    S[8] += r;
}

/* The bias block's upper half P[4 + i, 4 + j] -= x_i y_j + z_i v_j, mirrored */
static inline void ekf_update_bb(double* P, const double* x, const double* y, const double* z,
                                 const double* v) {
    int i, j;
    for (i = 0; i < 3; i++)
        for (j = i; j < 3; j++) {
            double s = P[7 * (4 + i) + 4 + j] - (x[i] * y[j] + z[i] * v[j]);
            P[7 * (4 + i) + 4 + j] = s;
            P[7 * (4 + j) + 4 + i] = s;
        }
}

/* The update with the optimal gain K = U S^-1 (Si = adj(S), det = 1 / det(S)), U from
 * ekfc_pht: [q, b] += K y (q not normalised here) and P <- P - K Uᵀ, the Joseph form
 * P - K Uᵀ - (U - K S) Kᵀ with its second term zero for this K (fusion/_ekf.pyx,
 * kalman_apply). */
static inline void ekfc_optimal(double* P, double* q, double* b, const double* U, const double* Si,
                                double det, const double* y) {
    ekf_v4 Kq[3], Kb[3], dq, db, c[3];
    double K[24];
    int i, j, m;
    for (j = 0; j < 3; j++) {
        ekf_v4 sq = ekf_mul(ekf_ld(U), Si[j]);
        ekf_v4 sb = ekf_mul(ekf_ld(U + 4), Si[j]);
        sq = ekf_madd(sq, ekf_ld(U + 8), Si[3 + j]);
        sb = ekf_madd(sb, ekf_ld(U + 12), Si[3 + j]);
        sq = ekf_madd(sq, ekf_ld(U + 16), Si[6 + j]);
        sb = ekf_madd(sb, ekf_ld(U + 20), Si[6 + j]);
        Kq[j] = ekf_mul(sq, det);
        Kb[j] = ekf_mul(sb, det);
        ekf_st(K + 8 * j, Kq[j]);
        ekf_st(K + 8 * j + 4, Kb[j]);
    }
    dq = ekf_mul(Kq[0], y[0]);
    db = ekf_mul(Kb[0], y[0]);
    for (j = 1; j < 3; j++) {
        dq = ekf_madd(dq, Kq[j], y[j]);
        db = ekf_madd(db, Kb[j], y[j]);
    }
    for (i = 0; i < 4; i++)
        q[i] += ekf_lane(dq, i);
    for (i = 0; i < 3; i++)
        b[i] += ekf_lane(db, i);
    /* attitude rows: P[i, 0:4] -= sum_m K[i, m] U[0:4, m] */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_ld(P + 7 * i);
        for (m = 0; m < 3; m++)
            s = ekf_msub(s, ekf_ld(U + 8 * m), K[8 * m + i]);
        ekf_st(P + 7 * i, s);
    }
    ekf_mirror_qq(P);
    /* attitude-bias columns: P[0:4, 4 + j] -= sum_m K[0:4, m] U[4 + j, m] */
    for (j = 0; j < 3; j++) {
        ekf_v4 s = ekf_ld(P + 7 * (4 + j));
        for (m = 0; m < 3; m++)
            s = ekf_msub(s, Kq[m], U[8 * m + 4 + j]);
        c[j] = s;
    }
    ekf_store_qb(P, c);
    /* bias block: P[4 + i, 4 + j] -= sum_m K[4 + i, m] U[4 + j, m] */
    for (i = 0; i < 3; i++)
        for (j = i; j < 3; j++) {
            double s = P[7 * (4 + i) + 4 + j] - (K[4 + i] * U[4 + j] + K[12 + i] * U[12 + j]
                                                 + K[20 + i] * U[20 + j]);
            P[7 * (4 + i) + 4 + j] = s;
            P[7 * (4 + j) + 4 + i] = s;
        }
}

/* The heading-only update's covariance (fusion/_ekf.pyx, heading_update): K = [u; 0] kaᵀ
 * + [0; w] kcᵀ in the Joseph form, P <- P - ū g̃ᵀ - g̃ ūᵀ - w̄ h̃ᵀ - h̃ w̄ᵀ with g = U ka,
 * h = U kc, α = kaᵀ S ka, β = kaᵀ S kc, γ = kcᵀ S kc, g̃ = g - (α/2) ū - β w̄,
 * h̃ = h - (γ/2) w̄. */
static inline void ekfc_heading(double* P, const double* U, const double* S, const double* u,
                                const double* w, const double* ka, const double* kc) {
    ekf_v4 gq, gb, hq, hb, uv, c[3];
    double t[3], gqa[4], gba[4], hqa[4], hba[4];
    double al, be, ga;
    int i, j;
    gq = ekf_mul(ekf_ld(U), ka[0]);
    gb = ekf_mul(ekf_ld(U + 4), ka[0]);
    hq = ekf_mul(ekf_ld(U), kc[0]);
    hb = ekf_mul(ekf_ld(U + 4), kc[0]);
    for (j = 1; j < 3; j++) {
        gq = ekf_madd(gq, ekf_ld(U + 8 * j), ka[j]);
        gb = ekf_madd(gb, ekf_ld(U + 8 * j + 4), ka[j]);
        hq = ekf_madd(hq, ekf_ld(U + 8 * j), kc[j]);
        hb = ekf_madd(hb, ekf_ld(U + 8 * j + 4), kc[j]);
    }
    for (i = 0; i < 3; i++)
        t[i] = S[3 * i] * ka[0] + S[3 * i + 1] * ka[1] + S[3 * i + 2] * ka[2];
    al = ka[0] * t[0] + ka[1] * t[1] + ka[2] * t[2];
    be = kc[0] * t[0] + kc[1] * t[1] + kc[2] * t[2];
    for (i = 0; i < 3; i++)
        t[i] = S[3 * i] * kc[0] + S[3 * i + 1] * kc[1] + S[3 * i + 2] * kc[2];
    ga = kc[0] * t[0] + kc[1] * t[1] + kc[2] * t[2];
    uv = ekf_ld(u);
    gq = ekf_msub(gq, uv, 0.5 * al);
    gb = ekf_msub(gb, ekf_set(w[0], w[1], w[2], 0.0), be);
    hb = ekf_msub(hb, ekf_set(w[0], w[1], w[2], 0.0), 0.5 * ga);
    ekf_st(gqa, gq);
    ekf_st(gba, gb);
    ekf_st(hqa, hq);
    ekf_st(hba, hb);
    /* attitude rows: P[i, 0:4] -= u_i g̃[0:4] + g̃_i u */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_msub(ekf_ld(P + 7 * i), gq, u[i]);
        ekf_st(P + 7 * i, ekf_msub(s, uv, gqa[i]));
    }
    ekf_mirror_qq(P);
    /* attitude-bias columns: P[0:4, 4 + j] -= u g̃_b[j] + h̃_q w_j */
    for (j = 0; j < 3; j++) {
        ekf_v4 s = ekf_msub(ekf_ld(P + 7 * (4 + j)), uv, gba[j]);
        c[j] = ekf_msub(s, hq, w[j]);
    }
    ekf_store_qb(P, c);
    ekf_update_bb(P, w, hba, hba, w);
}
#endif
