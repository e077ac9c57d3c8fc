"""Scene format, loaders and validation (plain NumPy; no solver core needed)."""

import math
import struct
import subprocess
import sys

import numpy as np
import pytest
import yaml

from sm_ros import point_files, shapes
import sm_ros.scene as scene_module
from sm_ros.scene import (cloud_body_spec, list_scenes, load_scene, parse_scene,
                          resolve_scene, SceneError)

BUNDLED = ('default', 'paper_8_clusters', 'plastic', 'sheet', 'rope', 'many', 'mesh')


def write_scene(tmp_path, data, name='x.yaml'):
    """Write `data` as YAML into tmp_path/scenes/name and return the path as a string."""
    d = tmp_path / 'scenes'
    d.mkdir(exist_ok=True)
    p = d / name
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return str(p)


def sponge(**extra):
    """A one-body scene dict with a box named sponge, updated with `extra`."""
    body = {'name': 'sponge', 'shape': 'box', 'size': [0.2, 0.2, 0.2], 'spacing': 0.05,
            'position': [0, 0, 1]}
    body.update(extra)
    return {'bodies': [body]}


# ------------------------------------------------------------------------ bundled scenes

def test_bundled_scenes_are_listed():
    assert set(BUNDLED) <= set(list_scenes())


@pytest.mark.parametrize('name', BUNDLED)
def test_bundled_scene_loads(name):
    spec = load_scene(name)
    assert spec.bodies
    assert spec.description
    for b in spec.bodies:
        assert b.points.shape == (b.n, 3) and b.n > 0
        assert np.all(np.isfinite(b.points))
        assert b.masses.shape == (b.n,) and np.all(b.masses > 0)
        assert b.pinned.dtype == np.int64


def test_bundled_scene_sizes():
    assert load_scene('paper_8_clusters').n_points == 10_000
    paper = load_scene('paper_8_clusters').bodies[0].overrides
    assert paper['clusters'] == 2 and paper['mode'] == 'quadratic'
    assert 1000 <= load_scene('').n_points <= 5000
    # the default scene leaves every node parameter to the node ('damping' is none)
    assert set(load_scene('default').bodies[0].overrides) <= {'damping'}
    assert len(load_scene('many').bodies) >= 24
    mesh = load_scene('mesh')
    assert all(b.surface is not None for b in mesh.bodies)
    assert len(load_scene('rope').bodies[0].pinned) > 0


def test_empty_name_is_default():
    assert resolve_scene('') == resolve_scene('default')


def test_unknown_scene_names_bundled():
    with pytest.raises(SceneError, match='bundled: .*default'):
        load_scene('no_such_scene')


def test_scene_without_mesh_does_not_import_trimesh():
    code = ('import sys; from sm_ros.scene import load_scene; load_scene("many"); '
            'print("trimesh" in sys.modules, "numba" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ['False', 'False']


# ------------------------------------------------------------------------ shapes

def test_box_lattice_counts_and_extent():
    pts = shapes.box_lattice([0.3, 0.2, 0.1], 0.025)
    assert len(pts) == 13 * 9 * 5
    assert np.allclose(pts.min(axis=0), [-0.15, -0.1, -0.05])
    assert np.allclose(pts.max(axis=0), [0.15, 0.1, 0.05])


def test_round_shapes():
    s = shapes.sphere_lattice(0.1, 0.02)
    assert np.all(np.linalg.norm(s, axis=1) <= 0.1 + 1e-12)
    assert abs(len(s) - 4 / 3 * math.pi * 0.1 ** 3 / 0.02 ** 3) < 0.15 * len(s)
    assert np.allclose(s.mean(axis=0), 0.0)
    cap0 = shapes.capsule_lattice(0.1, 0.0, 0.02)
    assert len(cap0) == len(s)
    cap = shapes.capsule_lattice(0.05, 0.2, 0.02)
    assert np.isclose(np.ptp(cap[:, 2]), 0.3 - 0.02 * (0.3 / 0.02 % 1), atol=0.021)
    cyl = shapes.cylinder_lattice(0.05, 0.2, 0.02)
    assert np.all(np.hypot(cyl[:, 0], cyl[:, 1]) <= 0.05 + 1e-12)
    assert np.isclose(np.ptp(cyl[:, 2]), 0.2)


def test_degenerate_shapes():
    sheet = shapes.sheet_lattice([1.0, 0.5], 0.1)
    assert len(sheet) == 11 * 6 and np.all(sheet[:, 2] == 0)
    rope = shapes.rope_points(1.0, 0.1)
    assert len(rope) == 11 and np.all(rope[:, 1:] == 0)


def test_too_many_points_is_refused():
    with pytest.raises(shapes.GeometryError, match='limit'):
        shapes.box_lattice([1, 1, 1], 1e-4)


def test_orientation_quaternion_equals_rpy(tmp_path):
    a = parse_scene(sponge(orientation=[0, 0, math.pi / 2], size=[0.4, 0.2, 0.1]))
    h = math.sqrt(0.5)
    b = parse_scene(sponge(orientation=[0, 0, h, h], size=[0.4, 0.2, 0.1]))
    assert np.allclose(a.bodies[0].points, b.bodies[0].points)
    pts = a.bodies[0].points
    assert np.isclose(np.ptp(pts[:, 1]), 0.4) and np.isclose(np.ptp(pts[:, 0]), 0.2)


def test_rpy_convention():
    r = shapes.rpy_to_matrix([0.1, 0.2, 0.3])
    rz = shapes.rpy_to_matrix([0, 0, 0.3])
    ry = shapes.rpy_to_matrix([0, 0.2, 0])
    rx = shapes.rpy_to_matrix([0.1, 0, 0])
    assert np.allclose(r, rz @ ry @ rx)
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)


