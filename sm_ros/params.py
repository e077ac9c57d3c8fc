"""
The parameter table: every node parameter and scene-body override, defined once.

Each :class:`Param` row holds a parameter's name, type (from its default), default, range,
unit, description, whether a scene body may override it, and the field of the core's
``BodyParams`` it maps to. Everything else is derived from this table:

* ``sm_ros.node`` declares the node parameters (descriptors, ranges) and checks new values
  with :meth:`Param.check`;
* ``sm_ros.scene`` validates a body's overrides (``scene_override=True`` rows) with the same
  ranges and builds ``BodyParams`` through ``core_field``;
* ``sm_ros.core.params`` takes ``MODES``, the cluster limit and the range of every
  ``BodyParams`` field from here, so the core refuses exactly what the node refuses;
* ``config/sim_node.yaml``, the parameter table of ``doc/interface.md`` and the overrides
  table of ``doc/scenes.md`` are generated from it: ``python -m sm_ros.params --write``
  (``--check`` exits 1 when a generated file is stale; ``test/test_params.py`` runs it).

Why the table lives here and not in ``sm_ros.core``: the core must stay importable without
the node and the node's table must stay importable without Numba (the scene loader and the
doc generator use it), so this module imports nothing but the standard library and the core
imports the few facts it needs from it.

Adding a parameter: add one row to ``TABLE`` (``node=False`` for a scene-only body key,
``core_field`` for a ``BodyParams`` field, ``scene_override=True`` if scene bodies may set
it), run ``python -m sm_ros.params --write``, and write the code that uses the value
(``sm_ros.sim.Simulation.apply_pending`` receives every accepted change between two steps;
body parameters with a ``core_field`` are applied to the bodies there without more code).
"""

from dataclasses import dataclass
import math
from pathlib import Path
import sys
import textwrap
from typing import Any, Dict, Optional, Sequence, Tuple

#: Deformation modes (algorithm.md sec. 3, 4.2, 4.3), in the order the docs list them.
MODES = ('rigid', 'linear', 'quadratic')
#: What a ``cloud_in`` body does to the scene's bodies.
CLOUD_IN_MODES = ('replace', 'add')
#: Largest ``clusters`` (cubes per axis of the cluster grid).
MAX_CLUSTERS = 64
#: Largest coordinate of a position parameter or input (m).
MAX_COORDINATE = 1e6
#: Shortest step: below it alpha (g - x) / h turns the rounding noise of positions into
#: absurd speeds (dt = 1e-300 s flung bodies to 1e298 m, beyond the float32 of the cloud).
MIN_DT = 1e-9
#: Lowest rate whose timer period rclpy can hold (int64 nanoseconds: 1e-9 Hz is 31 years;
#: 1e-13 Hz made every later tick raise).
MIN_TIMER_RATE = 1e-9

#: Type names (as the docs write them) and their rcl_interfaces/msg/ParameterType values
#: (test/test_params.py checks the numbers against rcl_interfaces).
ROS_TYPES = {'bool': 1, 'integer': 2, 'double': 3, 'string': 4, 'double[3]': 8}


