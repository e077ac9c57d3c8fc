"""Plain NumPy reference of one shape-matching step, written to be read (algorithm.md).

This is the twin of the Numba kernels: the tests compare trajectories of both, and the
benchmark uses it as the baseline.  It favours the textbook formulas over speed: centres
of mass, A_pq, A_qq and the goals are computed cluster by cluster with NumPy, the rotation
comes from an SVD (sign-corrected so it is proper), and A_qq from ``numpy.linalg.pinv``;
damping moves each velocity towards its clusters' rigid motion before Eq. 13.
"""

import numpy as np

from .clusters import build_memberships
from .kernels.colliders import ENTRY_TURN
from .params import BodyParams

RCOND = 1e-10


def proper_rotation(a: np.ndarray) -> np.ndarray:
    """The proper rotation R maximising tr(R^T a): SVD with the last singular flipped."""
    u, _, vt = np.linalg.svd(a)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def quadratic_terms(q: np.ndarray) -> np.ndarray:
    """q~ = [x, y, z, x^2, y^2, z^2, xy, yz, zx] for every row of q (Eq. 19)."""
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    return np.stack([x, y, z, x * x, y * y, z * z, x * y, y * z, z * x], axis=1)


STRETCH_LIMIT = 2.0


def _unit_det_values(s: np.ndarray) -> np.ndarray:
    """The x (prod x = 1) closest to the singular values s in least squares.

    Stationary points of sum (x_i - s_i)^2 + 2 mu (sum log x_i) satisfy x_i^2 - s_i x_i = mu:
    x_i = (s_i + sqrt(s_i^2 + 4 mu)) / 2, and for the smallest s_k also the minus root.
    On the plus branch prod x grows with mu from mu = -s_min^2 / 4; if the product is
    already above 1 there, the root lies on the minus branch of the smallest value
    (x_k falls from s_k / 2 to 0 as mu rises to 0).  Bisection: slow but obviously right.
    """
    k = int(np.argmin(s))
    lo0 = -0.25 * s[k] ** 2

    def x_of(mu, minus):
        r = np.sqrt(np.maximum(s * s + 4.0 * mu, 0.0))
        x = 0.5 * (s + r)
        if minus:
            x[k] = 0.5 * (s[k] - r[k])
        return x

    if np.prod(x_of(lo0, False)) <= 1.0:
        lo, hi = lo0, 1.0
        while np.prod(x_of(hi, False)) < 1.0:
            hi *= 2.0
        while hi - lo > 1e-15 * max(1.0, abs(lo)):
            mid = 0.5 * (lo + hi)
            if not lo < mid < hi:
                break
            lo, hi = (mid, hi) if np.prod(x_of(mid, False)) < 1.0 else (lo, mid)
        return x_of(0.5 * (lo + hi), False)
    lo, hi = lo0, 0.0                  # minus branch: product > 1 at lo, -> 0 at hi
    while hi - lo > 1e-15 * abs(lo0):
        mid = 0.5 * (lo + hi)
        if not lo < mid < hi:
            break
        lo, hi = (mid, hi) if np.prod(x_of(mid, True)) > 1.0 else (lo, mid)
    return x_of(0.5 * (lo + hi), True)


def volume_preserving(a: np.ndarray, limit: float = STRETCH_LIMIT):
    """The det-1 matrix closest to ``a`` with its singular vectors; None if det a <= 0.

    Singular values s_i -> x_i = (s_i + sqrt(s_i^2 + 4 lam)) / 2 with prod x_i = 1
    (least squares under the constraint), then limited to [1 / limit, limit].  Eq. 18's
    uniform a / cbrt(det a) pumps energy into bodies flattened on impact.  (The linear
    mode uses ``unit_det_match`` instead.)
    """
    if not np.linalg.det(a) > 1e-9:
        return None
    u, s, vt = np.linalg.svd(a)
    lo, hi = -0.25 * s.min() ** 2, 1.0

    def x_of(lam):
        return 0.5 * (s + np.sqrt(np.maximum(s * s + 4.0 * lam, 0.0)))

    if np.prod(x_of(lo)) > 1.0:        # no root: the uniform rescaling of Eq. 18
        x = s / np.cbrt(np.prod(s))
    else:
        while np.prod(x_of(hi)) < 1.0:
            hi *= 2.0
        for _ in range(200):           # bisection: slow but obviously right
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.prod(x_of(mid)) < 1.0 else (lo, mid)
        x = x_of(0.5 * (lo + hi))
    return u @ np.diag(np.clip(x, 1.0 / limit, limit)) @ vt