def test_position_mass_density_velocity():
    spec = parse_scene(sponge(mass=2.0, velocity=[1, 0, 0]))
    b = spec.bodies[0]
    assert np.allclose(b.points.mean(axis=0), [0, 0, 1])
    assert np.isclose(b.masses.sum(), 2.0)
    assert np.allclose(b.velocities, [1, 0, 0])
    dens = parse_scene(sponge(density=1000.0)).bodies[0]
    assert np.allclose(dens.masses, 1000.0 * 0.05 ** 3)
    spin = parse_scene(sponge(angular_velocity=[0, 0, 2.0])).bodies[0]
    r = spin.points - spin.points.mean(axis=0)
    assert np.allclose(spin.velocities, np.cross([0, 0, 2.0], r))
    assert parse_scene(sponge()).bodies[0].velocities is None


def test_overrides_use_node_names():
    b = parse_scene(sponge(mode='quadratic', alpha=0.2, beta=0.7, clusters=3, damping=0.1,
                           plasticity={'yield': 0.1, 'creep': 2.0, 'max': 0.5})).bodies[0]
    assert b.overrides == {'mode': 'quadratic', 'alpha': 0.2, 'beta': 0.7, 'clusters': 3,
                           'damping': 0.1, 'plasticity.yield': 0.1, 'plasticity.creep': 2.0,
                           'plasticity.max': 0.5}


def test_pinned_region_world_frame():
    b = parse_scene(sponge(pinned={'lo': [-1, -1, 1.06], 'hi': [1, 1, 2]})).bodies[0]
    assert len(b.pinned) == 25
    assert np.all(b.points[b.pinned, 2] > 1.06)
    two = parse_scene(sponge(pinned=[{'lo': [-1, -1, 1.06], 'hi': [1, 1, 2]},
                                     {'lo': [-1, -1, 0], 'hi': [1, 1, 0.94]}])).bodies[0]
    assert len(two.pinned) == 50


def test_copies_expand_and_translate():
    spec = parse_scene(sponge(copies={'count': [2, 3, 1], 'step': [1, 2, 0]},
                              pinned={'lo': [-1, -1, 1.06], 'hi': [1, 1, 2]}))
    assert [b.name for b in spec.bodies] == [f'sponge_{i}' for i in range(6)]
    c0, c5 = spec.bodies[0], spec.bodies[5]
    assert np.allclose(c5.points - c0.points, [1, 4, 0])
    assert np.array_equal(c0.pinned, c5.pinned)


def test_colliders_parse():
    data = sponge()
    data['colliders'] = {'ground': {'height': -0.5, 'friction': 0.2},
                         'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1]},
                                   {'center': [0, 0, 0], 'size': [2, 2, 2]}],
                         'spheres': [{'center': [0, 0, 0], 'radius': 0.5}]}
    c = parse_scene(data).colliders
    assert c['ground'] == {'enabled': True, 'height': -0.5, 'friction': 0.2}
    assert np.allclose(c['boxes'][1]['lo'], -1) and np.allclose(c['boxes'][1]['hi'], 1)
    assert c['spheres'][0]['radius'] == 0.5
    assert c['spheres'][0]['friction'] == 0.5 and c['boxes'][0]['restitution'] == 0.0
    data['colliders'] = {'ground': False}
    assert parse_scene(data).colliders['ground'] == {'enabled': False}
    assert parse_scene(sponge()).colliders['ground'] is None


# ------------------------------------------------------------------------ validation

