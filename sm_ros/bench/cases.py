"""
The contact cases, described once for every engine, and their build in sm_ros.

A ``Case`` is plain data: rigid solids (boxes, balls: size, mass, pose, velocity, spin),
static or kinematic colliders (boxes, capsules), the ground, gravity, one friction and one
restitution for every surface, the duration and the function that measures it.  An engine
turns a case into a ``Track`` (``simulate``: each solid's centre, rotation, velocity, spin,
kinetic energy, momentum and angular momentum every ``SAMPLE_DT``); the measurements read
only the track, so every engine is measured the same way (``python -m sm_ros.bench
peers``).  In sm_ros (``SmRos``) a solid is a lattice of particles ``SPACING`` apart
filling its outline (a ball: the points within radius - half a spacing), of contact
radius half a spacing, ``RIGID`` at the node's step.  Angles in degrees, drifts in mm.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from sm_ros.params import BY_NAME

G = 9.81
#: The node's default step and its steps per tick (``sm_ros/params.py``).
DT = float(BY_NAME['dt'].default)
SUBSTEPS = int(BY_NAME['substeps'].default)
#: Every engine's state is sampled once per node tick.
SAMPLE_DT = DT * SUBSTEPS
#: Lattice spacing of the sm_ros solids (m).
SPACING = 0.02
#: Material of the sm_ros solids (rigid, alpha 0.9 at the node's step).
RIGID = {'mode': 'rigid', 'alpha': 0.9}
#: A case's outcomes are measured "after settling" from this time on (s).
SETTLE_S = 0.5
IDENTITY = (0.0, 0.0, 0.0, 1.0)
Vec = Tuple[float, float, float]


def quat_about(axis, angle: float) -> Tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation by ``angle`` rad about ``axis``."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a) * math.sin(angle / 2.0)
    return (float(a[0]), float(a[1]), float(a[2]), math.cos(angle / 2.0))


@dataclass(frozen=True)
class Solid:
    """A rigid solid: ``shape`` 'box' (``size`` full extents) or 'ball' (``size`` (radius,)),
    ``mass`` kg, centre ``position``, ``quat`` (x, y, z, w), ``velocity`` of its centre and
    ``spin`` (angular velocity, rad/s, world axes)."""

    name: str
    shape: str
    size: Tuple[float, ...]
    mass: float
    position: Vec
    quat: Tuple[float, float, float, float] = IDENTITY
    velocity: Vec = (0.0, 0.0, 0.0)
    spin: Vec = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Fixed:
    """A static collider, or a kinematic one when ``path`` has keyframes ``(t, position)``
    (linear in between, held after the last): 'box' (``size`` full extents) or 'capsule'
    (``size`` (radius, length of its segment along the local z axis))."""

    name: str
    shape: str
    size: Tuple[float, ...]
    position: Vec
    quat: Tuple[float, float, float, float] = IDENTITY
    path: Tuple[Tuple[float, Vec], ...] = ()

    def pose_at(self, t: float) -> np.ndarray:
        """Centre at time ``t`` (the declared position before the first keyframe)."""
        if not self.path:
            return np.asarray(self.position, dtype=float)
        times = np.array([0.0] + [k[0] for k in self.path])
        pos = np.array([self.position] + [k[1] for k in self.path], dtype=float)
        return np.array([np.interp(t, times, pos[:, j]) for j in range(3)])


@dataclass(frozen=True)
class Case:
    """One contact situation and how it is measured (``measure(case, track)``)."""

    name: str
    what: str
    target: str
    solids: Tuple[Solid, ...]
    measure: Callable
    duration: float
    fixed: Tuple[Fixed, ...] = ()
    ground: bool = True
    gravity: Vec = (0.0, 0.0, -G)
    friction: float = 0.5
    restitution: float = 0.0
    extra: Dict[str, float] = field(default_factory=dict)


# --- Track and measurements (engine-agnostic) ---

class Track:
    """Sampled states of a case's solids: ``times`` (T,), ``com`` (T, B, 3), ``rot`` (T, B, 3,
    3), ``vel`` (T, B, 3), ``spin`` (T, B, 3), ``ke`` (T, B), ``mom`` (T, B, 3), ``angmom``
    (T, B, 3) about the origin; ``names`` (B,)."""

    KEYS = ('com', 'rot', 'vel', 'spin', 'ke', 'mom', 'angmom')

    def __init__(self, names):
        self.names = list(names)
        self.times: List[float] = []
        self._rows: Dict[str, list] = {k: [] for k in self.KEYS}

    def add(self, t: float, **state):
        """Append one sample (every key of ``KEYS``, arrays over the solids)."""
        self.times.append(float(t))
        for k in self.KEYS:
            self._rows[k].append(np.asarray(state[k], dtype=float))

    def __getattr__(self, key):
        if key in Track.KEYS:
            return np.array(self._rows[key])
        raise AttributeError(key)

    def at(self, t: float) -> int:
        """Index of the first sample at or after time ``t`` (the last one if none)."""
        return min(int(np.searchsorted(np.asarray(self.times), t - 1e-9)), len(self.times) - 1)


def rotation_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angle (deg) of the rotation from ``rot_a`` to ``rot_b`` (..., 3, 3)."""
    rel = np.einsum('...ji,...jk->...ik', rot_a, rot_b)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    sin = np.linalg.norm(rel - np.swapaxes(rel, -1, -2), axis=(-2, -1)) / (2.0 * math.sqrt(2.0))
    return np.degrees(np.arctan2(sin, cos))             # arccos alone is inexact near 0