def nearest_unit_det(f: np.ndarray) -> np.ndarray:
    """argmin ||C - f||_F over det C = 1, for det f > 0 (same singular vectors as f)."""
    u, s, vt = np.linalg.svd(f)
    return u @ np.diag(_unit_det_values(s)) @ vt


def stretch_limited(b: np.ndarray, r: np.ndarray, limit: float = STRETCH_LIMIT) -> np.ndarray:
    """R + t (B - R) with the largest t in [0, 1] whose singular values lie in [1/L, L].

    Any blend of B and R keeps A_pq T^T symmetric (no torque); t = 1 (B itself) unless
    the body is stretched or flattened beyond ``limit`` (a safeguard, rarely binding).
    """
    def inside(t):
        sv = np.linalg.svd(r + t * (b - r), compute_uv=False)
        return sv.max() <= limit and sv.min() >= 1.0 / limit

    if inside(1.0):
        return b
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    return r + lo * (b - r)


def unit_det_match(apq: np.ndarray, aqq: np.ndarray, r: np.ndarray,
                   limit: float = STRETCH_LIMIT):
    """The linear mode's B: argmin sum w ||p - B q||^2 over det B = 1 (None: use R).

    With E(B) = tr(B A_qq B^T) - 2 tr(B A_pq^T) + const, write A_qq = M^2 (M symmetric
    positive definite) and C = B M: E = ||C - A_pq M^-1||_F^2 + const and det C = det M.
    So C is the matrix of determinant det M closest to F = A_pq M^-1 (``nearest_unit_det``
    after scaling by det M^(1/3)) and B = C M^-1.  Stationarity gives B A_qq B^T - A_pq B^T
    = mu I: A_pq B^T is symmetric, the goals exert no torque on the cluster and, being an
    energy minimiser, do no net work over a closed path.  Safeguards kept from the former
    rule: det A <= 1e-9 (A = A_pq A_qq^-1: inverted, flat or line-like cluster) -> None, and
    stretches beyond [1/limit, limit] pulled back towards R (``stretch_limited``).
    """
    a = apq @ np.linalg.pinv(aqq, rcond=RCOND, hermitian=True)
    if not np.linalg.det(a) > 1e-9:
        return None
    lam, vec = np.linalg.eigh(aqq)
    c = np.cbrt(np.prod(lam))                       # det(A_qq)^(1/3) = det(M)^(2/3)
    n = vec @ np.diag((lam / c) ** -0.5) @ vec.T    # det(M)^(1/3) M^-1, unit determinant
    f = apq @ n / c                                 # F / det(M)^(1/3)
    b = nearest_unit_det(f) @ n
    return stretch_limited(b, r, limit)


def _spectral_norm(m: np.ndarray) -> float:
    return float(np.linalg.norm(m, 2))


def _unit_det(m: np.ndarray) -> np.ndarray:
    return m / np.cbrt(np.linalg.det(m))


def cap_plastic(sp: np.ndarray, c_max: float) -> np.ndarray:
    """Volume-normalise S^P and pull it towards I until ||S^P - I||_2 <= c_max (Eq. 27)."""
    eye = np.eye(3)
    if _spectral_norm(sp - eye) <= c_max:
        return sp
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        cand = eye + mid * (sp - eye)
        ok = np.linalg.det(cand) > 0 and _spectral_norm(_unit_det(cand) - eye) <= c_max
        lo, hi = (mid, hi) if ok else (lo, mid)
    return _unit_det(eye + lo * (sp - eye))