BAD = [
    (dict(spacing=-1), "body 'sponge': spacing must be > 0, got -1"),
    (dict(spacing=1e-4), "body 'sponge': spacing would make about"),
    (dict(sise=[1, 1, 1]), "body 'sponge': unknown key 'sise' (did you mean 'size'?)"),
    (dict(shape='blob'), "body 'sponge': shape must be one of box"),
    (dict(size=[1, 1]), "body 'sponge': size must be a list of 3 numbers"),
    (dict(size=[1, 0, 1]), "body 'sponge': size must be > 0 in every component"),
    (dict(position=[0, 0, float('nan')]), "body 'sponge': position must be a list of 3 "
                                          'finite numbers'),
    (dict(position='up'), "body 'sponge': position must be a list of 3 numbers"),
    (dict(alpha=1.5), "body 'sponge': alpha must be <= 1, got 1.5"),
    (dict(beta=-0.1), "body 'sponge': beta must be >= 0, got -0.1"),
    (dict(damping='x'), "body 'sponge': damping must be a number, got a string"),
    (dict(mode='soft'), "body 'sponge': mode must be one of rigid, linear, quadratic, "
                        'got a string'),
    (dict(clusters=0), "body 'sponge': clusters must be >= 1, got 0"),
    (dict(clusters=1.5), "body 'sponge': clusters must be an integer, got 1.5"),
    (dict(clusters=65), "body 'sponge': clusters must be <= 64, got 65"),
    (dict(plasticity={'creep': -1}), "body 'sponge': plasticity.creep must be >= 0, got -1"),
    (dict(plasticity={'yeild': 1}), "body 'sponge': unknown key 'plasticity.yeild'"),
    (dict(mass=-1), "body 'sponge': mass must be > 0, got -1"),
    (dict(mass=1, density=2), "body 'sponge': density and mass are exclusive"),
    (dict(density=0), "body 'sponge': density must be > 0, got 0"),
    (dict(orientation=[1, 2]), "body 'sponge': orientation must be [roll, pitch, yaw]"),
    (dict(orientation=[0, 0, 0, 0]), "body 'sponge': orientation quaternion must be "
                                     'non-zero'),
    (dict(velocity=[1, 2]), "body 'sponge': velocity must be a list of 3 numbers"),
    (dict(pinned={'lo': [5, 5, 5], 'hi': [6, 6, 6]}), "body 'sponge': pinned contains no "
                                                      'particle'),
    (dict(pinned={'lo': [1, 1, 1], 'hi': [0, 0, 0]}), "body 'sponge': pinned.hi must be >= "
                                                      'lo'),
    (dict(pinned={'lo': [1, 1, 1]}), "body 'sponge': pinned.hi must be a list of 3"),
    (dict(copies={'count': [2, 0, 1], 'step': [1, 1, 1]}), "body 'sponge': copies.count "
                                                           'must be >= 1, got 0'),
    (dict(name='two words'), "body '#0': name must be a non-empty string without spaces"),
    (dict(radius=0.1), "body 'sponge': unknown key 'radius'"),
]


@pytest.mark.parametrize('extra, message', BAD, ids=[m.split(': ', 1)[1][:40] for _, m in BAD])
def test_validation_error_names_file_body_key(tmp_path, extra, message):
    path = write_scene(tmp_path, sponge(**extra))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f'{path}: ')
    assert message in str(info.value)


def test_exact_message_example(tmp_path):
    path = write_scene(tmp_path, 'bodies:\n  - name: sponge\n    shape: box\n'
                                 '    size: [0.2, 0.2, 0.2]\n    spacing: -1\n')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value) == f"{path}: line 5: body 'sponge': spacing must be > 0, got -1"


SECRET = 'hunter2-s3cr3t'

#: Files that are no scene (or a scene with a bad value) around a secret, and the error
#: each gives: where it is and what kind of value, never the text.
SECRET_FILES = [
    (f'root:x:0:0:root:/root:/bin/bash\nadmin:{SECRET}:1000\n',
     'line 1: must be a mapping, got a string'),
    (f'{SECRET}\n', 'line 1: must be a mapping, got a string'),
    (f'- {SECRET}\n- 2\n', 'line 1: must be a mapping, got a list of 2 items'),
    (f'password: {SECRET}\n', 'line 1: unknown key at the top level; allowed:'),
    (f'bodies: {SECRET}\n', 'line 1: bodies must be a non-empty list, got a string'),
    (f'bodies: [{SECRET}]\n', 'line 1: bodies[0] must be a mapping, got a string'),
    (f'description: [{SECRET}]\nbodies: [{{shape: box}}]\n',
     'line 1: description must be a string, got a list of 1 item'),
    (f'bodies:\n- shape: box\n  mode: {SECRET}\n',
     "line 3: body 'body0': mode must be one of rigid, linear, quadratic, got a string"),
    (f'bodies:\n- shape: {SECRET}\n', "line 2: body 'body0': shape must be one of box"),
    (f'key: "{SECRET}\n', 'invalid YAML at line 2, column 1: found unexpected end'),
    (f'a: b\n{SECRET}: [\n', 'invalid YAML at line 3, column 1:'),
    (f'{SECRET}: *{SECRET}\n', 'invalid YAML at line 1'),
    (f'%YAML 9.9 {SECRET}\n', 'invalid YAML at line 1'),
    (f'{SECRET}\t: 1\n\t{SECRET}', 'invalid YAML at line'),
]