def turned_deg(track: Track, body: int) -> np.ndarray:
    """Angle (deg) each sample's rotation of solid ``body`` makes with its first."""
    rot = track.rot[:, body]
    return rotation_deg(np.broadcast_to(rot[0], rot.shape), rot)


def rolled_rad(track: Track, body: int) -> float:
    """Total angle (rad) solid ``body`` turned, summed sample to sample (each < 180 deg)."""
    rot = track.rot[:, body]
    return float(np.radians(rotation_deg(rot[:-1], rot[1:])).sum())


def drift_mm(track: Track, body: int, since: float = SETTLE_S) -> float:
    """How far (mm) the centre of solid ``body`` moved from time ``since`` to the end."""
    com = track.com[:, body]
    return 1e3 * float(np.linalg.norm(com[-1] - com[track.at(since)]))


def moved_mm(track: Track, body: int) -> float:
    """Horizontal distance (mm) the centre of solid ``body`` moved from start to end."""
    com = track.com[:, body]
    return 1e3 * float(np.linalg.norm(com[-1, :2] - com[0, :2]))


def fit_accel(times, dist, since: float = 0.25) -> float:
    """Acceleration of a distance series, from a least-squares parabola over t >= since."""
    t, d = np.asarray(times), np.asarray(dist)
    keep = t >= since
    return 2.0 * float(np.polyfit(t[keep], d[keep], 2)[0])


def measure_topple(case: Case, tr: Track) -> Dict[str, float]:
    """The top box: largest turn within 1.5 s, turn at the end, drift after settling."""
    k = tr.names.index('top')
    turn = turned_deg(tr, k)
    return {'turn_1.5s_deg': float(turn[:tr.at(1.5) + 1].max()), 'turn_end_deg': float(turn[-1]),
            'drift_mm': drift_mm(tr, k)}


def _downhill(case: Optional[Case], slope_deg: float = 0.0) -> np.ndarray:
    """The unit vector down the case's slope (or one of ``slope_deg``), falling in +x."""
    th = math.radians(case.extra['slope_deg'] if case else slope_deg)
    return np.array([math.cos(th), 0.0, -math.sin(th)])


def measure_slide(case: Case, tr: Track) -> Dict[str, float]:
    """A box on the slope: distance down it, acceleration against g(sin - mu cos)."""
    k = tr.names.index('box')
    th, mu = math.radians(case.extra['slope_deg']), case.friction
    dist = (tr.com[:, k] - tr.com[0, k]) @ _downhill(case)
    out = {'slide_mm': 1e3 * float(dist[-1]), 'turn_end_deg': float(turned_deg(tr, k)[-1])}
    expect = G * (math.sin(th) - mu * math.cos(th))
    if expect > 0:
        out['accel_ratio'] = fit_accel(tr.times, dist) / expect
    return out


