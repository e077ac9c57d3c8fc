"""Helper threads that share a job with the calling thread (no compiled code here).

``kernels.world_step.step_bodies_parallel`` steps the compiled-step records on the
calling thread and on these helpers: each calls ``step_bodies_claimed``, which takes
records from an atomic counter, so the calling thread never waits for a helper that has
not started.  Kept out of the kernel package: an edit here does not invalidate the
kernels' on-disk cache (``kernels.jit``: one stamp for the whole package).
"""

import os
import threading

#: ``cores_free``: the helpers are used while the 1-minute load average is below the CPUs
#: this process may run on plus this margin.  On the shared 2-core machine the records of
#: ``paper_384`` ran 1.5-1.9x faster with a helper while a core was free, and the tick ~8 %
#: slower at load 3.2-4.0 (doc/benchmarks.md, "The records of paper_384 on helper
#: threads"); the node's own busy thread counts about 1 of the load.
LOAD_MARGIN = 0.5
try:
    _CPUS = len(os.sched_getaffinity(0))
except AttributeError:                          # not on Linux
    _CPUS = os.cpu_count() or 1


def cores_free():
    """Whether a helper is likely to find a core: the 1-minute load average below the
    usable CPUs plus ``LOAD_MARGIN`` (True where the load average is not available).
    Only speed depends on it: the helpers' results are bit for bit the serial ones."""
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return True
    return load < _CPUS + LOAD_MARGIN


class Helpers:
    """Helper threads that join the calling thread on one job at a time (``run``).

    A job is a function and its arguments that every participant calls; the function
    itself shares the work out (``step_bodies_claimed``: an atomic counter), so a job is
    done once the calling thread's call returned and no helper is inside one.  A helper
    that wakes after the calling thread closed the job does not start it.
    """

    def __init__(self):
        self._cond = threading.Condition()
        self._threads = []
        self._job = None                       # (generation, fn, args) or None: closed
        self._gen = 0
        self._active = 0                       # helpers inside the current job's fn
        self._error = None
        self._busy = threading.Lock()          # one job at a time (see run)

    def _loop(self):
        seen = 0
        while True:
            with self._cond:
                while self._job is None or self._job[0] == seen:
                    self._cond.wait()
                seen, fn, args = self._job
                self._active += 1
            try:
                fn(*args)
            except BaseException as exc:        # handed to the caller (run)
                with self._cond:
                    self._error = exc
            finally:
                with self._cond:
                    self._active -= 1
                    self._cond.notify_all()

    def run(self, helpers, fn, args, before=None):
        """Call ``fn(*args)`` here and on up to ``helpers`` helper threads; return when
        this call has returned and no helper is still inside its call (an exception
        raised in a helper is raised here).  ``before()`` runs here first, after the
        helpers were woken (work of the calling thread alone, while they start).  While
        another thread's job runs (two worlds stepped from two threads), ``before`` and
        ``fn`` run on the calling thread alone."""
        if not self._busy.acquire(blocking=False):
            if before is not None:
                before()
            fn(*args)
            return
        try:
            self._run(helpers, fn, args, before)
        finally:
            self._busy.release()

    def _run(self, helpers, fn, args, before):
        with self._cond:
            while len(self._threads) < helpers:
                t = threading.Thread(target=self._loop, daemon=True,
                                     name=f'sm_ros-step-{len(self._threads) + 1}')
                t.start()
                self._threads.append(t)
            self._gen += 1
            self._job = (self._gen, fn, args)
            self._error = None
            self._cond.notify(helpers)
        try:
            if before is not None:
                before()
            fn(*args)
        finally:
            with self._cond:
                self._job = None
                while self._active:
                    self._cond.wait()
                error, self._error = self._error, None
        if error is not None:
            raise error

    def _after_fork(self):
        """In a forked child the helper threads do not exist: start over."""
        self.__init__()


#: The process's helper threads of ``step_bodies_parallel``.
HELPERS = Helpers()
if hasattr(os, 'register_at_fork'):
    os.register_at_fork(after_in_child=HELPERS._after_fork)
