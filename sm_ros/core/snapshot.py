"""Save a world's state and put it back bit for bit (the live error estimate's steps).

Each stateful solver class names the attributes a step changes and a later step reads in
its ``step_state()`` (the world, bodies and their set layouts, the flat state, the contact
pass, sleep, the collider pass).  From the world a :class:`Snapshot` follows those names:
an attribute holding an object with ``step_state`` (or a dict or list of them) is
followed, an array is copied by value into one buffer allocated once (again only when the
world's arrays change size), a list's items are kept, anything else (numbers, flags,
tuples, None) keeps its binding.  Derived and scratch arrays, which a step writes before
it reads them, are not named and not saved.  ``load`` writes the values back into the
arrays the attributes hold then, so a re-packing of the bodies since the save
(``packed.Pack``, after a change of a body's grabs or parameters: their attributes become
views of new rows) is undone too (``test/test_snapshot.py`` checks both the continuation
and the names)."""

from collections import deque
from ctypes import memmove
import operator

import numpy as np


def holders(world) -> list:
    """Every object of ``world`` with a ``step_state``, the world first, each once."""
    out, seen, stack = [], set(), [world]
    while stack:
        obj = stack.pop()
        if obj is None or id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, dict):
            stack.extend(reversed(list(obj.values())))
        elif isinstance(obj, (list, tuple)):
            stack.extend(reversed(obj))
        elif hasattr(obj, 'step_state'):
            out.append(obj)
            names = obj.step_state()
            stack.extend(reversed([getattr(obj, n) for n in names]))
    return out


def _followed(value) -> bool:
    """Whether ``value`` is a holder or a container of holders (followed, not saved)."""
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, (list, tuple)):
        return bool(value) and all(hasattr(v, 'step_state') for v in value)
    return hasattr(value, 'step_state')


def _getter(names):
    """A function of an object giving the tuple of its attributes ``names``."""
    return operator.attrgetter(*names, *names[:1]) if names else (lambda obj: ())


def _items(value) -> list:
    """The items of a list or tuple, the values of a dict."""
    return list(value.values()) if isinstance(value, dict) else list(value)


