"""
The worlds of ``python -m sm_ros.bench contact`` (``sm_ros.bench.contact``): the ball
pile, the bin of blocks and the squeezed state the per-step part is timed on.
"""

import numpy as np

#: Particle spacing of the blocks and balls (m); the contact radius is half of it.
SPACING = 0.02
#: Particles of one block along x, y, z.
BLOCK = (6, 6, 4)


def ball_pile(stacking: bool, clusters: int = 1, sleep: bool = True):
    """(World, bodies): 27 stiff balls (81 particles each, spacing 2 cm) above a 0.4 m x
    0.4 m bin, to be poured by stepping (the ball pile; ``test/test_contact.py`` steps
    it).  ``clusters`` > 1: linear balls of that many
    clusters per axis (``paper_384``'s stiff many-cluster bodies) instead of rigid ones.
    ``sleep``: ``ContactParams.sleep`` (the default: on)."""
    from sm_ros import shapes
    from sm_ros.core import BodyParams, Box, Ground, World
    from sm_ros.core.contact import ContactParams
    w = World()
    w.contact_params = ContactParams(stacking=stacking, sleep=sleep)
    w.set_colliders(ground=Ground(), boxes=[
        Box(lo=(-0.3, -0.3, 0), hi=(-0.2, 0.3, 0.6)), Box(lo=(0.2, -0.3, 0), hi=(0.3, 0.3, 0.6)),
        Box(lo=(-0.2, -0.3, 0), hi=(0.2, -0.2, 0.6)), Box(lo=(-0.2, 0.2, 0), hi=(0.2, 0.3, 0.6))])
    ball = shapes.sphere_lattice(0.05, SPACING)
    p = BodyParams(mode='rigid', alpha=0.9, damping=0.1)
    if clusters > 1:
        p = BodyParams(mode='linear', alpha=0.9, beta=0.2, clusters=clusters, damping=0.1)
    bodies = [w.add_body(ball + [(i - 1) * 0.12, (j - 1) * 0.12, 0.08 + k * 0.12 + 0.003 * i],
                         0.002, p, f'ball{i}{j}{k}')
              for i in range(3) for j in range(3) for k in range(3)]
    return w, bodies


def block_bin(n_blocks: int = 384, seed: int = 1, layers: int = 1, sleep: bool = False):
    """A World of n_blocks 6x6x4 blocks resting in a bin, faces one spacing apart.

    Neighbouring blocks touch: the facing particles of two blocks are exactly one spacing
    (their contact distance) apart.  Blocks stand on the ground (the colliders act on
    particle centres: the bottom layer 0-1 mm above it, at random), the walls 1 cm from the
    outer blocks' particles.  (Until this layout the faces were 0.95 spacing apart and the
    blocks started 2 cm into the ground; with stacking, blocks pushed apart then jammed
    against the walls and the bin never came to rest.)  One layer by default: 24 blocks a
    row.  ``sleep`` off by default: the bin times the contact pass, which a bin asleep
    would skip (``ContactParams.sleep``).
    """
    from sm_ros.core import BodyParams, Box, Ground, World
    from sm_ros.core.contact import ContactParams
    rng = np.random.default_rng(seed)
    nz = layers
    nx = 24 if layers == 1 else 8
    ny = int(np.ceil(n_blocks / (nx * nz)))
    size = (np.array(BLOCK) - 1) * SPACING
    pitch = size + SPACING
    g = np.stack(np.meshgrid(*[np.arange(k) for k in BLOCK], indexing='ij'),
                 -1).reshape(-1, 3) * SPACING
    w = World()
    w.contact_params = ContactParams(sleep=sleep)
    lo = -0.5 * pitch[:2] - 0.01
    hi = (np.array([nx, ny]) - 0.5) * pitch[:2] + 0.01
    w.set_colliders(ground=Ground(), boxes=[
        Box(lo=(lo[0] - 0.05, lo[1], 0), hi=(lo[0], hi[1], 2)),
        Box(lo=(hi[0], lo[1], 0), hi=(hi[0] + 0.05, hi[1], 2)),
        Box(lo=(lo[0], lo[1] - 0.05, 0), hi=(hi[0], lo[1], 2)),
        Box(lo=(lo[0], hi[1], 0), hi=(hi[0], hi[1] + 0.05, 2))])
    p = BodyParams(mode='linear', alpha=0.9, damping=0.1)
    k = 0
    for iz in range(nz):
        for ix in range(nx):
            for iy in range(ny):
                if k == n_blocks:
                    return w
                c = np.array([ix, iy, iz]) * pitch
                c[2] += 0.5 * size[2] + abs(rng.uniform(-0.05, 0.05)) * SPACING
                w.add_body(g - 0.5 * size + c, 0.01, p, f'block{k}')
                k += 1
    return w


def squeezed(X: np.ndarray) -> np.ndarray:
    """A copy of positions X (3, N) squeezed towards their centre by 5 % in x and y.

    Resting blocks that carry their contacts as a whole (stacking, the default) sit with
    their side faces at or a little beyond the contact distance (no side load; sagging
    under their weight, the faces bulge: gaps of 0.5-8 mm after 200 steps), so at rest no
    pair overlaps.  Squeezed by 5 %, about 8,500 facing pairs overlap by up to 0.9 mm (1 %:
    43 pairs), near the bin of 384 blocks (~12,700 pairs within 2 r).  The cKDTree baseline and
    the per-step part are timed on this state.
    """
    Xs = X.copy()
    mid = Xs[:2].mean(axis=1, keepdims=True)
    Xs[:2] = mid + (Xs[:2] - mid) * 0.95
    return Xs