@dataclass(frozen=True)
class Param:
    """
    One parameter: a row of the table.

    The type follows the default's Python type. ``lo``/``hi`` are the inclusive range
    (the ROS descriptor's range); ``positive`` also refuses ``lo`` itself; ``min_nonzero``
    refuses values in (0, min_nonzero) with ``min_nonzero_why``; ``choices`` lists the
    values a string may take; ``nonempty`` refuses a blank string. ``node=False`` marks a
    scene-body key that is not a node parameter; ``scene_override`` lets a scene body set
    it; ``core_field`` names the ``sm_ros.core.BodyParams`` field it sets.
    """

    name: str
    default: Any
    description: str
    unit: str = ''
    lo: Optional[float] = None
    hi: Optional[float] = None
    positive: bool = False
    min_nonzero: Optional[float] = None
    min_nonzero_why: str = ''
    choices: Tuple[str, ...] = ()
    nonempty: bool = False
    node: bool = True
    scene_override: bool = False
    core_field: Optional[str] = None
    read_only: bool = False

    @property
    def type_name(self) -> str:
        """Return the type as the docs write it: bool, integer, double, string, double[3]."""
        d = self.default
        if isinstance(d, bool):
            return 'bool'
        if isinstance(d, int):
            return 'integer'
        if isinstance(d, float):
            return 'double'
        if isinstance(d, str):
            return 'string'
        return 'double[3]'

    @property
    def ros_type(self) -> int:
        """Return the rcl_interfaces ParameterType value of the type."""
        return ROS_TYPES[self.type_name]

    def range_text(self) -> str:
        """Return the range as the docs write it: '[0, 1]', '(0, 1]', choices, or ''."""
        if self.choices:
            return ', '.join(self.choices)
        if self.lo is None:
            return ''
        return f"{'(' if self.positive else '['}{self.lo:g}, {self.hi:g}]"

    def check(self, value: Any) -> Optional[str]:
        """
        Return why ``value`` (already of this parameter's type) is refused, or None.

        The range is checked exactly: rclpy lets a double within a relative 1e-6 of an
        end through (ground.restitution 1.0000005 then failed every tick in the core).
        """
        kind = self.type_name
        if kind == 'double':
            if not math.isfinite(value):
                return f'{self.name} must be finite, got {value}'
            if self.positive and value <= self.lo:
                return f'{self.name} must be > {self.lo:g}, got {value}'
            if self.lo is not None and not self.lo <= value <= self.hi:
                return f'{self.name} must be in [{self.lo:g}, {self.hi:g}], got {value}'
            if self.min_nonzero is not None and 0.0 < value < self.min_nonzero:
                return self.min_nonzero_why.format(name=self.name, min=self.min_nonzero,
                                                   value=value)
        elif kind == 'integer':
            if self.positive and value <= self.lo:
                return f'{self.name} must be > {self.lo}, got {value}'
            if self.lo is not None and not self.lo <= value <= self.hi:
                return f'{self.name} must be in [{self.lo}, {self.hi}], got {value}'
        elif kind == 'string':
            if self.choices and value not in self.choices:
                return f"{self.name} must be one of {', '.join(self.choices)}, got '{value}'"
            if self.nonempty and not value.strip():
                return f'{self.name} must not be empty'
        elif kind == 'double[3]':
            v = list(value)
            if len(v) != 3:
                return f'{self.name} must have 3 values, got {len(v)}'
            if not all(math.isfinite(c) for c in v):
                return f'{self.name} must be finite, got {v}'
            if max(abs(c) for c in v) > MAX_COORDINATE:
                return f'{self.name} components must be within +-{MAX_COORDINATE:g}, got {v}'
        return None


_TIMER_WHY = ('{name} must be 0 or >= {min:g} Hz (a timer period fits in int64 '
              'nanoseconds), got {value}')