class ReferenceBody:
    """One body stepped with NumPy; same inputs and semantics as ``sm_ros.core.Body``."""

    def __init__(self, points, masses=1.0, params=None, pinned=None):
        self.x = np.array(points, dtype=float)
        self.v = np.zeros_like(self.x)
        n = len(self.x)
        self.m = np.broadcast_to(np.asarray(masses, dtype=float), (n,)).copy()
        self.params = (params or BodyParams()).validate()
        self.x_init = self.x.copy()
        self.force = np.zeros(3)
        self.torque = np.zeros(3)
        self.pinned = np.asarray(pinned if pinned is not None else [], dtype=int)
        self.grab_idx = np.zeros(0, dtype=int)
        self.grab_tgt = np.zeros((0, 3))
        # clusters: list of (particle indices, weights w = m / clusters per particle)
        if self.params.clusters == 1:
            members = [np.arange(n)]
            counts = np.ones(n)
        else:
            x0 = self.x_init - (self.m @ self.x_init) / self.m.sum()
            ptr, cluster_ids, nk = build_memberships(x0, self.params.clusters)
            counts = np.diff(ptr)
            rows = np.repeat(np.arange(n), counts)
            members = [rows[cluster_ids == k] for k in range(nk)]
        self.members = members
        self.weights = [self.m[idx] / counts[idx] for idx in members]
        self.counts = counts
        self.cm0 = [w @ self.x_init[idx] / w.sum() for idx, w in zip(members, self.weights)]
        self.plastic_state = [np.eye(3) for _ in members]
        self._rest()

    def _rest(self):
        """q = S^P (x0 - x0_cm) per cluster and the inverse moment matrices."""
        self.q, self.aqq, self.aqq9, self.mom = [], [], [], []
        for idx, w, cm0, sp in zip(self.members, self.weights, self.cm0, self.plastic_state):
            q = (self.x_init[idx] - cm0) @ sp.T
            self.q.append(q)
            self.mom.append((w[:, None] * q).T @ q)
            self.aqq.append(np.linalg.pinv(self.mom[-1], rcond=RCOND, hermitian=True))
            qt = self._centred_terms(q, w)
            self.aqq9.append(np.linalg.pinv((w[:, None] * qt).T @ qt, rcond=RCOND,
                                            hermitian=True))

    @staticmethod
    def _centred_terms(q, w):
        """q~ minus its weighted mean: goals then share the centre of mass."""
        qt = quadratic_terms(q)
        return qt - (w @ qt) / w.sum()

    def set_wrench(self, force, torque=(0.0, 0.0, 0.0)):
        """Hold a force at the centre of mass and a torque about it (like Body)."""
        self.force = np.asarray(force, dtype=float)
        self.torque = np.asarray(torque, dtype=float)

    def set_kinematic(self, indices, targets):
        """Hold the particles ``indices`` at ``targets`` (like Body)."""
        self.grab_idx = np.asarray(indices, dtype=int)
        self.grab_tgt = np.asarray(targets, dtype=float)

    def goals(self, h=None):
        """Goals of every particle (mean over its clusters); updates S^P if ``h`` is given.

        ``beta`` is the material's at the step ``h`` (``BodyParams.at_step``); as given
        without ``h``.
        """
        p = self.params
        beta = p.beta if h is None else p.at_step(h).beta
        goal_sum = np.zeros_like(self.x)
        changed = False
        for k, (idx, w, q) in enumerate(zip(self.members, self.weights, self.q)):
            x = self.x[idx]
            cm = w @ x / w.sum()                                   # Eq. 7
            pk = x - cm
            apq = (w[:, None] * pk).T @ q                          # Eq. 8
            r = proper_rotation(apq)                               # Eq. 11 (erratum)
            if p.mode == 'quadratic':
                qt = self._centred_terms(q, w)
                a9 = ((w[:, None] * pk).T @ qt) @ self.aqq9[k]     # Eq. 21 (erratum)
                r9 = np.hstack([r, np.zeros((3, 6))])
                goal = qt @ (beta * a9 + (1 - beta) * r9).T + cm   # Eq. 22
            else:
                t = r
                if p.mode == 'linear':
                    b = unit_det_match(apq, self.mom[k], r)        # Eq. 18 (see there)
                    if b is not None:
                        t = beta * b + (1 - beta) * r
                goal = q @ t.T + cm                                # Eq. 12
            goal_sum[idx] += goal
            if h is not None and p.plastic:
                changed |= self._plastic_update(k, apq, h)
        return goal_sum / self.counts[:, None], changed

    def _plastic_update(self, k, apq, h):
        """Eq. 24-27 for cluster k; True if S^P changed."""
        p = self.params
        a = apq @ self.aqq[k]
        ra = proper_rotation(a)
        s = ra.T @ a
        s = 0.5 * (s + s.T)
        e = s - np.eye(3)
        # directions the rest shape does not span (flat, line-like, one-point clusters:
        # A_qq is a pseudo-inverse there) count as unstretched, S = I, not S = 0
        lam, vec = np.linalg.eigh(self.aqq[k])
        null = vec[:, ~(lam > 1e-13 * lam.max())]
        e = e + null @ null.T
        if np.max(np.abs(np.linalg.eigvalsh(e))) <= p.plastic_yield:
            return False
        sp = (np.eye(3) + min(h * p.at_step(h).creep, 1.0) * e) @ self.plastic_state[k]
        if np.linalg.det(sp) <= 1e-12:
            return False
        self.plastic_state[k] = cap_plastic(_unit_det(sp), p.plastic_max)
        return True

    def _rigid_motion(self):
        """Each particle's damping target: the mean over its clusters of the cluster's
        rigid motion v_cm + omega x (x - x_cm), omega = I^+ L (``kernels.damping``)."""
        target = np.zeros_like(self.v)
        for idx, w in zip(self.members, self.weights):
            x, v = self.x[idx], self.v[idx]
            r = x - w @ x / w.sum()
            spin = (w[:, None] * np.cross(r, v)).sum(axis=0)
            inertia = (w * (r * r).sum(1)).sum() * np.eye(3) - (w[:, None] * r).T @ r
            omega = np.linalg.pinv(inertia, rcond=1e-12, hermitian=True) @ spin
            target[idx] += w @ v / w.sum() + np.cross(omega, r)
        return target / self.counts[:, None]

    def step(self, h, gravity=(0.0, 0.0, 0.0), ground=None, boxes=(), spheres=(),
             radius=0.0):
        """Damping, Eq. 13-14, then colliders (met by spheres of ``radius``), then
        kinematic particles."""
        p = self.params.at_step(h)             # the material's coefficients at this step
        goals, changed = self.goals(h)
        m = self.m
        acc = np.asarray(gravity, dtype=float) + self.force / m.sum()
        com = m @ self.x / m.sum()
        r = self.x - com
        a_part = np.broadcast_to(acc, self.x.shape).copy()
        if np.any(self.torque):
            inertia = (m * (r * r).sum(1)).sum() * np.eye(3) - (m[:, None] * r).T @ r
            ang = np.linalg.pinv(inertia, rcond=1e-12, hermitian=True) @ self.torque
            a_part += np.cross(ang, r)
        kin = np.concatenate([self.grab_idx[~np.isin(self.grab_idx, self.pinned)],
                              self.pinned]).astype(int)
        tgt = np.concatenate([self.grab_tgt[~np.isin(self.grab_idx, self.pinned)],
                              self.x_init[self.pinned]])
        x_prev = self.x[kin].copy()
        if p.damping > 0.0:
            self.v = self.v + p.damping * (self._rigid_motion() - self.v)
        self.v = self.v + p.alpha * (goals - self.x) / h + h * a_part   # Eq. 13
        self.x = self.x + h * self.v                                  # Eq. 14
        thresh = max(1e-3, 2.0 * np.linalg.norm(gravity) * h)
        for i in range(len(self.x)):
            self.x[i], self.v[i] = collide(self.x[i], self.v[i], ground, boxes, spheres,
                                           thresh, radius, h)
        self.x[kin] = tgt
        self.v[kin] = (tgt - x_prev) / h
        if changed:
            self._rest()


