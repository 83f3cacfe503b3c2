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
#include <math.h>
#include <string.h>

/* Four-lane vectors where the target has 256-bit registers (AVX: make's native build). Without
 * them (the portable build: x86-64's SSE2, two lanes), GCC assembles the 32-byte vectors from
 * scalars through the stack, and the 16-byte loads of 8-byte stores stall store-to-load
 * forwarding: that build ran 30 % slower than the scalar code before (benchmarks/README.md).
 * There the plain struct below runs: the same arithmetic on four doubles, which the compiler
 * keeps in scalar registers or pairs as it finds best. */
#if (defined(__GNUC__) || defined(__clang__)) && defined(__AVX__)
typedef double ekf_v4 __attribute__((vector_size(32)));
static inline ekf_v4 ekf_bc(double x) { ekf_v4 v = {x, x, x, x}; return v; }
static inline ekf_v4 ekf_set(double a, double b, double c, double d) { ekf_v4 v = {a, b, c, d}; return v; }
static inline ekf_v4 ekf_mul(ekf_v4 a, double s) { return a * ekf_bc(s); }
/* acc + a s, acc - a s: one fused multiply-add each where the target has it */
static inline ekf_v4 ekf_madd(ekf_v4 acc, ekf_v4 a, double s) { return acc + a * ekf_bc(s); }
static inline ekf_v4 ekf_msub(ekf_v4 acc, ekf_v4 a, double s) { return acc - a * ekf_bc(s); }
static inline double ekf_lane(ekf_v4 v, int i) { return v[i]; }
static inline ekf_v4 ekf_add(ekf_v4 a, ekf_v4 b) { return a + b; }
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
static inline ekf_v4 ekf_add(ekf_v4 a, ekf_v4 b) {
    ekf_v4 r; int i; for (i = 0; i < 4; i++) r.v[i] = a.v[i] + b.v[i]; return r; }
#endif

static inline ekf_v4 ekf_ld(const double* p) { ekf_v4 v; memcpy(&v, p, sizeof v); return v; }
static inline void ekf_st(double* p, ekf_v4 v) { memcpy(p, &v, sizeof v); }

/* The attitude block from rows whose upper halves hold it (R[i] = P[i, 0:4], lanes j >= i):
 * each row assembled whole, its lower lanes from the rows above, and written with one store.
 * Written as the upper half plus scalar stores of the mirrored entries, the next step's
 * vector load of a row would span five stores, which the processor cannot forward to it:
 * the load would wait for them to reach the cache, on the chain from one P to the next. */