def measure_roll(case: Case, tr: Track) -> Dict[str, float]:
    """A ball on the slope: acceleration against (5/7) g sin, turned angle x r / distance."""
    k = tr.names.index('ball')
    th = math.radians(case.extra['slope_deg'])
    dist = (tr.com[:, k] - tr.com[0, k]) @ _downhill(case)
    radius = case.solids[k].size[0]
    return {'accel_ratio': fit_accel(tr.times, dist) / (5.0 / 7.0 * G * math.sin(th)),
            'slip': rolled_rad(tr, k) * radius / max(float(dist[-1]), 1e-12)}


def measure_push(case: Case, tr: Track) -> Dict[str, float]:
    """The pushed box: yaw (about world z) and largest tilt of its z axis, distance moved."""
    k = tr.names.index('box')
    rot = tr.rot[:, k]
    rel = np.einsum('ji,tjk->tik', rot[0], rot)
    yaw = math.degrees(math.atan2(rel[-1, 1, 0], rel[-1, 0, 0]))
    tilt = np.degrees(np.arccos(np.clip(rot[:, 2, 2], -1.0, 1.0)))
    return {'yaw_deg': abs(yaw), 'tilt_max_deg': float(tilt.max()), 'moved_mm': moved_mm(tr, k)}


def measure_drop(case: Case, tr: Track) -> Dict[str, float]:
    """The dropped ball: first bounce's height over the drop's (target e^2), and its energy
    at the top of it (height, and kinetic energy but the vertical) over the drop's: read
    anywhere in flight, semi-implicit Euler's velocity, half a step ahead of the position,
    swings kinetic plus potential energy by g h v (2 % at the contact)."""
    k = tr.names.index('ball')
    z, m = tr.com[:, k, 2], case.solids[k].mass
    low = int(np.argmin(z[:tr.at(case.extra['first_low_s']) + 1]))
    drop = z[0] - z[low]
    flight = tr.at(tr.times[low] + 1.5 * math.sqrt(2.0 * drop / G))
    top = low + int(np.argmax(z[low:flight + 1]))
    moving = tr.ke[top, k] - 0.5 * m * tr.vel[top, k, 2] ** 2
    return {'bounce_ratio': float((z[top] - z[low]) / drop),
            'energy_ratio': float((moving + m * G * (z[top] - z[low])) / (m * G * drop))}


def measure_stack(case: Case, tr: Track) -> Dict[str, float]:
    """Every box of a stack: largest drift after settling, move from the start, turn."""
    n = len(tr.names)
    return {'drift_mm': max(drift_mm(tr, k) for k in range(n)),
            'moved_mm': max(moved_mm(tr, k) for k in range(n)),
            'turn_max_deg': max(float(turned_deg(tr, k)[-1]) for k in range(n))}


def measure_dominoes(case: Case, tr: Track) -> Dict[str, float]:
    """The row: how many fell (turned > 45 deg), whether in order, largest turn of those
    standing."""
    turns = [turned_deg(tr, k) for k in range(len(tr.names))]
    times = [float(tr.times[int(np.argmax(a > 45.0))]) if a.max() > 45.0 else math.inf
             for a in turns]
    fell = [t for t in times if t < math.inf]
    standing = [float(a[-1]) for a in turns if a.max() <= 45.0]
    return {'fallen': len(fell), 'in_sequence': fell == sorted(fell) and len(fell) > 1,
            'standing_turn_max_deg': max(standing) if standing else 0.0}


def measure_hit(case: Case, tr: Track) -> Dict[str, float]:
    """Two boxes in zero gravity: momentum and angular momentum changes (relative), spins,
    largest kinetic energy over the start's, separation over approach speed (along x)."""
    mom, ang, ke = tr.mom.sum(axis=1), tr.angmom.sum(axis=1), tr.ke.sum(axis=1)
    a, b, vel, spin = tr.names.index('a'), tr.names.index('b'), tr.vel, tr.spin[-1]
    approach = vel[0, a, 0] - vel[0, b, 0]
    return {'momentum_err': float(np.abs(mom - mom[0]).max() / np.linalg.norm(mom[0])),
            'angmom_err': float(np.abs(ang - ang[0]).max() / np.linalg.norm(ang[0])),
            'spin_a': float(np.linalg.norm(spin[a])), 'spin_b': float(np.linalg.norm(spin[b])),
            'energy_ratio': float(ke.max() / ke[0]),
            'separation': float((vel[-1, b, 0] - vel[-1, a, 0]) / approach)}


# --- The cases ---

