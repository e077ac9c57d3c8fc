"""The box of particles' displacements since a reference state, and the spread it gives.

The contact pass rebuilds its pair list once the displacements since the last build no
longer fit in a ball of radius skin / 2 (``contact_build.moved_spread2``).  Here in
the kernel package so that an edit to them recompiles every caller (``jit.py``: the
package's cache stamp).
"""

import numpy as np
from numba import njit

from .jit import JIT, U


@njit(inline='always', **JIT)
def moved_box(X, Xref, o, e, dlo, dhi):
    """dlo, dhi (3,): widened to hold the displacements X - Xref of particles o..e; returns
    0.0, or NaN when one is not finite (min/max reductions over unit-stride rows)."""
    lo0, lo1, lo2 = dlo[0], dlo[1], dlo[2]
    hi0, hi1, hi2 = dhi[0], dhi[1], dhi[2]
    nan = 0.0
    for i in range(U(o), U(e)):
        dx = X[0, i] - Xref[0, i]
        dy = X[1, i] - Xref[1, i]
        dz = X[2, i] - Xref[2, i]
        nan += 0.0 * (dx + dy + dz)
        lo0 = min(lo0, dx)
        hi0 = max(hi0, dx)
        lo1 = min(lo1, dy)
        hi1 = max(hi1, dy)
        lo2 = min(lo2, dz)
        hi2 = max(hi2, dz)
    dlo[0], dlo[1], dlo[2] = lo0, lo1, lo2
    dhi[0], dhi[1], dhi[2] = hi0, hi1, hi2
    return nan


@njit(inline='always', **JIT)
def spread_of(dlo, dhi, nan):
    """The squared half diagonal of the box dlo..dhi (``moved_spread2``): inf when ``nan``
    is NaN, 0 for an empty box."""
    if nan != nan:
        return np.inf
    if not dlo[0] <= dhi[0]:           # nothing colliding
        return 0.0
    e0 = 0.5 * (dhi[0] - dlo[0])
    e1 = 0.5 * (dhi[1] - dlo[1])
    e2 = 0.5 * (dhi[2] - dlo[2])
    r2 = e0 * e0 + e1 * e1 + e2 * e2
    return r2 if r2 == r2 else np.inf