#: The table. Order is the order of the docs and of ``config/sim_node.yaml``.
TABLE: Tuple[Param, ...] = (
    Param('scene', '', 'Scene YAML file, or the name of a bundled scene (default, rope, '
          'sheet, plastic, mesh, many, paper_8_clusters, grasp, paper_384); empty: default. '
          'Changing it reloads the scene'),
    Param('mode', 'linear', 'Deformation mode: rigid (sec. 3), linear (4.2) or quadratic '
          '(4.3)', choices=MODES, scene_override=True, core_field='mode'),
    Param('alpha', 0.5, 'Stiffness alpha (1 = rigid)', '', 0.0, 1.0,
          scene_override=True, core_field='alpha'),
    Param('beta', 0.5, 'Share beta of the linear/quadratic transform blended into the '
          'rotation', '', 0.0, 1.0, scene_override=True, core_field='beta'),
    Param('plasticity.yield', 0.0, 'c_yield: plastic strain starts beyond this elastic '
          'strain', '', 0.0, 1e3, scene_override=True, core_field='plastic_yield'),
    Param('plasticity.creep', 0.0, 'c_creep: rate at which strain beyond c_yield becomes '
          'plastic (0 disables plasticity)', '1/s', 0.0, 1e3, scene_override=True,
          core_field='plastic_creep'),
    Param('plasticity.max', 0.0, 'c_max: largest plastic strain', '', 0.0, 1e3,
          scene_override=True, core_field='plastic_max'),
    Param('clusters', 1, 'Cubes per axis of the overlapping cluster grid (1 = one cluster '
          'per body)', '', 1, MAX_CLUSTERS, scene_override=True, core_field='clusters'),
    Param('dt', 1.0 / 120.0, 'Time step h of one substep (s)', 's', 0.0, 1.0, positive=True,
          min_nonzero=MIN_DT, min_nonzero_why='{name} must be >= {min:g} s, got {value}'),
    Param('substeps', 2, 'Steps of dt per tick', '', 1, 1000),
    Param('rate', 60.0, 'Ticks (and published clouds) per second of wall time (Hz)', 'Hz',
          0.0, 1000.0, positive=True, min_nonzero=MIN_TIMER_RATE, min_nonzero_why=_TIMER_WHY),
    Param('gravity', [0.0, 0.0, -9.81], 'Gravity (m/s^2), three values x, y, z', 'm/s^2'),
    Param('ground.enabled', True, 'Whether the ground plane z = ground.height collides'),
    Param('ground.height', 0.0, 'Height of the ground plane (m)', 'm', -1e6, 1e6),
    Param('ground.friction', 0.5, 'Coulomb friction coefficient of the ground', '', 0.0, 10.0),
    Param('ground.restitution', 0.0, 'Restitution of the ground (0 = no bounce)', '',
          0.0, 1.0),
    Param('contact.enabled', True, 'Whether bodies collide with one another (body-body '
          'contact; a scene may set it in its contact mapping)'),
    Param('contact.friction', 0.5, 'Coulomb friction coefficient between bodies', '',
          0.0, 10.0),
    Param('contact.restitution', 0.0, 'Restitution between bodies (0 = no bounce)', '',
          0.0, 1.0),
    Param('contact.radius_scale', 1.0, "Factor on every body's default contact radius "
          '(half its median particle spacing)', '', 0.0, 10.0, positive=True),
    Param('contact.stacking', True, 'Under gravity, stiff one-cluster bodies carry their '
          'contacts as a whole (stacks stand, piles come to rest at the default step; '
          'false: every particle on its own)'),
    Param('contact.rigid', True, 'Stiff bodies, and under gravity those stacking carries '
          'among themselves, take their contacts as rigid bodies: contact turns them, '
          'static friction holds them, restitution never adds energy (false: they are '
          'carried as a whole, the faster model of paper_384)'),
    Param('contact.sleep', True, 'Bodies that have come to rest in a contact world sleep '
          '(are not stepped) until a moving body touches them or an input changes them'),
    Param('contact.sleep_speed', 0.01, 'A body falls asleep once no particle got farther '
          'than this times contact.sleep_time from where it was contact.sleep_time '
          'seconds before; 4 times this in two steps in a row wakes the sleeping bodies it '
          'touches',
          'm/s', 0.0, 10.0),
    Param('contact.sleep_time', 0.5, 'Seconds a body must stay still before it falls '
          'asleep', 's', 0.0, 3600.0),
    Param('grab_radius', 0.05, 'A gripper attaches the particles within this distance of '
          'its first pose (m)', 'm', 0.0, 100.0, positive=True),
    Param('force_timeout', 0.0, 'A force is cleared after this many seconds without a new '
          'force message (0: held until replaced)', 's', 0.0, 3600.0),
    Param('frame_id', 'world', 'Frame of the published clouds, poses and markers',
          nonempty=True),
    Param('publish_clock', False, 'Publish the simulation time on /clock'),
    Param('diagnostics_rate', 1.0, 'Rate of /diagnostics (Hz; 0 disables)', 'Hz', 0.0, 100.0,
          min_nonzero=MIN_TIMER_RATE, min_nonzero_why=_TIMER_WHY),
    Param('max_points', 20000, 'Cap on the particles of a cloud_in body (voxel '
          'downsampling)', '', 1, 10_000_000),
    Param('cloud_in_mode', 'replace', 'A cloud_in body replaces the scene bodies or joins '
          'them', choices=CLOUD_IN_MODES),
    Param('foxglove.port', 0, "Port of the Foxglove live view (WebSocket; needs the 'viz' "
          "extra); 0: off. Foxglove's own default is 8765 (make run uses it)", '', 0, 65535),
    Param('foxglove.host', '127.0.0.1', 'Interface the Foxglove live view listens on '
          '(0.0.0.0: every interface, reachable from other machines)', nonempty=True),
    Param('record.path', '', "Record the published topics into this rosbag2 folder (MCAP; "
          "needs the 'record' extra; it must not exist yet); '': not recording. The "
          '~/record service starts and stops recordings too'),
    Param('record.split_s', 10.0, 'Log time each file of a recording spans: every split_s the '
          'open .mcap file is finished (footer, summary) and listed in metadata.yaml, so a '
          'killed node leaves every earlier file readable without repair (as ros2 bag '
          'record --max-bag-duration); 0: one file. Applies to the next recording', 's',
          0.0, 86400.0, min_nonzero=1.0,
          min_nonzero_why='{name} must be 0 (one file) or >= {min:g} s, got {value}'),
    Param('damping', 0.0, "Fraction of each particle's velocity relative to its clusters' "
          'rigid motion removed per step (momentum-preserving; not in the paper)', '',
          0.0, 1.0, node=False, scene_override=True, core_field='damping'),
    Param('material_dt', 1.0 / 120.0, 'Step (s) at which alpha, beta, damping and the '
          'plastic creep fraction are defined; other steps convert them so the material '
          'does not depend on dt or substeps (0: act per step as given)', 's', 0.0, 1.0,
          scene_override=True, core_field='material_dt'),
    Param('max_speed', 100.0, 'Largest particle speed (m/s); a faster particle is slowed to it '
          'and counted in /diagnostics (speed_limited); 0: no limit', 'm/s', 0.0, 1e6,
          scene_override=True, core_field='max_speed'),
    Param('max_turn', 0.5, 'Largest rotation of a cluster in one step (rad): spin beyond '
          'max_turn / dt is taken away and counted in /diagnostics (turn_limited); 0: no limit',
          'rad', 0.0, 3.0, scene_override=True, core_field='max_turn'),
    Param('error_estimate.rate', 0.2, 'Rate of the live error estimate in /diagnostics '
          '(error_estimate_m: from the state of the moment, one step of dt against two of '
          'dt/2, two against four with a rigid-mode body, on the running world, which is '
          'then put back bit for bit; the local error per second times 2 s, '
          'doc/error_estimate.md). Its steps run in what the '
          'ticks leave of their period, or one piece a tick in the last ticks before the '
          'last one would be 2 / rate old (Hz; 0 disables)', 'Hz', 0.0, 10.0),
)