static inline void ekf_store_qq(double* P, const ekf_v4* R) {
    ekf_st(P, R[0]);
    ekf_st(P + 7, ekf_set(ekf_lane(R[0], 1), ekf_lane(R[1], 1), ekf_lane(R[1], 2), ekf_lane(R[1], 3)));
    ekf_st(P + 14, ekf_set(ekf_lane(R[0], 2), ekf_lane(R[1], 2), ekf_lane(R[2], 2), ekf_lane(R[2], 3)));
    ekf_st(P + 21, ekf_set(ekf_lane(R[0], 3), ekf_lane(R[1], 3), ekf_lane(R[2], 3), ekf_lane(R[3], 3)));
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
 * X = Xi(q) = [[-x, -y, -z], [w, -z, y], [z, w, -x], [-y, x, w]], A (4x4) row-major:
 * P <- F P Fᵀ + Q, Q = diag(gq X Xᵀ, qb I3); q <- A q. With M = A Pqq + L Pbq (rows) and
 * N = A Pqb + L Pbb (columns): Pqq <- M Aᵀ + N Lᵀ + gq X Xᵀ = M Aᵀ + N' Xᵀ with
 * N' = -(dt/2) N + gq X; Pqb <- N, Pbb <- Pbb + qb I3. X's entries are q's components, so its
 * products are multiply-adds and -subtracts with them, and L's carry the factor -(dt/2)
 * once per sum. */
static inline void ekfc_predict(double* P, double* q, const double* A, double dt, double gq,
                                double qb) {
    ekf_v4 Ac[4], Xc[3], Pq[7], N[3], R[4], qn, s, t, u;
    double m[16], n[12];
    double w = q[0], x = q[1], y = q[2], z = q[3];
    double hl = -0.5 * dt;
    int i, k;
    for (k = 0; k < 4; k++)
        Ac[k] = ekf_set(A[k], A[4 + k], A[8 + k], A[12 + k]);    /* columns of A */
    Xc[0] = ekf_set(-x, w, z, -y);                                  /* columns of X */
    Xc[1] = ekf_set(-y, -z, w, x);
    Xc[2] = ekf_set(-z, y, -x, w);
    for (k = 0; k < 7; k++)
        Pq[k] = ekf_ld(P + 7 * k);                                 /* P[k, 0:4] */
    /* rows of M: M[i, :] = sum_k A[i, k] P[k, 0:4] + (dt/2)-scaled sum_k X[i, k] P[4 + k, 0:4];
     * here and below the sums in independent parts, which shortens the chain from one
     * sample's P to the next (seven and ten dependent multiply-adds, 4 cycles each) */
    t = ekf_msub(ekf_msub(ekf_mul(Pq[4], -x), Pq[5], y), Pq[6], z);     /* X row 0: -x -y -z */
    R[0] = t;
    t = ekf_madd(ekf_msub(ekf_mul(Pq[4], w), Pq[5], z), Pq[6], y);      /* X row 1: w -z y */
    R[1] = t;
    t = ekf_msub(ekf_madd(ekf_mul(Pq[4], z), Pq[5], w), Pq[6], x);      /* X row 2: z w -x */
    R[2] = t;
    t = ekf_madd(ekf_madd(ekf_mul(Pq[5], x), Pq[4], -y), Pq[6], w);     /* X row 3: -y x w */
    R[3] = t;
    for (i = 0; i < 4; i++) {
        s = ekf_mul(Pq[0], A[4 * i]);
        s = ekf_madd(s, Pq[1], A[4 * i + 1]);
        u = ekf_mul(Pq[2], A[4 * i + 2]);
        u = ekf_madd(u, Pq[3], A[4 * i + 3]);
        ekf_st(m + 4 * i, ekf_madd(ekf_add(s, u), R[i], hl));
    }
    /* columns of N: N[:, j] = sum_k A[:, k] P[k, 4 + j] + (dt/2)-scaled sum_k X[:, k] P[4 + k, 4 + j] */
    for (i = 0; i < 3; i++) {
        s = ekf_mul(Ac[0], P[4 + i]);
        s = ekf_madd(s, Ac[1], P[11 + i]);
        u = ekf_mul(Ac[2], P[18 + i]);
        u = ekf_madd(u, Ac[3], P[25 + i]);
        t = ekf_mul(Xc[0], P[32 + i]);
        t = ekf_madd(t, Xc[1], P[39 + i]);
        t = ekf_madd(t, Xc[2], P[46 + i]);
        N[i] = ekf_madd(ekf_add(s, u), t, hl);
        /* N' = -(dt/2) N + gq X, column i */
        ekf_st(n + 4 * i, ekf_madd(ekf_mul(N[i], hl), Xc[i], gq));
    }
    /* rows of the new attitude block: sum_k M[i, k] A[:, k] + sum_k N'[i, k] X[:, k]
     * (Aᵀ's rows are A's columns) */
    for (i = 0; i < 4; i++) {
        s = ekf_mul(Ac[0], m[4 * i]);
        s = ekf_madd(s, Ac[1], m[4 * i + 1]);
        u = ekf_mul(Ac[2], m[4 * i + 2]);
        u = ekf_madd(u, Ac[3], m[4 * i + 3]);
        t = ekf_mul(Xc[0], n[i]);
        t = ekf_madd(t, Xc[1], n[4 + i]);
        t = ekf_madd(t, Xc[2], n[8 + i]);
        R[i] = ekf_add(ekf_add(s, u), t);
    }
    qn = ekf_mul(Ac[0], w);
    qn = ekf_madd(qn, Ac[1], x);
    qn = ekf_madd(qn, Ac[2], y);
    qn = ekf_madd(qn, Ac[3], z);
    ekf_store_qq(P, R);
    ekf_store_qb(P, N);
    P[32] += qb;
    P[40] += qb;
    P[48] += qb;
    ekf_st(q, qn);
}

/* The magnetometer's measurement model (fusion/_ekf.pyx, ekf_mag_update): with the unit
 * sample zv and n = R(q) zv (R body -> navigation), its horizontal part folded onto north,
 * v = [0, rho, n2], rho = |n_xy|, the prediction h = Rᵀ v and its Jacobian (3x4, row-major)
 * H = d(Rᵀ v)/dq|v + Rᵀ dv/dn dn/dq. Returns rho (0: rho < 1e-9, no heading information;
 * h and H not written).
 * d(Rᵀ v)/dq and dn/dq have rows that are q's components permuted with signs: nine such
 * vectors p1..p9 make all six rows, H row m = rho-and-n2 terms + r_y[m] D_y + r_z[m] dn2/dq
 * with r_y, r_z the rows of R (Rᵀ e_y, Rᵀ e_z) and D_y = (n0 dn0/dq + n1 dn1/dq) / rho. */
static inline double ekfc_mag_model(const double* q, const double* zv, double* h, double* H) {
    double w = q[0], x = q[1], y = q[2], z = q[3];
    double a = zv[0], b = zv[1], c = zv[2];
    double r00 = w * w + x * x - y * y - z * z, r01 = 2.0 * (x * y - w * z), r02 = 2.0 * (x * z + w * y);
    double ry0 = 2.0 * (x * y + w * z), ry1 = w * w - x * x + y * y - z * z, ry2 = 2.0 * (y * z - w * x);
    double rz0 = 2.0 * (x * z - w * y), rz1 = 2.0 * (y * z + w * x), rz2 = w * w - x * x - y * y + z * z;
    double n0 = r00 * a + r01 * b + r02 * c;
    double n1 = ry0 * a + ry1 * b + ry2 * c;
    double n2 = rz0 * a + rz1 * b + rz2 * c;
    double rho = sqrt(n0 * n0 + n1 * n1);
    double ux, uy;
    ekf_v4 p1, p2, p3, p4, p5, p6, p7, p8, p9, J0, J1, J2, Dy;
    if (rho < 1e-9)
        return 0.0;
    p1 = ekf_set(w, x, -y, -z);
    p2 = ekf_set(-z, y, x, -w);
    p3 = ekf_set(y, z, w, x);
    p4 = ekf_set(z, y, x, w);
    p5 = ekf_set(w, -x, y, -z);
    p6 = ekf_set(-x, -w, z, y);
    p7 = ekf_set(-y, z, -w, x);
    p8 = ekf_set(x, w, z, y);
    p9 = ekf_set(w, -x, -y, z);
    /* dn/dq = d(R zv)/dq, rows (the factor 2 of R's derivative on the scalars: exact) */
    J0 = ekf_madd(ekf_madd(ekf_mul(p1, 2.0 * a), p2, 2.0 * b), p3, 2.0 * c);
    J1 = ekf_madd(ekf_madd(ekf_mul(p4, 2.0 * a), p5, 2.0 * b), p6, 2.0 * c);
    J2 = ekf_madd(ekf_madd(ekf_mul(p7, 2.0 * a), p8, 2.0 * b), p9, 2.0 * c);
    ux = n0 / rho;
    uy = n1 / rho;
    Dy = ekf_madd(ekf_mul(J0, ux), J1, uy);
    h[0] = ry0 * rho + rz0 * n2;
    h[1] = ry1 * rho + rz1 * n2;
    h[2] = ry2 * rho + rz2 * n2;
    /* d(Rᵀ v)/dq|v = 2 (rho d(Rᵀ e_y) + n2 d(Rᵀ e_z)), plus Rᵀ [0; D_y; dn2/dq] */
    ekf_st(H, ekf_madd(ekf_madd(ekf_madd(ekf_mul(p4, 2.0 * rho), p7, 2.0 * n2), Dy, ry0), J2, rz0));
    ekf_st(H + 4, ekf_madd(ekf_madd(ekf_madd(ekf_mul(p5, 2.0 * rho), p8, 2.0 * n2), Dy, ry1), J2, rz1));
    ekf_st(H + 8, ekf_madd(ekf_madd(ekf_madd(ekf_mul(p6, 2.0 * rho), p9, 2.0 * n2), Dy, ry2), J2, rz2));
    return rho;
}

/* U = P Hᵀ for H = [Hq, 0] (Hq 3x4 row-major) as three columns of eight, U[8 m + i] =
 * (P Hᵀ)[i, m] for i < 7 (U[8 m + 7] = 0, not used), and S = Hq U[0:4] + r I3 (3x3,
 * row-major, the upper half mirrored). */
static inline void ekfc_pht(const double* P, const double* H, double r, double* U, double* S) {
    ekf_v4 Pq[4], T[4];
    ekf_v4 b4 = ekf_ld(P + 28), b5 = ekf_ld(P + 35), b6 = ekf_ld(P + 42);
    int m, l;
    /* by symmetry, column l of P is row l: U[0:4, m] = sum_l P[l, 0:4] H[m, l], and
     * U[4:7, m] = sum_l P[4:7, l] H[m, l] from the rows P[4 + k, 0:4] turned into columns
     * (whole rows, each written by one store: ekf_store_qq, ekf_store_qb) */
    for (l = 0; l < 4; l++) {
        Pq[l] = ekf_ld(P + 7 * l);
        T[l] = ekf_set(ekf_lane(b4, l), ekf_lane(b5, l), ekf_lane(b6, l), 0.0);
    }
    for (m = 0; m < 3; m++) {
        ekf_v4 uq = ekf_mul(Pq[0], H[4 * m]);
        ekf_v4 ub = ekf_mul(T[0], H[4 * m]);
        for (l = 1; l < 4; l++) {
            uq = ekf_madd(uq, Pq[l], H[4 * m + l]);
            ub = ekf_madd(ub, T[l], H[4 * m + l]);
        }
        ekf_st(U + 8 * m, uq);
        ekf_st(U + 8 * m + 4, ub);
    }
    /* the six entries at constant indices: as a triangular loop, the compiler's loop
     * vectoriser adds run-time alias checks and shuffles that cost more than the sums */
#define EKF_S(m, j) (H[4 * (m)] * U[8 * (j)] + H[4 * (m) + 1] * U[8 * (j) + 1] \
                     + H[4 * (m) + 2] * U[8 * (j) + 2] + H[4 * (m) + 3] * U[8 * (j) + 3])
    S[0] = EKF_S(0, 0) + r;
    S[1] = S[3] = EKF_S(0, 1);
    S[2] = S[6] = EKF_S(0, 2);
    S[4] = EKF_S(1, 1) + r;
    S[5] = S[7] = EKF_S(1, 2);
    S[8] = EKF_S(2, 2) + r;
#undef EKF_S
}

