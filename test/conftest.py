"""
Shared fixtures: an isolated ROS 2 graph per test, the node and a probe node in-process.

``ros`` gives a :class:`RosHarness`: a private rclpy Context, a SingleThreadedExecutor, a
probe node in a namespace of its own, and helpers that spin until a condition holds or a
future completes (with timeouts; never sleeps as synchronisation). ``warm`` compiles the
solver's Numba kernels once per session. ``scene_file`` writes a small scene YAML.

The DDS domain is picked per test session (unless ROS_DOMAIN_ID is set; each worker of
``pytest -n`` takes one of its own) and discovery is kept on this host, so parallel test
runs on one machine do not see each other.
"""

import itertools
import os
import random
import textwrap
import time

_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')           # 'gw0', 'gw1', ... under -n
if _WORKER:                          # the workers of one run: different domains for certain
    _base = random.Random(os.getppid()).randint(0, 199)
    os.environ['ROS_DOMAIN_ID'] = str(1 + (_base + 97 * int(_WORKER[2:])) % 200)
else:
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.Random(os.getpid()).randint(1, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

import pytest  # noqa: E402


def spare_domain() -> int:
    """A DDS domain for a node in a process of its own that no test of another worker of
    this run uses: 201-215 for the first worker (and a run without workers), 216-230 for
    the second, and so on around."""
    index = int(_WORKER[2:]) if _WORKER else 0
    return 201 + (15 * index + random.randrange(15)) % 30

DEFAULT_TIMEOUT = 10.0
_names = itertools.count()


def _ros_available() -> bool:
    try:
        import rclpy  # noqa: F401
        return True
    except ImportError:
        return False


class RosHarness:
    """A private ROS graph: context, executor, probe node and spin helpers."""

    def __init__(self):
        """Initialise a fresh Context and an executor on it."""
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.namespace = f'/t{os.getpid()}_{next(_names)}'
        from rclpy.node import Node
        self.probe = Node('probe', namespace=self.namespace, context=self.context)
        self.executor.add_node(self.probe)
        self.nodes = []
        self._publishers = {}

    # -------------------------------------------------------------- nodes

    def start(self, scene=None, paused=True, name='sim_node', **params):
        """
        Start a SimNode in this graph and return it.

        ``params`` use the node's parameter names with '.' written as '__' (e.g.
        ``ground__enabled=False``). Paused by default: tests drive ticks with ``node.tick()``
        or the ``step`` service, so the results do not depend on wall time.
        """
        from rclpy.parameter import Parameter
        from sm_ros.node import SimNode
        overrides = [Parameter(k.replace('__', '.'), value=v) for k, v in params.items()]
        if scene is not None:
            overrides.append(Parameter('scene', value=str(scene)))
        node = SimNode(name, paused=paused, context=self.context, namespace=self.namespace,
                       parameter_overrides=overrides)
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def close(self):
        """Destroy every node and shut the context down."""
        import rclpy
        for node in self.nodes + [self.probe]:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)

    # -------------------------------------------------------------- spinning

    def spin_until(self, predicate, timeout=DEFAULT_TIMEOUT) -> bool:
        """Spin the executor until ``predicate()`` is true; False on timeout."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def spin_for(self, seconds: float) -> None:
        """Spin for a span of wall time (for tests of wall-clock behaviour only)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.005)

    def wait(self, future, timeout=DEFAULT_TIMEOUT):
        """Spin until ``future`` is done and return its result."""
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), 'timed out waiting for a future'
        return future.result()

    # -------------------------------------------------------------- topics and services

    def publisher(self, msg_type, topic, qos=10):
        """Return a probe publisher on ``topic`` (relative to the namespace), matched."""
        key = (msg_type, topic)
        if key not in self._publishers:
            pub = self.probe.create_publisher(msg_type, topic, qos)
            assert self.spin_until(lambda: pub.get_subscription_count() > 0), \
                f'nobody subscribes to {topic}'
            self._publishers[key] = pub
        return self._publishers[key]

    def send(self, msg_type, topic, msg, until, timeout=DEFAULT_TIMEOUT, qos=10) -> bool:
        """Publish ``msg`` and spin until ``until()`` holds (the node handled it)."""
        pub = self.publisher(msg_type, topic, qos)
        pub.publish(msg)
        return self.spin_until(until, timeout)

    def subscribe(self, msg_type, topic, qos=10) -> list:
        """Collect the messages on ``topic`` into the returned list."""
        got = []
        self.probe.create_subscription(msg_type, topic, got.append, qos)
        return got

    def call(self, srv_type, name, request=None, timeout=DEFAULT_TIMEOUT):
        """Call a service (a name relative to the namespace) and return its response."""
        client = self.probe.create_client(srv_type, name)
        assert self.spin_until(lambda: client.service_is_ready(), timeout), \
            f'service {name} not available'
        future = client.call_async(request if request is not None else srv_type.Request())
        try:
            return self.wait(future, timeout)
        finally:
            self.probe.destroy_client(client)

    def refusal(self, node, topic, send):
        """Run ``send()`` and spin until ``node`` refused one more message on ``topic``."""
        before = node.refused.get(topic, 0)
        send()
        assert self.spin_until(lambda: node.refused.get(topic, 0) > before), \
            f'{topic}: the message was not refused'
        return node.last_refusal[topic]


