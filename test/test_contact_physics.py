"""Contact that behaves like physics (doc/contact.md): bodies tip, slide, stick, bounce
and stop, at the node's step (``dt`` of ``sm_ros/params.py``), rigid boxes ``alpha`` 0.9.

Each test is a case of issue 26 with its numbers: restitution never creates energy and
gives a bounce height ratio e^2; off-centre loads tip bodies; stacks stand; static
friction holds a box on a slope below its friction angle and kinetic friction slides it
at g (sin - mu cos) above; a capsule finger pushes a box; an off-centre hit in zero
gravity spins both bodies with both momenta kept.
"""

import math

import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World
from sm_ros.core.contact import ContactParams
from sm_ros.core.params import Box, Capsule
from sm_ros.params import BY_NAME

H = float(BY_NAME['dt'].default)
S = 0.02
RIGID = BodyParams(mode='rigid', alpha=0.9)
G = 9.81


def lattice(nx, ny, nz, center, s=S):
    """An nx x ny x nz lattice of spacing s centred on ``center``."""
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                 -1).reshape(-1, 3) * s
    return g - g.mean(axis=0) + np.asarray(center, dtype=float)


def ball(radius, center):
    """The lattice points within ``radius`` of ``center``."""
    n = int(round(2 * radius / S)) + 1
    g = lattice(n, n, n, (0.0, 0.0, 0.0))
    return g[np.linalg.norm(g, axis=1) <= radius + 1e-9] + np.asarray(center)


def kinetic(bodies):
    return sum(0.5 * float((b.m[:, None] * b.v ** 2).sum()) for b in bodies)


