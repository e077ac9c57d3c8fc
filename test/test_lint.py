"""
Lint every Python file of the repository with ruff (configured in pyproject.toml).

``make lint`` and ``.ci/run`` run the same check; this test makes ``make test`` fail on a
lint error too, and checks that no Python file of the repository escapes the linter.
"""

from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _ruff(*args):
    pytest.importorskip('ruff', reason='ruff is not installed (pip install -e .[test])')
    return subprocess.run([sys.executable, '-m', 'ruff', *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_ruff_finds_nothing():
    proc = _ruff('check', '--no-cache', '.')
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]


def test_ruff_checks_every_python_file():
    listed = _ruff('check', '--show-files', '.')
    assert listed.returncode == 0, listed.stderr
    checked = {Path(line.strip()).resolve() for line in listed.stdout.splitlines()
               if line.strip().endswith('.py')}
    git = subprocess.run(['git', 'ls-files', '--cached', '--others', '--exclude-standard',
                          '*.py'], cwd=ROOT, capture_output=True, text=True)
    if git.returncode != 0:
        pytest.skip('not a git checkout: the file list cannot be compared')
    ours = {(ROOT / f).resolve() for f in git.stdout.split()}
    assert ours and ours <= checked, sorted(str(p) for p in ours - checked)
