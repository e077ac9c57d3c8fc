"""Compilation options shared by every kernel, and a Numba cache that sees across files.

Numba's on-disk cache (``cache=True``) keys a compiled function on the source of the file
that defines it (its "source stamp") and on its own bytecode, but not on the jitted
functions it calls.  A kernel in ``integrate.py`` that calls ``colliders._collide_range``
would keep running the old collider code from the cache after ``colliders.py`` was edited
(that is why the kernels used to live in one file).  ``KernelCacheLocator`` closes the gap:
every function defined in this package gets one shared source stamp, the SHA-256 of all
the package's ``.py`` files, so an edit to any kernel file makes Numba discard and
recompile every cached kernel on first use.  It is registered, before any kernel is
decorated, in front of Numba's own locators and wraps the one Numba would have chosen
(``NUMBA_CACHE_DIR``, ``__pycache__`` or the user-wide cache directory); only the stamp
differs.  Jitted modules of ``sm_ros/core`` that call kernels (``pose.py``, ...) are stamped
with their own source plus the package's stamp.  ``test/test_kernel_cache.py`` checks this
end to end.
"""

import functools
import hashlib
import os

import numpy as np

from numba import carray as _carray
from numba import njit as _njit
from numba import types as _types
from numba.core import caching
from numba.extending import intrinsic as _intrinsic

# Numba's registry of cache locators (renamed from ``_CacheImpl`` in Numba 0.58).
_CACHE_IMPL = getattr(caching, 'CacheImpl', None) or caching._CacheImpl

#: Fastmath flags used by every kernel (no ``nnan``/``ninf``: NaN checks must still work).
FASTMATH = {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}
#: Options of every kernel: cached on disk, fast math as above, the GIL released.
JIT = dict(cache=True, fastmath=FASTMATH, nogil=True)

_KERNEL_DIR = os.path.dirname(os.path.abspath(__file__))
#: Directories whose modules share one cache stamp (this package; tests add their own).
SHARED_STAMP_DIRS = {_KERNEL_DIR}
#: Directories whose jitted modules call kernels (``sm_ros/core``: pose, contact, ...): each
#: module is stamped with its own source and the kernel package's stamp.
DEPENDENT_DIRS = {os.path.dirname(_KERNEL_DIR): _KERNEL_DIR}


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


class KernelCacheLocator(caching._CacheLocator):
    """Numba's usual cache place for a function, stamped with its whole directory."""

    def __init__(self, inner, directory, py_file=None):
        self._inner = inner
        self._directory = directory
        self._py_file = py_file

    def ensure_cache_path(self):
        """Create the wrapped locator's cache directory."""
        self._inner.ensure_cache_path()

    def get_cache_path(self):
        """The wrapped locator's cache directory."""
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        """The package's stamp (with the module's own hash for a dependent module)."""
        if self._py_file is None:
            return source_stamp(self._directory)
        st = os.stat(self._py_file)
        return (_hash_files(((self._py_file, st.st_mtime_ns, st.st_size),)),
                source_stamp(self._directory))

    def get_disambiguator(self):
        """The wrapped locator's disambiguator (the function's line number)."""
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        """A locator for functions of the stamped directories, else None."""
        own = os.path.dirname(os.path.abspath(py_file))
        if own in SHARED_STAMP_DIRS:
            directory, single = own, None
        elif own in DEPENDENT_DIRS:
            directory, single = DEPENDENT_DIRS[own], os.path.abspath(py_file)
        else:
            return None
        for other in _CACHE_IMPL._locator_classes:
            if other is cls:
                continue
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, directory, single)
        return None


if KernelCacheLocator not in _CACHE_IMPL._locator_classes:
    _CACHE_IMPL._locator_classes.insert(0, KernelCacheLocator)

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


