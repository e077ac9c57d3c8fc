"""Cold-start detection and the warm-up's progress (no compilation in these tests)."""

import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parent.parent
PROBE = 'from sm_ros import warmup; print(warmup.cold_kernels()); print(warmup.cold_start_note())'


def _probe(pkg_root: Path):
    env = dict(os.environ, PYTHONPATH=str(pkg_root), NUMBA_DISABLE_JIT='0')
    env.pop('NUMBA_CACHE_DIR', None)
    out = subprocess.run([sys.executable, '-c', PROBE], cwd=pkg_root, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    n, note = out.stdout.strip().splitlines()
    return int(n), note


@pytest.mark.slow
def test_fresh_copy_is_cold_warm_cache_is_not_and_an_edit_makes_it_cold(tmp_path, warm):
    if os.environ.get('NUMBA_CACHE_DIR'):
        pytest.skip('NUMBA_CACHE_DIR is set: the warm-up filled that cache, not the '
                    "package's own, which this test copies")
    # the worktree's cache is warm (the fixture ran the warm-up)
    assert _probe(ROOT) == (0, 'None')
    # a fresh install has no cache: every cached kernel is cold
    fresh = tmp_path / 'fresh'
    shutil.copytree(ROOT / 'sm_ros', fresh / 'sm_ros',
                    ignore=shutil.ignore_patterns('__pycache__'))
    n, note = _probe(fresh)
    assert n >= 10
    assert note.startswith(f'compiling {n} solver kernels (cold Numba cache): about ')
    assert 'ros2 run sm_ros warmup' in note
    # a warm cache copied along (times kept) is warm; one core file edited makes it cold
    edited = tmp_path / 'edited'
    shutil.copytree(ROOT / 'sm_ros', edited / 'sm_ros')
    assert _probe(edited) == (0, 'None')
    target = edited / 'sm_ros' / 'core' / 'world.py'
    target.write_text(target.read_text() + '\n# edited\n')
    assert _probe(edited)[0] == n


def test_progress_is_quiet_when_not_a_terminal(tmp_path):
    from sm_ros import progress
    with open(tmp_path / 'log', 'w') as f:
        assert not progress.enabled(f)
        b = progress.bar(total=3, stream=f)
        assert list(progress.bar(iterable=[1, 2], stream=f)) == [1, 2]
        b.update(2)
        b.close()
    assert (tmp_path / 'log').read_text() == ''


@pytest.mark.slow
def test_warmup_command_prints_no_control_characters_into_a_pipe(warm):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, '-m', 'sm_ros.warmup'], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert '\r' not in out.stdout + out.stderr and '\x1b' not in out.stdout + out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == 'sm_ros: loading the solver kernels from the cache'
    assert lines[-1].startswith('sm_ros: kernels ready (')


def test_a_failed_second_warm_up_process_is_reported_and_its_part_done_here(monkeypatch,
                                                                             capsys):
    import tempfile
    from sm_ros import warmup
    done = []
    monkeypatch.setattr(warmup, 'warm_extra', lambda: done.append(1) or 0.0)
    err = tempfile.TemporaryFile()
    proc = subprocess.Popen([sys.executable, '-c',
                             'import sys; print("boom", file=sys.stderr); sys.exit(3)'],
                            stderr=err)
    warmup._finish_extra((proc, err))
    assert done == [1]
    msg = capsys.readouterr().err
    assert 'a warm-up helper process failed (exit status 3): boom' in msg
    assert err.closed
    # the stiff pass's helper: its own part is done here
    err = tempfile.TemporaryFile()
    warmup._finish_extra((subprocess.Popen([sys.executable, '-c', 'import sys; sys.exit(1)'],
                                           stderr=err), err), lambda: done.append(2))
    assert done == [1, 2] and 'exit status 1' in capsys.readouterr().err
    assert err.closed
    # a process that succeeded: nothing said, nothing done again
    err = tempfile.TemporaryFile()
    warmup._finish_extra((subprocess.Popen([sys.executable, '-c', 'pass'], stderr=err), err))
    assert done == [1, 2] and capsys.readouterr().err == ''


@pytest.mark.slow
def test_second_warm_up_process_runs_its_part(warm):
    # what a cold warm-up starts beside itself (here on the warm cache: seconds)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, '-m', 'sm_ros.warmup', '--extra'], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout == ''


def test_scene_start_note_only_on_a_cold_cache(monkeypatch):
    """The node's cold-start line names the scene and the background warm-up; a warm cache
    (or one that cannot be told) logs nothing."""
    from sm_ros import warmup
    monkeypatch.setattr(warmup, 'cold_kernels', lambda: 150)
    note = warmup.scene_start_note('many')
    assert "compiling the kernels scene 'many' needs first" in note
    assert 'background process (niced, one core)' in note
    assert "scene 'default'" in warmup.scene_start_note('')
    for warm in (0, None):
        monkeypatch.setattr(warmup, 'cold_kernels', lambda answer=warm: answer)
        assert warmup.scene_start_note('many') is None


BACKGROUND_PROBE = '''
import os, sys
from sm_ros import warmup
done = []
warmup.warm_up = lambda **kw: done.append(kw)
warmup.warm_scene = lambda name: done.append(name)
assert warmup.main(['--background']) == 0
print(os.getpriority(os.PRIO_PROCESS, 0), len(os.sched_getaffinity(0)),
      os.sched_getscheduler(0) == os.SCHED_IDLE, done)
'''


@pytest.mark.skipif(not hasattr(os, 'sched_getaffinity'), reason='needs Linux affinity')
def test_background_warm_up_runs_niced_on_one_core_and_warms_everything(tmp_path):
    """``python -m sm_ros.warmup --background`` (what a node on a cold cache starts) lowers
    its own priority to 19 in the idle scheduling class and keeps to one core, then runs
    the whole warm-up in this one process (no split) and the default scene."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, '-c', BACKGROUND_PROBE], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "19 1 True [{'split': False}, 'default']"


def test_start_background_runs_with_the_nodes_thread_count_and_can_be_stopped(monkeypatch):
    """The background process gets this process's Numba thread count (the kernels it picks
    depend on it) and ``stop_background`` kills it; its waiter then sees no exit status."""
    import numba
    from sm_ros import warmup
    seen = []

    def spawn(args, env_extra=None):
        seen.append((args, env_extra))
        import tempfile
        return (subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']),
                tempfile.TemporaryFile())
    monkeypatch.setattr(warmup, '_spawn', spawn)
    extra = warmup.start_background()
    assert seen == [(['--background'],
                     {'NUMBA_NUM_THREADS': str(numba.config.NUMBA_NUM_THREADS)})]
    assert extra in warmup._HELPERS and extra[0].poll() is None
    warmup.stop_background(extra)
    assert warmup.finish_background(extra) is None
    assert extra not in warmup._HELPERS and extra[1].closed
