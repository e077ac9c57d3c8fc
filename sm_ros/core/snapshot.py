"""Save a world's state and put it back bit for bit (the live error estimate's steps).

Each stateful solver class names, in its ``step_state()``, the attributes a step changes
and a later step reads.  A :class:`Snapshot` follows those names from the world: an object
with ``step_state`` (or a dict, list or tuple of them) is followed, an array is copied by
value into a buffer kept from save to save, a plain list's items are kept, and anything
else (numbers, flags, None) keeps its binding.  Scratch and derived arrays, which a step
writes before it reads them, are not named and not saved.  ``load`` writes the values into
the arrays the attributes hold then, so a re-packing of the bodies since the save (their
attributes become views of new rows) is undone too."""

import operator

import numpy as np

_ARRAY, _LIST, _BOUND, _FOLLOWED = range(4)


def _is_holder(value) -> bool:
    return hasattr(value, 'step_state')


def _items(value) -> list:
    """The items of a list or tuple, the values of a dict."""
    return list(value.values()) if isinstance(value, dict) else list(value)


def _followed(value) -> bool:
    """Whether ``value`` is a holder or a container of holders (followed, not saved)."""
    if isinstance(value, (dict, list, tuple)):
        items = _items(value)
        return bool(items) and all(map(_is_holder, items))
    return _is_holder(value)


def named_state(world):
    """(holder, name, value) of every name in the ``step_state`` of every object reached
    from ``world`` (the world first, each object once)."""
    seen, stack = set(), [world]
    while stack:
        obj = stack.pop()
        if obj is None or id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, (dict, list, tuple)):
            stack.extend(reversed(_items(obj)))
        elif _is_holder(obj):
            named = [(obj, name, getattr(obj, name)) for name in obj.step_state()]
            yield from named
            stack.extend(reversed([value for _, _, value in named]))


def _same_items(value, items) -> bool:
    now = _items(value)
    return len(now) == len(items) and all(map(operator.is_, now, items))


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self.world = None
        self._entries = []               # (holder, name, kind, what was saved)
        self._buffers = []               # the saved arrays, reused by the next save

    def save(self, world) -> None:
        """Copy ``world``'s state into the snapshot."""
        entries, buffers, spare = [], [], iter(self._buffers)
        for obj, name, value in named_state(world):
            if isinstance(value, np.ndarray):
                saved = next(spare, None)
                if saved is None or saved.shape != value.shape or saved.dtype != value.dtype:
                    saved = np.empty_like(value)
                np.copyto(saved, value)
                buffers.append(saved)
                entries.append((obj, name, _ARRAY, saved))
            elif _followed(value):
                items = _items(value) if isinstance(value, (dict, list, tuple)) else None
                entries.append((obj, name, _FOLLOWED, items))
            elif isinstance(value, list):
                entries.append((obj, name, _LIST, list(value)))
            else:
                entries.append((obj, name, _BOUND, value))
        self.world, self._entries, self._buffers = world, entries, buffers

    @property
    def nbytes(self) -> int:
        """Bytes of array state the last save copied."""
        return sum(saved.nbytes for saved in self._buffers)

    def load(self, world) -> None:
        """Put the saved state back into ``world`` (the world it was saved from, with the
        same bodies)."""
        if world is not self.world:
            raise ValueError('a snapshot loads only into the world it was saved from')
        for obj, name, kind, items in self._entries:
            if kind == _FOLLOWED and items is not None and not _same_items(
                    getattr(obj, name), items):
                raise ValueError('the world has other bodies than when it was saved')
        for obj, name, kind, saved in self._entries:
            if kind == _ARRAY:
                now = getattr(obj, name)
                if (isinstance(now, np.ndarray) and now.shape == saved.shape
                        and now.dtype == saved.dtype):
                    np.copyto(now, saved)
                else:
                    setattr(obj, name, saved.copy())
            elif kind == _LIST:
                getattr(obj, name)[:] = saved
            elif kind == _BOUND:
                setattr(obj, name, saved)
