"""The kernels' Numba cache notices edits to jitted functions in other kernel files: it
lives in a directory keyed on every kernel file (``kernels.jit.cache_dir``)."""

import os
import subprocess
import sys
import textwrap

import pytest
from numba.core import config

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


def _run(tmp_path, keyed):
    """Import the two-file package in a fresh process and return caller(); ``keyed``: its
    cache in a directory keyed on its files (as the kernels'), else in NUMBA_CACHE_DIR."""
    init = ('import os\nfrom numba.core import config\n'
            'from sm_ros.core.kernels.jit import cache_dir\n'
            'config.CACHE_DIR = cache_dir(os.path.dirname(os.path.abspath(__file__)))\n'
            if keyed else
            'import os\nfrom numba.core import config\n'
            'config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]\n')
    (tmp_path / 'pkg' / '__init__.py').write_text(init)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), REPO]),
               NUMBA_CACHE_DIR=str(tmp_path / 'cache'))
    out = subprocess.run([sys.executable, '-c', 'from pkg.caller import caller; '
                          'print(caller())'], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    return float(out.stdout.split()[-1])


@pytest.mark.parametrize('keyed', [False, True])
def test_kernel_cache_sees_edits_in_other_files(tmp_path, keyed):
    """Edit a callee in another file between two runs: the keyed directory recompiles the
    caller; Numba's own per-file check (``keyed=False``) serves the stale result."""
    pkg = tmp_path / 'pkg'
    pkg.mkdir()
    (pkg / 'caller.py').write_text(textwrap.dedent(_CALLER))
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('1.0')))
    assert _run(tmp_path, keyed) == 1.5
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('2.0')))
    assert _run(tmp_path, keyed) == (2.5 if keyed else 1.5)


def test_every_kernel_and_its_callers_cache_in_the_keyed_directory():
    """Every cached kernel, and the core modules that call kernels (pose, the contact
    kernels, the collider pass), keep their cache in the directory of the kernel files'
    stamp."""
    from sm_ros.core import contact_kernels, kinematic, pose
    stamp = jit.source_stamp(os.path.dirname(os.path.abspath(jit.__file__)))
    assert config.CACHE_DIR == jit.cache_dir()
    assert os.path.basename(config.CACHE_DIR) == 'numba-' + stamp[:16]
    dispatchers = [getattr(K, name) for name in K.__all__ if hasattr(getattr(K, name), 'py_func')]
    for mod in (pose, contact_kernels, kinematic):
        dispatchers += [f for f in vars(mod).values()
                        if hasattr(f, 'py_func') and f.py_func.__module__ == mod.__name__]
    files = {os.path.basename(d.py_func.__code__.co_filename) for d in dispatchers}
    assert {'colliders.py', 'damping.py', 'goals.py', 'integrate.py', 'linalg.py',
            'plasticity.py', 'rotation.py', 'sets.py', 'pose.py', 'kinematic.py'} <= files
    for d in dispatchers:
        assert d._cache._cache_path.startswith(config.CACHE_DIR + os.sep), d


def test_source_stamp_changes_with_any_file(tmp_path):
    """The stamp (and so the cache directory) hashes the content of every .py file of the
    directory and nothing else."""
    (tmp_path / 'a.py').write_text('x = 1\n')
    (tmp_path / 'b.py').write_text('y = 1\n')
    first = jit.cache_dir(str(tmp_path), 'parent')
    (tmp_path / 'b.py').write_text('y = 2\n')
    second = jit.cache_dir(str(tmp_path), 'parent')
    (tmp_path / 'notes.txt').write_text('not source')
    assert first != second == jit.cache_dir(str(tmp_path), 'parent')
    assert os.path.dirname(second) == 'parent'
