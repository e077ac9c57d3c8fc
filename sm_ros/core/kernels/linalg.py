"""Small dense linear algebra written by hand (3x3, 4x4, 9x9): no equation of its own.

Supports Eq. 10-11 (the pseudo-inverses A_qq, A~_qq of Eq. 10 and 21, the eigenvectors of
Horn's matrix for Eq. 11) and the 2-norms of Eq. 24-27.  ``numpy.linalg`` inside Numba
needs SciPy's LAPACK and is slow for tiny matrices ("Practical requirements" of the
write-up), so these routines are used instead; each writes into caller-provided buffers.
"""

import numpy as np
from numba import njit

from .jit import JIT


@njit(**JIT)
def jacobi_eigh(mat, vecs, max_sweeps=50):
    """Diagonalise the symmetric matrix ``a`` in place by cyclic Jacobi rotations.

    On return the diagonal of ``a`` holds the eigenvalues and the columns of ``v`` the
    eigenvectors (``a_in = v diag(a) v^T``).  Works for any small n (used with 3, 4, 9).
    """
    n = mat.shape[0]
    for i in range(n):
        for j in range(n):
            vecs[i, j] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        off = 0.0
        diag = 0.0
        for i in range(n):
            diag += mat[i, i] * mat[i, i]
            for j in range(i + 1, n):
                off += mat[i, j] * mat[i, j]
        if off <= 1e-32 * diag or off == 0.0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = mat[p, q]
                if apq == 0.0:
                    continue
                theta = (mat[q, q] - mat[p, p]) / (2.0 * apq)
                if theta >= 0.0:
                    t = 1.0 / (theta + np.sqrt(theta * theta + 1.0))
                else:
                    t = -1.0 / (-theta + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp = mat[k, p]
                    akq = mat[k, q]
                    mat[k, p] = c * akp - s * akq
                    mat[k, q] = s * akp + c * akq
                for k in range(n):
                    apk = mat[p, k]
                    aqk = mat[q, k]
                    mat[p, k] = c * apk - s * aqk
                    mat[q, k] = s * apk + c * aqk
                for k in range(n):
                    vkp = vecs[k, p]
                    vkq = vecs[k, q]
                    vecs[k, p] = c * vkp - s * vkq
                    vecs[k, q] = s * vkp + c * vkq


@njit(**JIT)
def pinv_sym(mat, out, wa, wv, rcond):
    """Pseudo-inverse of the symmetric positive semi-definite matrix ``m`` into ``out``.

    Eigenvalues at or below ``rcond`` times the largest are treated as zero, so planar,
    line-like and single-point clusters (singular A_qq) get the least-squares inverse.
    ``wa`` and ``wv`` are n x n scratch buffers.
    """
    n = mat.shape[0]
    for i in range(n):
        for j in range(n):
            wa[i, j] = mat[i, j]
    jacobi_eigh(wa, wv, 50)
    lmax = 0.0
    for i in range(n):
        if abs(wa[i, i]) > lmax:
            lmax = abs(wa[i, i])
    tol = rcond * lmax
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
    for k in range(n):
        lam = wa[k, k]
        if lam > tol and lam > 0.0:
            inv = 1.0 / lam
            for i in range(n):
                vik = wv[i, k] * inv
                for j in range(n):
                    out[i, j] += vik * wv[j, k]


@njit(**JIT)
def det3(a):
    """Determinant of a 3x3 matrix."""
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
            - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@njit(**JIT)
def matmul(a, b, out):
    """``out = a @ b`` for small matrices (no aliasing between ``out`` and inputs)."""
    n, k = a.shape
    mass = b.shape[1]
    for i in range(n):
        for j in range(mass):
            s = 0.0
            for t in range(k):
                s += a[i, t] * b[t, j]
            out[i, j] = s


@njit(**JIT)
def norm2(mat, wa, wv):
    """Spectral norm (largest singular value) of the 3x3 matrix ``m``."""
    for i in range(3):
        for j in range(3):
            s = 0.0
            for t in range(3):
                s += mat[t, i] * mat[t, j]
            wa[i, j] = s
    jacobi_eigh(wa, wv, 50)
    lmax = 0.0
    for i in range(3):
        if wa[i, i] > lmax:
            lmax = wa[i, i]
    return np.sqrt(lmax)