@pytest.mark.parametrize('text, message', SECRET_FILES, ids=[m[:40] for _, m in SECRET_FILES])
def test_error_for_a_file_of_secrets_names_line_and_kind_not_text(tmp_path, text, message):
    """A file that is no scene (``scene:=/etc/passwd``) is refused with its path, the line
    and the kind of value found; its text (the secret) appears nowhere in the message."""
    path = write_scene(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f'{path}: ')
    assert message in str(info.value)
    assert SECRET not in str(info.value)
    assert 'bash' not in str(info.value)


def test_binary_and_huge_files_are_refused_without_their_bytes(tmp_path):
    """A file that is not UTF-8 names the offending byte's offset; a file larger than any
    scene is refused before it is read."""
    path = tmp_path / 'blob.yaml'
    path.write_bytes(b'bodies: []\n' + SECRET.encode() + b'\xff\xfe')
    with pytest.raises(SceneError, match=r'is not UTF-8 text \(byte 25\)') as info:
        load_scene(str(path))
    assert SECRET not in str(info.value)
    big = tmp_path / 'big.yaml'
    with open(big, 'wb') as f:
        f.truncate(scene_module.MAX_SCENE_BYTES + 1)
    with pytest.raises(SceneError, match='larger than'):
        load_scene(str(big))


CLOUD_SECRETS = [
    ('c.ply', f'ply\nformat ascii 1.0\nelement vertex 1\nproperty {SECRET} x\nend_header\n',
     'PLY header line 4: unsupported property'),
    ('c.ply', f'ply\nformat {SECRET} 1.0\nelement vertex 1\nproperty float x\nend_header\n',
     'unsupported PLY format'),
    ('c.ply', f'ply\nformat ascii 1.0\nelement vertex {SECRET}\nend_header\n',
     'PLY header line 3: element count is not a number'),
    ('c.ply', 'ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n'
              f'property float z\nend_header\n0 0 0\n1 {SECRET} 2\n',
     'PLY vertex 2 is not numeric'),
    ('c.pcd', f'FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS {SECRET}\nDATA ascii\n',
     'PCD header is malformed'),
    ('c.pcd', f'FIELDS x y z\nSIZE 4 4 4\nTYPE F F {SECRET}\nPOINTS 1\nDATA ascii\n',
     'PCD has an unsupported TYPE/SIZE'),
    ('c.pcd', f'FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA {SECRET}\n',
     'unsupported PCD DATA mode'),
    ('c.pcd', f'FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n0 {SECRET} 1\n',
     'PCD point 1 is not numeric'),
    ('c.npy', f"\x93NUMPY\x01\x00v\x00{{'descr': '{SECRET}', 'fortran_order': False}}\n",
     'cannot read .npy (ValueError)'),
]


@pytest.mark.parametrize('name, text, message', CLOUD_SECRETS,
                         ids=[m[:36] for _, _, m in CLOUD_SECRETS])
def test_cloud_file_errors_name_the_line_not_the_text(tmp_path, name, text, message):
    """A point-cloud file a cloud body names is refused with the header line or the row,
    never its text."""
    (tmp_path / 'scenes').mkdir()
    (tmp_path / 'scenes' / name).write_bytes(text.encode('latin-1'))
    path = write_scene(tmp_path, {'bodies': [body('cloud', file=name)]})
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert message in str(info.value)
    assert SECRET not in str(info.value)


def test_mesh_reader_error_names_only_its_kind(tmp_path, trimesh):
    """A mesh file trimesh cannot read is refused with the reader's error type."""
    (tmp_path / 'scenes').mkdir()
    (tmp_path / 'scenes' / 'm.obj').write_text(f'v 0 0 0\nv 1 0 0\nf 1 2 {SECRET}\n')
    path = write_scene(tmp_path, {'bodies': [body('mesh', file='m.obj')]})
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert "body 'b': file 'm.obj'" in str(info.value)
    assert SECRET not in str(info.value)


def test_scene_error_is_value_error():
    assert issubclass(SceneError, ValueError)