def _contact(v, n, friction, restitution, thresh):
    vn = v @ n
    if vn >= 0:
        return v
    vt = v - vn * n
    vn_new = -restitution * vn if -vn > thresh else 0.0
    speed = np.linalg.norm(vt)
    if speed > 0:
        vt = vt * max(0.0, 1.0 - friction * (vn_new - vn) / speed)
    return vt + vn_new * n


def box_entry(came, x, lo, hi):
    """(axis, positive, exit axis): the face of the box lo..hi through which the path from
    ``came`` to x enters it, and the axis of the face it leaves by; None where ``came`` is
    inside or the path misses (slab test)."""
    outside = (came <= lo) | (came >= hi)
    d = x - came
    if not outside.any() or np.any(outside & (d == 0.0)):
        return None
    moving = d != 0.0
    with np.errstate(divide='ignore', invalid='ignore'):
        t0, t1 = (lo - came) / d, (hi - came) / d
    enter = np.where(outside & moving, np.minimum(t0, t1), -np.inf)
    leave = np.where(moving, np.maximum(t0, t1), np.inf)
    axis, out_axis = int(np.argmax(enter)), int(np.argmin(leave))
    if not (0.0 <= enter[axis] <= 1.0 and enter[axis] < leave[out_axis]):
        return None
    return axis, bool(d[axis] < 0), out_axis


