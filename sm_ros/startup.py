"""
Start-up and shutdown of sim_node: argument checks, Ctrl-C at any moment, exit codes.

A cold start compiles the solver's kernels (or loads them from Numba's cache), which can
take a while; a Ctrl-C then must end the process cleanly, whenever it comes. ``run`` takes
care of that and of the exit code: 0 after Ctrl-C or an external shutdown, 2 (with one
``sim_node: error: ...`` line) for a bad scene, parameter or parameter file.

When the user has chosen no DDS profile, the node's own participant takes the packaged
Fast DDS profile ``config/fastdds_shm.xml`` (:func:`use_packaged_dds_profile`): with Fast
DDS's defaults a cloud larger than the 512 KiB shared-memory segment is sent in fragments.
"""

import os
import signal
import sys
import threading
import time
from typing import Optional, Sequence

import rclpy
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)
from rclpy.executors import ExternalShutdownException
from rclpy.signals import install_signal_handlers, SignalHandlerOptions
from sm_ros import warmup
from sm_ros.sim import ConfigError


#: The packaged DDS profile this process's participant uses (set by ``run`` when the user
#: chose none; the node's start-up line names it), or None.
DDS_PROFILE: Optional[str] = None

#: Environment variables and files by which a user chooses Fast DDS's configuration.
_DDS_CHOICES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                'FASTDDS_BUILTIN_TRANSPORTS')
_DDS_LOCAL_FILES = ('DEFAULT_FASTRTPS_PROFILES.xml', 'DEFAULT_FASTDDS_PROFILES.xml')


def packaged_dds_profile() -> Optional[str]:
    """The installed ``share/sm_ros/config/fastdds_shm.xml`` (colcon or pip), or the source
    tree's ``config/fastdds_shm.xml``; None when none is found."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    folders = [os.path.join(root, 'config')]
    try:
        from ament_index_python.packages import get_package_share_directory
        folders.append(os.path.join(get_package_share_directory('sm_ros'), 'config'))
    except Exception:  # noqa: B902 - not installed with colcon: the other places
        pass
    folders.append(os.path.join(sys.prefix, 'share', 'sm_ros', 'config'))
    for folder in folders:
        path = os.path.join(folder, 'fastdds_shm.xml')
        if os.path.isfile(path):
            return os.path.abspath(path)
    return None


def use_packaged_dds_profile(environ=None) -> Optional[str]:
    """
    Point ``FASTRTPS_DEFAULT_PROFILES_FILE`` at the packaged profile for this process (its
    participant, created by ``rclpy.init``) when the user chose no Fast DDS configuration
    (no profile variable, no ``FASTDDS_BUILTIN_TRANSPORTS``, no default profile file in
    the working directory) and the RMW is Fast DDS (the default); return the path, or None
    when nothing was set.  Subscribers need nothing: shared memory is the sender's segment.
    """
    environ = os.environ if environ is None else environ
    if any(environ.get(name) for name in _DDS_CHOICES):
        return None
    if any(os.path.isfile(name) for name in _DDS_LOCAL_FILES):
        return None
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    if rmw and not rmw.startswith('rmw_fastrtps'):
        return None
    path = packaged_dds_profile()
    if path is not None:
        environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = path
    return path


#: Seconds a Ctrl-C during the start-up waits for it to reach its safe point (the node
#: built) before the process ends without unwinding (``run``).
START_UP_GRACE_S = 1.0


def check_params_files(argv: Sequence[str]) -> Optional[str]:
    """
    Return why a ``--params-file`` in ``argv`` cannot be used, or None.

    Checked before rclpy.init so that a missing or broken file gives one clear line
    instead of rcl's multi-line error.
    """
    import yaml
    args = list(argv)
    for i, a in enumerate(args):
        if a != '--params-file':
            continue
        if i + 1 >= len(args):
            return '--params-file needs a file name'
        path = args[i + 1]
        if not os.path.isfile(path):
            return f'params file {path}: no such file'
        try:
            with open(path, encoding='utf-8') as f:
                data = yaml.safe_load(f)
        except OSError as exc:
            return f'params file {path}: cannot read: {exc.strerror or type(exc).__name__}'
        except UnicodeDecodeError as exc:
            return f'params file {path}: not UTF-8 text (byte {exc.start})'
        except yaml.YAMLError as exc:       # where, never the file's text
            from sm_ros.scene_spec import yaml_problem
            return f'params file {path}: invalid YAML at {yaml_problem(exc)}'
        if not isinstance(data, dict):
            return f'params file {path}: expected a mapping of node names to ros__parameters'
    return None


def _short_error(exc: BaseException) -> str:
    """Return the first line of an exception's message without rcl's source locations."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text.split(', at /')[0]