def _topple(on: str, offset: float, duration: float) -> Case:
    """A 0.3 x 0.2 x 0.1 m box (1 kg) on a 0.4 x 0.4 x 0.2 m box body (4 kg) or static table
    whose edge is at x = 0, its centre ``offset`` m beyond the edge (negative: inside)."""
    top = Solid('top', 'box', (0.3, 0.2, 0.1), 1.0, (offset, 0.0, 0.25))
    where, size, centre = ('past' if offset > 0 else 'inside'), (0.4, 0.4, 0.2), (-0.2, 0, 0.1)
    solids, fixed = (Solid('base', 'box', size, 4.0, centre), top), ()
    if on == 'table':
        solids, fixed = (top,), (Fixed('table', 'box', size, centre),)
    return Case(f'topple_{on}_{where}', f'box, COM {abs(offset) * 100:g} cm {where} the edge '
                f'of a {"box body" if on == "body" else "static table"}',
                '> 45 deg within 1.5 s' if offset > 0 else '< 2 deg, < 5 mm after settling',
                solids, measure_topple, duration, fixed)


def _slope(length: float, slope_deg: float = 20.0) -> Tuple[Fixed, np.ndarray, np.ndarray,
                                                           np.ndarray]:
    """A static plank 0.2 m thick, 1 m wide, falling in +x at ``slope_deg``: (collider,
    its surface normal, the point of its top surface at the plank's centre, downhill)."""
    th = math.radians(slope_deg)
    normal, centre = np.array([math.sin(th), 0.0, math.cos(th)]), np.array([0.0, 0.0, 2.0])
    plank = Fixed('slope', 'box', (length, 1.0, 0.2), tuple(centre), quat_about((0, 1, 0), th))
    return plank, normal, centre + 0.1 * normal, _downhill(None, slope_deg)


def _incline(mu: float) -> Case:
    """A 0.1 m cube (1 kg) at rest on the 20 deg slope, friction ``mu``."""
    plank, normal, top, down = _slope(8.0)
    box = Solid('box', 'box', (0.1, 0.1, 0.1), 1.0, tuple(top + 0.05 * normal - 3.5 * down),
                plank.quat)
    target = ('< 5 mm in 2 s' if mu > math.tan(math.radians(20))
              else 'accel g(sin - mu cos) +- 10 %')
    return Case(f'incline_mu{mu:g}', f'box on a 20 deg slope, mu {mu:g}', target, (box,),
                measure_slide, 2.0, (plank,), ground=False, friction=mu,
                extra={'slope_deg': 20.0})


def _roll() -> Case:
    """A ball of radius 0.1 m (1 kg) at rest on the 20 deg slope, friction 0.6."""
    plank, normal, top, down = _slope(10.0)
    ball = Solid('ball', 'ball', (0.1,), 1.0, tuple(top + 0.1 * normal - 4.0 * down))
    return Case('incline_ball', 'ball rolling down a 20 deg slope, mu 0.6',
                'accel (5/7) g sin +- 10 %, slip 1', (ball,), measure_roll, 2.0, (plank,),
                ground=False, friction=0.6, extra={'slope_deg': 20.0})


def _push(low: bool) -> Case:
    """A 0.2 m cube (1 kg) on the ground pushed 0.3 m in +x in 1 s by a capsule finger of
    radius 2 cm: upright 7 cm off the centre line, or lying across the box 3 cm high."""
    y, z = (0.0, 0.03) if low else (0.07, 0.1)
    q = quat_about((1, 0, 0), math.pi / 2) if low else IDENTITY
    finger = Fixed('finger', 'capsule', (0.02, 0.1), (-0.15, y, z), q, ((1.0, (0.15, y, z)),))
    box = Solid('box', 'box', (0.2, 0.2, 0.2), 1.0, (0.0, 0.0, 0.1))
    if low:
        return Case('push_low', 'box pushed 3 cm above the ground by a lying capsule',
                    'slides, tilt < 5 deg', (box,), measure_push, 1.5, (finger,))
    return Case('push_offcentre', 'box pushed 7 cm off its centre line by an upright capsule',
                'yaws', (box,), measure_push, 1.5, (finger,))


