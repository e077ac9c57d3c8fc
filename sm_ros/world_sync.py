"""Copy one world's state into another of the same make, in place (no ROS, no allocation).

The live error estimate (``sm_ros.error_estimate``) steps two copies of the running world.
A deep copy of the 384-body paper scene took 0.2 s, and each copy's first step another
0.14 s to re-pack its bodies' buffers and rebuild its compiled-step records (a copy drops
them: ``Body.__getstate__``, ``World.__getstate__``): the node's tick that made a copy took
that long.  :func:`sync_world` instead writes the state of a world into a copy made of it
earlier, which keeps its own packed buffers, records and pair lists: every array is copied
into its counterpart (an array viewing a larger block, a body's ``_arena`` or a pack, copies
that block once), plain values are assigned, what a copy drops (``__getstate__`` leaves it
out: a body's packed block, typed lists of its buffers) stays the copy's own, and what a
copy replaces (``World._split``, the compiled-step records, is None in a copy: rebuilt at
the next step, for its step size) is replaced alike unless the copy's was built for the
same key (bodies, step size) as the source's; what a class lists in ``SYNC_OWN``
(``FlatState``'s flag list, checked against the copy's own bodies) stays the copy's own too.
The copy steps afterwards exactly as a fresh deep copy would, bit for bit
(``test/test_world_sync.py``), and its first step costs what any step does: it keeps its
flag list and the contact coupling flags (``World._contact_coupling`` is keyed by the
count of flat states built, which a copy carries, not by the flat state's id).

:class:`Twin` walks both worlds once and replays the walk's plan (``_Plan``) at later
syncs with a few Python calls per container, the work per place at C speed: on
``paper_384`` (384 bodies,
55,680 particles) it checks the lengths of 5,114 containers and 71,002 places among the
84,030 values of 2,894 of them by identity (lists and dict values read at C speed), assigns
about 6,700 plain values in 676 dict updates and copies 12,548 arrays, 54.6 MB (mostly the
contact pass's buffers), in one compiled call
(``copy_blocks``: a ``memcpy`` each, by address, the plan holding the arrays).  A replay
took 25-28 ms with a ``np.copyto`` and an identity check per place, the copy's first step
1.5-2 ms more than a step (its flag list and coupling flags rebuilt); now 17 ms, about half
of it the copy of 54.6 MB, and a step.  The walk takes 100-150 ms and the first replay
after it about 50 ms (the copies' addresses; doc/benchmarks.md, "The estimate's copies
reused").

It refuses (returns False, and the caller makes a fresh copy) whenever the two differ in
make: another set of bodies or of attributes, an array of another shape, dtype or place in
its block, a read-only array (masses, rest shape) with other values, an object it does not
know how to write into.  A refused sync may have written part of the copy: the copy must
then be dropped.
"""

import dataclasses
import enum
import itertools
import operator
import types

import numpy as np
from numba import njit, types as nbtypes
from numba.core import cgutils
from numba.extending import intrinsic

from sm_ros.core.kernels.jit import JIT

#: Types whose values are immutable: assigned, never copied into.
_LEAVES = (type(None), bool, int, float, complex, str, bytes, np.generic, range, slice,
           types.FunctionType, types.BuiltinFunctionType, type, enum.Enum)


#: Types assigned at once (the common plain values).
_PLAIN = frozenset((type(None), bool, int, float, str, np.float64, np.int64, np.bool_))


class _Mismatch(Exception):
    """The two worlds are not of the same make."""


def sync_world(dst, src) -> bool:
    """Write ``src``'s state into ``dst`` (a deep copy of ``src`` made earlier, or a world
    synced from it) in place; return True, or False when they are not of the same make
    (``dst`` is then partly written and must be dropped).  :class:`Twin` keeps the walk's
    plan between calls."""
    return Twin(dst).sync(src)