/* The bias block from rows whose lanes j >= i hold it (R[i] = P[4 + i, 4:7], lane 3 unused),
 * as ekf_store_qq: each row assembled whole from the rows above and written once. (Written
 * as scalar pairs, P[4 + i, 4 + j] = P[4 + j, 4 + i] = s, GCC's straight-line vectoriser
 * grouped each of the two stores with its neighbours and computed s twice, in two vectors,
 * fused differently: P lost its exact symmetry in the last bit.) */
static inline void ekf_store_bb(double* P, const ekf_v4* R) {
    ekf_v4 r5 = ekf_set(ekf_lane(R[0], 1), ekf_lane(R[1], 1), ekf_lane(R[1], 2), 0.0);
    ekf_v4 r6 = ekf_set(ekf_lane(R[0], 2), ekf_lane(R[1], 2), ekf_lane(R[2], 2), 0.0);
    memcpy(P + 32, &R[0], 3 * sizeof(double));
    memcpy(P + 39, &r5, 3 * sizeof(double));
    memcpy(P + 46, &r6, 3 * sizeof(double));
}

/* P[4 + i, 4:7] as a vector (lane 3: 0) */
static inline ekf_v4 ekf_ld_bb(const double* P, int i) {
    return ekf_set(P[32 + 7 * i], P[33 + 7 * i], P[34 + 7 * i], 0.0);
}

