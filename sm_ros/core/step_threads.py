"""Helper threads that share a job with the calling thread (no compiled code here).

``kernels.world_step.step_bodies_parallel`` steps the compiled-step records on the
calling thread and on these helpers: each calls ``step_bodies_claimed``, which takes
records from an atomic counter, so the calling thread never waits for a helper that has
not started.  Kept out of the kernel package: an edit here does not invalidate the
kernels' on-disk cache (``kernels.jit``: one cache directory keyed on the kernel files).
"""

import os
import threading


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
