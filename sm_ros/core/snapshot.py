"""Save a world's state and put it back bit for bit (the live error estimate's steps).

A :class:`Snapshot` keeps the attribute bindings of the world and of every ``sm_ros.core``
object reachable from it, the items of their lists and dicts, and the bytes of every
writeable array they hold (in buffers allocated once).  Nothing is named, so it follows the
solver's storage as that changes; ``load`` rebinds what a step at another size re-packed
and writes the bytes back (``test/test_snapshot.py``).  The walk is reused while the same
objects stay bound."""

from collections import deque
from ctypes import memmove
import operator

import numpy as np

#: Immutable values: their binding is all there is to save.
_PLAIN = (type(None), bool, int, float, complex, str, bytes, np.generic, frozenset, type)


def _values(cont) -> list:
    return list(cont.values()) if isinstance(cont, dict) else list(cont)


def _block(a: np.ndarray) -> np.ndarray:
    """The writeable array owning ``a``'s memory (``a`` where that one is read-only)."""
    base = a.base if isinstance(a.base, np.ndarray) else a      # NumPy: the owner
    return base if base.flags.writeable else a


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self.world, self._buf, self._addr = None, np.zeros(0, np.uint8), ([], [], [])
        self._holders, self._keys, self._conts, self._blocks, self._dicts, self._items = (
            [], [], [], [], [], [])

    def _walk(self, world) -> None:
        """Find the solver objects, lists, dicts and memory blocks of ``world``."""
        holders, conts, blocks, seen, stack = [], [], {}, set(), [world]
        while stack:
            obj = stack.pop()
            if id(obj) in seen or isinstance(obj, _PLAIN):
                continue
            seen.add(id(obj))
            if isinstance(obj, np.ndarray):
                blocks.update({id(_block(obj)): _block(obj)} if obj.flags.writeable else {})
            elif isinstance(obj, (list, tuple, dict)):
                conts += [obj] if isinstance(obj, (list, dict)) else []
                stack.extend(obj.values() if isinstance(obj, dict) else obj)
            elif (type(obj).__module__ or '').startswith('sm_ros.core') \
                    and hasattr(obj, '__dict__'):
                holders.append(obj)
                stack.extend(vars(obj).values())
        self.world, self._holders, self._conts = world, holders, conts
        self._keys = []                 # per holder: its size, a getter of its objects
        for obj in holders:
            keys = [k for k, v in vars(obj).items() if not isinstance(v, _PLAIN)]
            # a tuple for one key too, and for none
            get = operator.itemgetter(*keys, *keys[:1]) if keys else (lambda state: ())
            self._keys.append((len(vars(obj)), get, get(vars(obj))))
        flat = list(blocks.values())            # saved in one buffer, copied by address
        if not all(b.flags.c_contiguous or b.flags.f_contiguous for b in flat):
            raise TypeError('a solver array owns memory it does not hold contiguously')
        sizes = [b.nbytes for b in flat]
        if self._buf.nbytes != sum(sizes):
            self._buf = np.empty(sum(sizes), dtype=np.uint8)
        start = self._buf.ctypes.data
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int).tolist()
        self._blocks = flat                     # held: their addresses are used
        self._addr = ([b.ctypes.data for b in flat], [start + o for o in offsets], sizes)

    def _same_make(self, world) -> bool:
        """Whether the walk still covers ``world``: the same objects bound and held."""
        if world is not self.world:
            return False
        for obj, (count, get, refs) in zip(self._holders, self._keys):
            state = vars(obj)
            if len(state) != count or not all(map(operator.is_, get(state), refs)):
                return False
        return all(len(c) == len(saved) and all(map(operator.is_, _values(c),
                                                     _values(saved)))
                   for c, saved in zip(self._conts, self._items))

    def save(self, world) -> None:
        """Copy ``world``'s state into the snapshot."""
        if not self._same_make(world):
            self._walk(world)
        self._dicts = [dict(vars(o)) for o in self._holders]
        self._items = [c.copy() for c in self._conts]
        blocks, bufs, sizes = self._addr                # one memmove a block, C speed
        deque(map(memmove, bufs, blocks, sizes), maxlen=0)

    def load(self, world) -> None:
        """Put the saved state back into ``world`` (the world it was saved from)."""
        if world is not self.world:
            raise ValueError('a snapshot loads only into the world it was saved from')
        for obj, saved in zip(self._holders, self._dicts):
            vars(obj).clear()
            vars(obj).update(saved)
        for c, saved in zip(self._conts, self._items):
            c.clear()
            c.update(saved) if isinstance(c, dict) else c.extend(saved)
        blocks, bufs, sizes = self._addr
        deque(map(memmove, blocks, bufs, sizes), maxlen=0)
