"""
Smoke test of ``python -m sm_ros.bench``: it runs on tiny sizes and writes its tables.

Nothing here times anything or checks a speed: the benchmark's figures are in
doc/benchmarks.md, measured on purpose, never asserted by the test suite.
"""

import csv
import importlib.util
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
                 'accuracy', 'accuracy_budget', 'targets'):
        assert (out / f'{name}.csv').is_file(), name
        assert (out / f'{name}.md').read_text().startswith('### '), name
    rows = _rows(out / 'scaling.csv')
    assert {r['mode'] for r in rows} == {'rigid', 'linear', 'quadratic'}
    assert {r['clusters'] for r in rows} == {'1', '8', '64'}
    assert all(float(r['ms_median']) > 0 for r in rows)
    acc = _rows(out / 'accuracy.csv')
    assert {r['scene'] for r in acc} == {'rigid_spin', 'soft_drop'}
    assert all(float(r['err_rms']) >= 0 for r in acc)
    if importlib.util.find_spec('matplotlib') is not None:
        assert (out / 'bench_scaling.png').stat().st_size > 0
        assert (out / 'bench_accuracy_rigid_spin.png').stat().st_size > 0
    assert 'Command: `python -m sm_ros.bench all --quick' in (out / 'targets.md').read_text()


def test_scaling_subcommand_as_a_process(tmp_path):
    out = tmp_path / 'scaling'
    res = subprocess.run([sys.executable, '-m', 'sm_ros.bench', 'scaling', '--sizes', '125',
                          '--modes', 'linear', '--clusters', '1,2', '--min-time', '0',
                          '--numpy-sizes', '', '--pypbd-sizes', '', '--bandwidth-mb', '4',
                          '--out', str(out)], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    rows = _rows(out / 'scaling.csv')
    assert [(r['N'], r['clusters']) for r in rows] == [('125', '1'), ('125', '8')]


def test_soak_hook_hands_over_its_arguments(monkeypatch):
    import sm_ros.soak
    seen = []
    monkeypatch.setattr(sm_ros.soak, 'main', lambda argv: seen.append(list(argv)) or 7)
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
