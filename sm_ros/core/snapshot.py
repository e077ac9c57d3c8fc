"""Save a world's state and put it back bit for bit (the live error estimate's steps).

Each stateful solver class names, in ``step_state()``, what a step changes and a later step
reads; scratch a step writes before it reads is not named. A :class:`Snapshot` follows those
names from the world: holders of ``step_state`` (alone or as a dict's, list's or tuple's
items) are followed, arrays are copied into buffers kept from save to save, a plain list
keeps its items and anything else its binding. ``load`` writes into the arrays the
attributes hold then, so a re-packing of the bodies since the save is undone too."""

import operator

import numpy as np


def _holders(value):
    """The objects with ``step_state`` that ``value`` is or holds, or None."""
    if hasattr(value, 'step_state'):
        return [value]
    if isinstance(value, (dict, list, tuple)):
        items = list(value.values()) if isinstance(value, dict) else list(value)
        if items and all(hasattr(item, 'step_state') for item in items):
            return items
    return None


def named_state(world):
    """(holder, name, value) of every name in the ``step_state`` of every holder reached
    from ``world`` (the world first, each holder once)."""
    seen, stack = set(), [world]
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        named = [(obj, name, getattr(obj, name)) for name in obj.step_state()]
        yield from named
        for _, _, value in reversed(named):
            stack.extend(reversed(_holders(value) or []))


class Snapshot:
    """A world's state: ``save(world)`` copies it in, ``load(world)`` puts it back."""

    def __init__(self):
        self.world = None
        self._entries = []               # (holder, name, kind, what was saved)
        self._buffers = []               # the saved arrays, reused by the next save

    @property
    def nbytes(self) -> int:
        """Bytes of array state the last save copied."""
        return sum(saved.nbytes for saved in self._buffers)

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
                entries.append((obj, name, 'array', saved))
            elif (held := _holders(value)) is not None:  # followed; a container's items stay
                entries.append((obj, name, 'held', None if held[0] is value else held))
            else:
                entries.append((obj, name, 'list' if isinstance(value, list) else 'bound',
                                list(value) if isinstance(value, list) else value))
        self.world, self._entries, self._buffers = world, entries, buffers

    def load(self, world) -> None:
        """Put the saved state back into ``world``, the world it was saved from, with the
        same bodies."""
        if world is not self.world:
            raise ValueError('a snapshot loads only into the world it was saved from')
        for obj, name, kind, saved in self._entries:
            if kind == 'held' and saved is not None:
                held = _holders(getattr(obj, name)) or []
                if len(held) != len(saved) or any(map(operator.is_not, held, saved)):
                    raise ValueError('the world has other bodies than when it was saved')
        for obj, name, kind, saved in self._entries:
            now = getattr(obj, name)
            if kind == 'array' and (isinstance(now, np.ndarray) and now.shape == saved.shape
                                    and now.dtype == saved.dtype):
                np.copyto(now, saved)
            elif kind == 'array':
                setattr(obj, name, saved.copy())
            elif kind == 'list':
                now[:] = saved
            elif kind == 'bound':
                setattr(obj, name, saved)