class Twin:
    """A world kept as a copy of another: :meth:`sync` writes the other's state into it.

    The first sync walks both worlds (``_Walk``) and records a plan (``_Plan``): the
    objects found at every place of the source and the copy (to be found there again),
    the plain values to assign and the memory blocks to copy.  Later syncs from the same
    source check the plan's places by identity (a body rebuilt, a buffer grown, an
    attribute added: the plan is dropped and both are walked again), then assign and copy
    (``_Plan.replay``).
    """

    def __init__(self, world):
        """Wrap ``world`` (made by a deep copy of the worlds it will be synced from)."""
        self.world = world
        #: why the last sync was refused (where the makes differ), else None
        self.refused = None
        self._plan = None
        self._source = None

    def sync(self, src) -> bool:
        """Write ``src``'s state into the twin; False when not of the same make (the twin
        is then partly written and must be dropped)."""
        self.refused = None
        if type(self.world) is not type(src):
            self.refused = f'{type(src).__name__}, not a {type(self.world).__name__}'
            return False
        if self._source is src and self._plan is not None and self._plan.replay():
            return True
        walk = _Walk()
        try:
            walk.obj(self.world, src)
        except _Mismatch as e:
            self._plan = self._source = None
            self.refused = str(e)
            return False
        self._plan = _Plan(walk) if walk.cacheable else None
        self._source = src
        return True


def _getter(keys):
    """``operator.itemgetter`` of ``keys`` that returns a tuple for one key too."""
    return operator.itemgetter(*keys) if len(keys) > 1 else operator.itemgetter(*keys, *keys)


