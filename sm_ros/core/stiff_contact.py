"""Stiff bodies take their contacts as rigid bodies (doc/contact.md).

Before the bodies' own step, every stiff body (``is_stiff``), and under gravity every body
stiff enough to carry its contacts as a whole (``takes_part``), takes its contacts with
the colliders and with the other bodies of the pass as one rigid body (``kernels/stiff_solve.py``
solves the contacts that ``kernels/stiff_contacts.py`` and ``kernels/stiff_pairs.py``
find): an impulse at a contact point changes the body's velocity and spin, so contact
tips, rolls, holds and spins it; restitution acts on the approach speed at the point, and
overlap is removed without adding speed.  A stiff body meets colliders with its outline:
its particles' lattice cells (``lattice_axes``), one sphere (``is_round``) or its
particles' spheres; another body with its particles' spheres, and only while it is near
another body of the pass (alone, its own step dents it against them).  Those contacts are
then left out of the per-particle contact pass, which softer bodies keep.
"""

import numpy as np
from numba import njit, types
from numba.typed import List as TypedList

from .colliders import ColliderSet
from .kinematic import C_E, C_MU, C_POS, ROW
from . import tuning
from .quaternion import quat_matrix
from .kernels import JIT
from .kernels.stiff_solve import StiffBodies, StiffScene, stiff_step

def _directions() -> np.ndarray:
    """The 26 lattice directions and 100 spread over the sphere (a Fibonacci spiral)."""
    grid = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * 3, indexing='ij'), -1).reshape(-1, 3)
    grid = grid[np.abs(grid).sum(axis=1) > 0]
    k = np.arange(100) + 0.5
    z, phi = 1.0 - 2.0 * k / 100, np.pi * (3.0 - np.sqrt(5.0)) * k
    ring = np.sqrt(1.0 - z * z)
    spiral = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], -1)
    dirs = np.concatenate([grid, spiral])
    return dirs / np.linalg.norm(dirs, axis=1)[:, None]


DIRECTIONS = _directions()


def is_round(rest, radius: float) -> bool:
    """Whether rest positions (N, 3) about their mass centre fill a ball to within one
    particle ``radius``: along every direction the body reaches to within ``radius`` of
    its farthest particle, so its outline is the sphere through that particle's and such
    a body meets colliders as that sphere (it rolls as a ball, not a polyhedron)."""
    rest = np.asarray(rest, dtype=float)
    reach = float(np.sqrt((rest * rest).sum(axis=1).max()))
    return all(float((rest @ u).max()) >= reach - radius for u in DIRECTIONS)


def lattice_axes(rest, samples: int = 64):
    """The unit axes (3, 3, as columns) of the cubic lattice that rest positions (N, 3)
    lie on, or None: every sampled particle's nearest neighbours are one spacing away
    (within 5 %) along them, as in a body built from a box, a lattice or a voxelised
    mesh; a scanned cloud or a ball's jittered points have none."""
    rest = np.asarray(rest, dtype=float)
    if len(rest) < 8:
        return None
    offsets, nearest = [], []
    for i in np.unique(np.linspace(0, len(rest) - 1, samples).astype(np.int64)):
        apart = rest - rest[i]
        dist = np.sqrt((apart * apart).sum(axis=1))
        dist[i] = np.inf
        nearest.append(dist.min())
        offsets.append(apart[dist < 1.05 * dist.min()])
    spacing = float(np.median(nearest))
    if not (min(nearest) > 0.0 and np.isfinite(spacing)):   # coincident or not finite
        return None
    flat = np.concatenate(offsets) / spacing
    first = flat[0] / np.linalg.norm(flat[0])
    across = flat[np.abs(flat @ first) < 0.1 * np.linalg.norm(flat, axis=1)]
    if not len(across):
        return None
    second = across[0] - (across[0] @ first) * first
    second /= np.linalg.norm(second)
    axes = np.stack([first, second, np.cross(first, second)], axis=1)
    on_axis = np.abs(flat @ axes).max(axis=1) > 0.99 * np.linalg.norm(flat, axis=1)
    even = np.abs(np.asarray(nearest) / spacing - 1.0) < 0.05
    return axes if on_axis.all() and even.all() else None


