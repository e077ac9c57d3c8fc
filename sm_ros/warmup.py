"""Compile (or load from Numba's on-disk cache) every solver kernel the node can need.

Numba compiles a kernel on its first call.  ``sim_node`` on a cold cache compiles only what
its scene needs (building the scene steps a throwaway copy of it) and then starts
:func:`start_background`: ``python -m sm_ros.warmup --background``, niced on one core,
compiles the rest into the cache while the node runs, so that a later scene, contact or
mode loads its kernels instead of compiling them.  ``python -m sm_ros.warmup`` (``ros2 run
sm_ros warmup``) does all of it ahead of time; ``make test`` runs it.  On a cold cache it
compiles in three processes, each stepping its share of the throwaway worlds of
``warmup_stages.py``: the stiff bodies' contact pass (``stiff_contact.py``) has one of its
own, since no other stage needs it.
"""

import argparse
import importlib
import os
import pkgutil
import subprocess
import sys
import tempfile
import threading
import time
from typing import Callable, Optional, Sequence

from .warmup_stages import MAIN_STAGES, run_soft, warm_extra, warm_scene, warm_stiff

#: Seconds a cold compile of every kernel takes on 2 idle cores (its three processes share
#: them; ``python -m sm_ros.bench startup`` reports the CPU seconds); ``warmup`` quotes it
#: in its cold-start line and progress bar.
COLD_COMPILE_S = 70.0


def _core_kernels():
    """Return the cached Numba dispatchers defined in sm_ros.core's modules."""
    from numba.core.registry import CPUDispatcher
    import sm_ros.core as core
    out = []
    for info in pkgutil.walk_packages(core.__path__, core.__name__ + '.'):
        mod = importlib.import_module(info.name)
        for value in vars(mod).values():
            files = getattr(getattr(value, '_cache', None), '_cache_file', None)
            if isinstance(value, CPUDispatcher) and files is not None \
                    and value.__module__ == mod.__name__:
                out.append(value)
    return out


def _stamp_path(kernels) -> str:
    return os.path.join(kernels[0]._cache._cache_file._cache_path, 'sm_ros_warm.json')


def _sources_stamp() -> dict:
    """Return what Numba's cache depends on: the core's source files and Numba's version."""
    import numba
    import sm_ros.core as core
    root = os.path.dirname(core.__file__)
    files = {}
    for folder, _, names in os.walk(root):
        for name in names:
            if name.endswith('.py'):
                st = os.stat(os.path.join(folder, name))
                files[os.path.relpath(os.path.join(folder, name), root)] = \
                    [st.st_mtime_ns, st.st_size]
    return {'numba': numba.__version__, 'python': sys.version.split()[0], 'files': files}


def cold_kernels() -> Optional[int]:
    """Return how many solver kernels the next start compiles: 0 when Numba's on-disk cache
    was filled by a warm-up since the core's sources last changed (its stamp: their times
    and sizes, Numba's version), else the number of cached kernels in ``sm_ros.core``;
    None when it cannot be told."""
    try:
        import json
        kernels = _core_kernels()
        if not kernels:
            return 0
        path = _stamp_path(kernels)
        try:
            with open(path, encoding='utf-8') as f:
                if json.load(f) == _sources_stamp():
                    return 0
        except (OSError, ValueError):
            pass
        return len(kernels)
    except Exception:  # noqa: BLE001 - internals of Numba: unknown rather than wrong
        return None


def mark_warm() -> None:
    """Record that the cache matches the current sources (after a complete warm-up)."""
    try:
        import json
        kernels = _core_kernels()
        if kernels:
            path = _stamp_path(kernels)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            tmp = path + f'.{os.getpid()}'
            with open(tmp, 'w', encoding='utf-8') as f:
                json.dump(_sources_stamp(), f)
            os.replace(tmp, path)
    except Exception:  # noqa: BLE001 - a read-only cache only loses the cold-start note
        pass