/* The update with the optimal gain K = U S^-1 (Si = adj(S), det = 1 / det(S)), U from
 * ekfc_pht: [q, b] += K y (q not normalised here) and P <- P - K Uᵀ, the Joseph form
 * P - K Uᵀ - (U - K S) Kᵀ with its second term zero for this K (fusion/_ekf.pyx,
 * kalman_apply). */
static inline void ekfc_optimal(double* P, double* q, double* b, const double* U, const double* Si,
                                double det, const double* y) {
    ekf_v4 Kq[3], Kb[3], dq, db, c[3], R[4];
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
    ekf_st(q, ekf_add(ekf_ld(q), dq));
    b[0] += ekf_lane(db, 0);
    b[1] += ekf_lane(db, 1);
    b[2] += ekf_lane(db, 2);
    /* attitude rows: P[i, 0:4] -= sum_m K[i, m] U[0:4, m] */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_ld(P + 7 * i);
        for (m = 0; m < 3; m++)
            s = ekf_msub(s, ekf_ld(U + 8 * m), K[8 * m + i]);
        R[i] = s;
    }
    ekf_store_qq(P, R);
    /* attitude-bias columns: P[0:4, 4 + j] -= sum_m K[0:4, m] U[4 + j, m] */
    for (j = 0; j < 3; j++) {
        ekf_v4 s = ekf_ld(P + 7 * (4 + j));
        for (m = 0; m < 3; m++)
            s = ekf_msub(s, Kq[m], U[8 * m + 4 + j]);
        c[j] = s;
    }
    ekf_store_qb(P, c);
    /* bias block: P[4 + i, 4:7] -= sum_m K[4 + i, m] U[4:7, m] */
    for (i = 0; i < 3; i++) {
        ekf_v4 r = ekf_ld_bb(P, i);
        for (m = 0; m < 3; m++)
            r = ekf_msub(r, ekf_ld(U + 8 * m + 4), K[8 * m + 4 + i]);
        R[i] = r;
    }
    ekf_store_bb(P, R);
}