@_intrinsic
def wide_vectors(typingctx):
    """Let LLVM vectorise the loops of the jitted function that calls this 512 bits wide.

    Numba builds every kernel for the host with LLVM's choice of vector width, which on
    AVX-512 hosts is 256 bits (the ``prefer-256-bit`` tuning; this machine kind's 32
    vector registers hold 8 doubles each, only 4 are used).  Numba has no per-function
    width, and 512 bits for every kernel (``NUMBA_CPU_FEATURES``) made the lattice-order
    8-cluster steps 9-50 % slower (doc/benchmarks.md).  This sets the LLVM function
    attribute ``"prefer-vector-width"="512"`` on the calling function only, which the X86
    backend reads per function; on a host without AVX-512 the widest legal vectors are
    used instead (256 bits on AVX2), so nothing changes there.  The loops vectorised in
    that function's own compilation keep the width when LLVM later inlines it into a
    caller.  ``test_kernel_jit.py`` checks that a caller's loop gets 512-bit registers.
    """
    def codegen(context, builder, sig, args):
        # llvmlite's attribute set takes only its list of known names: a string
        # attribute (key=value) is added to the set as LLVM IR writes it
        set.add(builder.function.attributes, '"prefer-vector-width"="512"')
        return context.get_dummy_value()
    return _types.none(), codegen



@_intrinsic
def _element_pointer(typingctx, arr, i):
    """Pointer to element ``i`` of a 1-D C-contiguous array (no bounds check)."""
    if not (isinstance(arr, _types.Array) and arr.ndim == 1 and arr.layout == 'C'):
        return None
    sig = _types.CPointer(arr.dtype)(arr, _types.intp)

    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        return builder.gep(ary.data, [args[1]])
    return sig, codegen


@_njit(inline='always', **JIT)
def scratch_view(buf, start, shape):
    """A C-contiguous array of ``shape`` on ``buf[start:]`` (1-D, C-contiguous) that takes
    no reference count: valid while ``buf`` is, so only for scratch a compiled function
    views at its start and drops before it returns (``packed._step_chunk``).

    ``buf[a:b].reshape(shape)`` calls Numba's run-time reshape helper and moves the
    buffer's reference count up and down (atomic): ~30 ns a view passed to a call, 0.08
    ns this way (``tools/pack_call.py``: ``reshape_view_ns``, ``scratch_view_ns``).  With
    these views,
    the pack's particle arrays by address (``address_view``) and a thinner call, the fixed
    cost of a one-cluster ``World.step`` fell from 4.5-4.9 to 2.4-2.6 us
    (``tools/loop_floor.py``).  IndexError past the end of ``buf``.
    """
    size = 1
    for s in shape:
        size *= s
    if start < 0 or start + size > buf.shape[0]:
        raise IndexError('scratch view past the end of its buffer')
    return _carray(_element_pointer(buf, start), shape)


@_intrinsic
def _address_pointer(typingctx, addr):
    """A float64 pointer to the address ``addr`` (an integer)."""
    sig = _types.CPointer(_types.float64)(_types.intp)

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], context.get_value_type(sig.return_type))
    return sig, codegen


@_njit(inline='always', **JIT)
def address_view(addr, shape):
    """The C-contiguous float64 array of ``shape`` at the address ``addr`` (an array's
    ``ctypes.data``), taking no reference count: valid only while that array lives and
    keeps its buffer, with no bounds known (``packed.Pack`` holds its bodies' particle
    arrays and checks their sizes when it takes their addresses).

    The pack passed its bodies' arrays in a typed list before: a no-op call unboxes a
    list of one body's four arrays in ~0.75 us, an array in ~0.16 (``tools/pack_call.py``:
    ``unbox_typed_list``, ``unbox_array``), and fetching a body's tuple moved four
    reference counts up and down (atomic) per body.
    """
    return _carray(_address_pointer(addr), shape)


@_intrinsic
def never_inline(typingctx):
    """Keep LLVM from inlining the jitted function that calls this into its callers (the
    ``noinline`` attribute).  Each caller's compiled module then calls the function's own
    machine code, optimised once from the same IR, instead of a copy optimised in the
    caller's context: under fast math two such copies may round differently
    (``packed._step_chunk``, called by the one-thread and the threaded pack steps)."""
    def codegen(context, builder, sig, args):
        builder.function.attributes.add('noinline')
        return context.get_dummy_value()
    return _types.none(), codegen