def is_stiff(body, h) -> bool:
    """Whether ``body`` takes its contacts as a rigid body at steps of ``h`` s: the rigid
    share of its goal, alpha (1 - beta) (alpha in rigid mode) at the step, at least
    ``tuning.STIFF_SHARE``, at most ``tuning.STIFF_CLUSTERS`` cluster cubes per axis, no
    pinned or grabbed particle."""
    prm = body._params
    p = prm.at_step(h)
    share = p.alpha if prm.mode == 'rigid' else p.alpha * (1.0 - p.beta)
    return (share >= tuning.STIFF_SHARE and prm.clusters <= tuning.STIFF_CLUSTERS
            and len(body._kin_idx) == 0)


def takes_part(body, h, gravity: bool) -> bool:
    """Whether ``body`` takes its contacts in the stiff pass at steps of ``h`` s: a stiff
    one (``is_stiff``), and under ``gravity`` one stiff enough to carry its contacts as a
    whole (alpha at the step at least ``tuning.COUPLE_ALPHA``, no pinned or grabbed
    particle), so that the loads resting on it and those it rests on are solved together;
    either takes a contact's impulse as a rigid body (velocity and spin)."""
    return is_stiff(body, h) or (gravity and len(body._kin_idx) == 0
                                 and body._params.at_step(h).alpha >= tuning.COUPLE_ALPHA)


#: The types of a body's arrays in the pass: (N, 3) positions and velocities of any layout
#: (a body of one particle is C- and F-contiguous at once) and read-only masses, so that
#: every caller shares one compiled pass.
_BLOCK = types.Array(types.float64, 2, 'A')
_MASSES = types.Array(types.float64, 1, 'C', readonly=True)


def lying_on_another(touches, count: int):
    """(count,) bool: the bodies that the stiff pass's body pairs in contact
    (``stiff_contacts.touches``, rows a, b, which lies above) show lying on another; None
    without any."""
    if not len(touches):
        return None
    lying = np.zeros(count, dtype=np.bool_)
    lying[touches[touches[:, 2] > 0, 0]] = True
    lying[touches[touches[:, 2] < 0, 1]] = True
    return lying


@njit(**JIT)
def _empty_lists():
    return (TypedList.empty_list(_BLOCK), TypedList.empty_list(_BLOCK),
            TypedList.empty_list(_MASSES))


@njit(**JIT)
def _append(lists, x, v, m):
    lists[0].append(x)
    lists[1].append(v)
    lists[2].append(m)


def body_lists(xs, vs, ms):
    """The typed lists of the bodies' positions, velocities and masses that
    ``stiff_solve.StiffBodies`` holds (made and filled by cached compiled functions:
    Numba keeps no disk cache for a typed list's own methods, which would compile again in
    every process)."""
    lists = _empty_lists()
    for x, v, m in zip(xs, vs, ms):
        _append(lists, x, v, m)
    return lists


