"""
What the particle loop of a one-cluster step costs on this machine, part by part, and the
fixed cost of a ``World.step`` around it: the floor under issue 11's "1.5 ns a particle at
10k" row.

Loops over N particles (default 10,648, the 22^3 lattice of ``bench scaling``), state in
64-byte aligned (3, N) blocks as bodies keep it (``body_build.soa``), unit masses, one
thread, compiled with the kernels' fast-math flags; ns a particle, medians of ``--rounds``
batches, the state restored before each batch:

- ``stream``: x += h v, the least a step can do (reads x and v, writes x);
- ``eq13_14``: Eq. 13-14 towards the goal G q + b, nothing else (reads x, v, q; writes x, v);
- ``eq13_14_sums``: the same and the 12 sums of the new state that the next shape match
  needs (sum d, sum d q^T, d = x - k);
- ``pass_loop``: the project's loop (``integrate._fused_range``, mass None: Eq. 13-14,
  the 12 sums, the shape error and the speed count) at LLVM's vector width (256 bits
  here), as the set layout's one loop a run compiles it;
- ``pass_loop_wide``: the same loop 512 bits wide, as the one-cluster pass compiles it
  (``integrate._int_single_fused``, ``jit.wide_vectors``);
- ``pass_loop_masses``: the same loop weighted by the masses (a body of several masses);
- ``pass_loop_damped``, ``pass_loop_damped_wide``: the damped loop (the damping towards a
  field, and the damping sums of the new state in the same loop), both widths;

The pass loops take their constants (alpha / h, h, h acc, the speed cap) as run-time
values and use every result, as the passes do (before 2026-12-05 they used one sum and
took the constants as literals, which LLVM folded: their floors were too low).
- ``damping_sums``: the damping sums as a loop of their own (``damping.damp_sums_range``,
  unit masses: sum v, sum d x v and the second moments of d), what a damped step added
  before they moved into the pass's loop (now only for a block the speed cap or a box or
  sphere moved).

``--sides 4,5,6,10,16,22`` times the pass loops at each lattice size instead (64 to
10,648 particles), 256 and 512 bits wide: where the wide loop pays.

``--offset B`` starts the loops' blocks B bytes past a 64-byte boundary (numpy's own
allocations start 16 or 48 past one): the cost of unaligned state.

Then ``World.step`` of one-cluster rigid lattices of 6^3 to 28^3 particles (undamped, no
ground, the state reset between batches so that no speed reaches the cap): the fitted
fixed cost (us a step) and cost a particle (ns), and the 10k step itself.

    cd /tmp && NUMBA_NUM_THREADS=1 PYTHONPATH=CHECKOUT python CHECKOUT/tools/loop_floor.py
"""

import argparse
import json
import statistics
import time

import numpy as np
from numba import literal_unroll, njit

from sm_ros.core.body_build import soa
from sm_ros.core.kernels.damping import damp_sums_range
from sm_ros.core.kernels.integrate import _fused_range
from sm_ros.core.kernels.jit import FASTMATH, U, wide_vectors

FM = dict(fastmath=FASTMATH)
H = 0.005


@njit(**FM)
def _stream(x, v, x0, g, reps):
    h = 0.005
    for _ in range(reps):
        # one lane a particle: unit-stride columns, unsigned index
        for i in range(U(0), U(x.shape[0])):
            x[i, 0] += h * v[i, 0]
            x[i, 1] += h * v[i, 1]
            x[i, 2] += h * v[i, 2]
    return 0.0


@njit(**FM)
def _eq(x, v, x0, g, reps, sums):
    l00, l01, l02, l10, l11, l12, l20, l21, l22, b0, b1, b2 = g
    alpha_h, h, hz = 100.0, 0.005, -0.05
    out = 0.0
    for _ in range(reps):
        s0 = s1 = s2 = 0.0
        c00 = c01 = c02 = c10 = c11 = c12 = c20 = c21 = c22 = 0.0
        # one lane a particle; the 12 sums (with ``sums``) as vector accumulators
        for i in range(U(0), U(x.shape[0])):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
            v0 = v[i, 0] + alpha_h * (l00 * a0 + l01 * a1 + l02 * a2 + b0 - p0)
            v1 = v[i, 1] + alpha_h * (l10 * a0 + l11 * a1 + l12 * a2 + b1 - p1)
            v2 = v[i, 2] + alpha_h * (l20 * a0 + l21 * a1 + l22 * a2 + b2 - p2) + hz
            y0 = p0 + h * v0
            y1 = p1 + h * v1
            y2 = p2 + h * v2
            x[i, 0] = y0
            x[i, 1] = y1
            x[i, 2] = y2
            v[i, 0] = v0
            v[i, 1] = v1
            v[i, 2] = v2
            if sums:
                d0, d1, d2 = y0 - b0, y1 - b1, y2 - b2
                s0 += d0
                s1 += d1
                s2 += d2
                c00 += d0 * a0
                c01 += d0 * a1
                c02 += d0 * a2
                c10 += d1 * a0
                c11 += d1 * a1
                c12 += d1 * a2
                c20 += d2 * a0
                c21 += d2 * a1
                c22 += d2 * a2
        out += s0 + s1 + s2 + c00 + c01 + c02 + c10 + c11 + c12 + c20 + c21 + c22
    return out