def _drop(e: float) -> Case:
    """A ball of radius 0.1 m (1 kg) dropped from 0.5 m (its bottom) onto the ground."""
    ball = Solid('ball', 'ball', (0.1,), 1.0, (0.0, 0.0, 0.6))
    return Case(f'drop_e{e:g}', f'ball dropped 0.5 m, restitution {e:g}',
                f'bounce ratio {e * e:g} +- 10 %, energy <= 1', (ball,), measure_drop, 3.0,
                restitution=e, extra={'first_low_s': 0.5})


def _pyramid() -> Case:
    """Ten 0.1 m cubes (0.5 kg) in rows of 4-3-2-1, 2 mm apart in a row."""
    pitch = 0.102
    solids = tuple(Solid(f'box{row}{i}', 'box', (0.1, 0.1, 0.1), 0.5,
                         ((i - (3 - row) / 2.0) * pitch, 0.0, 0.05 + 0.1 * row))
                   for row in range(4) for i in range(4 - row))
    return Case('pyramid', 'pyramid of 4-3-2-1 boxes', 'every COM < 5 mm in 10 s', solids,
                measure_stack, 10.0)


def _tower() -> Case:
    """Ten 0.1 m cubes (0.5 kg) stacked."""
    solids = tuple(Solid(f'box{k}', 'box', (0.1, 0.1, 0.1), 0.5, (0.0, 0.0, 0.05 + 0.1 * k))
                   for k in range(10))
    return Case('tower', 'tower of 10 boxes', 'every COM < 5 mm in 10 s', solids,
                measure_stack, 10.0)


def _dominoes(pushed: bool) -> Case:
    """Six slabs 0.06 x 0.2 x 0.44 m (0.5 kg), 0.2 m apart in x; the first one, pushed,
    starts turning at 1.5 rad/s about its front bottom edge."""
    solids = []
    for k in range(6):
        com = np.array([0.2 * k, 0.0, 0.22])
        spin = np.array([0.0, 1.5 if pushed and k == 0 else 0.0, 0.0])
        pivot = com + (0.03, 0.0, -0.22)
        solids.append(Solid(f'slab{k}', 'box', (0.06, 0.2, 0.44), 0.5, tuple(com),
                            velocity=tuple(np.cross(spin, com - pivot)), spin=tuple(spin)))
    if pushed:
        return Case('dominoes_pushed', 'six slabs, the first pushed',
                    'all 6 fall, in sequence', tuple(solids), measure_dominoes, 3.0)
    return Case('dominoes_still', 'six slabs, none pushed', 'none moves (< 2 deg)',
                tuple(solids), measure_dominoes, 3.0)


def _hit(e: float) -> Case:
    """Zero gravity, no friction: a 0.1 m cube (1 kg) at 1 m/s hits a resting one, their
    centre lines 5 cm apart."""
    solids = (Solid('a', 'box', (0.1, 0.1, 0.1), 1.0, (-0.15, 0.05, 0.0), velocity=(1, 0, 0)),
              Solid('b', 'box', (0.1, 0.1, 0.1), 1.0, (0.0, 0.0, 0.0)))
    return Case(f'hit_e{e:g}', f'zero-g off-centre hit, restitution {e:g}',
                'momentum kept, both spin, energy <= 1', solids, measure_hit, 0.6,
                ground=False, gravity=(0.0, 0.0, 0.0), friction=0.0, restitution=e)


def all_cases() -> List[Case]:
    """Every case, in the order of the tables."""
    return [_topple('body', 0.05, 2.0), _topple('body', -0.05, 10.0),
            _topple('table', 0.05, 2.0), _topple('table', -0.05, 10.0),
            _incline(0.6), _incline(0.2), _roll(), _push(False), _push(True),
            _drop(0.0), _drop(0.5), _drop(1.0), _pyramid(), _tower(),
            _dominoes(True), _dominoes(False), _hit(0.0), _hit(0.5), _hit(1.0)]


def case(name: str) -> Case:
    """The case called ``name`` (KeyError naming the known ones)."""
    found = {c.name: c for c in all_cases()}
    if name not in found:
        raise KeyError(f'no case {name!r}; known: {", ".join(found)}')
    return found[name]


# --- Running a case ---

