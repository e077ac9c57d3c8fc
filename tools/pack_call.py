"""
What one call of the packed one-cluster step costs besides its particles.

An 8-particle rigid body at rest (no gravity), one thread, ``timeit`` minima (us a call),
every figure from one process:

- ``world_step``: ``World.step``, all of it;
- ``pack_step``: ``Pack.step`` (the Python around the compiled call);
- ``entry``: ``step_packed_one``'s compiled entry, called straight (``Pack._resolve``);
- ``dispatch``: the same through Numba's dispatcher (it types every argument);
- ``parallel_one_chunk``: the threaded ``step_packed`` with one chunk: the parallel
  region's launch, even on one thread;
- ``unbox_array`` / ``unbox_typed_list``: a compiled no-op taking one array, or one typed
  list of the pack's four particle arrays (what the pack passed before ``Pack.ptrs``);

and, in ns a view (a compiled loop making six views and passing them to a call):
``reshape_view`` (``buf[a:b].reshape(shape)``, what the chunk's scratch was) against
``scratch_view`` (``jit.scratch_view``).

    cd /tmp && NUMBA_NUM_THREADS=1 PYTHONPATH=CHECKOUT python CHECKOUT/tools/pack_call.py
"""

import json
import timeit

import numpy as np
from numba import njit
from numba.typed import List as TypedList

from sm_ros.bench import scaling as S
from sm_ros.core import packed
from sm_ros.core.kernels.jit import scratch_view

VIEWS = 6


@njit
def _use(a, b, c):
    return a[0, 0] + b[0, 1, 1] + c[0, 2]


@njit
def _reshape_views(buf, reps):
    t = 0.0
    for _ in range(reps):
        a, b = buf[0:12].reshape((1, 12)), buf[12:21].reshape((1, 3, 3))
        c, d = buf[21:24].reshape((1, 3)), buf[24:36].reshape((1, 12))
        e, f = buf[36:45].reshape((1, 3, 3)), buf[45:48].reshape((1, 3))
        t += _use(a, b, c) + _use(d, e, f)
    return t


@njit
def _scratch_views(buf, reps):
    t = 0.0
    for _ in range(reps):
        a, b = scratch_view(buf, 0, (1, 12)), scratch_view(buf, 12, (1, 3, 3))
        c, d = scratch_view(buf, 21, (1, 3)), scratch_view(buf, 24, (1, 12))
        e, f = scratch_view(buf, 36, (1, 3, 3)), scratch_view(buf, 45, (1, 3))
        t += _use(a, b, c) + _use(d, e, f)
    return t


@njit
def _noop(a):
    return 0


def _best(fn, number=5000, repeat=7):
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def main():
    """Print the figures as one JSON line."""
    world, body = S.build_world(2, 'rigid', 1)
    world.gravity = (0.0, 0.0, 0.0)          # at rest: no speed ever reaches the cap
    for _ in range(5):
        world.step(S.DT)
    pack = world._split_bodies(S.DT)[0]
    thresh = max(1e-3, 2.0 * world._gnorm * S.DT)
    cols = (world._gravity, world._has_col, world._ground_row, world._box_rows,
            world._sphere_rows, thresh)
    head = (pack.P, pack.counts, pack.ptrs, pack.scratch)
    entry = pack._entry[0]
    one, par = packed.step_packed_one, packed.step_packed
    par(*head, 1, S.DT, *cols)
    parts = TypedList([(body._x.T, body._v.T, body._x0.T, body.m)])
    _noop(pack.P)
    _noop(parts)
    out = {
        'world_step': _best(lambda: world.step(S.DT)),
        'pack_step': _best(lambda: pack.step(S.DT, *cols)),
        'entry': _best(lambda: entry(*head, S.DT, *cols)),
        'dispatch': _best(lambda: one(*head, S.DT, *cols)),
        'parallel_one_chunk': _best(lambda: par(*head, 1, S.DT, *cols)),
        'unbox_array': _best(lambda: _noop(pack.P), number=50000),
        'unbox_typed_list': _best(lambda: _noop(parts), number=50000),
    }
    buf = np.zeros(64)
    reps = 200000
    for fn in (_reshape_views, _scratch_views):
        fn(buf, 1)
    for name, fn in (('reshape_view_ns', _reshape_views), ('scratch_view_ns', _scratch_views)):
        out[name] = _best(lambda f=fn: f(buf, reps), 1, 7) * 1e3 / (reps * VIEWS)
    print(json.dumps({k: round(v, 2) for k, v in out.items()}))


if __name__ == '__main__':
    main()