@njit(**FM)
def _eq_only(x, v, x0, g, reps):
    return _eq(x, v, x0, g, reps, False)


@njit(**FM)
def _eq_sums(x, v, x0, g, reps):
    return _eq(x, v, x0, g, reps, True)


@njit(**FM)
def _one_pass(x, v, x0, mass, wuni, damp, g, field, c):
    return _fused_range(0, x.shape[0], x, v, x0, mass, wuni, g, damp, field, c[0], c[1],
                        c[2], c[3], c[4], g[9], g[10], g[11], c[5], None)


@njit(**FM)
def _one_pass_wide(x, v, x0, mass, wuni, damp, g, field, c):
    wide_vectors()
    return _fused_range(0, x.shape[0], x, v, x0, mass, wuni, g, damp, field, c[0], c[1],
                        c[2], c[3], c[4], g[9], g[10], g[11], c[5], None)


@njit(**FM)
def _passes(x, v, x0, g, reps, mass, wuni, damp, field, wide, c):
    """``reps`` calls of the pass's loop: compiled once with ``mass`` None (one-mass bodies)
    and once with an array, ``damp`` a run-time flag as in the passes, ``wide``: 512 bits
    wide as the one-cluster pass compiles it (``integrate._int_single_fused``).  The
    constants ``c`` (alpha / h, h, h acc, the speed cap) are run-time values and every
    result is used, as in the passes: a constant acceleration of 0 or an unused sum would
    be folded away by LLVM and the floor would be too low."""
    out = 0.0
    for _ in range(reps):
        if wide:
            out += _total(_one_pass_wide(x, v, x0, mass, wuni, damp, g, field, c))
        else:
            out += _total(_one_pass(x, v, x0, mass, wuni, damp, g, field, c))
    return out


@njit(**FM)
def _total(t):
    """The sum of every result of a loop (none of them left for LLVM to drop)."""
    out = 0.0
    for e in literal_unroll(t):
        out += e
    return out


_IDLE = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
# km = 1 - k, f and o of a small field (``integrate.damp_constants``)
_FIELD = (0.95, 0.001, -0.002, 0.0005, 0.0, 0.0, 0.01)


# alpha / h, h, h acc (x, y, z), the speed cap squared
_CONSTS = np.array([100.0, 0.005, 0.0, 0.0, -0.05, 1e4])


def _pass_loop(x, v, x0, g, reps):
    return _passes(x, v, x0, g, reps, None, 1.0, False, _IDLE, False, _CONSTS)


def _pass_loop_wide(x, v, x0, g, reps):
    return _passes(x, v, x0, g, reps, None, 1.0, False, _IDLE, True, _CONSTS)


def _pass_loop_masses(x, v, x0, g, reps):
    return _passes(x, v, x0, g, reps, np.ones(x.shape[0]), 0.0, False, _IDLE, False,
                   _CONSTS)


def _pass_loop_damped(x, v, x0, g, reps):
    return _passes(x, v, x0, g, reps, None, 1.0, True, _FIELD, False, _CONSTS)


def _pass_loop_damped_wide(x, v, x0, g, reps):
    return _passes(x, v, x0, g, reps, None, 1.0, True, _FIELD, True, _CONSTS)


@njit(**FM)
def _one_damp(x, v, k0, k1, k2):
    return damp_sums_range(0, x.shape[0], x, v, v[:, 0], 1.0, k0, k1, k2)


@njit(**FM)
def _damping_sums(x, v, x0, g, reps):
    out = 0.0
    for _ in range(reps):
        out += _total(_one_damp(x, v, g[9], g[10], g[11]))
    return out


LOOPS = {'stream': _stream, 'eq13_14': _eq_only, 'eq13_14_sums': _eq_sums,
         'pass_loop': _pass_loop, 'pass_loop_wide': _pass_loop_wide,
         'pass_loop_masses': _pass_loop_masses, 'pass_loop_damped': _pass_loop_damped,
         'pass_loop_damped_wide': _pass_loop_damped_wide, 'damping_sums': _damping_sums}


