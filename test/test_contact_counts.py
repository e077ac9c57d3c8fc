"""Per-body contact counts of the ground and plain colliders (World.static_contacts), which
the bodies' fused step resolves without keeping a record, in World.contact_stats."""

import numpy as np

from sm_ros.core import BodyParams, Box, Ground, Sphere, World

S = 0.02


def lattice(n, center):
    g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing='ij'), -1).reshape(-1, 3) * S
    return g - g.mean(axis=0) + np.asarray(center, dtype=float)


def test_resting_bodies_count_their_touching_layer_per_collider():
    # a 4^3 block on the ground, one on a plain box, one on a plain sphere, one in the air
    w = World()
    w.set_colliders(ground=Ground(), boxes=[Box(lo=(0.9, -0.1, 0.0), hi=(1.1, 0.1, 0.2))],
                    spheres=[Sphere(center=(2.0, 0.0, 0.1), radius=0.1)])
    p = BodyParams(damping=0.2)
    w.add_body(lattice(4, (0, 0, 0.05)), 0.01, p, 'floor')
    w.add_body(lattice(4, (1.0, 0, 0.25)), 0.01, p, 'table')
    w.add_body(lattice(4, (2.0, 0, 0.25)), 0.01, p, 'ball')
    w.add_body(lattice(4, (3.0, 0, 5.0)), 0.01, p, 'air')
    for _ in range(120):
        w.step(1 / 120)
    counts = w.static_contacts()
    assert counts['floor'] == 16                      # the bottom layer of 4 x 4
    assert counts['table'] == 16
    xb = w.body('ball').x
    assert xb[:, 2].min() > 0.15                       # still on the sphere, wrapping it
    r = w.contact_radius('ball')                       # its particles' spheres touch
    on = np.abs(np.linalg.norm(xb - (2.0, 0.0, 0.1), axis=1) - 0.1 - r) < 1e-9
    assert counts['ball'] == on.sum() == 16           # its bottom layer, draped
    assert counts['air'] == 0
    # the same bodies by hand: on the surface to 1e-9 m
    x = w.body('floor').x
    assert counts['floor'] == int((x[:, 2] <= w.contact_radius('floor') + 1e-9).sum())
    stats = w.contact_stats()
    assert stats['floor'] == (16, 0.0) and stats['table'] == (16, 0.0)
    assert 'air' in stats and stats['air'][0] == 0


def test_no_static_colliders_count_nothing():
    w = World()
    w.set_colliders()
    w.add_body(lattice(3, (0, 0, -1.0)), 0.01, None, 'below')   # no ground: falls freely
    w.step(1 / 120)
    assert w.static_contacts() == {'below': 0}
    assert w.contact_stats()['below'] == (0, 0.0)