def cold_start_note() -> Optional[str]:
    """Return the line ``warmup`` prints before a cold compile, or None when it is warm."""
    n = cold_kernels()
    if not n:
        return None
    return (f'compiling {n} solver kernels (cold Numba cache): about {COLD_COMPILE_S:.0f} s '
            'on 2 cores, once per install; `ros2 run sm_ros warmup` (or '
            '`python -m sm_ros.warmup`) does it ahead of time')


def scene_start_note(scene: str) -> Optional[str]:
    """Return the line the node logs before it builds its first scene on a cold cache
    (None when the cache is warm)."""
    n = cold_kernels()
    if not n:
        return None
    return (f"cold Numba cache: compiling the kernels scene '{scene or 'default'}' needs "
            "first (seconds); the rest of the solver's kernels then compile in a background "
            'process (niced, one core) while the node runs')


def start_background():
    """Start ``python -m sm_ros.warmup --background`` (every kernel into the cache, niced,
    on one core, with this process's Numba thread count: the same variants); return
    ``(process, stderr file)``, or None when it cannot start (:func:`stop_helpers`)."""
    import numba
    env = {'NUMBA_NUM_THREADS': str(numba.config.NUMBA_NUM_THREADS)}
    extra = _spawn(['--background'], env)
    if extra is not None:
        _HELPERS.append(extra)
    return extra


def finish_background(extra) -> Optional[int]:
    """Wait for the background warm-up and release its files: its exit status (None:
    stopped by :func:`stop_helpers`)."""
    proc, err = extra
    code = proc.wait()
    if extra in _HELPERS:
        _HELPERS.remove(extra)
    err.close()
    return None if code < 0 else code


def stop_background(extra) -> None:
    """Kill a background warm-up if it still runs (the cache keeps what it finished)."""
    proc = extra[0]
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _background() -> int:
    """The background warm-up: lowest priority (nice 19 and, on Linux, the idle scheduling
    class: it runs only on a core nothing else wants), one core, every kernel, the stamp."""
    try:
        os.nice(19)
        cpus = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpus[-1]})
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        pass                       # the priority is a courtesy: warm up all the same
    warm_up(split=False)
    warm_scene('default')
    return 0


def warm_up(on_stage: Optional[Callable[[str], None]] = None, split: bool = True) -> float:
    """Compile the solver's Numba kernels on a throwaway world; return the seconds spent.

    Covers every deformation mode, clusters, plasticity, colliders, wrenches and kinematic
    particles, so the node's first tick does not pay for compilation (a fraction of a
    second from a warm cache).

    On a cold cache (and ``split``) two helper processes compile beside this one, which
    compiles ``MAIN_STAGES``: ``python -m sm_ros.warmup --extra`` (:func:`warm_extra`,
    ``EXTRA_STAGES``) and ``--stiff`` (the stiff bodies' contact pass); Numba's cache files
    are written whole (a temporary file, then renamed), so each process loads what another
    has finished.  Without helpers this one does all of it."""
    t0 = time.perf_counter()
    helpers = {}                             # (process, stderr file): its part
    if split and _cpus() > 1 and cold_kernels():
        for flag, part in (('--extra', warm_extra), ('--stiff', warm_stiff)):
            helper = _spawn([flag])
            if helper is not None:
                helpers[helper] = part
    _HELPERS.extend(helpers)
    try:
        return _warm_up(on_stage, helpers, t0)
    except BaseException:                    # Ctrl-C, an error: the other processes too
        for helper in helpers:
            _stop(helper)
        raise
    finally:
        for helper in helpers:
            if helper in _HELPERS:
                _HELPERS.remove(helper)


#: The warm-up helper processes running now (``warm_up``), for ``stop_helpers``.
_HELPERS = []


def _stop(extra) -> None:
    proc, err = extra
    proc.kill()
    proc.wait()
    err.close()


