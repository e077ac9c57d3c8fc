"""Compilation options shared by every kernel, and a Numba cache that sees across files.

Numba's on-disk cache (``cache=True``, in each folder's ``__pycache__``) checks a compiled
function against its own file only, not against the jitted functions it calls in other
files, so a cached kernel would keep an old copy of an edited callee.  Therefore, when
any kernel file changed since the cache was written, ``clear_stale_cache`` drops the
cache indexes of all of ``sm_ros/core`` at import, and every kernel and every core module
that calls one compiles afresh (``test/test_kernel_cache.py``).
"""

import functools
import hashlib
import os

import numpy as np
from llvmlite import ir
from numba import njit as _njit, types
from numba.core import config
from numba.extending import intrinsic

#: Fastmath flags used by every kernel (no ``nnan``/``ninf``: NaN checks must still work).
FASTMATH = {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}
#: Options of every kernel: cached on disk, fast math as above, the GIL released.
JIT = dict(cache=True, fastmath=FASTMATH, nogil=True)
#: Options of the kernels that allocate nothing (the body step's, the contact solves'
#: visits, the stiff pass's contact points): without Numba's reference counting (its
#: ``_nrt`` option), which counts a reference at every read of an array from a tuple and
#: at every call with an atomic operation that costs more than the arithmetic around it.
JIT_NO_REFCOUNT = dict(JIT, _nrt=False)

_KERNEL_DIR = os.path.dirname(os.path.abspath(__file__))


@functools.lru_cache(maxsize=None)
def _hash_files(stats):
    digest = hashlib.sha256()
    for path, _mtime, _size in stats:
        digest.update(os.path.basename(path).encode())
        with open(path, 'rb') as f:
            digest.update(hashlib.sha256(f.read()).digest())
    return digest.hexdigest()


def source_stamp(directory):
    """SHA-256 over every ``.py`` file of ``directory`` (re-read when one changes)."""
    paths = sorted(os.path.join(directory, name) for name in os.listdir(directory)
                   if name.endswith('.py'))
    stats = []
    for path in paths:
        st = os.stat(path)
        stats.append((path, st.st_mtime_ns, st.st_size))
    return _hash_files(tuple(stats))


def clear_stale_cache(directory=_KERNEL_DIR, root=None):
    """Drop the Numba cache indexes (``*.nbi``) below ``root`` (default: the folder above
    ``directory``) and in the ``NUMBA_CACHE_DIR`` folders of the same names when the files
    of ``directory`` changed since the last call (their stamp is kept in
    ``directory/__pycache__``)."""
    stamp = source_stamp(directory)
    mark = os.path.join(directory, '__pycache__', 'kernel_sources.sha256')
    try:
        with open(mark, encoding='ascii') as f:
            if f.read() == stamp:
                return
    except OSError:
        pass
    root = root or os.path.dirname(directory)
    tops = [root]
    if config.CACHE_DIR and os.path.isdir(config.CACHE_DIR):
        tops += [os.path.join(config.CACHE_DIR, cache_folder_name(f)) for f, _, _ in os.walk(root)]
    for top in tops:
        for folder, _, names in os.walk(top):
            for name in names:
                if name.endswith('.nbi'):
                    try:
                        os.remove(os.path.join(folder, name))
                    except OSError:             # gone already (another process)
                        pass
    try:
        os.makedirs(os.path.dirname(mark), exist_ok=True)
        with open(mark, 'w', encoding='ascii') as f:
            f.write(stamp)
    except OSError:                             # a read-only install: nothing is cached
        pass


def cache_folder_name(folder):
    """The folder under ``NUMBA_CACHE_DIR`` that holds the cache of the files of ``folder``:
    Numba names it after the folder and the SHA-1 of its absolute path, so another copy of
    the package (an install tree, say) has folders of the same names but other hashes."""
    path = os.path.abspath(folder)
    return f'{os.path.basename(path)}_{hashlib.sha1(path.encode()).hexdigest()}'


clear_stale_cache()

#: Index type of the particle loops that run over a range ``start..end``:
#: ``for i in range(U(start), U(end))``.  Numba wraps a negative signed index around
#: (``i + n`` when ``i < 0``); with a start whose sign LLVM cannot prove, that select makes
#: every address non-affine in i and the loop vectoriser gives up (a loop from 0 is fine).
#: An unsigned index has no wraparound, so the per-component loads and stores of the
#: (N, 3) F-contiguous state become unit-stride vectors.  Only index with it: numba types
#: ``uint64 + int64`` as a float.
U = np.uint64
#: The largest finite float64.
FLOAT_MAX = 1.7976931348623157e308


@_njit(inline='always', **JIT)
def finite(x):
    """Whether ``x`` is finite (neither inf nor nan), for every kernel's guards.

    Under ``FASTMATH`` LLVM folds ``np.isfinite(x)`` / ``math.isfinite(x)`` to True when a
    comparison of the same value comes first (``det > 1e-9 and np.isfinite(det)`` let an
    overflowed ``det = inf`` through). Comparisons with the largest float are not folded
    and are False for nan (``test/test_nonfinite_kernels.py``).
    """
    return -FLOAT_MAX <= x <= FLOAT_MAX


@intrinsic
def claim_next(typingctx, counter):
    """``counter[0] += 1`` as one atomic operation (sequentially consistent); returns the
    value before.  Threads that share one counter each take distinct work items with it
    (the bodies of ``world_step.step_bodies_claimed``, the chunks of a big body's passes)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64
            and counter.ndim == 1):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.atomic_rmw('add', ary.data, ir.Constant(ir.IntType(64), 1), 'seq_cst')

    return sig, codegen
