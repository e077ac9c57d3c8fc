"""Damping towards each cluster's rigid motion (not an equation of the paper).

Velocities move a fraction ``k_damp`` towards v_cm + omega x r of their clusters (averaged
like the goals of Eq. 23), so damping removes deformation and spin-relative motion but
keeps every cluster's linear and angular momentum.
"""

from numba import njit

from .jit import JIT
from .linalg import pinv_sym


@njit(**JIT)
def damp_rigid(x, v, mass, ptr, cl, ref, k_damp, lin, w3, m3a, m3b, m3c, m3d):
    """Damp velocities towards each cluster's rigid motion (v_cm + w x r), never the motion.

    Per cluster: v_cm = sum w v / W, L = sum w r x v, I = sum w (|r|^2 - r r^T),
    omega = I^+ L; each particle moves a fraction ``k_damp`` towards the mean of its
    clusters' rigid velocities.  Linear and angular momentum of every cluster are kept.
    ``lin`` (K, 13) and ``w3`` (K, 3) are scratch buffers.

    r = x - ref is taken about the centre of mass d = sum w r / W that ``ref`` holds only
    up to rounding: L and I are corrected to d (L - W d x v_cm, parallel axes).  Without
    that, a body flying at 1e10 m/s far from the origin got ``(sum w r) x v`` of rounding
    noise as angular momentum, and the damping spun it apart.
    """
    nk = ref.shape[0]
    for k in range(nk):
        for j in range(13):
            lin[k, j] = 0.0
        for j in range(3):
            w3[k, j] = 0.0
    single = ptr.shape[0] == 0
    n = x.shape[0]
    for i in range(n):
        if single:
            j0, j1, w = 0, 1, mass[i]
        else:
            j0, j1 = ptr[i], ptr[i + 1]
            w = mass[i] / (j1 - j0)
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            r0 = x[i, 0] - ref[k, 0]
            r1 = x[i, 1] - ref[k, 1]
            r2 = x[i, 2] - ref[k, 2]
            v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
            rr = r0 * r0 + r1 * r1 + r2 * r2
            lin[k, 0] += w
            lin[k, 1] += w * v0
            lin[k, 2] += w * v1
            lin[k, 3] += w * v2
            w3[k, 0] += w * r0
            w3[k, 1] += w * r1
            w3[k, 2] += w * r2
            lin[k, 4] += w * (r1 * v2 - r2 * v1)
            lin[k, 5] += w * (r2 * v0 - r0 * v2)
            lin[k, 6] += w * (r0 * v1 - r1 * v0)
            lin[k, 7] += w * (rr - r0 * r0)
            lin[k, 8] += w * (rr - r1 * r1)
            lin[k, 9] += w * (rr - r2 * r2)
            lin[k, 10] -= w * r0 * r1
            lin[k, 11] -= w * r1 * r2
            lin[k, 12] -= w * r2 * r0
    for k in range(nk):
        wk = lin[k, 0]
        for j in range(1, 4):
            lin[k, j] /= wk
        u0, u1, u2 = lin[k, 1], lin[k, 2], lin[k, 3]
        d0, d1, d2 = w3[k, 0] / wk, w3[k, 1] / wk, w3[k, 2] / wk
        # about the centre of mass: L - W d x v_cm, I - W (|d|^2 - d d^T)
        l0 = lin[k, 4] - wk * (d1 * u2 - d2 * u1)
        l1 = lin[k, 5] - wk * (d2 * u0 - d0 * u2)
        l2 = lin[k, 6] - wk * (d0 * u1 - d1 * u0)
        dd = d0 * d0 + d1 * d1 + d2 * d2
        m3a[0, 0] = lin[k, 7] - wk * (dd - d0 * d0)
        m3a[1, 1] = lin[k, 8] - wk * (dd - d1 * d1)
        m3a[2, 2] = lin[k, 9] - wk * (dd - d2 * d2)
        m3a[0, 1] = m3a[1, 0] = lin[k, 10] + wk * d0 * d1
        m3a[1, 2] = m3a[2, 1] = lin[k, 11] + wk * d1 * d2
        m3a[2, 0] = m3a[0, 2] = lin[k, 12] + wk * d2 * d0
        pinv_sym(mat=m3a, out=m3b, wa=m3c, wv=m3d, rcond=1e-12)
        o0 = m3b[0, 0] * l0 + m3b[0, 1] * l1 + m3b[0, 2] * l2
        o1 = m3b[1, 0] * l0 + m3b[1, 1] * l1 + m3b[1, 2] * l2
        o2 = m3b[2, 0] * l0 + m3b[2, 1] * l1 + m3b[2, 2] * l2
        w3[k, 0] = o0
        w3[k, 1] = o1
        w3[k, 2] = o2
        # rigid field v_cm + omega x (r - d) = (v_cm - omega x d) + omega x r
        lin[k, 1] = u0 - (o1 * d2 - o2 * d1)
        lin[k, 2] = u1 - (o2 * d0 - o0 * d2)
        lin[k, 3] = u2 - (o0 * d1 - o1 * d0)
    for i in range(n):
        if single:
            j0, j1 = 0, 1
        else:
            j0, j1 = ptr[i], ptr[i + 1]
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            r0 = x[i, 0] - ref[k, 0]
            r1 = x[i, 1] - ref[k, 1]
            r2 = x[i, 2] - ref[k, 2]
            t0 += lin[k, 1] + w3[k, 1] * r2 - w3[k, 2] * r1
            t1 += lin[k, 2] + w3[k, 2] * r0 - w3[k, 0] * r2
            t2 += lin[k, 3] + w3[k, 0] * r1 - w3[k, 1] * r0
        inv = 1.0 / (j1 - j0)
        v[i, 0] += k_damp * (t0 * inv - v[i, 0])
        v[i, 1] += k_damp * (t1 * inv - v[i, 1])
        v[i, 2] += k_damp * (t2 * inv - v[i, 2])