/* The heading-only update's covariance (fusion/_ekf.pyx, heading_update): K = [u; 0] kaᵀ
 * + [0; w] kcᵀ in the Joseph form, P <- P - ū g̃ᵀ - g̃ ūᵀ - w̄ h̃ᵀ - h̃ w̄ᵀ with g = U ka,
 * h = U kc, α = kaᵀ S ka, β = kaᵀ S kc, γ = kcᵀ S kc, g̃ = g - (α/2) ū - β w̄,
 * h̃ = h - (γ/2) w̄. */
static inline void ekfc_heading(double* P, const double* U, const double* S, const double* u,
                                const double* w, const double* ka, const double* kc) {
    ekf_v4 gq, gb, hq, hb, uv, wv, c[3], R[4];
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
    wv = ekf_set(w[0], w[1], w[2], 0.0);
    gb = ekf_msub(gb, wv, be);
    hb = ekf_msub(hb, wv, 0.5 * ga);
    ekf_st(gqa, gq);
    ekf_st(gba, gb);
    ekf_st(hqa, hq);
    ekf_st(hba, hb);
    /* attitude rows: P[i, 0:4] -= u_i g̃[0:4] + g̃_i u */
    for (i = 0; i < 4; i++) {
        ekf_v4 s = ekf_msub(ekf_ld(P + 7 * i), gq, u[i]);
        R[i] = ekf_msub(s, uv, gqa[i]);
    }
    ekf_store_qq(P, R);
    /* attitude-bias columns: P[0:4, 4 + j] -= u g̃_b[j] + h̃_q w_j */
    for (j = 0; j < 3; j++) {
        ekf_v4 s = ekf_msub(ekf_ld(P + 7 * (4 + j)), uv, gba[j]);
        c[j] = ekf_msub(s, hq, w[j]);
    }
    ekf_store_qb(P, c);
    /* bias block: P[4 + i, 4:7] -= w_i h̃_b + h̃_b[i] w */
    for (i = 0; i < 3; i++)
        R[i] = ekf_msub(ekf_msub(ekf_ld_bb(P, i), hb, w[i]), wv, hba[i]);
    ekf_store_bb(P, R);
}
#endif
