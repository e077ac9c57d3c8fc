"""
Part 1 of the benchmark: ms/step against N (the paper's Fig. 6 on this machine).

Bodies are n x n x n lattices on the unit cube (the lattice pypbd's peer script builds),
unit masses, gravity, no colliders, alpha = 1 (pypbd's stiffness 1), beta = 0.5. The
cluster parameter is the number of cubes per axis: 1, 2, 4 give 1, 8, 64 clusters. Every
configuration runs in four variants by default, timed round-robin in one run: ``plain`` (no
damping, one step per tick), ``damped`` (damping 0.05, what 6 of the 7 bundled scenes use),
``substeps2`` (damping 0.05, two steps of dt / 2 per tick, the node's default) and
``damped_ground`` (damped, the lattice settling on a ground, as the bundled scenes run
bodies); the times are per tick.  ``--variants`` adds ``ground`` (plain, on a ground).
Every body is built through
``World.add_body``, which picks its storage order.  ``many``: 64 and 384 bodies of 144
particles in one world (the paper's Fig. 7 body count, contact off), timed round-robin too.

In the same run: the NumPy reference (``sm_ros.core.reference``), the peer pypbd (one
configuration per subprocess: ``sm_ros.bench.pypbd_driver``), and the memory bandwidth of a
streaming copy with the fraction of it the single-cluster linear step reaches.
"""

import argparse
import importlib.util
from pathlib import Path
from typing import Any, Dict, List

import numpy as np

from . import common as bc
from .scaling_timing import (CLUSTER_NAMES, MANY_BODY, MODES, VARIANTS,  # noqa: F401
                             bandwidth_fraction, build_world, measure_bandwidth,
                             time_many, time_numba, time_numpy, time_pypbd, time_size)

#: the columns of the variants table: each variant's ms, then these ratios (num / den)
VARIANT_COLUMNS = tuple(VARIANTS)
VARIANT_RATIOS = (('damped', 'plain'), ('substeps2', 'damped'), ('ground', 'plain'),
                  ('damped_ground', 'ground'))