#: Every row by name.
BY_NAME: Dict[str, Param] = {p.name: p for p in TABLE}
#: The node's parameters, in declaration order.
NODE_PARAMS: Tuple[Param, ...] = tuple(p for p in TABLE if p.node)
#: Keys a scene body may set (node-parameter naming, e.g. 'plasticity.yield').
OVERRIDE_KEYS: Tuple[str, ...] = tuple(p.name for p in TABLE if p.scene_override)
#: Parameter name -> BodyParams field, for every row that sets one.
BODY_FIELDS: Dict[str, str] = {p.name: p.core_field for p in TABLE if p.core_field}
#: Parameters with a timer rate (their smallest non-zero value is MIN_TIMER_RATE).
TIMER_RATES: Tuple[str, ...] = ('rate', 'diagnostics_rate')
#: Ground parameters (a change rebuilds the ground collider).
GROUND_KEYS: Tuple[str, ...] = tuple(p.name for p in TABLE if p.name.startswith('ground.'))
#: Scene-wide contact parameters (a change rebuilds the contact settings).
CONTACT_KEYS: Tuple[str, ...] = tuple(p.name for p in TABLE if p.name.startswith('contact.'))
#: The values a scene is built with: body parameters, gravity, ground and contact.
SCENE_DEFAULT_KEYS: Tuple[str, ...] = (tuple(k for k in BODY_FIELDS if BY_NAME[k].node)
                                       + ('gravity',) + GROUND_KEYS + CONTACT_KEYS)


def defaults(names: Optional[Sequence[str]] = None) -> Dict[str, Any]:
    """Return ``{name: default}`` for ``names`` (default: every node parameter); lists copied."""
    rows = NODE_PARAMS if names is None else [BY_NAME[n] for n in names]
    return {p.name: list(p.default) if isinstance(p.default, list) else p.default
            for p in rows}


def scene_defaults() -> Dict[str, Any]:
    """Return the defaults a scene is built with when no node gives its values."""
    return defaults(SCENE_DEFAULT_KEYS)


def core_range(field: str) -> Tuple[Optional[float], Optional[float]]:
    """Return the inclusive (lo, hi) range of a BodyParams field (the core validates it)."""
    for p in TABLE:
        if p.core_field == field:
            return p.lo, p.hi
    raise KeyError(f'no parameter sets BodyParams.{field}')


# ----------------------------------------------------------------------------------------
# Generated files
# ----------------------------------------------------------------------------------------

ROOT = Path(__file__).resolve().parent.parent
REGENERATE = 'python -m sm_ros.params --write'
BEGIN = ('<!-- generated by `python -m sm_ros.params --write` from sm_ros/params.py: '
         'do not edit -->')
END = '<!-- end of generated table -->'


