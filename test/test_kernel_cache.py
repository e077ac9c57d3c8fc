"""The kernels' Numba cache notices edits to jitted functions in other kernel files."""

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


def _run(tmp_path, shared):
    """Import the two-file package in a fresh process and return caller()."""
    init = ('import os\nfrom sm_ros.core.kernels.jit import SHARED_STAMP_DIRS\n'
            'SHARED_STAMP_DIRS.add(os.path.dirname(os.path.abspath(__file__)))\n'
            if shared else '')
    (tmp_path / 'pkg' / '__init__.py').write_text(init)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), REPO]),
               NUMBA_CACHE_DIR=str(tmp_path / 'cache'))
    out = subprocess.run([sys.executable, '-c', 'from pkg.caller import caller; '
                          'print(caller())'], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    return float(out.stdout.split()[-1])


@pytest.mark.parametrize('shared', [False, True])
def test_kernel_cache_sees_edits_in_other_files(tmp_path, shared):
    """Edit a callee in another file between two runs: the shared stamp recompiles the
    caller; Numba's own per-file stamp (``shared=False``) serves the stale result."""
    pkg = tmp_path / 'pkg'
    pkg.mkdir()
    (pkg / 'caller.py').write_text(textwrap.dedent(_CALLER))
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('1.0')))
    assert _run(tmp_path, shared) == 1.5
    (pkg / 'callee.py').write_text(textwrap.dedent(_CALLEE.format('2.0')))
    assert _run(tmp_path, shared) == (2.5 if shared else 1.5)


def test_every_kernel_carries_the_package_stamp():
    """All cached kernels of every kernel file use the stamp of the whole package."""
    stamp = jit.source_stamp(os.path.dirname(os.path.abspath(jit.__file__)))
    dispatchers = [getattr(K, name) for name in K.__all__ if hasattr(getattr(K, name), 'py_func')]
    files = {os.path.basename(d.py_func.__code__.co_filename) for d in dispatchers}
    assert {'colliders.py', 'damping.py', 'goals.py', 'integrate.py', 'linalg.py',
            'plasticity.py', 'rotation.py', 'sets.py'} <= files
    for d in dispatchers:
        locator = d._cache._impl.locator
        assert isinstance(locator, jit.KernelCacheLocator), d
        assert locator.get_source_stamp() == stamp


def test_core_modules_calling_kernels_carry_the_package_stamp():
    """A jitted function of sm_ros/core outside the kernel package (pose.py calls
    ``extract_rotation``) is stamped with its own source and the package's stamp."""
    from sm_ros.core import pose
    stamp = jit.source_stamp(os.path.dirname(os.path.abspath(jit.__file__)))
    jitted = [f for f in vars(pose).values()
              if hasattr(f, 'py_func') and f.py_func.__module__ == pose.__name__]
    assert jitted
    for d in jitted:
        locator = d._cache._impl.locator
        assert isinstance(locator, jit.KernelCacheLocator), d
        assert locator.get_source_stamp()[1] == stamp


def test_source_stamp_changes_with_any_file(tmp_path):
    """The stamp hashes the content of every .py file of the directory."""
    (tmp_path / 'a.py').write_text('x = 1\n')
    (tmp_path / 'b.py').write_text('y = 1\n')
    first = jit.source_stamp(str(tmp_path))
    (tmp_path / 'b.py').write_text('y = 2\n')
    second = jit.source_stamp(str(tmp_path))
    (tmp_path / 'notes.txt').write_text('not source')
    assert first != second == jit.source_stamp(str(tmp_path))


@pytest.mark.parametrize('module', ['contact_kernels', 'kinematic'])
def test_contact_law_callers_carry_the_package_stamp(module):
    """The contact kernels (they call ``kernels.colliders.collide_point``) and kinematic.py
    (it calls ``kernels.colliders.contact_velocity``) are stamped with the kernel package,
    so an edit of the shared contact law recompiles them."""
    import importlib
    from sm_ros.core import contact, kinematic
    assert contact.contact_velocity is kinematic.contact_velocity is K.contact_velocity
    mod = importlib.import_module(f'sm_ros.core.{module}')
    stamp = jit.source_stamp(os.path.dirname(os.path.abspath(jit.__file__)))
    jitted = [f for f in vars(mod).values()
              if hasattr(f, 'py_func') and f.py_func.__module__ == mod.__name__]
    assert jitted
    for d in jitted:
        locator = d._cache._impl.locator
        assert isinstance(locator, jit.KernelCacheLocator), d
        assert locator.get_source_stamp()[1] == stamp