def body(shape, **kw):
    """A body dict of `shape` named b, updated with `kw`."""
    d = {'name': 'b', 'shape': shape}
    d.update(kw)
    return d


BAD_SHAPES = [
    (body('sphere', radius=0), "body 'b': radius must be > 0, got 0"),
    (body('sphere'), "body 'b': radius must be a number, got nothing"),
    (body('capsule', radius=0.1, length=-1), "body 'b': length must be >= 0, got -1"),
    (body('cylinder', radius=0.1, length=0), "body 'b': length must be > 0, got 0"),
    (body('sheet', size=[1, 1, 1]), "body 'b': size must be a list of 2 numbers"),
    (body('rope', length=1, density=3), "body 'b': density needs a volume lattice"),
    (body('mesh', file='nope.stl'), "body 'b': file 'nope.stl' not found"),
    (body('mesh', file='m.stl', fill='surface'), "body 'b': fill must be one of lattice, "
                                                 'vertices, got a string'),
    (body('cloud', file='c.xyz'), "body 'b': file 'c.xyz': unsupported cloud file type"),
    (body('cloud', file='c.npy', max_points=0), "body 'b': max_points must be >= 1, got 0"),
    (body('cloud', file='c.npy', scale=-2), "body 'b': scale must be > 0, got -2"),
    (body('cloud', file='c.npy', center='yes'), "body 'b': center must be true or false"),
    (body('cloud', file='bad.npy'), "body 'b': file 'bad.npy': .npy must be a numeric (N, 3)"),
    (body('cloud', file='nan.npy'), "body 'b': file 'nan.npy': the cloud file has no finite"),
    ({'shape': 'box', 'size': [1, 1, 1], 'spacing': 1e-3}, "body 'body0': spacing would make"),
]


@pytest.mark.parametrize('raw, message', BAD_SHAPES,
                         ids=[m.split(': ', 1)[1][:36] for _, m in BAD_SHAPES])
def test_shape_errors(tmp_path, raw, message):
    (tmp_path / 'scenes').mkdir()
    (tmp_path / 'scenes' / 'm.stl').write_text('solid x\nendsolid x\n')
    np.save(tmp_path / 'scenes' / 'c.npy', np.zeros((4, 3)))
    (tmp_path / 'scenes' / 'c.xyz').write_text('0 0 0\n')
    np.save(tmp_path / 'scenes' / 'bad.npy', np.zeros(4))
    np.save(tmp_path / 'scenes' / 'nan.npy', np.full((4, 3), np.nan))
    path = write_scene(tmp_path, {'bodies': [raw]})
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f'{path}: ')
    assert message in str(info.value)


TOP_BAD = [
    ('bodies: []\n', 'bodies must be a non-empty list'),
    ('', 'is empty'),
    ('- 1\n', 'must be a mapping'),
    ('bodys: []\n', "unknown key 'bodys' (did you mean 'bodies'?)"),
    ('bodies: [1]\n', 'line 1: bodies[0] must be a mapping, got a number'),
    ('bodies: [{name: a}]\n', "body 'a': shape is required"),
    ('bodies: [{shape: box, size: [1, 1, 1]}, {shape: box, size: [1, 1, 1], name: body0}]\n',
     "body 'body0': name is used twice"),
    ('bodies: [{shape: box}]\ncolliders: {boxes: [{lo: [0, 0, 0], hi: [1, 0, 1]}]}\n',
     'colliders.boxes[0].hi must exceed lo'),
    ('bodies: [{shape: box}]\ncolliders: {spheres: [{center: [0, 0, 0], radius: 0}]}\n',
     'colliders.spheres[0].radius must be > 0, got 0'),
    ('bodies: [{shape: box}]\ncolliders: {ground: {restitution: 2}}\n',
     'colliders.ground.restitution must be <= 1, got 2'),
    ('bodies: [{shape: box}]\ncolliders: {walls: []}\n', "unknown key 'colliders.walls'"),
    ('bodies: [{shape: box}]\ncolliders: {spheres: [{center: [0, 0, 0], radius: 1, '
     'friction: -1}]}\n', 'colliders.spheres[0].friction must be >= 0, got -1'),
    ('bodies: [{shape: box\n', 'invalid YAML'),
    ('bodies: [{shape: box}]\ndescription: 3\n', 'description must be a string'),
]


@pytest.mark.parametrize('text, message', TOP_BAD, ids=[m[:30] for _, m in TOP_BAD])
def test_top_level_errors(tmp_path, text, message):
    path = write_scene(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f'{path}: ')
    assert message in str(info.value)


def test_missing_file_is_scene_error(tmp_path):
    with pytest.raises(SceneError, match='no such scene file'):
        load_scene(str(tmp_path / 'absent.yaml'))