def turned_deg(body):
    """Angle (deg) of the best-fit rotation of a body from its initial shape."""
    x0 = body.x_init - body.x_init.mean(axis=0)
    x = body.x - body.x.mean(axis=0)
    u, _, vt = np.linalg.svd(x0.T @ x)
    r = (u @ vt).T
    return math.degrees(math.acos(float(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def run(w, seconds):
    for _ in range(int(round(seconds / H))):
        w.step(H)


# ---------------------------------------------------------------------------------------
# Restitution
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_dropped_ball_bounces_e_squared_and_never_gains_energy(e):
    w = World()
    w.set_colliders(ground=Ground(restitution=e))
    b = w.add_body(ball(0.05, (0.0, 0.0, 0.55)), 1.0, RIGID, 'ball')
    m = float(b.m.sum())
    e0 = m * G * b.com()[2]
    z, vz, energy = [], [], []
    for _ in range(int(1.6 / H)):
        w.step(H)
        z.append(b.com()[2])
        vz.append(b.v[:, 2].mean())
        # the energy the symplectic step keeps in free fall: the potential at z - h v / 2
        energy.append(m * G * (b.com()[2] - 0.5 * H * vz[-1]) + kinetic([b]))
    z, vz = np.array(z), np.array(vz)
    assert max(energy) <= e0 * (1.0 + 1e-9)              # no collision creates energy
    hit = int(np.argmax(np.diff(vz) > 0.0)) + 1          # the step the ground acted
    approach = -vz[hit - 1]
    assert approach > 2.5 and z[hit - 1] < 0.04 + approach * H   # it fell to the ground
    if e == 0.0:
        assert vz[hit:].max() <= 0.05 * approach         # no separating speed
    else:
        bounce = (z[hit:].max() - z[hit - 1]) / (0.55 - z[hit - 1])
        assert bounce == pytest.approx(e * e, rel=0.1)


@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_off_centre_hit_in_zero_gravity_spins_both_and_keeps_momentum(e):
    w = World(gravity=(0.0, 0.0, 0.0))
    w.contact_params = ContactParams(friction=0.0, restitution=e)
    n = 125
    a = w.add_body(lattice(5, 5, 5, (-0.1, 0.0, 0.0)), 1.0, RIGID, 'a',
                   velocities=np.tile([1.0, 0.0, 0.0], (n, 1)))
    b = w.add_body(lattice(5, 5, 5, (0.1, 0.0, 0.06)), 1.0, RIGID, 'b',
                   velocities=np.tile([-1.0, 0.0, 0.0], (n, 1)))
    bodies = (a, b)
    p0 = sum(x.momentum() for x in bodies)
    l0 = sum(x.angular_momentum() for x in bodies)
    k0 = kinetic(bodies)
    for _ in range(60):
        w.step(H)
        assert kinetic(bodies) <= k0 * (1.0 + 1e-12)
    assert w.contact.builds > 0
    np.testing.assert_allclose(sum(x.momentum() for x in bodies), p0, atol=1e-9)
    lz = np.abs(l0).max()
    np.testing.assert_allclose(sum(x.angular_momentum() for x in bodies), l0,
                               atol=1e-8 * lz)
    for x in bodies:                                     # both spin, about y
        r = x.x - x.com()
        spin = (x.m[:, None] * np.cross(r, x.v - x.v.mean(axis=0))).sum(axis=0)
        assert abs(spin[1]) > 0.05 * lz


# ---------------------------------------------------------------------------------------
# Contact turns bodies: toppling, stacks
# ---------------------------------------------------------------------------------------

def _box_on(under, offset):
    """A 0.1 m box with its centre ``offset`` m past (> 0) or inside (< 0) the +x edge of a
    0.2 m box body or a static table of that top."""
    w = World()
    table = [Box(lo=(-0.11, -0.11, 0.0), hi=(0.11, 0.11, 0.3))] if under == 'table' else []
    w.set_colliders(ground=Ground(), boxes=table)
    if under == 'body':
        w.add_body(lattice(11, 11, 3, (0.0, 0.0, 0.02)), 2.0, RIGID, 'base')
        top = 0.06
    else:
        top = 0.3
    return w, w.add_body(lattice(6, 6, 6, (0.1 + offset, 0.0, top + 0.05)), 1.0, RIGID, 'box')


@pytest.mark.parametrize('under', ['body', 'table'])
def test_box_past_an_edge_topples(under):
    w, box = _box_on(under, 0.05)
    run(w, 1.5)
    assert turned_deg(box) > 45.0


@pytest.mark.parametrize('under', ['body', 'table'])
def test_box_inside_an_edge_stays(under):
    w, box = _box_on(under, -0.05)
    c0 = box.com().copy()
    run(w, 10.0)
    assert turned_deg(box) < 2.0
    assert np.linalg.norm(box.com()[:2] - c0[:2]) < 0.005


@pytest.mark.parametrize('rows', [(4, 3, 2, 1), (1,) * 10], ids=['pyramid', 'tower'])
def test_pyramid_and_tower_stand(rows):
    w = World()
    w.set_colliders(ground=Ground())
    bodies = []
    for level, count in enumerate(rows):
        for k in range(count):
            x = (k - (count - 1) / 2.0) * 0.102
            bodies.append(w.add_body(lattice(5, 5, 5, (x, 0.0, 0.04 + 0.1 * level)), 1.0,
                                     RIGID, f'b{level}_{k}'))
    run(w, 0.5)
    c0 = [b.com().copy() for b in bodies]
    run(w, 10.0)
    for b, c in zip(bodies, c0):
        assert np.linalg.norm(b.com() - c) < 0.005


# ---------------------------------------------------------------------------------------
# Friction on a slope, pushes by a finger
# ---------------------------------------------------------------------------------------

def _on_slope(mu):
    """A 0.1 m box at rest on a 20 degree slope (an oriented static box), no ground."""
    th = math.radians(20.0)
    q = (0.0, -math.sin(th / 2.0), 0.0, math.cos(th / 2.0))
    c, s = math.cos(th), math.sin(th)
    rot = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    w = World()
    w.set_colliders(ground=None, boxes=[Box(lo=(-3, -1, -0.2), hi=(3, 1, 0.0), friction=mu,
                                             orientation=q)])
    top = np.array([0.0, 0.0, -0.1]) + rot @ np.array([0.0, 0.0, 0.1])
    pts = (rot @ (lattice(5, 5, 5, (0.0, 0.0, 0.04))).T).T + top
    box = w.add_body(pts, 1.0, RIGID, 'box')
    return w, box, rot @ np.array([-1.0, 0.0, 0.0])      # downhill


def test_static_friction_holds_a_box_on_a_slope():
    w, box, down = _on_slope(0.6)                        # tan 20 deg = 0.36 < 0.6
    c0 = box.com().copy()
    run(w, 2.0)
    assert np.linalg.norm(box.com() - c0) < 0.005


def test_kinetic_friction_slides_a_box_at_g_sin_minus_mu_cos():
    w, box, down = _on_slope(0.2)
    c0 = box.com().copy()
    t = 1.5
    run(w, t)
    th = math.radians(20.0)
    expected = 0.5 * G * (math.sin(th) - 0.2 * math.cos(th)) * t * t
    assert float(np.dot(box.com() - c0, down)) == pytest.approx(expected, rel=0.1)
    assert turned_deg(box) < 2.0                         # slides, does not tumble


@pytest.mark.parametrize('push', ['low', 'offcentre'])
def test_capsule_finger_pushes_a_box(push):
    # a kinematic capsule of radius 2 cm moved 0.3 m at 0.3 m/s: lying across the box 3 cm
    # above the ground it slides the box without tipping it; upright 3 cm off the box's
    # centre line it turns the box about the vertical
    w = World()
    if push == 'low':
        q, c = (math.sin(math.pi / 4), 0.0, 0.0, math.cos(math.pi / 4)), (-0.2, 0.0, 0.03)
    else:
        q, c = (0.0, 0.0, 0.0, 1.0), (-0.2, 0.03, 0.06)
    w.set_colliders(ground=Ground(), capsules=[Capsule(center=c, radius=0.02, length=0.2,
                                                       name='finger', kinematic=True,
                                                       orientation=q)])
    box = w.add_body(lattice(6, 6, 6, (0.0, 0.0, 0.05)), 1.0, RIGID, 'box')
    run(w, 0.25)
    c0 = box.com().copy()
    w.move_collider('finger', (c[0] + 0.3, c[1], c[2]), q, 1.0)
    run(w, 1.25)
    assert box.com()[0] - c0[0] > 0.1
    if push == 'low':
        assert turned_deg(box) < 5.0
    else:
        assert turned_deg(box) > 10.0


# ---------------------------------------------------------------------------------------
# Kernels against NumPy
# ---------------------------------------------------------------------------------------

def _one_body_state(seed):
    """A jittered 5^3 box (flat state of one body) just below the ground, with a linear
    and an angular velocity, after a step of H (x = x_start + H v)."""
    from sm_ros.core.kernels import contact_rows as KR
    rng = np.random.default_rng(seed)
    x0 = lattice(5, 5, 5, (0.0, 0.0, 0.0)).T.copy()
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    xs = rot @ x0 + np.array([[0.0], [0.0], [0.039]]) + rng.normal(0.0, 1e-4, x0.shape)
    n = x0.shape[1]
    m = rng.uniform(0.5, 1.5, n)
    c = (xs * m).sum(axis=1) / m.sum()
    v = np.array([[0.1], [-0.05], [-0.5]]) + np.cross([0.3, -0.2, 0.1], (xs - c[:, None]).T).T
    X = xs + H * v
    pt = KR.Particles(X, v.copy(), 1.0 / m, np.full(n, 0.01), np.zeros(n, np.int32), m,
                      np.zeros((3, n)), np.zeros((3, n)))
    c0 = (x0 * m).sum(axis=1) / m.sum()
    bd = KR.Bodies(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 9)), np.zeros((1, 3)),
                   np.zeros((1, 3)), np.zeros(1), np.zeros((1, 12)), np.zeros((1, 9)),
                   c0[None].copy())
    return pt, bd, xs, x0, rot


@pytest.mark.parametrize('seed', [0, 1])
def test_body_frames_match_numpy(seed):
    from sm_ros.core.contact_frames import body_frames
    pt, bd, xs, x0, rot = _one_body_state(seed)
    box = np.zeros((1, 6))
    body_frames(pt, np.array([0, xs.shape[1]]), np.array([True]), bd, H, box, x0)
    m = pt.M
    c = (xs * m).sum(axis=1) / m.sum()
    r = (xs - c[:, None]).T
    inertia = (m[:, None, None] * ((r * r).sum(1)[:, None, None] * np.eye(3)
                                   - r[:, :, None] * r[:, None, :])).sum(0)
    ang = np.cross(r, m[:, None] * pt.V.T).sum(0)
    assert bd.share[0] == 1.0 and bd.bw[0] == pytest.approx(1.0 / m.sum())
    np.testing.assert_allclose(bd.bc[0], c, atol=1e-14)
    np.testing.assert_allclose(bd.vb[0], (m * pt.V).sum(1) / m.sum(), atol=1e-14)
    np.testing.assert_allclose(bd.biv[0].reshape(3, 3) @ inertia, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(bd.bom[0], np.linalg.solve(inertia, ang), rtol=1e-6)
    np.testing.assert_allclose(bd.rot[0].reshape(3, 3), rot, atol=1e-3)
    np.testing.assert_allclose(box[0, :3], pt.X.min(axis=1))


def test_block_pass_meets_the_targets_of_a_flat_patch_at_once():
    # a box landing tilted and spinning on the ground: one block solve of its 25 ground
    # rows leaves every row at its target normal speed (no spin left over), exactly as
    # the 3x3 system of the linear normal-speed field promises
    from sm_ros.core import contact_frames as F, contact_solve as CS, contact_statics as T
    from sm_ros.core import contact_sweeps as SW
    from sm_ros.core.kernels import contact_rows as KR
    pt, bd, xs, x0, _ = _one_body_state(0)
    pt = pt._replace(X=lattice(5, 5, 5, (0.0, 0.0, 0.039)).T + H * pt.V)
    n = pt.X.shape[1]
    off = np.array([0, n])
    box = np.zeros((1, 6))
    F.body_frames(pt, off, np.array([True]), bd, H, box, pt.X - H * pt.V)
    rows = KR.Rows(np.zeros((2 * n, KR.ROW_WIDTH)), np.zeros((2 * n, 5), np.int64))
    st = KR.Statics(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros((0, 8)), np.zeros((0, 6)))
    m = T.collider_rows(pt, bd, off, st, rows, 0, box)
    law = np.array([H, 1e-3, 0.0, 0.0, 1.0, 1.0, 8, 4, 0.0, 0.0, 0.0, 0.0])
    CS.collider_offsets(pt, bd, rows, 0, m, H)
    assert m == 25
    order, start = np.zeros(m, np.int64), np.zeros(m + 1, np.int64)
    ng = F.group_rows(rows, m, bd.share, order, start, pt.R)
    cold = np.full((n, KR.WARM_WIDTH), -np.inf)
    CS.fill_rows(pt, bd, rows, order, start[ng], law, cold, cold)

    def residual():
        out = []
        for a in order[:start[ng]]:
            u = KR._rel_velocity(bd, pt.V, rows.f[a], rows.i[a], 0)
            out.append(np.dot(u, rows.f[a, :3]) - rows.f[a, KR.ROW_TARGET])
        return np.array(out)
    assert residual().min() < -0.4
    SW.block_pass(pt, bd, rows, (order, start, ng, H), 0, pt.V, False)
    np.testing.assert_allclose(residual(), 0.0, atol=1e-5)      # 1e-6 regularised
    assert (rows.f[order[:start[ng]], KR.ROW_ACCN] > 0.0).all()