class StiffContact:
    """The pass of one world: its static collider rows and its bodies' typed lists."""

    def __init__(self):
        self._static_key = None
        self._static = np.zeros((0, ROW))
        self._lists_key = None
        self._lists = None
        self._round = {}     # id of a body: (its rest shape, radius, round, lattice axes)
        self.keys = np.zeros(0, dtype=np.int64)      # the last step's contacts (sorted)
        self.impulses = np.zeros((0, 3))            # and their impulses

    def __getstate__(self):
        """Copies (pickle, deepcopy) leave out the typed lists; they are made again."""
        state = dict(self.__dict__)
        state['_lists'] = state['_lists_key'] = None
        state['_round'] = {}
        return state

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): the last step's
        contacts and impulses, which warm-start the next."""
        return ('keys', 'impulses')

    def forget(self):
        """A step in which nothing could touch: no contacts to warm-start the next."""
        if len(self.keys):
            self.keys = np.zeros(0, dtype=np.int64)
            self.impulses = np.zeros((0, 3))

    def _rows(self, world):
        """Row 0 the ground, then the plain boxes and spheres, then the collider set's
        rows at this step's poses; and how many of them are plain."""
        key = (id(world.boxes), id(world.spheres))
        if key != self._static_key:
            simple = [c for c in tuple(world.boxes) + tuple(world.spheres) if c.simple]
            self._static = (ColliderSet(simple).rows.copy() if simple
                            else np.zeros((0, ROW)))
            self._static_key = key
        ground = np.zeros((1, ROW))
        if world.ground is not None:
            g = world._ground_row
            ground[0, C_POS + 2], ground[0, C_MU], ground[0, C_E] = g[1], g[2], g[3]
        cset = world._cset
        moving = cset.rows if cset is not None else np.zeros((0, ROW))
        return np.concatenate([ground, self._static, moving]), len(self._static)

    def _bodies(self, world, bodies, stiff):
        """``StiffBodies`` of (body, radius) pairs, ``stiff`` whether each is stiff.  What
        does not change from step to step (the typed lists, radii, collide flags, outlines)
        is kept while the world passes the same list (``World._stiff_members``: the same
        bodies and settings; a body's arrays, rest shape included, are its own for its
        lifetime)."""
        if self._lists_key is not bodies:
            self._lists = self._body_constants(world, bodies, stiff)
            self._lists_key = bodies
        lists, radius, collide, ball, (boxy, rest) = self._lists
        awake = np.fromiter((not b.asleep for b, _ in bodies), dtype=np.bool_,
                            count=len(bodies))
        cells = np.zeros((len(bodies), 3, 3))
        if len(boxy):      # the lattice axes turned as the body's shape match turns them
            wxyz = np.array([bodies[k][0]._quat[0] for k in boxy])
            cells[boxy] = quat_matrix(wxyz[:, [1, 2, 3, 0]]) @ rest
        return StiffBodies(*lists, radius, awake, collide, stiff, ball, cells)

    def _body_constants(self, world, bodies, stiff):
        """(typed lists, radii, collide flags, round flags, (the bodies on a lattice, their
        cells' half edges at rest)) of the pass's bodies.  A body not ``stiff`` deforms too
        much for an outline of its rest shape: it meets everything with its particles'
        spheres."""
        lists = body_lists([b._x for b, _ in bodies], [b._v for b, _ in bodies],
                           [b._m for b, _ in bodies])
        ids = {id(b) for b, _ in bodies}           # forget the bodies that left the pass
        self._round = {k: v for k, v in self._round.items() if k in ids}
        radius = np.array([r for _, r in bodies])
        on = world._contact_params.enabled
        collide = np.array([on and world._contacts[b.name][0].collide for b, _ in bodies],
                           dtype=np.bool_)
        shapes = [self._outline(b, r) if hard else (False, None)
                  for (b, r), hard in zip(bodies, stiff)]
        ball = np.array([round_ for round_, _ in shapes], dtype=np.bool_)
        boxy = np.array([k for k, (_, axes) in enumerate(shapes) if axes is not None],
                        dtype=np.int64)
        rest = np.array([shapes[k][1] * radius[k] for k in boxy]).reshape(-1, 3, 3)
        return lists, radius, collide, ball, (boxy, rest)

    def _outline(self, body, radius):
        """(``is_round``, ``lattice_axes`` unless round) of a body, kept while it keeps
        its rest shape and radius."""
        rest, known = body._x0, self._round.get(id(body))
        if known is None or known[0] is not rest or known[1] != radius:
            ball = is_round(rest, radius)
            known = (rest, radius, ball, None if ball else lattice_axes(rest))
            self._round[id(body)] = known
        return known[2], known[3]

    def run(self, world, bodies, stiff, h, thresh):
        """The pass over ``bodies`` ((body, contact radius) pairs; ``stiff`` whether each
        is stiff, ``is_stiff``) before a step of ``h`` s; returns (B, 5) per body: its
        particles touching the plain colliders and the others, its body-pair contacts, its
        deepest overlap (m), and 1 where its velocities changed, 2 where its positions did
        too, 3 where a hit woke it; and the body pairs that touch (``stiff_contacts.touches``,
        indices into ``bodies``)."""
        rows, plain = self._rows(world)
        p = world._contact_params
        scene = StiffScene(rows, plain, world.ground is not None, float(p.friction),
                           float(p.restitution), world._gravity, float(h), float(thresh),
                           tuning.STIFF_SWEEPS, tuning.WAKE_FACTOR * float(p.sleep_speed),
                           tuning.TOUCH_FACTOR)
        tally = np.zeros((len(rows) - 1, 6))
        stats = np.zeros((len(bodies), 5))
        self.keys, self.impulses, touches = stiff_step(
            self._bodies(world, bodies, stiff), scene, (self.keys, self.impulses), tally, stats)
        for k in np.flatnonzero(stats[:, 4]):
            bodies[k][0]._dirty = True
            if stats[k, 4] == 3:
                bodies[k][0].wake()
        cset = world._cset
        if cset is not None and len(self.keys):
            cset.imp[:] += tally[plain:]
        return stats, touches
