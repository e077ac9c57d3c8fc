"""
Smoke test of ``python -m sm_ros.bench``: it runs on tiny sizes and writes its tables.

Nothing here times anything or checks a speed: the benchmark's figures are in
doc/benchmarks.md, measured on purpose, never asserted by the test suite.
"""

import csv
import importlib.util
import math
from pathlib import Path
import subprocess
import sys

import pytest

from sm_ros.bench import common as bc
from sm_ros.bench.__main__ import main

ROOT = Path(__file__).resolve().parents[1]


def _rows(path: Path):
    with open(path, newline='') as f:
        return list(csv.DictReader(f))


def test_quick_run_writes_tables(tmp_path):
    out = tmp_path / 'bench'
    assert main(['all', '--quick', '--out', str(out)]) == 0
    for name in ('scaling', 'scaling_summary', 'bandwidth', 'numpy_reference', 'pypbd',
                 'accuracy', 'accuracy_budget', 'accuracy_order', 'targets'):
        assert (out / f'{name}.csv').is_file(), name
        assert (out / f'{name}.md').read_text().startswith('### '), name
    rows = _rows(out / 'scaling.csv')
    assert {r['mode'] for r in rows} == {'rigid', 'linear', 'quadratic'}
    assert {r['clusters'] for r in rows} == {'1', '8', '64'}
    # every configuration in every variant, once; figures consistent with each other
    keys = [(r['N'], r['mode'], r['clusters'], r['variant']) for r in rows]
    assert len(keys) == len(set(keys)) == 2 * 3 * 3 * 4
    assert {r['variant'] for r in rows} == {'plain', 'damped', 'substeps2', 'damped_ground'}
    for r in rows:
        assert float(r['ms_min']) <= float(r['ms_median'])
        assert float(r['ns_per_particle']) == pytest.approx(
            1e6 * float(r['ms_median']) / int(r['N']), rel=1e-3)
        assert r['layout'] == 'single' if r['clusters'] == '1' else r['layout'] != 'single'
    var = _rows(out / 'scaling_variants.csv')
    assert len(var) == 2 * 3 * 3
    for r in var:
        assert float(r['damped_over_plain']) == pytest.approx(
            float(r['damped_ms']) / float(r['plain_ms']), rel=1e-3)
        assert float(r['substeps2_over_damped']) == pytest.approx(
            float(r['substeps2_ms']) / float(r['damped_ms']), rel=1e-3)
        assert r['damped_ground_over_ground'] == ''      # ground not run: no ratio
    many = _rows(out / 'many.csv')
    assert [(r['bodies'], r['particles']) for r in many] == [('2', '288'), ('6', '864')]
    acc = _rows(out / 'accuracy.csv')
    assert {r['scene'] for r in acc} == {'rigid_spin', 'soft_drop'}
    for r in acc:
        assert math.isfinite(float(r['err_rms'])), r
        assert float(r['dt_ms']) == pytest.approx(
            1e3 / (float(r['rate_hz']) * int(r['substeps'])), rel=1e-3)
        # rigid_spin is measured against its exact solution, soft_drop against a finer run
        assert (float(r['ref_err']) == 0.0) == (r['scene'] == 'rigid_spin'), r
    if importlib.util.find_spec('matplotlib') is not None:
        assert (out / 'bench_scaling.png').stat().st_size > 0
        assert (out / 'bench_accuracy_rigid_spin.png').stat().st_size > 0
    assert 'Command: `python -m sm_ros.bench all --quick' in (out / 'targets.md').read_text()