def _fail(message: str) -> int:
    print(f'sim_node: error: {message}', file=sys.stderr)
    return 2


def interrupt_noise(unraisable, interrupted: bool) -> bool:
    """Whether an exception Python could not raise (``sys.unraisablehook``) is only the
    echo of a Ctrl-C during the start-up: ctypes reports a KeyboardInterrupt it dropped
    inside an LLVM callback, and after one that cut an llvmlite object's ``__init__``
    short, its ``__del__`` fails (AttributeError ``_as_parameter_``) when it is collected.
    """
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        return True
    where = getattr(unraisable.object, '__module__', None) or \
        type(unraisable.object).__module__
    return interrupted and str(where).startswith(('llvmlite', 'numba'))


def run(node_class, args=None) -> int:
    """Start ``node_class()`` and spin it until Ctrl-C; exit code 2 for a bad configuration."""
    argv = sys.argv if args is None else args
    reason = check_params_files(argv)
    if reason:
        return _fail(reason)
    global DDS_PROFILE
    DDS_PROFILE = use_packaged_dds_profile()      # before rclpy.init creates the participant
    try:
        # No rclpy signal handlers while starting: a Ctrl-C during the (possibly long,
        # cold Numba cache) warm-up is ``on_sigint``'s below; rclpy's handlers take over
        # once the node exists, for a clean shutdown of the spinning node.
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: B902 - rcl reports bad arguments as RCLError
        return _fail(_short_error(exc))
    node = None
    code = 0
    starting = threading.Event()
    starting.set()
    interrupted = threading.Event()

    def on_sigint(signum, frame):
        # No KeyboardInterrupt into the start-up: it lands inside Numba's compiler or
        # llvmlite (a cold warm-up is nearly all compiling), where an exception can cut an
        # object's set-up or tear-down short: a traceback from its __del__, a hang, or
        # glibc's "double free detected" and an abort (seen in a fresh-clone CI run).  The
        # start-up ends at its next safe point, once the node is built (below), or the
        # watchdog ends the process.
        interrupted.set()

    def start_up_watchdog():
        # Still starting a moment after the Ctrl-C (a cold warm-up takes minutes): stop
        # the warm-up helper processes and leave at once (nothing is spinning yet).
        interrupted.wait()
        time.sleep(START_UP_GRACE_S)
        if starting.is_set():
            warmup.stop_helpers()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)

    def quiet_dropped_interrupt(unraisable):
        if not interrupt_noise(unraisable, interrupted.is_set()):
            sys.__unraisablehook__(unraisable)

    signal.signal(signal.SIGINT, on_sigint)
    sys.unraisablehook = quiet_dropped_interrupt
    threading.Thread(target=start_up_watchdog, daemon=True).start()
    try:
        try:
            node = node_class()
        except Exception:  # noqa: B902 - a dropped Ctrl-C can leave Numba mid-compile
            if interrupted.is_set():
                raise KeyboardInterrupt from None
            raise
        starting.clear()
        sys.unraisablehook = sys.__unraisablehook__
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if interrupted.is_set():
            raise KeyboardInterrupt
        install_signal_handlers(SignalHandlerOptions.ALL)
        try:
            rclpy.spin(node)
        except Exception:  # noqa: B902 - the executor may fail once Ctrl-C shut rcl down
            if rclpy.ok():
                raise
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        code = _fail(str(exc))
    except (InvalidParameterTypeException, InvalidParameterValueException,
            ParameterException) as exc:
        code = _fail(f'parameter: {_short_error(exc)}')
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


