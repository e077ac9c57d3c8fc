"""World-level flat (structure-of-arrays) state for the passes that span bodies.

Contact between bodies (``contact.py``) and kinematic colliders work on every particle of
the world at once, so they read one set of arrays instead of one per body:

* ``X``, ``V`` (3, N) float64, C-contiguous: positions and velocities; body ``b`` holds
  columns ``off[b]:off[b + 1]``;
* ``M`` (N,) the particles' masses (``Body.m``);
* ``W`` (N,) inverse mass, 0 for pinned and grabbed (kinematic) particles and for the
  particles of sleeping bodies (infinite mass; ``sleep.py``); ``awake_W`` the same without the
  sleeping bodies (what a body gets back when it wakes);
* ``B`` (N,) int32 body index of each particle; ``R`` (N,) contact radius (metres);
* ``X0`` (3, N) rest positions (``Body.x_init``), for the self-collision rest-distance test.

Until the World owns these arrays itself (the fused world step), ``World.step`` runs the
bodies' own steps, then ``gather`` copies every body's ``_x``/``_v`` (stored per component,
so ``_x.T`` is a (3, n) C-contiguous block: one contiguous copy a row) into ``X``/``V``, the
world-level passes move particles and mark the bodies they touched in ``touched``, and
``scatter`` copies only those bodies back and flags them ``_dirty`` (their per-cluster sums,
fused into the integration pass, must be recomputed from the moved positions).  Both
copies are one compiled call each and allocate nothing; ``bench contact`` prints their
cost.  When the World owns ``X``/``V``, ``gather``/``scatter`` become no-ops and only the
``_dirty`` flags remain.
"""

import operator

import numpy as np
from numba import njit
from numba.typed import List

from . import packed
from .body_build import _GENERATION
from .kernels import JIT
from .kernels.flags import SLEEP


@njit(**JIT)
def gather_state(xs, vs, off, X, V, flags):
    """X[:, off[b]:off[b + 1]] = xs[b] (and V from vs) for every body b that is not
    asleep (``flags[b][3]`` > 0: its flat state is already its own, ``sleep.py``).

    ``xs[b]``, ``vs[b]`` are the bodies' (3, n) blocks (``Body._x.T``): each row is a
    unit-stride copy, written as a slice assignment (a vectorised copy loop, faster than
    an element loop).
    """
    for b in range(len(xs)):
        if flags[b][3] > 0.0:
            continue
        x = xs[b]
        v = vs[b]
        o = off[b]
        n = x.shape[1]
        for j in range(3):
            X[j, o:o + n] = x[j]
            V[j, o:o + n] = v[j]


@njit(**JIT)
def scatter_state(xs, vs, off, X, V, touched, flags):
    """xs[b] = X[:, off[b]:off[b + 1]] (and vs from V) for the bodies with ``touched[b]``;
    their ``flags[b][0]`` (``Body._flags``: dirty) set to 1."""
    for b in range(len(xs)):
        if not touched[b]:
            continue
        flags[b][0] = 1.0
        x = xs[b]
        v = vs[b]
        o = off[b]
        n = x.shape[1]
        for j in range(3):
            x[j] = X[j, o:o + n]
            v[j] = V[j, o:o + n]


class FlatState:
    """The flat arrays of a list of bodies (rebuilt when bodies are added or removed)."""

    def __init__(self, bodies):
        self.bodies = list(bodies)
        nb = len(self.bodies)
        counts = np.array([b.n for b in self.bodies], dtype=np.int64)
        self.off = np.zeros(nb + 1, dtype=np.int64)
        np.cumsum(counts, out=self.off[1:])
        n = int(self.off[-1])
        self.n = n
        self.X = np.zeros((3, n))
        self.V = np.zeros((3, n))
        self.W = np.zeros(n)
        self.awake_W = np.zeros(n)
        self.M = np.zeros(n)                 # masses (``Body.m``), for the contact pass's sums
        self.B = np.repeat(np.arange(nb, dtype=np.int32), counts)
        self.R = np.zeros(n)
        self.X0 = np.zeros((3, n))
        self.touched = np.zeros(max(nb, 1), dtype=np.uint8)
        self._blocks()
        for k, b in enumerate(self.bodies):
            self.X0[:, self.off[k]:self.off[k + 1]] = b._x_init.T
        self._kin_seen = [None] * nb
        self._mass_gen = None
        self.w_version = 0
        self._flags_seen = None
        self._flag_list = None
        self._packs_seen = None
        self.refresh_masses()

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): the flat positions
        and velocities (a sleeping body's are not gathered again) and inverse masses."""
        return ('X', 'V', 'W', 'w_version')

    def __getstate__(self):
        state = self.__dict__.copy()           # the typed lists do not pickle: rebuilt
        del state['_x_blocks'], state['_v_blocks'], state['_flag_list']
        state['_flags_seen'] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._mass_gen = None                # a copy's bodies: refresh once
        self._flag_list = None
        self._flags_seen = None
        self._blocks()

    def _blocks(self):
        """The typed lists of the bodies' (3, n) position and velocity blocks (``Body``
        stores x and v per component)."""
        self._x_blocks, self._v_blocks = List(), List()
        for b in self.bodies:
            self._x_blocks.append(b._x.T)
            self._v_blocks.append(b._v.T)

    def refresh_masses(self):
        """W from the bodies' masses; 0 for pinned/grabbed particles (cheap if unchanged).

        A body's masses are fixed (read-only) and its pinned and grabbed particles
        (``_kin_idx``) change only with a new body generation (``body_build.
        merge_kinematic``), so nothing is read while the generation is the one of the last
        refresh (the loop over the bodies is not free in a scene of hundreds of bodies).
        """
        gen = _GENERATION[0]
        if gen == self._mass_gen:
            return
        for k, b in enumerate(self.bodies):
            kin = b._kin_idx
            if kin is self._kin_seen[k]:
                continue
            o0, o1 = self.off[k], self.off[k + 1]
            self.awake_W[o0:o1] = 1.0 / b._m
            self.M[o0:o1] = b._m
            if len(kin):
                self.awake_W[o0 + kin] = 0.0
            if not b._flags[SLEEP] > 0.0:        # a sleeping body keeps W = 0 (sleep.py)
                self.W[o0:o1] = self.awake_W[o0:o1]
            self.w_version += 1              # W changed (Contact keeps body masses of it)
            self._kin_seen[k] = kin
        self._mass_gen = gen

    def gather(self):
        """Copy every awake body's positions and velocities into X, V (a sleeping body's
        are there already: nothing moves it); clear ``touched``."""
        self.refresh_masses()
        gather_state(self._x_blocks, self._v_blocks, self.off, self.X, self.V, self.flag_list())
        self.touched[:] = 0

    def flag_list(self):
        """The bodies' flag arrays (``Body._flags``) as a typed list for the kernels."""
        # a packed body's flag array is a view of its pack's row, replaced when a pack is
        # built (``packed.PACKS_BUILT``): only then are the arrays compared with the list's
        if self._flag_list is not None and self._packs_seen == packed.PACKS_BUILT[0]:
            return self._flag_list
        self._packs_seen = packed.PACKS_BUILT[0]
        flags = [b._flags for b in self.bodies]
        seen = self._flags_seen
        if seen is None or any(map(operator.is_not, flags, seen)):
            self._flag_list = List(flags)
            self._flags_seen = flags
        return self._flag_list

    def scatter(self):
        """Copy the touched bodies back and flag them for a fresh accumulation."""
        if not self.touched.any():
            return
        scatter_state(self._x_blocks, self._v_blocks, self.off, self.X, self.V, self.touched,
                      self.flag_list())