class _Plan:
    """Where each named array of each holder goes in the buffer (the arrays as saved), and
    what the plan is good for: the holders as followed (their objects, containers and
    the attributes that were None) and the arrays as planned."""

    def __init__(self, objs):
        self.objs = objs
        self.arrays, self.others, self.lists = [], [], []   # per holder: names
        self.getters, self.refs, self.offsets = [], [], []
        self.fixed = []                         # per holder: getter, values (identity)
        self.sizes = []                         # (holder, name, items) of the containers
        total = 0
        for obj in objs:
            arr, other, lists, fixed = [], [], [], []
            for name in obj.step_state():
                value = getattr(obj, name)
                if isinstance(value, np.ndarray):
                    arr.append(name)
                elif isinstance(value, list) and not _followed(value):
                    lists.append(name)
                elif not _followed(value):
                    other.append(name)
                    fixed += [name] if value is None else []
                else:
                    fixed.append(name)
                    if isinstance(value, (dict, list, tuple)):
                        self.sizes.append((obj, name, _items(value)))
            get = _getter(arr)
            refs = get(obj)[:len(arr)]
            offs = []
            for a in refs:
                offs.append(total)
                total += -(-a.nbytes // 8) * 8
            self.arrays.append(tuple(arr))
            self.others.append(tuple(other))
            self.lists.append(tuple(lists))
            self.getters.append(get)
            self.refs.append(refs)
            self.offsets.append(offs)
            self.fixed.append((_getter(fixed), _getter(fixed)(obj)))
        self.nbytes = total
        # every array's holder and name in one list each: one check at C speed
        self.flat = ([o for o, names in zip(objs, self.arrays) for _ in names],
                     [n for names in self.arrays for n in names],
                     [a for refs in self.refs for a in refs])
        self.bound = ([o for o, names in zip(objs, self.others) for _ in names],
                      [n for names in self.others for n in names])

    def all_same(self) -> bool:
        """Whether every holder holds the very arrays it held when planned."""
        objs, names, refs = self.flat
        return all(map(operator.is_, map(getattr, objs, names), refs))

    def valid(self) -> bool:
        """Whether the holders hold the objects, containers and arrays planned."""
        return (self.all_same() and self.same_items()
                and all(all(map(operator.is_, get(obj), refs))
                        for obj, (get, refs) in zip(self.objs, self.fixed)))

    def same_items(self) -> bool:
        """Whether the followed dicts and lists (the world's bodies) hold what they held."""
        return all(len(getattr(obj, name)) == len(items)
                   and all(map(operator.is_, _items(getattr(obj, name)), items))
                   for obj, name, items in self.sizes)

    def same_arrays(self, k, obj) -> bool:
        """Whether holder ``k`` holds the very arrays it held when planned."""
        return all(map(operator.is_, self.getters[k](obj), self.refs[k]))

    def moves(self, start: int):
        """(array addresses, buffer addresses, sizes in bytes) of every planned array."""
        src, dst, size = [], [], []
        for refs, offs in zip(self.refs, self.offsets):
            for a, off in zip(refs, offs):
                src.append(a.ctypes.data)
                dst.append(start + off)
                size.append(a.nbytes)
        return src, dst, size


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self.world, self._plan, self._buf = None, None, np.zeros(0, np.uint8)
        self._moves, self._others, self._lists = ([], [], []), [], []

    @property
    def nbytes(self) -> int:
        """Bytes of array state the last save copied."""
        return 0 if self._plan is None else self._plan.nbytes

    def _replan(self, world, objs) -> None:
        plan = _Plan(objs)
        for refs in plan.refs:
            for a in refs:
                if not (a.flags.c_contiguous or a.flags.f_contiguous):
                    raise TypeError('a solver state array is not contiguous')
        if self._buf.nbytes < plan.nbytes:
            self._buf = np.empty(plan.nbytes, dtype=np.uint8)
        self.world, self._plan = world, plan
        self._moves = plan.moves(self._buf.ctypes.data)

    def _view(self, k, j, a) -> np.ndarray:
        """The buffer's copy of array ``j`` of holder ``k`` (saved as ``a``'s shape)."""
        off = self._plan.offsets[k][j]
        order = 'F' if a.flags.f_contiguous and not a.flags.c_contiguous else 'C'
        return self._buf[off:off + a.nbytes].view(a.dtype).reshape(a.shape, order=order)

    def save(self, world) -> None:
        """Copy ``world``'s state into the snapshot."""
        plan = self._plan
        if plan is None or world is not self.world or not plan.valid():
            self._replan(world, holders(world))
            plan = self._plan
        objs = plan.objs
        src, dst, size = self._moves                   # one memmove an array, C speed
        deque(map(memmove, dst, src, size), maxlen=0)
        self._others = list(map(getattr, *plan.bound))
        self._lists = [[list(getattr(obj, n)) for n in names]
                       for obj, names in zip(objs, plan.lists)]

    def load(self, world) -> None:
        """Put the saved state back into ``world`` (the world it was saved from, with the
        same bodies)."""
        plan = self._plan
        if world is not self.world or plan is None:
            raise ValueError('a snapshot loads only into the world it was saved from')
        if not plan.same_items():
            raise ValueError('the world has other bodies than when it was saved')
        objs = plan.objs                    # objects built since (a first step) are let go
        src, dst, size = self._moves
        if plan.all_same():
            deque(map(memmove, src, dst, size), maxlen=0)
        else:
            for k, obj in enumerate(objs):
                self._load_arrays(k, obj, plan.same_arrays(k, obj))
        deque(map(setattr, *plan.bound, self._others), maxlen=0)
        for obj, names, items in zip(objs, plan.lists, self._lists):
            for name, saved in zip(names, items):
                getattr(obj, name)[:] = saved

    def _load_arrays(self, k, obj, same) -> None:
        """Holder ``k``'s arrays back where a step rebound some of them (a new pack's rows,
        a pair list grown): the values into the arrays held now, or the saved arrays'
        copies where the shape changed."""
        plan = self._plan
        for j, (name, ref) in enumerate(zip(plan.arrays[k], plan.refs[k])):
            saved = self._view(k, j, ref)
            now = getattr(obj, name)
            if same or now is ref:
                np.copyto(ref, saved)
            elif (isinstance(now, np.ndarray) and now.shape == ref.shape
                  and now.dtype == ref.dtype):
                np.copyto(now, saved)
            else:
                setattr(obj, name, saved.copy(order='A'))
