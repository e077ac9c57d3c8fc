"""
Geometry for scene bodies: lattices, voxel downsampling and surfaces.

Everything here is plain NumPy and returns plain arrays; nothing imports rclpy, the solver
core or trimesh (the mesh reader in :mod:`sm_ros.scene` imports trimesh lazily). Functions
raise :class:`GeometryError` (a ``ValueError``) with a short reason; the scene loader adds
the file, body and key to the message.  The point-cloud file readers (PLY, PCD, .npy) are
in :mod:`sm_ros.point_files`.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

import numpy as np

#: Largest number of particles one body may have (guards against a tiny `spacing`).
MAX_BODY_POINTS = 1_000_000


class GeometryError(ValueError):
    """
    Bad geometry input (degenerate size, unreadable file, too many points).

    `key` names the scene key at fault when it is not the file ('spacing', ...).
    """

    def __init__(self, message: str, key: Optional[str] = None):
        """Keep the message and the optional scene key."""
        super().__init__(message)
        self.key = key


# ----------------------------------------------------------------------------------------
# Rotations
# ----------------------------------------------------------------------------------------

def quat_to_matrix(q: Sequence[float]) -> np.ndarray:
    """
    Rotation matrix of a quaternion given as ``(x, y, z, w)`` (the ROS order).

    The quaternion is normalised; a zero quaternion raises GeometryError.
    """
    x, y, z, w = (float(c) for c in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 1e-12:
        raise GeometryError('quaternion has zero length')
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rpy_to_matrix(rpy: Sequence[float]) -> np.ndarray:
    """
    Rotation matrix of roll, pitch, yaw in radians: R = Rz(yaw) Ry(pitch) Rx(roll) (REP 103).
    """
    r, p, y = (float(c) for c in rpy)
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


# ----------------------------------------------------------------------------------------
# Lattices
# ----------------------------------------------------------------------------------------

def _axis(extent: float, spacing: float) -> np.ndarray:
    """Points from -extent/2 to +extent/2 at `spacing`, centred (one point if extent < spacing)."""
    n = int(math.floor(extent / spacing + 1e-6)) + 1
    return (np.arange(n) - (n - 1) / 2.0) * spacing


def _check_count(count: float) -> None:
    if count > MAX_BODY_POINTS:
        raise GeometryError(
            f'would make about {int(count)} particles (limit {MAX_BODY_POINTS}); '
            'increase spacing', key='spacing')


def _grid(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> np.ndarray:
    _check_count(float(len(xs)) * len(ys) * len(zs))
    g = np.stack(np.meshgrid(xs, ys, zs, indexing='ij'), axis=-1)
    return g.reshape(-1, 3).astype(np.float64)


def box_lattice(size: Sequence[float], spacing: float) -> np.ndarray:
    """
    Cubic lattice filling a box of full extents `size` (m), centred on the origin.

    Along each axis there are floor(size / spacing) + 1 points spanning the box symmetrically,
    so `size` = (n - 1) * spacing gives exactly n points reaching the faces.
    """
    return _grid(_axis(size[0], spacing), _axis(size[1], spacing), _axis(size[2], spacing))


def _symmetric_axis(half: float, spacing: float) -> np.ndarray:
    k = int(math.floor(half / spacing + 1e-6))
    return np.arange(-k, k + 1) * spacing


def sphere_lattice(radius: float, spacing: float) -> np.ndarray:
    """Lattice points (a node at the centre) inside a sphere of `radius`; at least the centre."""
    a = _symmetric_axis(radius, spacing)
    _check_count(len(a) ** 3 * math.pi / 6.0)
    g = _grid(a, a, a)
    return g[np.einsum('ij,ij->i', g, g) <= radius * radius * (1 + 1e-9)]


def cylinder_lattice(radius: float, length: float, spacing: float) -> np.ndarray:
    """Lattice points inside a cylinder along the local z axis (`length` end to end)."""
    a = _symmetric_axis(radius, spacing)
    z = _axis(length, spacing)
    _check_count(len(a) ** 2 * len(z) * math.pi / 4.0)
    g = _grid(a, a, z)
    return g[g[:, 0] ** 2 + g[:, 1] ** 2 <= radius * radius * (1 + 1e-9)]


def capsule_lattice(radius: float, length: float, spacing: float) -> np.ndarray:
    """
    Lattice points inside a capsule along local z.

    `length` is the distance between the centres of the two hemispherical caps (0 gives a
    sphere); the capsule's end-to-end length is `length` + 2 `radius`.
    """
    a = _symmetric_axis(radius, spacing)
    z = _axis(length + 2.0 * radius, spacing)
    _check_count(len(a) ** 2 * len(z) * math.pi / 4.0)
    g = _grid(a, a, z)
    zc = np.clip(g[:, 2], -length / 2.0, length / 2.0)
    d2 = g[:, 0] ** 2 + g[:, 1] ** 2 + (g[:, 2] - zc) ** 2
    return g[d2 <= radius * radius * (1 + 1e-9)]


def sheet_lattice(size: Sequence[float], spacing: float) -> np.ndarray:
    """A flat square grid in the local xy plane (z = 0), full extents `size` = (lx, ly)."""
    return _grid(_axis(size[0], spacing), _axis(size[1], spacing), np.zeros(1))


def rope_points(length: float, spacing: float) -> np.ndarray:
    """Points on a line along the local x axis, centred, end to end `length`."""
    x = _axis(length, spacing)
    _check_count(len(x))
    return np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)


# ----------------------------------------------------------------------------------------
# Meshes (arrays only; reading the file is done with trimesh in scene.py)
# ----------------------------------------------------------------------------------------

def _column_windings(vertices: np.ndarray, faces: np.ndarray, xs: np.ndarray,
                     ys: np.ndarray, zs: np.ndarray, chunk_elems: int = 4_000_000
                     ) -> np.ndarray:
    """
    Winding numbers (nx, ny, nz) of lattice points w.r.t. a closed triangle mesh.

    Casts one ray per lattice column straight up (+z), slightly jittered in x and y so it
    misses edges and vertices, and sums the signed crossings (sign of the triangle's n_z)
    above each point: +-1 inside a closed mesh, 0 outside. Vectorised over columns and
    faces in chunks; crossings are few, so their accumulation is cheap.
    """
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = np.abs(area) > 1e-300
    a, b, c, area = a[keep], b[keep], c[keep], area[keep]
    ext = float(np.max(np.ptp(tri.reshape(-1, 3), axis=0))) or 1.0
    jit = ext * np.array([1.2345e-7, 2.7183e-7])
    gx, gy = np.meshgrid(xs + jit[0], ys + jit[1], indexing='ij')
    cols = np.stack([gx.ravel(), gy.ravel()], axis=1)           # (C, 2)
    diff = np.zeros((len(cols), len(zs) + 1))
    step = max(1, chunk_elems // max(1, len(a)))
    for s0 in range(0, len(cols), step):
        px = cols[s0:s0 + step, 0:1]
        py = cols[s0:s0 + step, 1:2]
        wa = (c[:, 0] - b[:, 0]) * (py - b[:, 1]) - (c[:, 1] - b[:, 1]) * (px - b[:, 0])
        wb = (a[:, 0] - c[:, 0]) * (py - c[:, 1]) - (a[:, 1] - c[:, 1]) * (px - c[:, 0])
        wc = (b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (b[:, 1] - a[:, 1]) * (px - a[:, 0])
        sgn = np.sign(area)
        hit = (wa * sgn > 0) & (wb * sgn > 0) & (wc * sgn > 0)
        ci, fi = np.nonzero(hit)
        if len(ci) == 0:
            continue
        zc = (wa[ci, fi] * a[fi, 2] + wb[ci, fi] * b[fi, 2] + wc[ci, fi] * c[fi, 2]) / area[fi]
        # points with z < zc (indices 0 .. k0-1 of the column) get the crossing's sign
        k0 = np.searchsorted(zs, zc, side='left')
        np.add.at(diff, (ci + s0, np.zeros_like(k0)), sgn[fi])
        np.add.at(diff, (ci + s0, k0), -sgn[fi])
    wind = np.cumsum(diff, axis=1)[:, :len(zs)]
    return wind.reshape(len(xs), len(ys), len(zs))


def mesh_lattice(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """
    Lattice points at `spacing` inside a closed triangle mesh (|winding number| > 0.5).

    The lattice is aligned with the mesh's bounding box centre. A mesh thinner than the
    spacing everywhere yields no points; then GeometryError asks for a smaller spacing.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = (lo + hi) / 2.0
    axes = [_symmetric_axis((hi[i] - lo[i]) / 2.0, spacing) + centre[i] for i in range(3)]
    _check_count(float(len(axes[0])) * len(axes[1]) * len(axes[2]) * 0.5)
    inside = np.abs(_column_windings(vertices, faces, *axes)) > 0.5
    pts = _grid(*axes)[inside.ravel()]
    if len(pts) == 0:
        raise GeometryError(
            f'no lattice point at spacing {spacing:g} lies inside the mesh (is it closed?); '
            'decrease spacing or use fill: vertices', key='spacing')
    return pts


# ----------------------------------------------------------------------------------------
# Surfaces that follow the particles
# ----------------------------------------------------------------------------------------

def knn(queries: np.ndarray, points: np.ndarray, k: int,
        chunk_elems: int = 8_000_000) -> Tuple[np.ndarray, np.ndarray]:
    """
    Indices (Q, k) and distances (Q, k) of the k nearest `points` of every query, nearest
    first. Brute force in chunks (no SciPy); meant for precomputation, not per step.
    """
    queries = np.asarray(queries, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    k = min(k, len(points))
    idx = np.empty((len(queries), k), dtype=np.int64)
    dist = np.empty((len(queries), k))
    pn = np.einsum('ij,ij->i', points, points)
    step = max(1, chunk_elems // max(1, len(points)))
    for s in range(0, len(queries), step):
        q = queries[s:s + step]
        d2 = (np.einsum('ij,ij->i', q, q)[:, None] + pn[None, :] - 2.0 * q @ points.T)
        if k < len(points):
            part = np.argpartition(d2, k - 1, axis=1)[:, :k]
        else:
            part = np.broadcast_to(np.arange(len(points)), d2.shape).copy()
        pd = np.take_along_axis(d2, part, axis=1)
        order = np.argsort(pd, axis=1)
        idx[s:s + step] = np.take_along_axis(part, order, axis=1)
        dist[s:s + step] = np.sqrt(np.maximum(np.take_along_axis(pd, order, axis=1), 0.0))
    return idx, dist


class Surface:
    """
    A triangle surface whose vertices follow a body's particles.

    Attributes:
        faces: (F, 3) int32 triangle vertex indices.
        rest_vertices: (V, 3) surface vertices in the rest pose (world frame).

    Call :meth:`vertices` with the body's current positions x (N, 3) to get the deformed
    vertices (vectorised, no loop over vertices). Two kinds:

    - *direct*: the vertices are the particles (a body made of a mesh's vertices);
      ``vertices(x)`` returns ``x``.
    - *embedded*: each vertex is a fixed combination of its k nearest rest particles plus
      a small constant offset, v = sum_j w_j x_j + r with sum_j w_j = 1 exactly. The
      weights are the inverse-distance weights changed as little as possible so that
      sum_j w_j x0_j = v0 (affine reproduction, solved in a least-squares sense), and r is
      what remains (about zero unless the neighbours are coplanar), so the rest pose is
      reproduced exactly, a translation exactly, and rotations and linear deformations of
      the neighbourhood up to |r|. Precomputed once.
    """

    def __init__(self, faces: np.ndarray, rest_vertices: np.ndarray,
                 index: Optional[np.ndarray] = None, weights: Optional[np.ndarray] = None,
                 offset: Optional[np.ndarray] = None):
        """Use :meth:`direct` or :meth:`embedded` rather than this constructor."""
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)
        self.rest_vertices = np.asarray(rest_vertices, dtype=np.float64)
        self.index = index
        self.weights = weights
        self.offset = offset

    @classmethod
    def direct(cls, faces: np.ndarray, rest_points: np.ndarray) -> 'Surface':
        """Surface whose vertices are the particles themselves (faces index particles)."""
        return cls(faces, rest_points)

    @classmethod
    def embedded(cls, faces: np.ndarray, rest_vertices: np.ndarray,
                 rest_points: np.ndarray, k: int = 16) -> 'Surface':
        """Surface embedded in the k nearest particles of each vertex (see class doc)."""
        v0 = np.asarray(rest_vertices, dtype=np.float64)
        x0 = np.asarray(rest_points, dtype=np.float64)
        idx, dist = knn(v0, x0, k)
        k = idx.shape[1]
        # inverse-distance weights (a vertex on a particle takes it almost fully)
        h = max(float(np.median(dist[:, 0])), 1e-12)
        w0 = 1.0 / (dist / h + 1e-3) ** 2
        w0 /= w0.sum(axis=1, keepdims=True)
        w0 = np.maximum(w0, 1e-9)
        # minimise rho |sum_j w_j d_j|^2 + sum_j (w_j - w0_j)^2 / w0_j  s.t.  sum_j w_j = 1,
        # with d_j = (x0_j - v0) / h; KKT system [[rho D^T D + diag(1/w0), 1], [1^T, 0]]
        rho = 1e8
        d = (x0[idx] - v0[:, None, :]) / h                       # (V, k, 3)
        kkt = np.zeros((len(v0), k + 1, k + 1))
        kkt[:, :k, :k] = rho * np.einsum('vid,vjd->vij', d, d)
        kkt[:, np.arange(k), np.arange(k)] += 1.0 / w0
        kkt[:, :k, k] = 1.0
        kkt[:, k, :k] = 1.0
        rhs = np.concatenate([np.ones((len(v0), k)), np.ones((len(v0), 1))], axis=1)
        w = np.linalg.solve(kkt, rhs[..., None])[:, :k, 0]
        w /= w.sum(axis=1, keepdims=True)
        offset = v0 - np.einsum('vk,vkd->vd', w, x0[idx])
        return cls(faces, v0, idx, w, offset)

    def reordered(self, order: np.ndarray) -> 'Surface':
        """The same surface for the particles stored in ``order`` (row i of the new
        positions is particle ``order[i]`` of the old ones, as ``Body.order``): the
        particle indices are remapped, the vertices, weights and offsets kept."""
        order = np.asarray(order, dtype=np.int64)
        inv = np.empty(len(order), dtype=np.int64)
        inv[order] = np.arange(len(order))
        if self.index is None:                  # direct: the vertices are the particles
            return Surface(inv[self.faces], self.rest_vertices[order])
        return Surface(self.faces, self.rest_vertices, inv[self.index], self.weights,
                       self.offset)

    def vertices(self, x: np.ndarray) -> np.ndarray:
        """Deformed surface vertices (V, 3) for current particle positions x (N, 3)."""
        if self.index is None:
            return np.asarray(x)
        return np.einsum('vk,vkd->vd', self.weights, np.asarray(x)[self.index]) + self.offset


# ----------------------------------------------------------------------------------------
# Voxel downsampling
# ----------------------------------------------------------------------------------------

def _voxel_keys(points: np.ndarray, lo: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 key per point naming its voxel (flattened 3-D index, or rows if huge)."""
    ijk = np.floor((points - lo) / voxel).astype(np.int64)
    dims = ijk.max(axis=0) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) < 2.0 ** 62:
        return (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    return np.unique(ijk, axis=0, return_inverse=True)[1].reshape(-1)


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroids of the points in each occupied cubic voxel of edge `voxel` (m)."""
    points = np.asarray(points, dtype=np.float64)
    if voxel <= 0.0 or len(points) == 0:
        return points.copy()
    keys = _voxel_keys(points, points.min(axis=0), voxel)
    _, inv, counts = np.unique(keys, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out = np.stack([np.bincount(inv, weights=points[:, i], minlength=len(counts))
                    for i in range(3)], axis=1)
    return out / counts[:, None]


def _voxel_count(points: np.ndarray, lo: np.ndarray, voxel: float) -> int:
    keys = np.sort(_voxel_keys(points, lo, voxel))
    return int(np.count_nonzero(np.diff(keys))) + 1


def voxel_size_for(points: np.ndarray, max_points: int, tolerance: float = 0.01) -> float:
    """
    A voxel edge whose downsampling leaves at most `max_points` points; 0.0 if the points
    already fit.

    Bisection on a log scale between a voxel that leaves too many points and one that
    leaves few enough, until the two are within `tolerance` (relative) of each other; the
    larger one is returned, so the cap always holds.
    """
    points = np.asarray(points, dtype=np.float64)
    if max_points < 1:
        raise GeometryError(f'max_points must be >= 1, got {max_points}')
    if len(points) <= max_points:
        return 0.0
    lo_pt = points.min(axis=0)
    extent = float(np.max(points.max(axis=0) - lo_pt))
    if extent <= 0.0:
        return 1.0  # all points coincide: any voxel gives one point
    # first guess: the cap's share of the bounding box's volume (or area, or length)
    span = np.sort(points.max(axis=0) - lo_pt)[::-1]
    span = span[span > extent * 1e-6]
    guess = float(np.prod(span) / max_points) ** (1.0 / len(span))
    hi = min(max(guess, extent * 1e-9), extent * 1.001)
    while _voxel_count(points, lo_pt, hi) > max_points:
        hi *= 2.0
    lo = hi
    while True:                               # invariant: count(lo) > max_points
        lo /= 2.0
        if lo < extent * 1e-9:                # only duplicates left: merge them
            return lo
        if _voxel_count(points, lo_pt, lo) > max_points:
            break
        hi = lo
    while hi / lo > 1.0 + tolerance:
        mid = math.sqrt(lo * hi)
        if _voxel_count(points, lo_pt, mid) <= max_points:
            hi = mid
        else:
            lo = mid
    return hi