class _Plan:
    """What a walk found, replayed in bulk (Python cost per place, not per call).

    * places: the containers (dicts, lists) the walk went through, on both sides, with
      their lengths and (dicts) their keys in order; the places among their values that
      the walk went into (``_pick``: positions in all the containers' values one after
      another) and what they held after the walk (``_held``);
    * sets: per container, the keys of plain values (``_LEAVES``) to assign; a place of a
      ``_PLAIN`` value must hold one again (one type check each), a place of another
      leaf (parameters: a frozen dataclass, a tuple of leaves) the same object or a leaf
      again;
    * copies: pairs of C- or F-contiguous arrays of one layout, copied by addresses in
      one compiled call (``copy_blocks``; the plan holds the arrays, so the memory stays
      theirs and cannot be resized under it), the others by ``np.copyto`` (empty ones
      not at all);
    * caches: as the walk met them (``_cache``).
    """

    #: copy the contiguous blocks in one compiled call (False: ``np.copyto`` each, the
    #: replay the compiled one is tested against)
    compiled = True

    def __init__(self, walk):
        self._total = 0
        conts, pos, held = [], [], []
        for c, keys in walk.places.values():
            at = {k: i for i, k in enumerate(c)} if isinstance(c, dict) else None
            for k in keys:
                pos.append(self._total + (k if at is None else at[k]))
                held.append(c[k])
            conts.append(c)
            self._total += len(c)
        self._values = [c.values() if isinstance(c, dict) else c for c in conts]
        self._keys_of = [c.keys() for c in conts if isinstance(c, dict)]
        self._keys = list(itertools.chain.from_iterable(self._keys_of))
        self._pick = _getter(pos) if pos else (lambda values: ())
        self._held = tuple(held * 2 if len(pos) == 1 else held)
        self._len_of = [c for c, _ in walk.lens] + conts
        self._lens = list(map(len, self._len_of))
        self._sets = [(dc, isinstance(dc, dict), keys if len(keys) > 1 else keys * 2,
                       _getter(keys), sc)
                      for dc, sc, keys in ((dc, sc, tuple(ks))
                                           for dc, sc, ks in walk.sets.values())]
        seen = [v for _, _, _, g, sc in self._sets for v in g(sc)]
        plain = [i for i, v in enumerate(seen) if type(v) in _PLAIN]
        other = [i for i, v in enumerate(seen) if type(v) not in _PLAIN]
        self._plain = _getter(plain) if plain else None
        self._other = _getter(other) if other else None
        self._other_seen = self._other(seen) if other else ()
        self._copies = walk.copies
        self._blocks = None                  # made at the first replay (``_split_copies``)
        self._caches = walk.caches
        self._keep = walk.keep

    def _split_copies(self):
        """The copies as blocks of bytes (addresses, sizes) and the others; made at the
        first replay, not by the walk (~25 ms for ``paper_384``: the tick of the walk is
        the longer one)."""
        blocks, self._slow = [], []
        for d, s in self._copies:
            if s.size:                       # nothing to copy in an empty array
                (blocks if _flat_bytes(d, s) else self._slow).append((d, s))
        self._dst = np.array([d.ctypes.data for d, _ in blocks], dtype=np.int64)
        self._src = np.array([s.ctypes.data for _, s in blocks], dtype=np.int64)
        self._nbytes = np.array([s.nbytes for _, s in blocks], dtype=np.int64)
        self._blocks = blocks                # held: the addresses stay theirs

    def replay(self) -> bool:
        """Check the places, then assign and copy; False (nothing written) when a place
        holds another object or a container another length, or a plain place another
        kind of value."""
        # the containers' lengths, their keys in order, then all their values (a list or
        # a dict's values read at C speed), those at the places the walk went into
        # compared by identity
        if list(map(len, self._len_of)) != self._lens \
                or list(itertools.chain.from_iterable(self._keys_of)) != self._keys \
                or not all(map(operator.is_, self._pick(
                    list(itertools.chain.from_iterable(self._values))), self._held)):
            return False
        try:
            vals = [g(sc) for _, _, _, g, sc in self._sets]
        except (KeyError, IndexError):       # a container of plain values only, renamed
            return False
        flat = list(itertools.chain.from_iterable(vals))
        # places of plain values must hold plain values (a type check each); the others
        # (parameters, leaf tuples) the values of plan time, else leaves again
        if self._plain is not None and not set(map(type, self._plain(flat))) <= _PLAIN:
            return False
        if self._other is not None:
            now = self._other(flat)
            if not all(map(operator.is_, now, self._other_seen)) and not all(
                    v is w or _leaf(v) for v, w in zip(now, self._other_seen)):
                return False
        for (dc, is_dict, keys, _, _), v in zip(self._sets, vals):
            if is_dict:
                dc.update(zip(keys, v))
            else:
                for k, x in zip(keys, v):
                    dc[k] = x
        if self._blocks is None:
            self._split_copies()
        if self.compiled:
            copy_blocks(self._dst, self._src, self._nbytes)
        else:
            for d, s in self._blocks:
                np.copyto(d, s)
        for d, s in self._slow:
            np.copyto(d, s)
        for dd, k, sd, w in self._caches:
            _cache(dd, k, sd, w)
        return True


def _flat_bytes(d, s) -> bool:
    """Whether ``s`` may be copied into ``d`` as one run of bytes: both C- or both
    F-contiguous (the same layout: the walk checked shapes, dtypes and strides)."""
    return d.size > 0 and ((d.flags.c_contiguous and s.flags.c_contiguous)
                           or (d.flags.f_contiguous and s.flags.f_contiguous))


@intrinsic
def _memcpy(typingctx, dst, src, nbytes):
    """``memcpy`` of ``nbytes`` bytes from address ``src`` to address ``dst`` (int64)."""
    def codegen(context, builder, signature, args):
        d = builder.inttoptr(args[0], cgutils.voidptr_t)
        s = builder.inttoptr(args[1], cgutils.voidptr_t)
        cgutils.raw_memcpy(builder, d, s, args[2], 1)
        return context.get_dummy_value()
    i64 = nbtypes.int64
    return nbtypes.void(i64, i64, i64), codegen