#: what ``bench scaling`` / ``bench all`` time by default: the plain lattice, and as the
#: bundled scenes run bodies (damped, on a ground)
DEFAULT_VARIANTS = ('plain', 'damped', 'substeps2', 'damped_ground')


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``scaling`` subcommand."""
    p.add_argument('--sizes', default='1e3,1e4,1e5,1e6',
                   help='particle counts (rounded to n^3 lattices), comma separated')
    p.add_argument('--modes', default=','.join(MODES))
    p.add_argument('--clusters', default='1,2,4', help='cubes per axis (1, 8, 64 clusters)')
    p.add_argument('--min-time', type=float, default=0.3,
                   help='seconds of timed steps per configuration (at least 3 samples)')
    p.add_argument('--numpy-sizes', default='1e4,1e5',
                   help='sizes for the NumPy reference ("" to skip)')
    p.add_argument('--numpy-clusters', default='1,2')
    p.add_argument('--pypbd-sizes', default='1e4,1e5', help='sizes for pypbd ("" to skip)')
    p.add_argument('--pypbd-steps', type=int, default=30)
    p.add_argument('--pypbd-threads', default='1,2',
                   help='OMP_NUM_THREADS settings for pypbd (its best is compared)')
    p.add_argument('--bandwidth-mb', type=float, default=256.0,
                   help='array size of the streaming copy (MB); 0: no bandwidth fraction')
    p.add_argument('--variants', default=','.join(DEFAULT_VARIANTS),
                   help='plain (no damping), damped (0.05), substeps2 (0.05, 2 substeps), '
                        'ground and damped_ground (plain and damped, settling on a ground, as in '
                        'the bundled scenes)')
    p.add_argument('--many', default='64,384',
                   help='body counts of the many-bodies rows ("" to skip)')


# ---------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------

def run(args, out: Path) -> Dict[str, Any]:
    """Run every part of the scaling benchmark; write tables and plots; return findings."""
    sizes = sorted({bc.lattice_side(s) for s in bc.as_list(args.sizes)})
    modes = list(bc.as_list(args.modes, str))
    ks = bc.ints(args.clusters)
    variants = list(bc.as_list(args.variants, str))
    unknown = set(variants) - set(VARIANTS)
    if unknown or not variants:
        raise SystemExit(f'--variants: choose from {", ".join(VARIANTS)}, got {args.variants}')
    findings: Dict[str, Any] = {}
    bc.log('[scaling] memory bandwidth (streaming copy)')
    bandwidth = measure_bandwidth(args.bandwidth_mb)
    findings['bandwidth'] = bandwidth
    results = _scaling_table(args, out, sizes, modes, ks, variants)
    findings['scaling'] = results
    pick = _picker(results, variants[0])
    findings['variants'] = _variants_table(out, sizes, modes, ks, pick)
    counts = bc.ints(args.many) if args.many else []
    findings['many'] = _many_table(out, time_many(counts, args.min_time) if counts else [])
    findings['summary'] = _summary_table(out, results, modes, ks, variants[0], pick)
    nmax = max(r['N'] for r in results) if results else 0
    findings.update(_bandwidth_table(args, out, bandwidth, nmax, modes, ks))
    best_copy = findings.get('bw_interleaved', {}).get(
        'best_copy_GBps', max(bandwidth['numpy_copy_GBps'],
                              bandwidth['numba_parallel_copy_GBps']))
    findings['numpy'] = _numpy_table(args, out, modes, pick)
    findings['pypbd'] = _pypbd_table(args, out, ks)
    _plot(results, findings, best_copy, out)
    return findings


def _picker(results: List[Dict[str, Any]], first_variant: str):
    """pick(N, mode, k, variant=first_variant): the result row of one configuration."""
    def pick(n, mode, k, variant=None):
        variant = variant or first_variant
        for row in results:
            if (row['N'] == n and row['mode'] == mode and row['k'] == k
                    and row['variant'] == variant):
                return row
        return None
    return pick


def _scaling_table(args, out: Path, sizes, modes, ks, variants) -> List[Dict[str, Any]]:
    """Every configuration of every size, timed round-robin per size."""
    table = bc.Table('scaling', ['N', 'mode', 'clusters', 'variant', 'memberships', 'layout',
                                 'set_runs', 'ms_median', 'ms_min',
                                 'ns_per_particle', 'parallel', 'build_s'],
                     'ms per tick against N (World.step, dt = 5 ms per tick, gravity, no '
                     'colliders but in the ground variants; variants: plain, damped = '
                     'damping 0.05, substeps2 = damping 0.05 in two steps of 2.5 ms, '
                     'ground / damped_ground = plain / damped settling on a ground; '
                     'set_runs: runs of one set in the set layout; the configurations of '
                     'one N timed round-robin)')
    results: List[Dict[str, Any]] = []
    for n_side in sizes:
        bc.log(f'[scaling] sm_ros N={n_side ** 3}: {len(modes) * len(ks) * len(variants)} '
               'configurations, interleaved')
        for row in time_size(n_side, modes, ks, args.min_time, variants):
            results.append(row)
            table.add(**{key: row[key] for key in table.columns})
    table.write(out)
    return results


def _variants_table(out: Path, sizes, modes, ks, pick) -> List[Dict[str, Any]]:
    """The variants side by side: what damping and substeps cost (same run, round-robin)."""
    table = bc.Table('scaling_variants', ['N', 'mode', 'clusters']
                     + [f'{v}_ms' for v in VARIANT_COLUMNS]
                     + [f'{num}_over_{den}' for num, den in VARIANT_RATIOS],
                     'ms per tick of the variants (medians of one interleaved run) and '
                     'their ratios')
    rows = []
    for n_side in sizes:
        for mode in modes:
            for k in ks:
                got = {v: pick(n_side ** 3, mode, k, v) for v in VARIANTS}
                ms = {v: (r['ms_median'] if r else None) for v, r in got.items()}
                row = dict(N=n_side ** 3, mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                           **{f'{v}_ms': ms[v] for v in VARIANT_COLUMNS})
                for num, den in VARIANT_RATIOS:        # None where one was not run
                    row[f'{num}_over_{den}'] = (ms[num] / ms[den] if ms[num] and ms[den]
                                                else None)
                table.add(**row)
                rows.append(row)
    table.write(out)
    return rows


def _many_table(out: Path, rows: List[Dict[str, Any]]) -> List[Dict[str, Any]]:
    """Many bodies in one world, interleaved."""
    table = bc.Table('many', ['bodies', 'particles', 'ms_median', 'ms_min', 'us_per_body',
                              'ns_per_particle'],
                     f'many bodies of {np.prod(MANY_BODY)} particles (linear, 1 cluster, '
                     'damping 0.05, contact off, one step of 5 ms; timed round-robin)')
    for row in rows:
        table.add(**row)
    table.write(out)
    return rows


def _summary_table(out: Path, results, modes, ks, variant: str, pick) -> List[Dict[str, Any]]:
    """Log-log slopes of ms/step against N and quadratic / linear at the largest N."""
    table = bc.Table('scaling_summary', ['mode', 'clusters', 'slope_loglog',
                                         'slope_upper_half', 'quad_over_linear_at_max_N'],
                     'log-log slope of ms/step against N, and quadratic / linear '
                     f'({variant})')
    nmax = max(r['N'] for r in results) if results else 0
    for mode in modes:
        for k in ks:
            rows = [r for r in results if r['mode'] == mode and r['k'] == k
                    and r['variant'] == variant]
            ns = [r['N'] for r in rows]
            ms = [r['ms_median'] for r in rows]
            upper = [(n, m) for n, m in zip(ns, ms) if n >= 1e4]
            ratio = None
            if mode == 'quadratic' and pick(nmax, 'linear', k) and pick(nmax, mode, k):
                ratio = pick(nmax, mode, k)['ms_median'] / pick(nmax, 'linear', k)['ms_median']
            table.add(mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                      slope_loglog=bc.loglog_slope(ns, ms),
                      slope_upper_half=(bc.loglog_slope(*zip(*upper)) if len(upper) > 1
                                        else None),
                      quad_over_linear_at_max_N=ratio)
    table.write(out)
    return table.rows


def _bandwidth_table(args, out: Path, bandwidth, nmax: int, modes, ks) -> Dict[str, Any]:
    """Bandwidth fraction of the single-cluster linear step, interleaved with the copies;
    returns the findings it adds."""
    table = bc.Table('bandwidth', ['what', 'value', 'unit'],
                     'memory bandwidth and the fraction the single-cluster linear step '
                     'reaches (copies and steps interleaved, best of each)')
    found: Dict[str, Any] = {}
    if args.bandwidth_mb > 0 and 1 in ks and 'linear' in modes:
        bc.log(f'[scaling] bandwidth fraction, linear, 1 cluster, N={nmax} (interleaved)')
        inter = bandwidth_fraction(bc.lattice_side(nmax), args.bandwidth_mb)
        for key, label in (('numpy_copy_GBps', 'streaming copy, NumPy (1 thread)'),
                           ('numba_parallel_copy_GBps', 'streaming copy, Numba prange')):
            table.add(what=label, value=inter[key], unit='GB/s')
        table.add(what='bytes per particle per step (layout)', value=inter['bpp'], unit='B')
        for tag, label in (('built', f'as built ({inter["threads_built"]} thread(s))'),
                           ('serial', 'one thread')):
            table.add(what=f'linear, 1 cluster, N={inter["N"]}, {label}: ms/step (best)',
                      value=inter[f'{tag}_ms_min'], unit='ms')
            table.add(what='  same, median', value=inter[f'{tag}_ms_median'], unit='ms')
            table.add(what='  achieved (best step)', value=inter[f'{tag}_GBps'], unit='GB/s')
            table.add(what='  fraction of the best copy bandwidth (best step)',
                      value=inter[f'{tag}_fraction'], unit='')
            table.add(what='  fraction of the best copy bandwidth (median step)',
                      value=inter[f'{tag}_fraction_median'], unit='')
        found = {'bw_interleaved': inter,
                 'bw_fraction': max(inter['built_fraction'], inter['serial_fraction']),
                 'bw_fraction_median': max(inter['built_fraction_median'],
                                           inter['serial_fraction_median']),
                 'bw_N': inter['N']}
    else:
        table.add(what='streaming copy, NumPy (1 thread)',
                  value=bandwidth['numpy_copy_GBps'], unit='GB/s')
        table.add(what='streaming copy, Numba prange',
                  value=bandwidth['numba_parallel_copy_GBps'], unit='GB/s')
    table.write(out)
    return found


def _numpy_table(args, out: Path, modes, pick) -> List[Dict[str, Any]]:
    """The Numba step against the NumPy reference."""
    np_sizes = sorted({bc.lattice_side(x) for x in bc.as_list(args.numpy_sizes)})
    table = bc.Table('numpy_reference', ['N', 'mode', 'clusters', 'numba_ms', 'numpy_step_ms',
                                         'numpy_goals_ms', 'speedup_step', 'speedup_goals'],
                     'Numba step against the NumPy reference (sm_ros.core.reference)')
    rows = []
    for n_side in np_sizes:
        for mode in modes:
            for k in bc.ints(args.numpy_clusters):
                bc.log(f'[scaling] numpy N={n_side ** 3} {mode} k={k}')
                ref = time_numpy(n_side, mode, k, min(args.min_time, 1.0))
                if ref is None:
                    bc.log('  sm_ros.core.reference not importable: skipped')
                    break
                ours = pick(n_side ** 3, mode, k) or time_numba(n_side, mode, k, args.min_time)
                row = dict(N=n_side ** 3, mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                           numba_ms=ours['ms_median'], **ref,
                           speedup_step=ref['numpy_step_ms'] / ours['ms_median'],
                           speedup_goals=ref['numpy_goals_ms'] / ours['ms_median'])
                table.add(**row)
                rows.append(row)
    table.write(out)
    return rows


def _pypbd_table(args, out: Path, ks) -> List[Dict[str, Any]]:
    """sm_ros against pypbd, ours timed again right after the peer (same load)."""
    pp_sizes = sorted({bc.lattice_side(x) for x in bc.as_list(args.pypbd_sizes)})
    table = bc.Table('pypbd', ['N', 'clusters', 'memberships_pypbd', 'memberships_ours',
                               'pypbd_1thread_ms', 'pypbd_2threads_ms', 'pypbd_best_ms',
                               'ours_rigid_ms', 'ours_linear_ms', 'ours_rigid_damped_ms',
                               'speedup_rigid', 'speedup_linear', 'speedup_rigid_damped'],
                     'sm_ros against pypbd (same lattice and clusters, 1 iteration, dt 5 ms; '
                     'medians; speedup = pypbd at its best thread count / ours; ours built '
                     'through World.add_body; rigid_damped: damping 0.05)')
    rows = []
    if pp_sizes and importlib.util.find_spec('pypbd') is None:
        bc.log('[scaling] pypbd not installed (pip install pypbd): skipped')
        pp_sizes = []
    for n_side in pp_sizes:
        for k in ks:
            row = _pypbd_row(args, n_side, k)
            if row is not None:
                table.add(**row)
                rows.append(row)
    table.write(out)
    return rows


def _pypbd_row(args, n_side: int, k: int):
    """One row of the pypbd table (None when pypbd ran at no thread count)."""
    per = {}
    for threads in bc.ints(args.pypbd_threads):
        bc.log(f'[scaling] pypbd N={n_side ** 3} k={k} OMP_NUM_THREADS={threads}')
        peer = time_pypbd(n_side, k, args.pypbd_steps, threads)
        if peer is not None:
            per[threads] = peer
    if not per:
        return None
    peer = min(per.values(), key=lambda r: r['median_ms'])
    rigid, rigid_damped, linear, _ = time_size(n_side, ['rigid', 'linear'], [k],
                                               args.min_time, ('plain', 'damped'))
    return {'N': n_side ** 3, 'clusters': peer['clusters'],
            'memberships_pypbd': peer['memberships'],
            'memberships_ours': rigid['memberships'],
            'pypbd_1thread_ms': per[1]['median_ms'] if 1 in per else None,
            'pypbd_2threads_ms': per[2]['median_ms'] if 2 in per else None,
            'pypbd_best_ms': peer['median_ms'],
            'ours_rigid_ms': rigid['ms_median'], 'ours_linear_ms': linear['ms_median'],
            'ours_rigid_damped_ms': rigid_damped['ms_median'],
            'speedup_rigid': peer['median_ms'] / rigid['ms_median'],
            'speedup_linear': peer['median_ms'] / linear['ms_median'],
            'speedup_rigid_damped': peer['median_ms'] / rigid_damped['ms_median']}


def _plot(results, findings, bw_best, out: Path):
    plt = bc.pyplot()
    if plt is None or not results:
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    colors = {'rigid': 'tab:blue', 'linear': 'tab:green', 'quadratic': 'tab:red'}
    styles = {1: '-', 2: '--', 3: '-.', 4: ':'}
    ax = axes[0]
    for mode in MODES:
        for k in sorted({r['k'] for r in results}):
            rows = sorted((r for r in results if r['mode'] == mode and r['k'] == k),
                          key=lambda r: r['N'])
            if rows:
                ax.loglog([r['N'] for r in rows], [r['ms_median'] for r in rows],
                          styles.get(k, '-'), marker='o', ms=3, color=colors[mode],
                          label=f'{mode}, {CLUSTER_NAMES.get(k, k ** 3)} cl.')
    ns = np.array(sorted({r['N'] for r in results}), dtype=float)
    bpp = results[0]['bytes_per_particle']
    ax.loglog(ns, bpp * ns / (bw_best * 1e9) * 1e3, 'k:', lw=1,
              label=f'memory bound ({bpp} B/particle)')
    ax.set_xlabel('particles N')
    ax.set_ylabel('ms / step')
    ax.set_title('sm_ros World.step (Numba)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax = axes[1]
    for row in findings.get('numpy', []):
        ax.loglog(row['N'], row['numpy_step_ms'], 's', color=colors[row['mode']], mfc='none')
        ax.loglog(row['N'], row['numba_ms'], 'o', color=colors[row['mode']])
    for row in findings.get('pypbd', []):
        ax.loglog(row['N'], row['pypbd_best_ms'], '^', color='k', mfc='none')
        ax.loglog(row['N'], row['ours_rigid_ms'], 'o', color=colors['rigid'])
    ax.plot([], [], 's', color='gray', mfc='none', label='NumPy reference')
    ax.plot([], [], '^', color='k', mfc='none', label='pypbd (1 iteration)')
    ax.plot([], [], 'o', color='gray', label='sm_ros (Numba)')
    ax.set_xlabel('particles N')
    ax.set_ylabel('ms / step')
    ax.set_title('against the NumPy reference and pypbd')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    bc.save_figure(fig, out / 'bench_scaling.png')
