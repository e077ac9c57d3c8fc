"""The named arguments of the contact pass's compiled solves (``contact_kernels.py``,
``contact_bodies.py``): tuples of arrays that Numba passes as one value, so a solve takes
a handful of them instead of dozens of positional arrays.  ``Contact`` makes them from its
buffers at every pass; the ``*_for`` helpers make zeroed ones for a given size.
"""

from collections import namedtuple

import numpy as np

#: The particles in flat order: positions and velocities (3, N), inverse masses, contact
#: radii, body index, and the flags of those the solve moved on their own (uint8, zero
#: on entry and on return).
ContactParticles = namedtuple('ContactParticles', 'x v inv_mass radius body moved')
#: The pair list: its first and second particles and how many pairs it holds.
PairList = namedtuple('PairList', 'first second count')
#: The law and its sweeps: Coulomb friction, restitution (above the resting speed
#: ``thresh``), the step ``h``, at most ``sweeps`` sweeps, stopping once none changes a
#: velocity by more than ``tol``; the fraction of the last step's impulses to start from
#: (``warm``).
ContactLaw = namedtuple('ContactLaw', 'friction restitution thresh h sweeps tol warm')
#: What a pass found, per body: touched (uint8), contacts and the deepest overlap (m).
ContactReport = namedtuple('ContactReport', 'touched count deepest')
#: The bodies carried as a whole (``carried`` and a positive ``inv_mass``): particle
#: offsets, inverse mass, at the pass's start the velocity of the centre of mass, the
#: lowest particle (2, bodies: height, vertical velocity), the centre, the inverse inertia
#: (9 per body) and the spin; during the pass the body's changes (``change``: velocity,
#: position, 1 when another body held it), whether it has any (``pending``) and its
#: accumulated ground impulses (2, bodies: velocity, position); what else than the ground
#: each rests on as a whole (``floor`` (2, bodies): height and friction of the stiff body
#: a stiff one lies on, where the stiff pass left it; -inf: nothing).
CarriedBodies = namedtuple('CarriedBodies', 'offsets inv_mass carried velocity lowest centre '
                                            'inv_inertia spin change pending ground_impulse '
                                            'floor')
#: Per pair of the list, for the carried bodies' sweeps: the pairs the later sweeps visit
#: (``active``), the accumulated impulses (2, P: velocity, position), the law fixed at a
#: pair's first visit (``target``), and the compact rows of pairs of two carried bodies
#: (``rows`` (7, P) float, ``row_index`` (5, P) int32; ``contact_bodies``).
PairSweep = namedtuple('PairSweep', 'active impulse target rows row_index')
#: The carried bodies' particles near a box or sphere (``particles[start[b]:start[b + 1]]``)
#: and how far a particle may move before it must be put through them again.
WallCandidates = namedtuple('WallCandidates', 'particles start margin')


def carried_bodies_for(offsets, inv_mass, carried) -> CarriedBodies:
    """Zeroed carried-body state for the bodies of ``offsets`` (their inverse masses and
    carried flags as given)."""
    nb = len(offsets) - 1
    return CarriedBodies(np.asarray(offsets, dtype=np.int64), inv_mass, carried,
                         np.zeros((nb, 3)), np.zeros((2, nb)), np.zeros((nb, 3)),
                         np.zeros((nb, 9)), np.zeros((nb, 3)), np.zeros((nb, 7)),
                         np.zeros(nb, dtype=np.uint8), np.zeros((2, nb)),
                         np.full((2, nb), -np.inf))


def pair_sweep_for(count: int) -> PairSweep:
    """Zeroed per-pair state for ``count`` pairs."""
    return PairSweep(np.zeros(count, dtype=np.int64), np.zeros((2, count)),
                     np.zeros(count), np.zeros((7, count)),
                     np.zeros((5, count), dtype=np.int32))


def report_for(bodies: int) -> ContactReport:
    """A zeroed report for ``bodies`` bodies."""
    return ContactReport(np.zeros(bodies, dtype=np.uint8), np.zeros(bodies, dtype=np.int64),
                         np.zeros(bodies))


NO_WALLS = WallCandidates(np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64), np.inf)