@njit(**JIT)
def copy_blocks(dst, src, nbytes):
    """Copy ``nbytes[i]`` bytes from address ``src[i]`` to ``dst[i]``, in order, for every
    i: the plan's contiguous arrays (``np.copyto`` of each, twin in the tests), one
    ``memcpy`` each (about 20 ns a block against ~0.5 us a ``np.copyto`` call from Python;
    the large ones run at memory speed)."""
    for i in range(len(nbytes)):
        _memcpy(dst[i], src[i], nbytes[i])


def _cache(dd, k, sd, w):
    """A cache a copy replaces by ``w`` (``World._split`` by None: rebuilt at the next
    step): kept when it is held as (key, ...) with the source's key (built for the same
    bodies and step size), else replaced like a copy's."""
    mine, theirs = dd.get(k), sd.get(k)
    if not (type(mine) is tuple and type(theirs) is tuple and mine and theirs
            and mine[0] == theirs[0]):
        dd[k] = w


def _root(a: np.ndarray):
    """The array that owns the memory ``a`` views (``a`` itself when it owns it)."""
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


class _Walk:
    def __init__(self):
        self.memo = {}               # id(src object) -> its counterpart in dst
        self.keep = []               # keep the src objects alive (ids stay unique)
        self.blocks = {}             # id(src memory block) -> dst's block, once copied
        self.places = {}             # id(container) -> (container, {key walked into: None})
        self.lens = []               # (container, length)
        self.sets = {}               # (id(dst), id(src) container) -> (dst, src, {key: None}):
        #                              plain values to assign
        self.copies = []             # (dst array, src array): memory to copy
        self.caches = []             # (dst dict, key, src dict, what a copy holds)
        self.cacheable = True

    def item(self, dc, sc, k, dv, sv):
        """The value at place ``k`` of the containers ``sc`` (src) and ``dc`` (dst)."""
        if type(sv) in _PLAIN or (type(sv) is not np.ndarray and _leaf(sv)):
            if type(dc) is not tuple:
                g = self.sets.get((id(dc), id(sc)))
                if g is None:
                    g = self.sets[(id(dc), id(sc))] = (dc, sc, {})
                g[2][k] = None
            return sv
        if type(dc) is not tuple:
            self.place(sc, k)
            self.place(dc, k)
        return self.value(dv, sv)

    def place(self, c, k):
        """Check place ``k`` of container ``c`` (what it holds after the walk) at replay."""
        g = self.places.get(id(c))
        if g is None:
            g = self.places[id(c)] = (c, {})
        g[1][k] = None

    def value(self, d, s):
        """Write ``s`` into ``d``; return what ``d``'s owner must hold afterwards."""
        seen = self.memo.get(id(s))
        if seen is not None:
            return seen
        if type(d) is not type(s):
            raise _Mismatch(type(s).__name__)
        self.memo[id(s)] = d
        self.keep.append(s)
        if type(s) is np.ndarray:
            self.array(d, s)
        elif isinstance(s, dict):
            if d.keys() != s.keys():
                raise _Mismatch('dict keys')
            self.lens += ((s, len(s)), (d, len(d)))
            for k, v in s.items():
                try:
                    d[k] = self.item(d, s, k, d[k], v)
                except _Mismatch as e:   # say where (only on the way out)
                    raise _Mismatch(f'[{k!r}]: {e}') from None
        elif isinstance(s, list):
            if len(d) != len(s):
                raise _Mismatch('list length')
            self.lens += ((s, len(s)), (d, len(d)))
            for i, v in enumerate(s):
                try:
                    d[i] = self.item(d, s, i, d[i], v)
                except _Mismatch as e:
                    raise _Mismatch(f'[{i}]: {e}') from None
        elif isinstance(s, tuple):
            if len(d) != len(s):
                raise _Mismatch('tuple length')
            out = tuple(self.item(d, s, i, a, b) for i, (a, b) in enumerate(zip(d, s)))
            if any(a is not b for a, b in zip(out, d)):
                del self.memo[id(s)]     # a new tuple: the owner takes it (walked each time)
                self.cacheable = False
                return out
        elif hasattr(s, '__dict__') and not isinstance(s, (types.ModuleType,
                                                           types.MethodType)):
            self.obj(d, s)
        else:
            raise _Mismatch(type(s).__name__)
        return d

    def obj(self, d, s):
        """Write the attributes of ``s`` a copy would carry into ``d``'s."""
        self.memo[id(s)] = d
        self.keep.append(s)
        sd, dd = s.__dict__, d.__dict__
        get = getattr(s, '__getstate__', None)
        state = get() if get is not None else sd
        if state is None and not sd:
            return
        if not isinstance(state, dict):
            raise _Mismatch('state')
        self.lens.append((sd, len(sd)))
        own = getattr(type(s), 'SYNC_OWN', ())
        for k, v in sd.items():
            if k not in state or k in own:
                continue                 # a copy drops it, or d keeps its own
            if state[k] is not v:        # a copy holds another value (None: rebuilt)
                w = state[k]
                if not _leaf(w):
                    raise _Mismatch(f'{type(s).__name__}.{k}: copied as an object')
                self.caches.append((dd, k, sd, w))
                _cache(dd, k, sd, w)
                continue
            if k not in dd:
                raise _Mismatch(f'{type(s).__name__}.{k}: missing')
            try:
                dd[k] = self.item(dd, sd, k, dd[k], v)
            except _Mismatch as e:
                raise _Mismatch(f'{type(s).__name__}.{k}: {e}') from None

    def array(self, d, s):
        if d.shape != s.shape or d.dtype != s.dtype or s.dtype.hasobject \
                or (d.strides != s.strides and s.size > 1):
            raise _Mismatch('array')
        if not s.flags.writeable or not d.flags.writeable:
            if not np.array_equal(d, s):
                raise _Mismatch('read-only values')
            return
        sr, dr = _root(s), _root(d)
        # a view of a larger block (a body's arena, a pack's rows): the block is copied
        # once, whole, when the first view met sits at the same place in both blocks up to
        # one shift (an arena aligns its start); later views of it must view d's block
        # too (same shapes throughout: the blocks were laid out alike)
        done = self.blocks.get(id(sr))
        if done is not None:
            if done is not dr:
                raise _Mismatch('views of another block')
            return
        if not (sr.nbytes == dr.nbytes and sr.flags.c_contiguous and dr.flags.c_contiguous
                and sr.flags.writeable and dr.flags.writeable):
            self.copy(d, s)
            return
        self.blocks[id(sr)] = dr
        self.keep.append(sr)
        if sr is s:
            self.copy(d, s)
            return
        shift = (_address(d) - _address(dr)) - (_address(s) - _address(sr))
        if shift == 0 and sr.shape == dr.shape and sr.dtype == dr.dtype:
            self.copy(dr, sr)
            return
        n = sr.nbytes
        sb, db = sr.reshape(-1).view(np.uint8), dr.reshape(-1).view(np.uint8)
        lo, hi = max(0, -shift), min(n, n - shift)
        self.copy(db[lo + shift:hi + shift], sb[lo:hi])

    def copy(self, d, s):
        np.copyto(d, s)
        self.copies.append((d, s))


def _address(a: np.ndarray) -> int:
    return a.__array_interface__['data'][0]


def _frozen(s) -> bool:
    """A frozen dataclass of immutable values (parameters): shared, like a number."""
    return (dataclasses.is_dataclass(s) and not isinstance(s, type)
            and s.__dataclass_params__.frozen
            and all(_leaf(getattr(s, f.name)) for f in dataclasses.fields(s)))


def _leaf(v) -> bool:
    if isinstance(v, tuple):
        return all(_leaf(x) for x in v)
    return isinstance(v, _LEAVES) or _frozen(v)
