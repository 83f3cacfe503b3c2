# Wahba's problem for two weighted vector pairs: QUEST (Shuster & Oh 1981) with the exact
# two-observation maximum eigenvalue and the eigenvector taken from the adjugate, which is
# Shuster's formula with the sequential-rotation fallback folded in (no 180-degree singularity).
# Inlined, no Python objects: any kernel can cimport it. Spec: docs/aekf.md, "QUEST".
# Convention (docs/estimators.md): q = [w, x, y, z] rotates body vectors into the reference
# frame, r_i ≈ R(q) b_i.
from libc.math cimport sqrt, fabs

cdef inline double _det3_minor(const double* M, int ri, int ci) noexcept nogil:
    """Determinant of the 3x3 matrix left of the 4x4 row-major M without row ri, column ci."""
    cdef int r[3]
    cdef int c[3]
    cdef int i, k = 0, l = 0
    for i in range(4):
        if i != ri:
            r[k] = i * 4
            k += 1
        if i != ci:
            c[l] = i
            l += 1
    return (M[r[0] + c[0]] * (M[r[1] + c[1]] * M[r[2] + c[2]] - M[r[1] + c[2]] * M[r[2] + c[1]])
            - M[r[0] + c[1]] * (M[r[1] + c[0]] * M[r[2] + c[2]] - M[r[1] + c[2]] * M[r[2] + c[0]])
            + M[r[0] + c[2]] * (M[r[1] + c[0]] * M[r[2] + c[1]] - M[r[1] + c[1]] * M[r[2] + c[0]]))


cdef inline bint quest2(const double* b1, const double* b2, const double* r1, const double* r2,
                        double w1, double w2, double* q) noexcept nogil:
    """q (4) minimising w1 |r1 - R(q) b1|² + w2 |r2 - R(q) b2|² over unit quaternions, for
    unit vectors b1, b2 (body) and r1, r2 (reference) and weights w1, w2 > 0. Returns False
    (q untouched) when the problem has no unique solution: b1 ∥ b2 or r1 ∥ r2 (|b1 × b2| or
    |r1 × r2| below 1e-9). The result has w >= 0.

    Davenport: maximise qᵀ K q, K = [[σ, zᵀ], [z, S - σ I3]], B = Σ w_i r_i b_iᵀ, σ = tr B,
    S = B + Bᵀ, z = [B32 - B23, B13 - B31, B21 - B12]. Two observations: the largest
    eigenvalue is λ = sqrt(w1² + w2² + 2 w1 w2 ((b1·b2)(r1·r2) + |b1 × b2| |r1 × r2|)).
    adj(λ I - K) = c q qᵀ (c > 0): column k of the adjugate, k the largest of its diagonal,
    normalised, is ±q."""
    cdef double B[9]
    cdef double M[16]
    cdef double cb[3]
    cdef double cr[3]
    cdef double v[4]
    cdef double nb, nr, lam, s, sig, d, dmax
    cdef int i, j, k
    cb[0] = b1[1] * b2[2] - b1[2] * b2[1]
    cb[1] = b1[2] * b2[0] - b1[0] * b2[2]
    cb[2] = b1[0] * b2[1] - b1[1] * b2[0]
    cr[0] = r1[1] * r2[2] - r1[2] * r2[1]
    cr[1] = r1[2] * r2[0] - r1[0] * r2[2]
    cr[2] = r1[0] * r2[1] - r1[1] * r2[0]
    nb = sqrt(cb[0] * cb[0] + cb[1] * cb[1] + cb[2] * cb[2])
    nr = sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2])
    if not (nb > 1e-9 and nr > 1e-9):
        return False
    s = 1.0 / (w1 + w2)          # scale-free: weights normalised to sum 1
    w1 *= s
    w2 *= s
    lam = w1 * w1 + w2 * w2 + 2.0 * w1 * w2 * (
        (b1[0] * b2[0] + b1[1] * b2[1] + b1[2] * b2[2]) * (r1[0] * r2[0] + r1[1] * r2[1] + r1[2] * r2[2])
        + nb * nr)
    lam = sqrt(lam) if lam > 0.0 else 0.0
    for i in range(3):
        for j in range(3):
            B[i * 3 + j] = w1 * r1[i] * b1[j] + w2 * r2[i] * b2[j]
    sig = B[0] + B[4] + B[8]
    # M = λ I - K
    M[0] = lam - sig
    M[1] = M[4] = -(B[7] - B[5])
    M[2] = M[8] = -(B[2] - B[6])
    M[3] = M[12] = -(B[3] - B[1])
    for i in range(3):
        for j in range(3):
            M[(i + 1) * 4 + j + 1] = -(B[i * 3 + j] + B[j * 3 + i])
        M[(i + 1) * 5] += sig + lam
    # adjugate diagonal = principal minors; the largest picks the best-conditioned column
    k = 0
    dmax = _det3_minor(M, 0, 0)
    for i in range(1, 4):
        d = _det3_minor(M, i, i)
        if d > dmax:
            dmax = d
            k = i
    if not (dmax > 0.0):
        return False
    for i in range(4):
        # adj[i, k] = cofactor C[k, i] = (-1)^(i+k) minor(row k, column i)
        d = _det3_minor(M, k, i)
        v[i] = d if (i + k) % 2 == 0 else -d
    s = 1.0 / sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3])
    if v[0] < 0.0:
        s = -s
    for i in range(4):
        q[i] = v[i] * s
    return True