def test_second_bad_body_fails_whole_scene(tmp_path):
    data = sponge()
    data['bodies'].append({'name': 'bad', 'shape': 'box', 'spacing': 0})
    with pytest.raises(SceneError, match="body 'bad': spacing must be > 0, got 0"):
        load_scene(write_scene(tmp_path, data))


# ------------------------------------------------------------------------ mesh files

@pytest.fixture
def trimesh():
    """The trimesh module (a test dependency)."""
    return pytest.importorskip('trimesh')


@pytest.mark.parametrize('ext', ['obj', 'ply', 'stl'])
def test_mesh_file_vertices_and_lattice(tmp_path, trimesh, ext):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    mesh.export(tmp_path / f'ball.{ext}')
    data = {'bodies': [
        body('mesh', name='v', file=f'../ball.{ext}', fill='vertices', position=[1, 0, 0]),
        body('mesh', name='l', file=f'../ball.{ext}', spacing=0.04, mass=3.0)]}
    spec = load_scene(write_scene(tmp_path, data))
    v, lat = spec.bodies
    assert v.n == len(mesh.vertices)
    assert np.allclose(np.linalg.norm(v.points - [1, 0, 0], axis=1), 0.2, atol=1e-6)
    assert v.surface.faces.shape == (len(mesh.faces), 3) and v.surface.faces.dtype == np.int32
    assert np.array_equal(v.surface.vertices(v.points), v.points)
    assert np.all(np.linalg.norm(lat.points, axis=1) <= 0.2 + 1e-9)
    assert abs(lat.n - len(shapes.sphere_lattice(0.2, 0.04))) < 0.1 * lat.n
    assert np.isclose(lat.masses.sum(), 3.0)
    assert lat.surface.vertices(lat.points).shape == (len(mesh.vertices), 3)
    assert np.allclose(lat.surface.vertices(lat.points), lat.surface.rest_vertices, atol=1e-7)


def test_mesh_scale_center_and_errors(tmp_path, trimesh):
    trimesh.creation.box(extents=[1, 2, 3]).apply_translation([5, 5, 5]).export(
        tmp_path / 'b.stl')
    spec = parse_scene({'bodies': [body('mesh', file='b.stl', fill='vertices', scale=0.5,
                                        center=True)]}, 'mem', tmp_path)
    pts = spec.bodies[0].points
    assert np.allclose(pts.min(axis=0), [-0.25, -0.5, -0.75])
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                           faces=[[0, 1, 2], [0, 2, 3]])
    flat.export(tmp_path / 'thin.obj')
    with pytest.raises(SceneError, match="mem: body 'b': spacing no lattice point"):
        parse_scene({'bodies': [body('mesh', file='thin.obj', spacing=0.3)]}, 'mem', tmp_path)
    trimesh.PointCloud(np.random.default_rng(0).random((20, 3))).export(tmp_path / 'pc.ply')
    with pytest.raises(SceneError, match="file 'pc.ply' has no triangles"):
        parse_scene({'bodies': [body('mesh', file='pc.ply')]}, 'mem', tmp_path)


def test_mesh_lattice_matches_analytic_torus(trimesh):
    m = trimesh.creation.torus(major_radius=0.2, minor_radius=0.08, major_sections=48,
                               minor_sections=24)
    pts = shapes.mesh_lattice(m.vertices, m.faces, 0.02)
    d = np.hypot(np.hypot(pts[:, 0], pts[:, 1]) - 0.2, pts[:, 2])
    assert d.max() <= 0.08 + 1e-9
    lattice = shapes.box_lattice([0.56, 0.56, 0.16], 0.02)
    dd = np.hypot(np.hypot(lattice[:, 0], lattice[:, 1]) - 0.2, lattice[:, 2])
    assert abs(len(pts) - np.count_nonzero(dd < 0.08)) <= 0.05 * len(pts)


# ------------------------------------------------------------------------ surfaces

def test_embedded_surface_follows_affine_motion(trimesh):
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    x0 = shapes.sphere_lattice(0.2, 0.04) + [0.3, 0.1, 0.5]
    v0 = m.vertices + [0.3, 0.1, 0.5]
    surf = shapes.Surface.embedded(m.faces, v0, x0)
    assert np.allclose(surf.vertices(x0), v0, atol=1e-7)
    assert np.allclose(surf.vertices(x0 + [1, -2, 3]), v0 + [1, -2, 3], atol=1e-7)
    rot = shapes.rpy_to_matrix([0.4, -0.7, 1.9])
    assert np.allclose(surf.vertices(x0 @ rot.T), v0 @ rot.T, atol=1e-7)
    a = np.array([[1.2, 0.1, 0], [0, 0.8, 0.2], [0.1, 0, 1.1]])
    assert np.allclose(surf.vertices(x0 @ a.T), v0 @ a.T, atol=1e-7)
    # a local dent moves nearby vertices only
    x = x0.copy()
    top = np.argmax(x0[:, 2])
    x[top, 2] -= 0.05
    moved = np.linalg.norm(surf.vertices(x) - v0, axis=1)
    assert moved.max() > 0.005 and np.count_nonzero(moved > 1e-9) < len(v0) / 2


