"""
Which bodies went non-finite: one compiled pass over every body's state per tick (no ROS).

``Simulation.tick`` resets a body whose positions or velocities are no longer finite. Asking
every body (``Body.is_finite``: ``np.isfinite`` on x and on v, four NumPy calls and two
temporary arrays) costs a pass over every particle plus a fixed cost per body, which adds
up in scenes of many bodies. :class:`NonFiniteCheck` keeps flat views of every body's x and v
in one typed list, rebuilt only when the bodies change, and
:func:`first_nonfinite` scans them in one call; only a body it flags is looked at again.

Right after a step that ended with the bodies' own integration passes
(``World.state_flagged``: no body-body contact or pass collider moved particles after
them), the pass has already flagged a non-finite state: a body's shape-error sums
(``Body._err``, one number per chunk) are then not finite (``kernels.integrate.advance``).
``bad_bodies(bodies, flagged=True)`` scans those few numbers instead of x and v (reading
every particle would be the tick's largest cost beside the steps), and reads x and v only
of a body they flag (an overflow of finite values is not a non-finite state).
"""

import math
from typing import List, Optional, Sequence

import numpy as np
from numba import njit
from numba.typed import List as TypedList

#: Up to this many flags (all bodies' ``Body._err`` together) are read in Python.
PYTHON_FLAGS_MAX = 32

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
        self._err_key = None
        self._errs = None               # every body's Body._err (list or typed list)
        self.rebuilds = 0               # how often the list was rebuilt (tests)
        self.full_scans = 0             # calls that read x and v (tests, benchmarks)

    def _state(self, bodies: Sequence) -> None:
        # the bodies' identities are enough (comparing their buffers too would cost several times
        # more): a body's x and v buffers live as long as the body (``Body`` makes them once, and
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

    def _flags(self, bodies: Sequence) -> Optional[list]:
        """The indices of the bodies whose shape-error sums are not finite, or None when a
        body has no such sums to read."""
        # a body's _err is made anew when the body is rebuilt (parameters, reset): keyed
        # on the arrays themselves, held here so that their ids stay unique
        errs = [getattr(b, '_err', None) for b in bodies]
        key = tuple(map(id, errs))
        if key != self._err_key:
            for e in errs:
                if not (isinstance(e, np.ndarray) and e.dtype == np.float64 and e.ndim == 1
                        and e.flags.c_contiguous):
                    return None
            size = sum(len(e) for e in errs)
            # a few numbers are read in Python (a compiled call, or Python reading a typed
            # list, costs more); many in one compiled call
            self._errs = errs if size <= PYTHON_FLAGS_MAX else TypedList(errs)
            self._err_key = key
        if isinstance(self._errs, list):
            return [k for k, e in enumerate(self._errs)
                    if not all(map(math.isfinite, e.tolist()))]
        flagged = []
        k = first_nonfinite(self._errs, 0)
        while k >= 0:
            flagged.append(k)
            k = first_nonfinite(self._errs, k + 1)
        return flagged

    def bad_bodies(self, bodies: Sequence, flagged: bool = False) -> list:
        """Return the bodies of ``bodies`` whose positions or velocities are not finite.

        ``flagged``: the bodies were just stepped and nothing wrote their state after
        their integration passes (``World.state_flagged``): read the flags those passes
        left instead of every x and v.
        """
        if not bodies:
            return []
        if flagged:
            ks = self._flags(bodies)
            if ks is not None:
                return [bodies[k] for k in ks if not bodies[k].is_finite()]
        self.full_scans += 1
        self._state(bodies)
        bad = {k for k in self._slow if not bodies[k].is_finite()}
        k = first_nonfinite(self._buffers, 0)
        while k >= 0:
            bad.add(k // 2)
            k = first_nonfinite(self._buffers, 2 * (k // 2) + 2)
        return [bodies[k] for k in sorted(bad)]