def _block(a, offset):
    """``a`` (N, 3) as ``soa`` stores it, its block ``offset`` bytes past a 64-byte
    boundary (0: as bodies keep it)."""
    if offset == 0:
        return soa(a)
    buf = np.empty(a.size + 16)
    start = (-buf.ctypes.data % 64 + offset) // 8
    block = buf[start:start + a.size].reshape(3, -1)
    block[:] = a.T
    return block.T


def loops(n_side, rounds, reps, offset=0):
    """{loop: ns a particle} on the n_side^3 lattice, every loop round-robin."""
    from sm_ros.bench import common as bc
    q = bc.cube_lattice(n_side)
    q = q - q.mean(axis=0)
    n = len(q)
    x, v, x0 = (_block(a, offset) for a in (q + (0.1, 0.2, 0.3), np.zeros((n, 3)), q))
    # a goal map of a small turn about z, offset to where x is (the particles move little)
    c, s = np.cos(1e-3), np.sin(1e-3)
    g = (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0, 0.1, 0.2, 0.3)
    start = (x.copy(), v.copy())
    times = {name: [] for name in LOOPS}
    for fn in LOOPS.values():
        fn(x, v, x0, g, 1)
    for _ in range(rounds):
        for name, fn in LOOPS.items():
            x[:] = start[0]
            v[:] = start[1]
            t0 = time.perf_counter()
            fn(x, v, x0, g, reps)
            times[name].append((time.perf_counter() - t0) / (reps * n) * 1e9)
    return n, {name: round(statistics.median(t), 3) for name, t in times.items()}


def world_steps(rounds, steps):
    """{'fixed_us', 'ns_particle', 'step_10k_us'}: World.step against N, one cluster."""
    from sm_ros.bench import scaling as S
    sides = (6, 10, 14, 18, 22, 28)
    meds = []
    for side in sides:
        world, body = S.build_world(side, 'rigid', 1)
        x, v = body.x.copy(), body.v.copy()
        for _ in range(3):
            world.step(S.DT)
        runs = []
        for _ in range(rounds):
            body.set_state(x=x, v=v)
            world.step(S.DT)
            t0 = time.perf_counter()
            for _ in range(steps):
                world.step(S.DT)
            runs.append((time.perf_counter() - t0) / steps * 1e6)
        meds.append(statistics.median(runs))
    ns = np.array([s ** 3 for s in sides], dtype=float)
    slope, icpt = np.polyfit(ns, np.array(meds), 1)
    return {'fixed_us': round(float(icpt), 2), 'ns_particle': round(float(slope) * 1e3, 3),
            'step_10k_us': round(meds[sides.index(22)], 2),
            'step_us': {int(s ** 3): round(m, 2) for s, m in zip(sides, meds)}}


def main(argv=None):
    """Print the loops and the steps as one JSON line."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--side', type=int, default=22, help='lattice side of the loops (22)')
    ap.add_argument('--rounds', type=int, default=15)
    ap.add_argument('--reps', type=int, default=50, help='passes a timed batch (50)')
    ap.add_argument('--steps', type=int, default=200, help='World.step a batch (200)')
    ap.add_argument('--offset', type=int, default=0, choices=range(0, 64, 8),
                    help="bytes past a 64-byte boundary the loops' blocks start (0)")
    ap.add_argument('--sides', default='',
                    help='comma-separated lattice sides: the pass loops at each size, 256 '
                         'and 512 bits wide, and their ratio (no World.step)')
    a = ap.parse_args(argv)
    if a.sides:
        out = {}
        for side in (int(s) for s in a.sides.split(',')):
            # about 500k particle updates a timed batch, whatever the size
            n, ns = loops(side, a.rounds, max(a.reps, 500000 // side ** 3), a.offset)
            out[n] = {k: ns[k] for k in ('pass_loop', 'pass_loop_wide', 'pass_loop_damped',
                                         'pass_loop_damped_wide')}
            out[n]['wide_over_narrow'] = round(ns['pass_loop_wide'] / ns['pass_loop'], 2)
            out[n]['damped_wide_over_narrow'] = round(
                ns['pass_loop_damped_wide'] / ns['pass_loop_damped'], 2)
        print(json.dumps(out))
        return
    n, ns = loops(a.side, a.rounds, a.reps, a.offset)
    out = {'n': n, 'offset': a.offset, 'loops_ns_particle': ns,
           'world_step': world_steps(a.rounds, a.steps)}
    print(json.dumps(out))


if __name__ == '__main__':
    main()