def simulate(sim, case: Case, duration: Optional[float] = None) -> Track:
    """Step ``sim`` (an engine's case: ``step()``, ``time``, ``state()`` -> the ``Track``
    keys) for ``duration`` s (the case's), sampling every ``SAMPLE_DT``."""
    end = case.duration if duration is None else duration
    track = Track([s.name for s in case.solids])
    track.add(sim.time, **sim.state())
    sample = SAMPLE_DT
    while sim.time < end - 1e-9:
        sim.step()
        if sim.time >= sample - 1e-9:
            track.add(sim.time, **sim.state())
            sample += SAMPLE_DT
    return track


def run(case: Case, engine=None, duration: Optional[float] = None) -> Dict[str, float]:
    """Outcomes of ``case`` built in ``engine`` (a class taking the case; sm_ros default)."""
    return case.measure(case, simulate((engine or SmRos)(case), case, duration))


# --- sm_ros ---

def lattice(solid: Solid, spacing: float = SPACING) -> np.ndarray:
    """The particles of ``solid`` in world coordinates: the centres of the cells of side
    ``spacing`` filling a box, the lattice points within radius - spacing/2 of a ball."""
    from sm_ros.shapes import quat_to_matrix, sphere_lattice
    if solid.shape == 'ball':
        local = sphere_lattice(solid.size[0] - spacing / 2.0, spacing)
    else:
        axes = [(np.arange(round(s / spacing)) + 0.5) * spacing - s / 2.0 for s in solid.size]
        local = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3)
    return local @ quat_to_matrix(solid.quat).T + np.asarray(solid.position, dtype=float)


def sm_colliders(case: Case) -> dict:
    """``World.set_colliders`` arguments of the case's ground and fixed colliders."""
    from sm_ros.core import Box, Capsule, Ground
    mat = {'friction': case.friction, 'restitution': case.restitution}
    boxes, capsules = [], []
    for f in case.fixed:
        c, q = np.asarray(f.position, dtype=float), (None if f.quat == IDENTITY else f.quat)
        if f.shape == 'box':
            half = np.asarray(f.size) / 2.0
            boxes.append(Box(lo=tuple(c - half), hi=tuple(c + half), orientation=q, **mat))
            continue
        path = tuple((t, tuple(p), f.quat) for t, p in f.path)
        capsules.append(Capsule(center=tuple(c), radius=f.size[0], length=f.size[1],
                                orientation=f.quat, name=f.name, kinematic=bool(path),
                                path=path, **mat))
    ground = Ground(friction=case.friction, restitution=case.restitution) if case.ground else None
    return {'ground': ground, 'boxes': boxes, 'capsules': capsules}


class SmRos:
    """A case as an sm_ros ``World`` at the node's default step (``DT``)."""

    label = 'sm_ros'

    def __init__(self, case: Case, spacing: float = SPACING):
        from sm_ros.core import BodyParams, World
        from sm_ros.core.contact import ContactParams
        self.world = World(gravity=case.gravity)
        self.world.contact_params = ContactParams(friction=case.friction,
                                                  restitution=case.restitution)
        self.world.set_colliders(**sm_colliders(case))
        params = BodyParams(**RIGID)
        self.bodies = []
        for s in case.solids:
            x = lattice(s, spacing)
            v = np.asarray(s.velocity) + np.cross(np.asarray(s.spin), x - x.mean(axis=0))
            self.bodies.append(self.world.add_body(x, s.mass / len(x), params, s.name,
                                                   velocities=v))

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.world.time

    def step(self):
        """One step of the node's ``dt``."""
        self.world.step(DT)

    def state(self) -> Dict[str, np.ndarray]:
        """The ``Track`` keys of every body (spin from its angular momentum and inertia)."""
        rows = {k: [] for k in Track.KEYS}
        for b in self.bodies:
            m, x, v = b.m, b.x, b.v
            mass = float(m.sum())
            com = (m @ x) / mass
            mom = m @ v
            ang = np.cross(x, v * m[:, None]).sum(axis=0)
            r = x - com
            inertia = (m * (r * r).sum(axis=1)).sum() * np.eye(3) - (r.T * m) @ r
            own = ang - np.cross(com, mom)
            rows['com'].append(com)
            rows['rot'].append(b.rotation())
            rows['vel'].append(mom / mass)
            rows['spin'].append(np.linalg.lstsq(inertia, own, rcond=None)[0])
            rows['ke'].append(0.5 * float(m @ (v * v).sum(axis=1)))
            rows['mom'].append(mom)
            rows['angmom'].append(ang)
        return rows