def stop_helpers() -> None:
    """Kill and reap the warm-up helper processes still running: a Ctrl-C while the node
    starts ends the process without unwinding the warm-up (``startup.run``)."""
    for extra in list(_HELPERS):
        _stop(extra)


def _warm_up(on_stage, helpers, t0) -> float:
    for stage in MAIN_STAGES:
        run_soft(stage)
        if on_stage is not None:
            on_stage(stage.__name__.strip('_').replace('_', ' '))
    for helper, part in helpers.items():
        _finish_extra(helper, part)
    for part in (warm_extra, warm_stiff):
        if part not in helpers.values():         # no helper started for it: here
            part()
    mark_warm()
    return time.perf_counter() - t0


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _spawn(args, env_extra=None):
    """Start ``python -m sm_ros.warmup ARGS`` on this package; (process, stderr file)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, **(env_extra or {}))
    env['PYTHONPATH'] = os.pathsep.join(p for p in (root, env.get('PYTHONPATH')) if p)
    err = tempfile.TemporaryFile()
    try:
        proc = subprocess.Popen([sys.executable, '-m', 'sm_ros.warmup', *args], env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=err)
    except OSError:
        err.close()
        return None
    return proc, err


def _finish_extra(extra, part=None) -> None:
    """Wait for a helper process; if it failed, say so and compile its ``part`` (default
    :func:`warm_extra`) here."""
    proc, err = extra
    with err:
        code = proc.wait()
        if code != 0:
            err.seek(0)
            tail = err.read().decode(errors='replace').strip().splitlines()[-3:]
            print('sm_ros: a warm-up helper process failed (exit status '
                  f'{code}): {" / ".join(tail)}; compiling its kernels here',
                  file=sys.stderr, flush=True)
            (part or warm_extra)()


#: Stages ``warm_up`` reports to ``on_stage``.
WARM_UP_STAGES = len(MAIN_STAGES)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Warm the generic kernels and the given bundled scenes (default: 'default')."""
    ap = argparse.ArgumentParser(prog='python -m sm_ros.warmup', description=__doc__)
    ap.add_argument('scenes', nargs='*', default=['default'],
                    help="bundled scene names or YAML paths (default: 'default')")
    ap.add_argument('--extra', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--stiff', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--background', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.extra:                      # the helper processes of a cold warm_up
        warm_extra()
        return 0
    if args.stiff:
        warm_stiff()
        return 0
    if args.background:                 # started by a node on a cold cache
        return _background()
    from sm_ros.progress import bar
    note = cold_start_note()
    print('sm_ros: ' + (note or 'loading the solver kernels from the cache'), flush=True)
    if note:
        # a cold compile is one long call: the bar runs on the expected time (it never
        # claims to be done before the compile is), stages only name what is compiling
        with bar(total=COLD_COMPILE_S, desc='compiling', unit='s',
                 bar_format='{l_bar}{bar}| {n:.0f}/{total:.0f} s expected [{elapsed}]') as pb:
            done = threading.Event()

            def tick():
                t0 = time.monotonic()
                while not done.wait(0.5):
                    pb.n = min(time.monotonic() - t0, COLD_COMPILE_S * 0.99)
                    pb.refresh()
            ticker = threading.Thread(target=tick, daemon=True)
            ticker.start()
            try:
                total = warm_up(on_stage=pb.set_postfix_str)
                for name in args.scenes:
                    pb.set_postfix_str(name)
                    total += warm_scene(name)
            finally:
                done.set()
                ticker.join()
            pb.n = pb.total
            pb.refresh()
    else:
        with bar(total=WARM_UP_STAGES + len(args.scenes), desc='warmup', unit='stage') as pb:
            total = warm_up(on_stage=lambda _: pb.update())
            for name in args.scenes:
                pb.set_postfix_str(name)
                total += warm_scene(name)
                pb.update()
    print(f'sm_ros: kernels ready ({total:.1f} s)', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
