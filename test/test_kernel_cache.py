"""The kernels' Numba cache notices edits to jitted functions in other kernel files: an
edit to any kernel file drops the core's cache indexes at import
(``kernels.jit.clear_stale_cache``)."""

import os
import subprocess
import sys
import textwrap

import pytest

from sm_ros.core import kernels as K
from sm_ros.core.kernels import jit

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CALLER = '''
from numba import njit
from sm_ros.core.kernels.jit import JIT
from .callee import value

@njit(**JIT)
def caller():
    return value() + 0.5
'''
_CALLEE = '''
from numba import njit
from sm_ros.core.kernels.jit import JIT

@njit(**JIT)
def value():
    return {}
'''


def _run(tmp_path, checked):
    """Import the two-file package in a fresh process and return caller(); ``checked``:
    the package clears its stale cache at import (as the kernels do), else Numba's own
    per-file check alone."""
    init = ('import os\nfrom sm_ros.core.kernels.jit import clear_stale_cache\n'
            'clear_stale_cache(os.path.dirname(os.path.abspath(__file__)))\n'
            if checked else '')
    (tmp_path / 'pkg' / '__init__.py').write_text(init)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), REPO]))
    env.pop('NUMBA_CACHE_DIR', None)
    out = subprocess.run([sys.executable, '-c', 'from pkg.caller import caller; '
                          'print(caller())'], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    return float(out.stdout.split()[-1])


@pytest.mark.parametrize('checked', [False, True])
def test_kernel_cache_sees_edits_in_other_files(tmp_path, checked):
    """Edit a callee in another file between two runs: the cleared cache recompiles the
    caller; Numba's own per-file check (``checked=False``) serves the stale result, and a
    run without an edit loads the cache."""
    pkg = tmp_path / 'pkg'
    pkg.mkdir()
    (pkg / 'caller.py').write_text(textwrap.dedent(_CALLER))
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('1.0')))
    assert _run(tmp_path, checked) == 1.5
    index = sorted((pkg / '__pycache__').glob('caller.caller-*.nbi'))
    assert index
    stamp = index[0].stat().st_mtime_ns
    assert _run(tmp_path, checked) == 1.5
    assert index[0].stat().st_mtime_ns == stamp              # loaded, not rewritten
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('2.0')))
    assert _run(tmp_path, checked) == (2.5 if checked else 1.5)


def test_the_stamp_of_the_kernel_files_is_kept_with_the_cache():
    """The import left the kernel files' stamp beside their cache (so the next import
    keeps the cache), and an import with that stamp removes nothing."""
    directory = os.path.dirname(os.path.abspath(jit.__file__))
    mark = os.path.join(directory, '__pycache__', 'kernel_sources.sha256')
    with open(mark, encoding='ascii') as f:
        assert f.read() == jit.source_stamp(directory)
    before = sorted(p for p, _, names in os.walk(os.path.dirname(directory))
                    for n in names if n.endswith('.nbi'))
    jit.clear_stale_cache()
    after = sorted(p for p, _, names in os.walk(os.path.dirname(directory))
                   for n in names if n.endswith('.nbi'))
    assert before == after
    assert callable(K.extract_rotation)


def test_source_stamp_changes_with_any_file(tmp_path):
    """The stamp hashes the content of every .py file of the directory and nothing else."""
    (tmp_path / 'a.py').write_text('x = 1\n')
    (tmp_path / 'b.py').write_text('y = 1\n')
    first = jit.source_stamp(str(tmp_path))
    (tmp_path / 'b.py').write_text('y = 2\n')
    second = jit.source_stamp(str(tmp_path))
    (tmp_path / 'notes.txt').write_text('not source')
    assert first != second == jit.source_stamp(str(tmp_path))


def test_a_stale_cache_clears_only_its_own_folders_under_numba_cache_dir(tmp_path,
                                                                        monkeypatch):
    """With ``NUMBA_CACHE_DIR`` set, a stale copy of the kernels drops the cache indexes of
    its own folders there, not those of another copy whose folders have the same names
    (an install tree built from the checkout must not make the checkout recompile)."""
    from numba.core.caching import _CacheLocator
    mine, other = tmp_path / 'a' / 'core' / 'kernels', tmp_path / 'b' / 'core' / 'kernels'
    for folder in (mine, other):
        folder.mkdir(parents=True)
        (folder / 'k.py').write_text('x = 1\n')
    # the folder names Numba gives them
    assert jit.cache_folder_name(mine) == _CacheLocator.get_suitable_cache_subpath(
        str(mine / 'k.py'))
    cache = tmp_path / 'cache'
    index = {}
    for folder in (mine, mine.parent, other, other.parent):
        index[folder] = cache / jit.cache_folder_name(folder) / 'f.nbi'
        index[folder].parent.mkdir(parents=True)
        index[folder].write_text('')
    monkeypatch.setattr(jit.config, 'CACHE_DIR', str(cache))
    jit.clear_stale_cache(str(mine))               # no stamp yet: stale
    assert not index[mine].exists() and not index[mine.parent].exists()
    assert index[other].exists() and index[other.parent].exists()