def test_surface_of_scene_body_follows_translation():
    b = load_scene('mesh').bodies[0]
    v = b.surface.vertices(b.points)
    assert np.allclose(b.surface.vertices(b.points + [0, 0, 1]), v + [0, 0, 1])


def test_knn_matches_brute_force():
    rng = np.random.default_rng(1)
    pts, q = rng.random((300, 3)), rng.random((50, 3))
    idx, dist = shapes.knn(q, pts, 5, chunk_elems=1000)
    d = np.linalg.norm(q[:, None] - pts[None], axis=2)
    assert np.array_equal(idx, np.argsort(d, axis=1)[:, :5])
    assert np.allclose(dist, np.sort(d, axis=1)[:, :5])


# ------------------------------------------------------------------------ cloud files

CLOUD = np.random.default_rng(7).uniform(-0.5, 0.5, (200, 3)) + [0, 0, 2]


def write_ply(path, pts, fmt):
    """Write points (with an extra uchar colour and a face element) as PLY `fmt`."""
    head = (f'ply\nformat {fmt} 1.0\ncomment test\nelement vertex {len(pts)}\n'
            'property float x\nproperty uchar red\nproperty double y\nproperty float z\n'
            'element face 1\nproperty list uchar int vertex_indices\nend_header\n')
    if fmt == 'ascii':
        rows = ''.join(f'{x:.9g} 7 {y:.17g} {z:.9g}\n' for x, y, z in pts.tolist())
        path.write_text(head + rows + '3 0 1 2\n')
        return
    e = '<' if fmt == 'binary_little_endian' else '>'
    dt = np.dtype([('x', e + 'f4'), ('r', 'u1'), ('y', e + 'f8'), ('z', e + 'f4')])
    rec = np.zeros(len(pts), dtype=dt)
    rec['x'], rec['y'], rec['z'] = pts[:, 0], pts[:, 1], pts[:, 2]
    path.write_bytes(head.encode() + rec.tobytes() + b'\x03' + struct.pack(e + '3i', 0, 1, 2))


def write_pcd(path, pts, mode):
    """Write points with fields x y z rgb (+ a 2-count normal field) as PCD `mode`."""
    n = len(pts)
    head = ('# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb n\nSIZE 4 4 4 4 4\nTYPE F F F U F\n'
            f'COUNT 1 1 1 1 2\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n'
            f'DATA {mode}\n')
    if mode == 'ascii':
        rows = ''.join(f'{x:.9g} {y:.9g} {z:.9g} 255 0.5 0.5\n' for x, y, z in pts.tolist())
        path.write_text(head + rows)
        return
    dt = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', '<u4'), ('n', '<f4', (2,))])
    rec = np.zeros(n, dtype=dt)
    rec['x'], rec['y'], rec['z'] = pts[:, 0], pts[:, 1], pts[:, 2]
    if mode == 'binary':
        path.write_bytes(head.encode() + rec.tobytes())
        return
    raw = b''.join(np.ascontiguousarray(rec[f]).tobytes() for f in dt.names)
    comp = lzf_literals(raw)
    path.write_bytes(head.encode() + struct.pack('<II', len(comp), len(raw)) + comp)