@pytest.fixture(scope='session')
def warm():
    """Compile (or load from Numba's cache) the solver kernels once per session."""
    if not _ros_available():
        pytest.skip('rclpy is not installed (pip install -e .[ros])')
    from sm_ros.warmup import warm_up
    return warm_up()


@pytest.fixture
def ros(warm):
    """Yield a RosHarness for one test; everything is destroyed afterwards."""
    harness = RosHarness()
    try:
        yield harness
    finally:
        harness.close()


def _copy_world(world):
    """A deep copy of ``world`` whose read-only arrays stay read-only (Numba types them
    apart: a plain deep copy's first step would load other kernel specialisations)."""
    import copy
    import numpy as np
    memo = {}
    twin = copy.deepcopy(world, memo)
    for original in memo.get(id(memo), ()):
        if isinstance(original, np.ndarray) and not original.flags.writeable:
            dup = memo.get(id(original))
            if isinstance(dup, np.ndarray) and dup is not original:
                dup.flags.writeable = False
    return twin


@pytest.fixture
def copy_world():
    """``copy_world(world)``: a deep copy of a world that steps through the same kernels."""
    return _copy_world


@pytest.fixture
def scene_file(tmp_path):
    """Return a function that writes a scene YAML (text, dedented) and returns its path."""
    counter = itertools.count()

    def write(text: str) -> str:
        path = tmp_path / f'scene{next(counter)}.yaml'
        path.write_text(textwrap.dedent(text))
        return str(path)
    return write


#: A 27-particle cube floating in space (no ground, no gravity), for exact mechanics.
CUBE_SCENE = """
    colliders:
      ground: false
    bodies:
      - name: cube
        shape: box
        size: [0.1, 0.1, 0.1]
        spacing: 0.05
        mass: 2.0
        position: [0.0, 0.0, 1.0]
"""

#: Two small bodies; 'stiff' overrides alpha and mode in the scene.
TWO_BODY_SCENE = """
    bodies:
      - name: soft
        shape: box
        size: [0.1, 0.1, 0.1]
        spacing: 0.05
        mass: 1.0
        position: [0.0, 0.0, 0.5]
      - name: stiff
        shape: box
        size: [0.1, 0.1, 0.1]
        spacing: 0.05
        mass: 1.0
        position: [0.5, 0.0, 0.5]
        alpha: 0.9
        mode: rigid
"""


@pytest.fixture
def cube_scene(scene_file):
    """Path of CUBE_SCENE."""
    return scene_file(CUBE_SCENE)


@pytest.fixture
def two_body_scene(scene_file):
    """Path of TWO_BODY_SCENE."""
    return scene_file(TWO_BODY_SCENE)


def pytest_configure(config):
    """Register the ``slow`` marker (end-to-end tests; ``make test`` still runs them)."""
    config.addinivalue_line('markers', 'slow: a slow end-to-end test (still run by make test)')


@pytest.fixture(autouse=True)
def _numba_threads_restored():
    """Give every test the session's Numba thread count back (a benchmark driver that sets
    it would otherwise make later tests skip their parallel cases)."""
    try:
        import numba
    except ImportError:
        yield
        return
    threads = numba.get_num_threads()
    yield
    numba.set_num_threads(threads)
