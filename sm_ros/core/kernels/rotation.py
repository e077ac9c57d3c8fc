"""Rotation of the polar decomposition A_pq = R S (Eq. 11, with its erratum).

R is found by Horn's quaternion method (top eigenvector of a symmetric 4x4 matrix), warm
started from the previous step's rotation: it never fails, is proper by construction and
stays continuous where A_pq is singular (flat, line-like or single-point clusters).  From
the warm start the top eigenvector usually takes a few Newton steps on the secular
equation, far cheaper than a Jacobi eigen-decomposition.
"""

import numpy as np
from numba import njit

from .jit import JIT_NO_REFCOUNT, finite
from .linalg import jacobi_eigh


@njit(**JIT_NO_REFCOUNT)
def quat_to_mat(quat, rot):
    """Rotation matrix of the unit quaternion ``q`` = (w, x, y, z) into ``r`` (3x3)."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    rot[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    rot[0, 1] = 2.0 * (x * y - w * z)
    rot[0, 2] = 2.0 * (x * z + w * y)
    rot[1, 0] = 2.0 * (x * y + w * z)
    rot[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    rot[1, 2] = 2.0 * (y * z - w * x)
    rot[2, 0] = 2.0 * (x * z - w * y)
    rot[2, 1] = 2.0 * (y * z + w * x)
    rot[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(**JIT_NO_REFCOUNT)
def _top_jacobi(n4, v4, scale):
    """The unit top eigenvector of Horn's matrix ``n4`` (destroyed) closest to e0 (Jacobi):
    e0 projected onto the eigenspace of the eigenvalues within 1e-9 ``scale`` of the top,
    the sign with u0 >= 0."""
    jacobi_eigh(n4, v4, 50)      # the sweep cap of every caller: one specialisation
    lmax = n4[0, 0]
    for k in range(1, 4):
        if n4[k, k] > lmax:
            lmax = n4[k, k]
    tol = 1e-9 * scale
    # Project e0 (no change) onto the top eigenspace: the closest optimal rotation.
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    u3 = 0.0
    for k in range(4):
        if n4[k, k] >= lmax - tol:
            c = v4[0, k]
            u0 += c * v4[0, k]
            u1 += c * v4[1, k]
            u2 += c * v4[2, k]
            u3 += c * v4[3, k]
    nu = u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3
    if nu < 1e-12:
        kbest = 0
        for k in range(1, 4):
            if n4[k, k] > n4[kbest, kbest]:
                kbest = k
        u0, u1, u2, u3 = v4[0, kbest], v4[1, kbest], v4[2, kbest], v4[3, kbest]
        nu = u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3
    inv = 1.0 / np.sqrt(nu)
    if u0 < 0.0:
        inv = -inv
    u0 *= inv
    u1 *= inv
    u2 *= inv
    u3 *= inv
    return u0, u1, u2, u3


#: ``_top_newton`` is used when the top eigenvalue of Horn's matrix is separated from the
#: rest by more than this fraction of the matrix's largest entry (provably, see there).
NEWTON_GAP = 1e-6


@njit(**JIT_NO_REFCOUNT)
def _top_newton(n4, scale):
    """(ok, u): the top eigenvector of Horn's matrix N from the warm start e0, by Newton's
    method on its secular equation; ok False where that is not provably the answer.

    With u = (1, z), N u = lam u reads z = (lam I - B)^-1 n and f(lam) = lam - N00 -
    n^T (lam I - B)^-1 n = 0 (B = N[1:, 1:], n = N[1:, 0]).  For lam above B's largest
    eigenvalue f is increasing and concave, f(N00) <= 0, so Newton's steps from lam = N00
    rise monotonically to the top eigenvalue (f' = 1 + |z|^2).  It is used only when
    N00 I - B is positive definite with a margin of ``NEWTON_GAP`` ``scale`` (Sylvester's
    criterion): by interlacing the top eigenvalue is then isolated by more than that, so
    the Jacobi path (``_top_jacobi``) would return this same eigenvector (to rounding
    over the gap).  A rotation that changed little since the last step needs 2-4 steps
    instead of a full eigen-decomposition.
    """
    n00 = n4[0, 0]
    b0, b1, b2 = n4[1, 0], n4[2, 0], n4[3, 0]
    b11, b12, b13 = n4[1, 1], n4[1, 2], n4[1, 3]
    b22, b23, b33 = n4[2, 2], n4[2, 3], n4[3, 3]
    c = n00 - NEWTON_GAP * scale
    c11, c22, c33 = c - b11, c - b22, c - b33
    d2 = c11 * c22 - b12 * b12
    d3 = (c11 * (c22 * c33 - b23 * b23) - b12 * (b12 * c33 + b23 * b13)
          - b13 * (b12 * b23 + c22 * b13))
    if not (c11 > 0.0 and d2 > 0.0 and d3 > 0.0):
        return False, 1.0, 0.0, 0.0, 0.0
    lam = n00
    z0 = z1 = z2 = 0.0
    done = False
    for _ in range(40):
        # z = (lam I - B)^-1 n by the adjugate (lam I - B is positive definite here)
        a11, a22, a33 = lam - b11, lam - b22, lam - b33
        k11 = a22 * a33 - b23 * b23
        k12 = b12 * a33 + b13 * b23
        k13 = b12 * b23 + b13 * a22
        k22 = a11 * a33 - b13 * b13
        k23 = a11 * b23 + b12 * b13
        k33 = a11 * a22 - b12 * b12
        det = a11 * k11 - b12 * k12 - b13 * k13
        inv = 1.0 / det
        z0 = (k11 * b0 + k12 * b1 + k13 * b2) * inv
        z1 = (k12 * b0 + k22 * b1 + k23 * b2) * inv
        z2 = (k13 * b0 + k23 * b1 + k33 * b2) * inv
        if done:
            break
        f = lam - n00 - (b0 * z0 + b1 * z1 + b2 * z2)
        step = -f / (1.0 + z0 * z0 + z1 * z1 + z2 * z2)
        lam += step
        done = not (abs(step) > 4e-16 * scale)
    if not done or not finite(z0 + z1 + z2):
        return False, 1.0, 0.0, 0.0, 0.0
    inv = 1.0 / np.sqrt(1.0 + z0 * z0 + z1 * z1 + z2 * z2)
    return True, inv, z0 * inv, z1 * inv, z2 * inv


@njit(**JIT_NO_REFCOUNT)
def extract_rotation(mat, quat, rot, n4, v4):
    """Least-squares rotation of ``a`` (3x3): the proper R maximising tr(R^T a).

    For det(a) > 0 this is the rotational factor of the polar decomposition a = R S
    (algorithm.md, Eq. 11 erratum); for det(a) <= 0 it is the nearest *proper* rotation
    (the SVD with the smallest singular vector flipped).  Horn's quaternion method: R's
    quaternion is the top eigenvector of a symmetric 4x4 matrix, found by Newton's method
    from the warm start where its eigenvalue is isolated (``_top_newton``), else by
    Jacobi, so it never fails and is proper by construction.  Warm start: ``q`` (in/out)
    holds the previous rotation; the problem is solved relative to it and, where the
    answer is not unique (singular ``a``: planar, collinear, single or coincident points),
    the solution closest to the previous rotation is kept.  ``r`` receives the matrix;
    ``n4``/``v4`` are 4x4 scratch buffers.
    """
    quat_to_mat(quat, rot)
    # b = R0^T a: the match relative to the previous rotation; horn's S = b^T.
    sxx = rot[0, 0] * mat[0, 0] + rot[1, 0] * mat[1, 0] + rot[2, 0] * mat[2, 0]
    sxy = rot[0, 0] * mat[0, 1] + rot[1, 0] * mat[1, 1] + rot[2, 0] * mat[2, 1]
    sxz = rot[0, 0] * mat[0, 2] + rot[1, 0] * mat[1, 2] + rot[2, 0] * mat[2, 2]
    syx = rot[0, 1] * mat[0, 0] + rot[1, 1] * mat[1, 0] + rot[2, 1] * mat[2, 0]
    syy = rot[0, 1] * mat[0, 1] + rot[1, 1] * mat[1, 1] + rot[2, 1] * mat[2, 1]
    syz = rot[0, 1] * mat[0, 2] + rot[1, 1] * mat[1, 2] + rot[2, 1] * mat[2, 2]
    szx = rot[0, 2] * mat[0, 0] + rot[1, 2] * mat[1, 0] + rot[2, 2] * mat[2, 0]
    szy = rot[0, 2] * mat[0, 1] + rot[1, 2] * mat[1, 1] + rot[2, 2] * mat[2, 1]
    szz = rot[0, 2] * mat[0, 2] + rot[1, 2] * mat[1, 2] + rot[2, 2] * mat[2, 2]
    # b[i, j] = s_ij above (row i of R0^T times column j of a); Horn uses S = b^T,
    # S_ab = b_ba.  Written out with S_ab -> b[b, a]:
    Sxx, Syy, Szz = sxx, syy, szz
    Sxy, Sxz = syx, szx
    Syx, Syz = sxy, szy
    Szx, Szy = sxz, syz
    n4[0, 0] = Sxx + Syy + Szz
    n4[0, 1] = Syz - Szy
    n4[0, 2] = Szx - Sxz
    n4[0, 3] = Sxy - Syx
    n4[1, 1] = Sxx - Syy - Szz
    n4[1, 2] = Sxy + Syx
    n4[1, 3] = Szx + Sxz
    n4[2, 2] = -Sxx + Syy - Szz
    n4[2, 3] = Syz + Szy
    n4[3, 3] = -Sxx - Syy + Szz
    for i in range(4):
        for j in range(i):
            n4[i, j] = n4[j, i]
    scale = 0.0
    total = 0.0                      # inf or nan anywhere makes it non-finite
    for i in range(4):
        for j in range(4):
            a = abs(n4[i, j])
            total += a
            if a > scale:
                scale = a
    if not (scale > 0.0) or not finite(total):
        # Zero or non-finite match: keep the previous rotation.
        return
    ok, u0, u1, u2, u3 = _top_newton(n4, scale)
    if not ok:
        u0, u1, u2, u3 = _top_jacobi(n4, v4, scale)
    # q <- q0 (x) u  (R = R0 R_u)
    w0, x0, y0, z0 = quat[0], quat[1], quat[2], quat[3]
    w = w0 * u0 - x0 * u1 - y0 * u2 - z0 * u3
    x = w0 * u1 + x0 * u0 + y0 * u3 - z0 * u2
    y = w0 * u2 - x0 * u3 + y0 * u0 + z0 * u1
    z = w0 * u3 + x0 * u2 - y0 * u1 + z0 * u0
    nq = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
    quat[0] = w * nq
    quat[1] = x * nq
    quat[2] = y * nq
    quat[3] = z * nq
    quat_to_mat(quat, rot)
