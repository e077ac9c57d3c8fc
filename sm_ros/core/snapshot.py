"""Save a world's state and put it back bit for bit (the live error estimate's steps).

``sm_ros.error_estimate`` steps the running world itself from another state at another
step size, then puts it back as it was.  A :class:`Snapshot` holds, in arrays it allocates
once and reuses, everything a step of the world reads or writes: the attribute bindings of
the world and of the solver objects it holds (bodies, packs, the contact pass, the flat
state, sleep, colliders: every object of an ``sm_ros.core`` class reachable from the
world), the contents of the lists and dicts among them, and the bytes of every writeable
array they hold (an array viewing a larger block is saved as that block, once).  Nothing
is named: the snapshot reads objects' ``__dict__``, so it follows the solver's storage as
that changes.  ``load`` rebinds every attribute to the object it held at ``save`` (a step
at another size that re-packed bodies or rebuilt records leaves its objects behind) and
writes the saved bytes back, so the world then steps exactly as if it had never been
touched (``test/test_snapshot.py``).

The walk that finds the holders and arrays is kept and checked by identity at the next
``save`` (the same objects bound: its lists reused); it is walked again when the world's
make changed (bodies added, buffers grown).
"""

import operator

import numpy as np

#: Values that are immutable: their binding is all there is to save.
_PLAIN = (type(None), bool, int, float, complex, str, bytes, np.generic, frozenset, type)


def _is_solver(obj) -> bool:
    return (type(obj).__module__ or '').startswith('sm_ros.core') and hasattr(obj, '__dict__')


def _block(a: np.ndarray) -> np.ndarray:
    """The writeable array owning ``a``'s memory (``a`` where that one is read-only)."""
    base = a
    while isinstance(base.base, np.ndarray):
        base = base.base
    return base if base.flags.writeable else a


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self._holders = []      # solver objects whose attribute bindings are saved
        self._dicts = []        # their saved ``__dict__`` (shallow copies)
        self._lists = []        # the lists among their attributes
        self._maps = []         # the dicts among them
        self._saved_lists = []  # the lists' and dicts' saved items
        self._saved_maps = []
        self._blocks = []       # the writeable arrays' memory blocks
        self._bufs = []         # their saved bytes, one buffer each (allocated once)
        self.world = None       # the world saved last

    def _walk(self, world) -> None:
        """Find the holders, containers and memory blocks of ``world``."""
        holders, lists, maps, blocks, seen = [], [], [], {}, set()
        stack = [world]
        while stack:
            obj = stack.pop()
            if id(obj) in seen or isinstance(obj, _PLAIN):
                continue
            seen.add(id(obj))
            if isinstance(obj, np.ndarray):
                if obj.flags.writeable:
                    base = _block(obj)
                    blocks[id(base)] = base
            elif isinstance(obj, (list, tuple)):
                if isinstance(obj, list):
                    lists.append(obj)
                stack.extend(obj)
            elif isinstance(obj, dict):
                maps.append(obj)
                stack.extend(obj.values())
            elif _is_solver(obj):
                holders.append(obj)
                stack.extend(vars(obj).values())
        old = {id(b): buf for b, buf in zip(self._blocks, self._bufs)}
        self._holders, self._lists, self._maps = holders, lists, maps
        # per holder: how many attributes, and a getter of those bound to objects (not
        # plain values, which change at every step): the walk holds while they are the same
        self._keys = []
        for obj in holders:
            keys = [k for k, v in vars(obj).items() if not isinstance(v, _PLAIN)]
            get = operator.itemgetter(*keys) if len(keys) > 1 else (
                (lambda d, k=keys[0]: (d[k],)) if keys else (lambda d: ()))
            self._keys.append((len(vars(obj)), get, get(vars(obj))))
        self._items = [(list(c), c) for c in lists] + [(list(c.values()), c) for c in maps]
        self._blocks = list(blocks.values())
        self._bufs = [old[id(b)] if id(b) in old and old[id(b)].shape == b.shape
                      and old[id(b)].dtype == b.dtype else np.empty_like(b)
                      for b in self._blocks]

    def _same_make(self, world) -> bool:
        """Whether the last walk still covers ``world``: its holders bound to the same
        objects, its lists and dicts holding the same ones (compared by identity)."""
        if world is not self.world:
            return False
        for obj, (count, get, refs) in zip(self._holders, self._keys):
            state = vars(obj)
            if len(state) != count or not all(map(operator.is_, get(state), refs)):
                return False
        for items, c in self._items:
            now = c.values() if isinstance(c, dict) else c
            if len(c) != len(items) or not all(map(operator.is_, now, items)):
                return False
        return True

    def save(self, world) -> None:
        """Copy ``world``'s state into the snapshot's arrays."""
        if not self._same_make(world):
            self._walk(world)
            self.world = world
        self._dicts = [dict(vars(o)) for o in self._holders]
        self._saved_lists = [list(c) for c in self._lists]
        self._saved_maps = [dict(c) for c in self._maps]
        for buf, block in zip(self._bufs, self._blocks):
            np.copyto(buf, block)

    def load(self, world) -> None:
        """Put the saved state back into ``world`` (the world it was saved from)."""
        if world is not self.world:
            raise ValueError('a snapshot loads only into the world it was saved from')
        for obj, saved in zip(self._holders, self._dicts):
            state = vars(obj)
            state.clear()
            state.update(saved)
        for c, saved in zip(self._lists, self._saved_lists):
            c[:] = saved
        for c, saved in zip(self._maps, self._saved_maps):
            c.clear()
            c.update(saved)
        for buf, block in zip(self._bufs, self._blocks):
            np.copyto(block, buf)
