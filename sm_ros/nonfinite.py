"""
Which bodies went non-finite: one compiled pass over every body's state per tick (no ROS).

``Simulation.tick`` resets a body whose positions or velocities are no longer finite. Asking
every body (``Body.is_finite``: ``np.isfinite`` on x and on v, four NumPy calls and two
temporary arrays) cost 0.2 ms per tick at 100k particles and a few microseconds per body
(1.5 ms for 384 bodies). :class:`NonFiniteCheck` keeps flat views of every body's x and v
in one typed list, rebuilt only when the bodies change, and
:func:`first_nonfinite` scans them in one call; only a body it flags is looked at again.
"""

from typing import List, Optional, Sequence

import numpy as np
from numba import njit
from numba.typed import List as TypedList

#: The largest finite float64: |a| <= BIG is False exactly for inf and nan.
BIG = float(np.finfo(np.float64).max)


@njit(cache=True, nogil=True)
def first_nonfinite(buffers, start):
    """Index of the first buffer from ``start`` on holding an inf or a nan, or -1.

    No fast math (it may assume finite values). The inner loop is an OR-reduction of
    comparisons without early exit, which the compiler vectorises.
    """
    for k in range(start, len(buffers)):
        a = buffers[k]
        bad = False
        for i in range(a.shape[0]):
            bad |= not (abs(a[i]) <= BIG)
        if bad:
            return k
    return -1


def _flat(a: np.ndarray) -> Optional[np.ndarray]:
    """A 1-D view of every element of a contiguous array (None if it has no such view)."""
    if a.dtype != np.float64 or not a.flags.writeable:
        return None                     # one element type in the typed list
    if a.flags.c_contiguous:
        return a.reshape(-1)
    if a.flags.f_contiguous:
        return a.T.reshape(-1)
    return None


class NonFiniteCheck:
    """The bodies of a world whose state is not finite, in one compiled call per tick."""

    def __init__(self):
        """Nothing cached yet."""
        self._key = None
        self._buffers = None
        self._slow: List[int] = []      # bodies whose buffers have no flat view
        self.rebuilds = 0               # how often the list was rebuilt (tests)

    def _state(self, bodies: Sequence) -> None:
        # the bodies' identities (20 us for 384 bodies; their buffers' too would cost 100):
        # a body's x and v buffers live as long as the body (``Body`` makes them once, and
        # rebuilds, resets and set_state write into them; test_nonfinite_check checks it)
        key = tuple(map(id, bodies))
        if key == self._key:
            return
        buffers = TypedList()
        slow = []
        for k, b in enumerate(bodies):
            fx, fv = _flat(b._x), _flat(b._v)
            if fx is None or fv is None:
                slow.append(k)
                fx = fv = np.zeros(0)
            buffers.append(fx)
            buffers.append(fv)
        # the bodies are held, so that their ids are not reused while cached
        self._key, self._buffers, self._slow, self._held = key, buffers, slow, list(bodies)
        self.rebuilds += 1

    def bad_bodies(self, bodies: Sequence) -> list:
        """Return the bodies of ``bodies`` whose positions or velocities are not finite."""
        if not bodies:
            return []
        self._state(bodies)
        bad = {k for k in self._slow if not bodies[k].is_finite()}
        k = first_nonfinite(self._buffers, 0)
        while k >= 0:
            bad.add(k // 2)
            k = first_nonfinite(self._buffers, 2 * (k // 2) + 2)
        return [bodies[k] for k in sorted(bad)]
