"""
Check the parameter table (sm_ros/params.py).

The generated files are up to date, the module needs nothing beyond the standard library,
and the node, the scene loader and the core refuse exactly the same values of every body
parameter.
"""

import shutil
import subprocess
import sys

import pytest

from sm_ros import params
from sm_ros.core import BodyParams
from sm_ros.scene import parse_scene, SceneError


def test_generated_files_are_up_to_date():
    stale = params.stale_files()
    assert not stale, (f'{", ".join(str(p.relative_to(params.ROOT)) for p in stale)} '
                       f'stale: run `{params.REGENERATE}`')


def test_a_changed_row_makes_the_generated_files_stale(tmp_path, monkeypatch):
    for rel in ('doc/interface.md', 'doc/scenes.md', 'config/sim_node.yaml'):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(params.ROOT / rel, tmp_path / rel)
    assert params.stale_files(tmp_path) == []
    alpha = params.BY_NAME['alpha']
    changed = tuple(params.Param(**{**alpha.__dict__, 'hi': 0.9}) if p is alpha else p
                    for p in params.TABLE)
    monkeypatch.setattr(params, 'TABLE', changed)
    monkeypatch.setattr(params, 'NODE_PARAMS', tuple(p for p in changed if p.node))
    stale = {p.name for p in params.stale_files(tmp_path)}
    assert stale == {'interface.md', 'scenes.md', 'sim_node.yaml'}


def test_check_mode_names_the_regenerate_command(tmp_path, monkeypatch, capsys):
    readme = tmp_path / 'README.md'
    readme.write_text('x\n' + params.BEGIN + '\n| old |\n' + params.END + '\n')
    monkeypatch.setattr(params, 'stale_files', lambda root=None: [readme])
    monkeypatch.setattr(params, 'ROOT', tmp_path)
    assert params.main(['--check']) == 1
    assert 'python -m sm_ros.params --write' in capsys.readouterr().err
    assert params.main(['--bogus']) == 2


def test_the_table_imports_only_the_standard_library():
    code = ('import sys; import sm_ros.params; '
            "print(sorted(m for m in ('numpy', 'numba', 'rclpy', 'yaml') if m in sys.modules))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == '[]'


def test_ros_type_numbers_match_rcl_interfaces():
    msg = pytest.importorskip('rcl_interfaces.msg')
    t = msg.ParameterType
    assert params.ROS_TYPES == {'bool': t.PARAMETER_BOOL, 'integer': t.PARAMETER_INTEGER,
                                'double': t.PARAMETER_DOUBLE, 'string': t.PARAMETER_STRING,
                                'double[3]': t.PARAMETER_DOUBLE_ARRAY}


def test_every_default_passes_its_own_check():
    for p in params.TABLE:
        assert p.check(p.default) is None, p.name
    assert len(params.BY_NAME) == len(params.TABLE)                 # names are unique


def _scene_accepts(key, value):
    body = {'name': 'b', 'shape': 'box', 'size': [0.2, 0.2, 0.2], 'spacing': 0.1}
    group, _, sub = key.rpartition('.')
    if group:
        body[group] = {sub: value}
    else:
        body[key] = value
    try:
        got = parse_scene({'bodies': [body]}).bodies[0].overrides
    except SceneError:
        return False
    assert got == {key: value}
    return True


def _core_accepts(field, value):
    try:
        BodyParams(**{field: value}).validate()
    except ValueError:
        return False
    return True


def _probes(p):
    """Values at and just beyond the ends of a row's range (and the choices)."""
    if p.choices:
        return [(c, True) for c in p.choices] + [('nope', False)]
    if p.type_name == 'integer':
        return [(p.lo, True), (p.hi, True), (p.lo - 1, False), (p.hi + 1, False)]
    eps = 1e-9 * max(1.0, abs(p.hi))
    return [(p.lo, not p.positive), (p.hi, True), (p.lo - eps, False), (p.hi + eps, False),
            ((p.lo + p.hi) / 2, True)]


@pytest.mark.parametrize('name', params.BODY_FIELDS)
def test_node_scene_and_core_refuse_the_same_body_values(name):
    p = params.BY_NAME[name]
    for value, ok in _probes(p):
        if p.node:
            assert (p.check(value) is None) == ok, (name, value)
        if p.scene_override:
            assert _scene_accepts(name, value) == ok, (name, value)
        assert _core_accepts(p.core_field, value) == ok, (name, value)


def test_every_scene_override_reaches_its_core_field():
    from sm_ros.scene import params_from
    for key in params.OVERRIDE_KEYS:
        p = params.BY_NAME[key]
        value = p.choices[-1] if p.choices else p.hi
        assert getattr(params_from(None, {key: value}), p.core_field) == value, key


def test_derived_lists():
    assert params.NODE_PARAMS == tuple(p for p in params.TABLE if p.node)
    assert 'damping' in params.OVERRIDE_KEYS and 'damping' not in params.SCENE_DEFAULT_KEYS
    assert set(params.scene_defaults()) == set(params.SCENE_DEFAULT_KEYS)
    assert params.value_text(1.0 / 120.0) == '1/120' and params.value_text(0.05) == '0.05'