def value_text(value: Any) -> str:
    """Return a default as the docs write it (1/120 for dt)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, list):
        return '[' + ', '.join(value_text(v) for v in value) + ']'
    if isinstance(value, float) and 0.0 < value < 1.0 and len(f'{value:g}') > 6:
        inverse = 1.0 / value
        if inverse == round(inverse):
            return f'1/{int(inverse)}'
    if isinstance(value, float):
        return f'{value:g}'
    return str(value)


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, list):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


def sim_node_yaml() -> str:
    """Return config/sim_node.yaml: every node parameter at its default, with a comment."""
    lines = ['# sim_node parameters, every one at its default (doc/interface.md, "Parameters").',
             f'# Generated from sm_ros/params.py by `{REGENERATE}`: do not edit.',
             '# Use: ros2 run sm_ros sim_node --ros-args --params-file config/sim_node.yaml',
             '#      make run ARGS="--ros-args --params-file config/sim_node.yaml"',
             '# "/**" matches the node under any name and namespace.',
             '/**:', '  ros__parameters:']
    for p in NODE_PARAMS:
        text = p.description
        if p.choices:
            text += ' (one of: ' + ', '.join(p.choices) + ')'
        elif p.range_text():
            text += '; range ' + p.range_text()
        lines += textwrap.wrap(text, 92, initial_indent='    # ', subsequent_indent='    # ')
        lines.append(f'    {p.name}: {_yaml_value(p.default)}')
    lines += ['    # QoS of the publishers can be changed at start-up, e.g. for best-effort '
              'clouds:',
              '    # qos_overrides./points.publisher.reliability: best_effort',
              '    # qos_overrides./points.publisher.depth: 1']
    return '\n'.join(lines) + '\n'


def interface_table() -> str:
    """Return the parameter table of doc/interface.md (markdown)."""
    rows = ['| name | type | default | range | meaning | unit | scene body may set |',
            '| --- | --- | --- | --- | --- | --- | --- |']
    for p in NODE_PARAMS:
        rows.append(f'| `{p.name}` | {p.type_name} | `{value_text(p.default)}` | '
                    f'{p.range_text()} | {p.description} | {p.unit} | '
                    f"{'yes' if p.scene_override else ''} |")
    return '\n'.join(rows)


def overrides_table() -> str:
    """Return doc/scenes.md's table of the keys a scene body may set (markdown)."""
    rows = ['| key | node parameter | range | meaning |', '| --- | --- | --- | --- |']
    for p in TABLE:
        if not p.scene_override:
            continue
        node = f'`{p.name}`' if p.node else f'(none; default {value_text(p.default)})'
        kind = p.range_text() if p.type_name != 'integer' else \
            f'integer {p.lo}–{p.hi}'
        rows.append(f'| `{p.name}` | {node} | {kind} | {p.description} |')
    return '\n'.join(rows)


def _spliced(text: str, table: str, where: str) -> str:
    """Return ``text`` with the block between BEGIN and END replaced by ``table``."""
    try:
        start = text.index(BEGIN) + len(BEGIN)
        end = text.index(END, start)
    except ValueError:
        raise ValueError(f'{where}: the markers of the generated table are missing '
                         f'({BEGIN!r} ... {END!r})') from None
    return text[:start] + '\n' + table + '\n' + text[end:]


def generated_files(root: Path = ROOT) -> Dict[Path, str]:
    """Return {path: the text it must have} for every file generated from the table."""
    interface = root / 'doc' / 'interface.md'
    scenes = root / 'doc' / 'scenes.md'
    return {
        root / 'config' / 'sim_node.yaml': sim_node_yaml(),
        interface: _spliced(interface.read_text(encoding='utf-8'), interface_table(),
                            'doc/interface.md'),
        scenes: _spliced(scenes.read_text(encoding='utf-8'), overrides_table(),
                         'doc/scenes.md'),
    }


def stale_files(root: Path = ROOT) -> Sequence[Path]:
    """Return the generated files whose text differs from what the table gives."""
    return [path for path, text in generated_files(root).items()
            if not path.is_file() or path.read_text(encoding='utf-8') != text]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``--write`` regenerates the files; ``--check`` (default) exits 1 if one is stale."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args not in ([], ['--check'], ['--write']):
        print('usage: python -m sm_ros.params [--check | --write]', file=sys.stderr)
        return 2
    if args == ['--write']:
        for path, text in generated_files().items():
            if not path.is_file() or path.read_text(encoding='utf-8') != text:
                path.write_text(text, encoding='utf-8')
                print(f'wrote {path.relative_to(ROOT)}')
        return 0
    stale = stale_files()
    for path in stale:
        print(f'{path.relative_to(ROOT)} is stale: run `{REGENERATE}`', file=sys.stderr)
    return 1 if stale else 0


if __name__ == '__main__':
    sys.exit(main())