def collide(x, v, ground, boxes, spheres, thresh, radius=0.0, h=0.0):
    """Project one particle, a sphere of ``radius``, out of the colliders (each grown by
    the radius; a box keeps its square edges) and correct its velocity; one the step of
    ``h`` s carried past a box's middle, or through it, leaves by the face it entered
    through, and one whose path entered a sphere through a surface that turns from the
    one nearest its end by more than 45 degrees by the tangent plane where it entered (it
    was at x - h v)."""
    x, v = x.copy(), v.copy()
    came = x - h * v
    if ground is not None and x[2] < ground.height + radius:
        x[2] = ground.height + radius
        v = _contact(v, np.array([0.0, 0.0, 1.0]), ground.friction, ground.restitution,
                     thresh)
    for b in boxes:
        lo = np.asarray(b.lo, dtype=float) - radius
        hi = np.asarray(b.hi, dtype=float) + radius
        entry, inside = box_entry(came, x, lo, hi), np.all(x > lo) and np.all(x < hi)
        through = entry is not None and entry[2] == entry[0]   # out at the opposite face
        if inside or through:
            depth = np.concatenate([x - lo, hi - x])   # -x, +x faces interleaved below
            order = [0, 3, 1, 4, 2, 5]
            face = min(order, key=lambda f: depth[f])
            axis, positive = face % 3, face >= 3
            if not inside or (entry is not None and entry[0] == axis
                              and entry[1] != positive):
                axis, positive = entry[:2]
            n = np.zeros(3)
            n[axis] = 1.0 if positive else -1.0
            x[axis] = hi[axis] if positive else lo[axis]
            v, x = _held(v, _contact(v, n, b.friction, b.restitution, thresh), x, n, h)
    for s in spheres:
        c, rad = np.asarray(s.center, dtype=float), s.radius + radius
        n, m = _unit(x - c), _sphere_entry(came - c, x - came, rad)
        inside = np.linalg.norm(x - c) < rad
        u = x - came
        t = np.clip(-((came - c) @ u) / (u @ u), 0.0, 1.0) if u @ u > 0 else 0.0
        meets = inside or np.linalg.norm(came + t * u - c) < rad
        push = rad - (x - c) @ m
        on_plane = meets and n @ m < ENTRY_TURN
        if on_plane:
            if push <= 0.0:
                continue
            x, n = x + push * m, m                      # the tangent plane it entered by
        elif not inside:
            continue
        v, x = _held(v, _contact(v, n, s.friction, s.restitution, thresh), x, n, h)
        if not on_plane:                # onto the surface where friction held it
            x = c + rad * _unit(x - c)
    return x, v


def _held(v, v_new, x, n, h):
    """(v_new, x moved by h times the tangential part of v_new - v at the normal n)."""
    dv = v_new - v
    dn = dv[0] * n[0] + dv[1] * n[1] + dv[2] * n[2]
    return v_new, x + h * (dv - dn * n)


def _sphere_entry(o, u, rad):
    """The outward normal where the path o + t u (t in [0, 1], relative to a sphere's
    centre) enters the sphere of ``rad``; where it starts inside, at o."""
    b, c = o @ u, o @ o - rad * rad
    if c > 0.0 and u @ u > 0.0 and b * b - (u @ u) * c >= 0.0:
        return _unit(o + (-b - np.sqrt(b * b - (u @ u) * c)) / (u @ u) * u)
    return _unit(o)


def _unit(d):
    """d over its length; +z for the zero vector."""
    size = np.linalg.norm(d)
    return d / size if size > 0 else np.array([0.0, 0.0, 1.0])


def cluster_sums(x, x0, m, ptr, cluster_ids, rest_lin, rest_off, ref, quad):
    """Per-cluster accumulators (clusters, 12 or 30) straight from the particles: row k =
    [sum w (x - ref_k), sum w (x - ref_k) f^T (row-major)] over k's members, w = m / (the
    particle's number of clusters), f = q-hat = G_k x0 + h_k or its quadratic features q~.
    Twin of ``kernels.sets_reduce`` (after ``sets_accumulate_chunks``)."""
    nk = len(rest_lin)
    out = np.zeros((nk, 30 if quad else 12))
    counts = np.diff(ptr)
    for i in range(len(x)):
        w = m[i] / counts[i]
        for k in cluster_ids[ptr[i]:ptr[i + 1]]:
            q = rest_lin[k] @ x0[i] + rest_off[k]
            f = quadratic_terms(q[None])[0] if quad else q
            d = w * (x[i] - ref[k])
            out[k, :3] += d
            out[k, 3:] += np.outer(d, f).reshape(-1)
    return out


def set_goals(x0, ptr, cluster_ids, rest_lin, rest_off, trans, goal_lin, goal_off, quad):
    """Every particle's goal, the mean over its clusters of T_k q~ + goal_off_k (quadratic)
    or goal_lin_k x0 + goal_off_k: what ``kernels.sets_maps``'s per-set polynomials give."""
    g = np.zeros_like(x0)
    for i in range(len(x0)):
        ks = cluster_ids[ptr[i]:ptr[i + 1]]
        for k in ks:
            if quad:
                q = rest_lin[k] @ x0[i] + rest_off[k]
                g[i] += trans[k] @ quadratic_terms(q[None])[0] + goal_off[k]
            else:
                g[i] += goal_lin[k] @ x0[i] + goal_off[k]
        g[i] /= len(ks)
    return g
