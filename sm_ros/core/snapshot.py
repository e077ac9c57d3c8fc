"""Save a world's state and put it back bit for bit (the live error estimate's steps).

A :class:`Snapshot` holds what a step of the world reads or writes: the attribute bindings
of the world and of every ``sm_ros.core`` object reachable from it (bodies, packs, contact,
flat state, sleep, colliders), the items of the lists and dicts among them, and the bytes
of every writeable array they hold (a view is saved as the block it views), in buffers
allocated once.  Nothing is named: it reads ``__dict__``, so it follows the solver's
storage as that changes.  ``load`` rebinds every attribute to what it held at ``save`` (a
step at another size re-packs bodies and rebuilds records) and writes the bytes back: the
world then steps as if never touched (``test/test_snapshot.py``).  The walk is kept while
the same objects stay bound (checked by identity at each ``save``).
"""

import operator

import numpy as np

#: Immutable values: their binding is all there is to save.
_PLAIN = (type(None), bool, int, float, complex, str, bytes, np.generic, frozenset, type)


def _nothing(state) -> tuple:
    return ()


def _block(a: np.ndarray) -> np.ndarray:
    """The writeable array owning ``a``'s memory (``a`` where that one is read-only)."""
    base = a
    while isinstance(base.base, np.ndarray):
        base = base.base
    return base if base.flags.writeable else a


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self.world = None
        self._holders, self._keys, self._conts, self._blocks, self._bufs = [], [], [], [], []
        self._dicts, self._items = [], []

    def _walk(self, world) -> None:
        """Find the solver objects, lists, dicts and memory blocks of ``world``."""
        holders, conts, blocks, seen, stack = [], [], {}, set(), [world]
        while stack:
            obj = stack.pop()
            if id(obj) in seen or isinstance(obj, _PLAIN):
                continue
            seen.add(id(obj))
            if isinstance(obj, np.ndarray):
                if obj.flags.writeable:
                    base = _block(obj)
                    blocks[id(base)] = base
            elif isinstance(obj, (list, tuple, dict)):
                conts += [obj] if isinstance(obj, (list, dict)) else []
                stack.extend(obj.values() if isinstance(obj, dict) else obj)
            elif (type(obj).__module__ or '').startswith('sm_ros.core') \
                    and hasattr(obj, '__dict__'):
                holders.append(obj)
                stack.extend(vars(obj).values())
        old = {id(b): buf for b, buf in zip(self._blocks, self._bufs)}
        self.world, self._holders, self._conts = world, holders, conts
        self._keys = []                 # per holder: its size, a getter of its objects
        for obj in holders:
            keys = [k for k, v in vars(obj).items() if not isinstance(v, _PLAIN)]
            # a tuple for one key too, and for none
            get = operator.itemgetter(*keys, *keys[:1]) if keys else _nothing
            self._keys.append((len(vars(obj)), get, get(vars(obj))))
        self._blocks = list(blocks.values())
        self._bufs = [old[id(b)] if id(b) in old and old[id(b)].shape == b.shape
                      and old[id(b)].dtype == b.dtype else np.empty_like(b)
                      for b in self._blocks]

    @staticmethod
    def _values(cont):
        return list(cont.values()) if isinstance(cont, dict) else list(cont)

    def _same_make(self, world) -> bool:
        """Whether the walk still covers ``world``: the same objects bound and held."""
        if world is not self.world:
            return False
        for obj, (count, get, refs) in zip(self._holders, self._keys):
            state = vars(obj)
            if len(state) != count or not all(map(operator.is_, get(state), refs)):
                return False
        return all(len(c) == len(saved) and all(map(operator.is_, self._values(c),
                                                     self._values(saved)))
                   for c, saved in zip(self._conts, self._items))

    def save(self, world) -> None:
        """Copy ``world``'s state into the snapshot."""
        if not self._same_make(world):
            self._walk(world)
        self._dicts = [dict(vars(o)) for o in self._holders]
        self._items = [c.copy() for c in self._conts]
        for buf, block in zip(self._bufs, self._blocks):
            np.copyto(buf, block)

    def load(self, world) -> None:
        """Put the saved state back into ``world`` (the world it was saved from)."""
        if world is not self.world:
            raise ValueError('a snapshot loads only into the world it was saved from')
        for obj, saved in zip(self._holders, self._dicts):
            vars(obj).clear()
            vars(obj).update(saved)
        for c, saved in zip(self._conts, self._items):
            if isinstance(c, dict):
                c.clear()
                c.update(saved)
            else:
                c[:] = saved
        for buf, block in zip(self._bufs, self._blocks):
            np.copyto(block, buf)