def test_scaling_subcommand_as_a_process(tmp_path):
    out = tmp_path / 'scaling'
    res = subprocess.run([sys.executable, '-m', 'sm_ros.bench', 'scaling', '--sizes', '125',
                          '--modes', 'linear', '--clusters', '1,2', '--min-time', '0',
                          '--numpy-sizes', '', '--pypbd-sizes', '', '--bandwidth-mb', '4',
                          '--variants', 'plain,substeps2', '--many', '', '--out', str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    rows = _rows(out / 'scaling.csv')
    assert [(r['N'], r['clusters'], r['variant']) for r in rows] == [
        ('125', '1', 'plain'), ('125', '1', 'substeps2'), ('125', '8', 'plain'),
        ('125', '8', 'substeps2')]
    assert _rows(out / 'many.csv') == []
    bad = subprocess.run([sys.executable, '-m', 'sm_ros.bench', 'scaling', '--variants',
                          'fast', '--out', str(out)], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode != 0
    assert 'choose from plain, damped, substeps2, ground, damped_ground' in bad.stderr


def test_soak_hook_hands_over_its_arguments(monkeypatch):
    import sm_ros.bench.soak
    seen = []
    monkeypatch.setattr(sm_ros.bench.soak, 'main', lambda argv: seen.append(list(argv)) or 7)
    assert main(['soak', '--seconds', '1']) == 7        # its exit code comes back
    assert seen == [['--seconds', '1']]


def test_helpers():
    assert bc.lattice_side(1e6) == 100
    assert bc.lattice_side(1e4) == 22
    assert bc.lattice_side(1e5) == 46
    assert abs(bc.loglog_slope([1, 10, 100], [2, 20, 200]) - 1.0) < 1e-12
    t = bc.Table('t', ['a', 'b'], 'title')
    t.add(a=1, b=0.5)
    with pytest.raises(KeyError):
        t.add(c=1)
    assert '| 1 | 0.5 |' in t.markdown()


def test_pypbd_driver_uses_our_clusters():
    from sm_ros.bench import common as bc
    from sm_ros.bench.pypbd_driver import clusters
    from sm_ros.core.clusters import build_memberships
    x0 = bc.cube_lattice(6)
    ptr, cluster_ids, n_clusters = build_memberships(x0, 2)
    members = clusters(x0, 2)
    assert len(members) == n_clusters == 8
    assert sum(len(m) for m in members) == len(cluster_ids)
    for i in (0, 17, 215):
        assert {c for c, m in enumerate(members) if i in m} == set(cluster_ids[ptr[i]:ptr[i + 1]])


def test_pypbd_driver_runs_one_configuration():
    pytest.importorskip('pypbd', reason='pypbd is not installed (the bench extra)')
    import json
    proc = subprocess.run([sys.executable, '-m', 'sm_ros.bench.pypbd_driver', '--n', '6',
                           '--k', '2', '--steps', '3'], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert (res['N'], res['clusters']) == (216, 8)
    assert res['com_drop_m'] == pytest.approx(res['com_drop_expected_m'], rel=1e-6)
    assert res['shape_rms_m'] < 1e-9                # a rigid drop keeps the shape


def test_contact_subcommand_smoke(tmp_path):
    import json
    import numba
    threads = numba.get_num_threads()
    out = tmp_path / 'contact'
    assert main(['contact', '--out', str(out), '--blocks', '24', '--steps', '3', '--settle',
                 '2', '--scales', '1,2', '--paper-seconds', '0', '--one-body-side', '6',
                 '--sleep-scene', 'many', '--sleep-seconds', '0.1']) == 0
    assert numba.get_num_threads() == threads      # the caller's thread count is given back
    res = json.loads((out / 'contact.json').read_text())
    assert res['N'] == 24 * 144 and res['settle']['steps'] == 3
    assert [r['blocks'] for r in res['scaling']] == [24, 48]
    assert res['one_body']['n'] == 6 ** 3 and res['paper_384'] is None
    sl = res['sleeping']                # 64 falling bodies: none asleep within 0.1 s
    assert (sl['scene'], sl['ticks'], sl['bodies'], sl['asleep_end']) == ('many', 6, 64, 0)
    assert sl['all_asleep_s'] is None
    b = res['builders']                 # the bin's blocks touch: the list holds pairs
    assert b['pairs_listed'] > 0 and b['N'] == res['N']
    text = (out / 'contact.md').read_text()
    assert 'pair-list rebuild alone' in text and 'cKDTree' in text
    assert 'sleeping bodies on / off' in text
    assert 'build_pairs_grid' in text and 'per step while moving' in text


def test_contact_block_bin_starts_touching_on_the_ground():
    # the bench's bin: blocks standing on the ground (colliders act on particle centres),
    # clear of the walls, neighbouring faces one spacing (the contact distance) apart (they
    # once started 2 cm into the ground, 1 mm overlapping)
    import numpy as np
    from sm_ros.bench.contact import SPACING, block_bin
    w = block_bin(48)                   # 24 a row: 2 rows
    xs = [b.x for b in w.bodies]
    x = np.concatenate(xs)
    assert 0.0 <= x[:, 2].min() and max(a[:, 2].min() for a in xs) <= 1e-3
    for box in w.boxes:
        lo, hi = np.asarray(box.lo), np.asarray(box.hi)
        assert not np.all((x > lo) & (x < hi), axis=1).any()
    for a, b in [(xs[k], xs[k + 1]) for k in range(0, 47, 2)] + [(xs[k], xs[k + 2])
                                                                 for k in range(0, 46, 2)]:
        near = np.linalg.norm(a[:, None] - b[None], axis=-1).min()
        assert SPACING - 1e-12 < near < np.hypot(SPACING, 1e-3)     # touching (z: 0-1 mm)


def _targets(tmp_path, variants, pypbd=()):
    """targets.csv rows by target for findings with the 100k 8-cluster linear ``variants``
    ({variant: ms a step}) and the ``pypbd`` rows."""
    from sm_ros.bench.__main__ import _write_targets
    rows = [dict(N=46 ** 3, mode='linear', k=2, variant=v, ms_median=ms,
                 ns_per_particle=1e6 * ms / 46 ** 3) for v, ms in variants.items()]
    f = dict(scaling=dict(scaling=rows, pypbd=list(pypbd)),
             command='python -m sm_ros.bench scaling', wall_s=1.0,
             machine=dict(cpu='cpu', cpus=2, numba='0', numba_threads=1, numpy='0'))
    _write_targets(f, tmp_path)
    return {r['target']: r for r in _rows(tmp_path / 'targets.csv')}


def test_targets_judge_the_100k_rows_and_the_damped_pypbd_ratio(tmp_path):
    """The 100k damped row, the damping overhead (damped / plain, one run) and the
    damped rigid 8-cluster ratio against pypbd, each judged against its goal."""
    pypbd = [dict(N=22 ** 3, clusters=8, speedup_rigid=6.0, speedup_rigid_damped=9.31),
             dict(N=46 ** 3, clusters=8, speedup_rigid=2.5, speedup_rigid_damped=3.0)]
    t = _targets(tmp_path, dict(plain=0.5, damped=0.7), pypbd)
    row = t['linear, 8 clusters, damping 0.05, 100k points']
    assert (row['measured'], row['met']) == ('0.7 ms', 'True')
    row = t['damping overhead (same, damped / undamped)']
    assert (row['measured'], row['met']) == ('1.40x', 'False')
    row = t['rigid, 8 clusters, damping 0.05, 10k points, against pypbd '
            '(through the plain World.add_body)']
    assert (row['measured'], row['met']) == ('9.3x', 'True')
    row = t['faster than pypbd (10k, 100k; 1/8/64 clusters)']
    assert row['met'] == 'True' and row['measured'].startswith('2.5x worst')
    t = _targets(tmp_path, dict(plain=0.5, damped=0.95),
                 [dict(pypbd[0], speedup_rigid_damped=7.9)])
    assert t['linear, 8 clusters, damping 0.05, 100k points']['met'] == 'False'
    assert t['damping overhead (same, damped / undamped)']['measured'] == '1.90x'
    assert t['rigid, 8 clusters, damping 0.05, 10k points, against pypbd '
             '(through the plain World.add_body)']['met'] == 'False'
    t = _targets(tmp_path, dict(plain=0.5, damped=0.55))
    assert t['linear, 8 clusters, damping 0.05, 100k points']['measured'] == '0.55 ms'
    row = t['damping overhead (same, damped / undamped)']
    assert (row['measured'], row['met']) == ('1.10x', 'True')
    assert t['faster than pypbd']['measured'] == 'not run'
