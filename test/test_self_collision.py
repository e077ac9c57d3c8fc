"""Self-collision of one body: the bundled ``sheet_rod`` scene.

A 31 x 11 particle sheet (spacing 2 cm) drops flat onto a horizontal rod (a capsule along
y) and folds over it: its halves swing down on both sides, meet below the rod and would
swing on through each other.  With ``self_collision: true`` no particle of one half ever
crosses the other half; with it off most of them do (the test can fail).

"Crossing" is the sign of the distance to the other half's local surface: for a particle p
of one half, q is the nearest particle of the other half and n that half's surface normal
at q (the cross product of the sheet's two lattice directions there, the same face for both
halves at rest: after the fold the halves face each other with the -n side).  p has crossed
when it lies on the +n side of that surface, d = (p - q) . n > 0, while within one spacing
of q along the surface (so the patch around q is what p is compared with, not the region
past the other half's edge).  Only particles at least ``FAR`` lattice steps from the fold
line count: around the rod the two halves are one continuous sheet.
"""

import numpy as np
import pytest

from sm_ros.core.contact import BodyContact
from sm_ros.scene import build_world, load_scene

H = 1 / 120                    # the node's default step (dt)
FAR = 5                        # lattice steps from the fold line: past the rod's wrap


def _scene(self_collision, clusters=None):
    world, _ = build_world(load_scene('sheet_rod'))
    world.set_body_contact('sheet', BodyContact(self_collision=self_collision))
    if clusters is not None:
        world.body('sheet').set_params(clusters=clusters)
    return world, world.body('sheet')


def _lattice(x0, s):
    """(nx, ny) and the (nx, ny) particle-index grid of the rest sheet."""
    ij = np.rint((x0[:, :2] - x0[:, :2].min(axis=0)) / s).astype(int)
    nx, ny = ij.max(axis=0) + 1
    grid = np.full((nx, ny), -1)
    grid[ij[:, 0], ij[:, 1]] = np.arange(len(x0))
    assert (grid >= 0).all() and nx % 2 == 1
    return nx, ny, grid


def _normals(x, grid):
    """(nx, ny, 3) unit normals of the sheet: (d/di) x (d/dj) by central differences
    (one-sided at the edges); the rest sheet's +z face."""
    p = x[grid]
    du = np.gradient(p, axis=0)
    dv = np.gradient(p, axis=1)
    n = np.cross(du, dv)
    return n / np.linalg.norm(n, axis=2, keepdims=True)


def crossings(x, grid, s):
    """Indices of the far particles of each half that lie across the other half's surface."""
    nx = grid.shape[0]
    mid = nx // 2
    n = _normals(x, grid)
    halves = (grid[:mid - FAR + 1], grid[mid + FAR:])      # columns i <= mid-FAR, >= mid+FAR
    normals = (n[:mid - FAR + 1], n[mid + FAR:])
    out = []
    for a, b in ((0, 1), (1, 0)):
        p = x[halves[a].reshape(-1)]
        q = x[halves[b].reshape(-1)]
        nq = normals[b].reshape(-1, 3)
        d = p[:, None, :] - q[None, :, :]
        k = np.einsum('ijk,ijk->ij', d, d).argmin(axis=1)
        dk = p - q[k]
        along = np.einsum('ij,ij->i', dk, nq[k])
        tangential = np.linalg.norm(dk - along[:, None] * nq[k], axis=1)
        out.append(halves[a].reshape(-1)[(along > 0.0) & (tangential < s)])
    return np.concatenate(out)


def _far_gap(x, grid):
    """Smallest distance between a far particle of one half and one of the other."""
    mid = grid.shape[0] // 2
    a = x[grid[:mid - FAR + 1].reshape(-1)]
    b = x[grid[mid + FAR:].reshape(-1)]
    d = a[:, None, :] - b[None, :, :]
    return float(np.sqrt(np.einsum('ijk,ijk->ij', d, d).min()))


def test_crossings_sees_a_particle_pushed_through_the_other_half():
    # the measure itself: a folded sheet (halves 3 cm apart, facing each other) has none;
    # one particle moved 1 cm past the other half has crossed (the bump it makes in its own
    # half may put a few of the other half's particles across it too), 1 cm short has not
    s = 0.02
    ii, jj = np.meshgrid(np.arange(21), np.arange(5), indexing='ij')
    arc = (ii - 10) * s
    x = np.stack([np.where(arc < 0, -0.015, 0.015), jj * s, -np.abs(arc)], -1).reshape(-1, 3)
    x0 = np.stack([arc, jj * s, 0 * arc], -1).reshape(-1, 3)
    _, _, grid = _lattice(x0, s)
    assert len(crossings(x, grid, s)) == 0
    far_left = grid[2, 2]
    x[far_left, 0] = 0.005
    assert len(crossings(x, grid, s)) == 0
    x[far_left, 0] = 0.025
    assert far_left in crossings(x, grid, s)


def _drop(self_collision, steps=240, clusters=None):
    world, sheet = _scene(self_collision, clusters)
    s = 0.02
    nx, ny, grid = _lattice(sheet.x, s)
    rod = world.collider('rod')
    top = rod.center[2] + rod.radius
    fold = grid[nx // 2]
    crossed, gap, lowest_fold = 0, np.inf, np.inf
    for _ in range(steps):
        world.step(H)
        x = sheet.x
        crossed = max(crossed, len(crossings(x, grid, s)))
        gap = min(gap, _far_gap(x, grid))
        lowest_fold = min(lowest_fold, x[fold, 2].min())
    return world, sheet, grid, top, dict(crossed=crossed, gap=gap, fold=lowest_fold)


@pytest.mark.parametrize('clusters', [None, 8])       # the scene's 30 per axis, and 8
def test_sheet_folds_over_the_rod_without_crossing_itself(clusters):
    world, sheet, grid, top, r = _drop(True, clusters=clusters)
    s = 0.02
    dist = 2 * world.contact_radius('sheet')          # the contact distance, 1 spacing
    assert r['crossed'] == 0
    # the halves met (they came within 1.1 contact distances) but never closer than 0.9
    assert 0.9 * dist < r['gap'] < 1.1 * dist
    # it folded over the rod and stays there: the fold line rests on the rod's top
    # (particles are points for the colliders) and both free edges hang far below it
    assert r['fold'] > top - 0.5 * s
    x = sheet.x
    ends = x[grid[0]], x[grid[-1]]
    assert all(e[:, 2].max() < top - 0.2 for e in ends)
    assert np.all(np.isfinite(x)) and np.abs(sheet.v).max() < 5.0


def test_without_self_collision_the_halves_swing_through_each_other():
    _, _, grid, _, r = _drop(False, steps=60)
    mid = grid.shape[0] // 2
    far = 2 * (mid - FAR + 1) * grid.shape[1]
    assert r['crossed'] > far // 2                       # the test above can fail
    assert r['gap'] < 0.2 * 0.02
