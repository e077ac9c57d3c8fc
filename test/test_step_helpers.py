"""The helper threads of the threaded world step (``sm_ros.core.step_threads``)."""

import threading

import pytest

from sm_ros.core.step_threads import Helpers


def _claiming_job(n, entered, done, lock, who):
    """A job in the manner of ``step_bodies_claimed``: every caller takes items from one
    counter until none is left; the calling thread first waits for a helper to join."""
    nxt = [0]

    def fn():
        if threading.current_thread() is threading.main_thread():
            assert entered.wait(10.0), 'no helper joined'
        else:
            entered.set()
        while True:
            with lock:
                k = nxt[0]
                nxt[0] += 1
            if k >= n:
                return
            with lock:
                done[k] += 1
                who.add(threading.current_thread().name)
    return fn


def test_helpers_share_a_job_and_every_item_is_done_once():
    helpers = Helpers()
    for _ in range(3):                      # the same helper thread, job after job
        entered, lock, who = threading.Event(), threading.Lock(), set()
        done = [0] * 200
        before = []
        helpers.run(1, _claiming_job(200, entered, done, lock, who), (),
                    before=lambda b=before: b.append(threading.current_thread().name))
        assert done == [1] * 200 and entered.is_set()
        # ``before`` ran once, on the calling thread (the helper may have started already)
        assert before == [threading.current_thread().name]
    assert len(helpers._threads) == 1 and helpers._active == 0 and helpers._job is None


def test_an_exception_in_a_helper_is_raised_in_the_caller():
    helpers = Helpers()
    entered = threading.Event()
    release = threading.Event()

    def fn():
        if threading.current_thread() is threading.main_thread():
            assert entered.wait(10.0)
            release.set()
            return
        entered.set()
        release.wait(10.0)
        raise ValueError('helper failed')

    with pytest.raises(ValueError, match='helper failed'):
        helpers.run(1, fn, ())
    assert helpers._active == 0 and helpers._error is None


def test_a_second_caller_runs_its_job_alone_while_one_is_running():
    """Two worlds stepped from two threads: the job that finds the helpers busy runs on
    its own thread, whole, and the first job is not disturbed."""
    helpers = Helpers()
    entered, inner_done = threading.Event(), []
    lock, who, done = threading.Lock(), set(), [0] * 50

    def outer():
        if threading.current_thread() is threading.main_thread():
            assert entered.wait(10.0)
            # meanwhile another thread runs a job of its own: not shared, done whole
            t = threading.Thread(target=lambda: helpers.run(
                1, lambda: inner_done.append(threading.current_thread().name), ()))
            t.start()
            t.join(10.0)
            assert inner_done and inner_done[0] == t.name
        else:
            entered.set()

    helpers.run(1, outer, ())
    helpers.run(1, _claiming_job(50, threading.Event(), done, lock, who), ())
    assert done == [1] * 50 and len(inner_done) == 1


def test_the_world_shares_its_records_with_the_helpers(monkeypatch):
    """With several threads and records ``World.step`` hands its records to the
    helpers."""
    import numba
    import numpy as np

    import sm_ros.core.world as world_mod
    from sm_ros.core import BodyParams, World, tuning
    from sm_ros.core.contact import ContactParams

    if numba.get_num_threads() < 2:
        pytest.skip('one Numba thread: no helpers')
    monkeypatch.setattr(tuning, 'RECORDS_PARALLEL_MIN_WORK', 0)
    calls = []
    real = world_mod.step_bodies_parallel

    def spy(*args, **kw):
        calls.append(len(args[0]))
        return real(*args, **kw)

    monkeypatch.setattr(world_mod, 'step_bodies_parallel', spy)
    g = np.arange(4) * 0.02
    lat = np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)
    world = World()
    world.contact_params = ContactParams(enabled=False)
    for b in range(3):
        world.add_body(lat + (0.2 * b, 0.0, 0.5), masses=0.01,
                       params=BodyParams(mode='linear', clusters=2, damping=0.05))
    world.step(1.0 / 240.0)
    assert len(world._split[2]) == 3 and world._split[4]
    assert calls == [3]