def lzf_literals(raw):
    """LZF 'compression' with literal runs only (valid LZF any decoder must accept)."""
    out = bytearray()
    for i in range(0, len(raw), 32):
        chunk = raw[i:i + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


@pytest.mark.parametrize('fmt', ['ascii', 'binary_little_endian', 'binary_big_endian'])
def test_ply_cloud(tmp_path, fmt):
    write_ply(tmp_path / 'c.ply', CLOUD, fmt)
    pts = point_files.read_cloud_file(tmp_path / 'c.ply')
    assert np.allclose(pts, CLOUD, atol=1e-6)


def test_ply_cloud_written_by_trimesh(tmp_path, trimesh):
    trimesh.PointCloud(CLOUD).export(tmp_path / 'c.ply')
    spec = parse_scene({'bodies': [body('cloud', file='c.ply', mass=2)]}, 'mem', tmp_path)
    assert np.allclose(spec.bodies[0].points, CLOUD, atol=1e-6)
    assert np.isclose(spec.bodies[0].masses.sum(), 2.0)


@pytest.mark.parametrize('mode', ['ascii', 'binary', 'binary_compressed'])
def test_pcd_cloud(tmp_path, mode):
    write_pcd(tmp_path / 'c.pcd', CLOUD, mode)
    pts = point_files.read_cloud_file(tmp_path / 'c.pcd')
    assert np.allclose(pts, CLOUD, atol=1e-6)


def test_lzf_back_reference():
    # literal 'abc', then a back reference of length 6 at distance 3 (overlapping copy)
    data = bytes([2]) + b'abc' + bytes([(4 << 5) | 0, 2])
    assert point_files.lzf_decompress(data, 9) == b'abcabcabc'
    with pytest.raises(shapes.GeometryError):
        point_files.lzf_decompress(data, 10)


def test_npy_cloud_plain_and_structured_nan_dropped(tmp_path):
    pts = np.vstack([CLOUD, [[np.nan, 0, 0]]])
    np.save(tmp_path / 'a.npy', np.hstack([pts, np.ones((len(pts), 2))]))
    rec = np.zeros(len(CLOUD), dtype=[('x', 'f4'), ('y', 'f4'), ('z', 'f4'), ('i', 'f4')])
    rec['x'], rec['y'], rec['z'] = CLOUD.T
    np.save(tmp_path / 's.npy', rec)
    spec = parse_scene({'bodies': [body('cloud', name='a', file='a.npy'),
                                   body('cloud', name='s', file='s.npy', center=True)]},
                       'mem', tmp_path)
    a, s = spec.bodies
    assert np.allclose(a.points, CLOUD)
    assert np.allclose(s.points.min(axis=0), -s.points.max(axis=0), atol=1e-6)


def test_cloud_body_max_points_in_scene(tmp_path):
    np.save(tmp_path / 'c.npy', np.random.default_rng(2).random((5000, 3)))
    spec = parse_scene({'bodies': [body('cloud', file='c.npy', max_points=300),
                                   body('cloud', name='v', file='c.npy', voxel=0.25)]},
                       'mem', tmp_path)
    assert 0 < spec.bodies[0].n <= 300
    assert spec.bodies[1].n <= 64


# ------------------------------------------------------------------------ voxel downsampling

@pytest.mark.parametrize('n, cap', [(10_000, 1000), (10_000, 1), (500, 499), (2000, 64),
                                    (300, 1000)])
def test_cloud_body_spec_respects_max_points_and_bbox(n, cap):
    rng = np.random.default_rng(n + cap)
    pts = rng.normal(size=(n, 3)) * [1.0, 0.3, 0.01] + [5, -2, 1]
    b = cloud_body_spec(pts, cap, name='seen')
    assert b.name == 'seen' and b.velocities is None
    assert 1 <= b.n <= cap
    assert np.isclose(b.masses.sum(), 1.0)
    if n <= cap:
        assert np.array_equal(b.points, pts)
        return
    voxel = shapes.voxel_size_for(pts, cap)
    assert np.all(b.points.min(axis=0) >= pts.min(axis=0) - 1e-9)
    assert np.all(b.points.max(axis=0) <= pts.max(axis=0) + 1e-9)
    assert np.all(b.points.min(axis=0) <= pts.min(axis=0) + voxel)
    assert np.all(b.points.max(axis=0) >= pts.max(axis=0) - voxel)
    if cap >= 64:
        assert b.n >= cap // 8   # the bisection does not overshoot wildly


def test_voxel_size_close_to_cap():
    pts = np.random.default_rng(3).random((20_000, 3))
    v = shapes.voxel_size_for(pts, 1000)
    assert len(shapes.voxel_downsample(pts, v)) <= 1000
    assert len(shapes.voxel_downsample(pts, v * 0.98)) > 1000


def test_duplicates_and_coincident_points():
    same = np.ones((50, 3))
    assert cloud_body_spec(same, 3).n == 1
    dup = np.repeat(np.random.default_rng(4).random((10, 3)), 20, axis=0)
    b = cloud_body_spec(dup, 50)
    assert b.n == 10


@pytest.mark.parametrize('pts, cap, message', [
    (np.zeros((0, 3)), 5, 'is empty'),
    (np.zeros((5, 2)), 5, r'shape \(N, 3\)'),
    (np.array([[0, 0, np.inf]]), 5, 'NaN or Inf'),
    (np.zeros((5, 3)), 0, 'max_points must be >= 1'),
])
def test_cloud_body_spec_errors(pts, cap, message):
    with pytest.raises(SceneError, match=message):
        cloud_body_spec(pts, cap)
