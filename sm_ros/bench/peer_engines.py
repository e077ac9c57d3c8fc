"""
PyBullet and MuJoCo as ``sm_ros.bench.cases`` engines, with their defaults (``peers.py``).

Each class takes a ``Case`` and offers ``step()``, ``time`` and ``state()`` (the ``Track``
keys).  The engines' own defaults are kept (PyBullet: 1/240 s, 50 solver iterations,
damping 0.04, sleeping; MuJoCo: 0.002 s, Newton solver, pyramidal cones, no sleeping);
what a case needs is set so that every pair of surfaces gets the case's coefficients:

- PyBullet multiplies the two surfaces' friction and restitution: every object takes
  sqrt(mu) and sqrt(e);
- MuJoCo takes the larger friction of the two: every geom takes mu.  It has no restitution
  coefficient: e > 0 sets every geom's contact to a spring-damper with the damping ratio
  of a bounce e (``solref`` = (-k, -b), k = 1e4 s^-2, b = 2 zeta sqrt(k)); e = 0 keeps the
  default (critically damped) contact;
- a kinematic collider is a body held by a fixed constraint moved each step (PyBullet) or a
  mocap body (MuJoCo) following ``Fixed.pose_at``.

Both engines are imported only here, inside the classes.
"""

import math
from typing import Dict

import numpy as np

from .cases import Case, IDENTITY, Track


def _rigid_row(mass, com, rot, vel, spin_world, inertia, rows):
    """Append one rigid body's ``Track`` keys (``inertia``: its world inertia tensor)."""
    own = inertia @ spin_world
    rows['com'].append(com)
    rows['rot'].append(rot)
    rows['vel'].append(vel)
    rows['spin'].append(spin_world)
    rows['ke'].append(0.5 * mass * float(vel @ vel) + 0.5 * float(spin_world @ own))
    rows['mom'].append(mass * vel)
    rows['angmom'].append(np.cross(com, mass * vel) + own)


class Bullet:
    """A case in PyBullet (DIRECT, its default step 1/240 s)."""

    label = 'PyBullet'
    DT = 1.0 / 240.0
    #: Linear and angular damping of every solid; None keeps PyBullet's default (0.04).
    damping = None

    def __init__(self, case: Case):
        import pybullet as pb
        self.bullet, self.case, self.time = pb, case, 0.0
        self.cid = pb.connect(pb.DIRECT)
        kw = {'physicsClientId': self.cid}
        pb.setGravity(*case.gravity, **kw)
        mat = {'lateralFriction': math.sqrt(case.friction),
               'restitution': math.sqrt(case.restitution)}
        if case.ground:
            plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, **kw), **kw)
            pb.changeDynamics(plane, -1, **mat, **kw)
        self.kinematic = []
        for f in case.fixed:
            mass = 1.0 if f.path else 0.0
            body = pb.createMultiBody(mass, self._shape(f.shape, f.size), -1, f.position,
                                      f.quat, **kw)
            pb.changeDynamics(body, -1, **mat, **kw)
            if f.path:
                con = pb.createConstraint(body, -1, -1, -1, pb.JOINT_FIXED, (0, 0, 0),
                                          (0, 0, 0), f.position, childFrameOrientation=f.quat,
                                          **kw)
                self.kinematic.append((f, con))
        self.ids = []
        for s in case.solids:
            body = pb.createMultiBody(s.mass, self._shape(s.shape, s.size), -1, s.position,
                                      s.quat, **kw)
            pb.changeDynamics(body, -1, **mat, **kw)
            if self.damping is not None:
                pb.changeDynamics(body, -1, linearDamping=self.damping,
                                  angularDamping=self.damping, **kw)
            pb.resetBaseVelocity(body, s.velocity, s.spin, **kw)
            self.ids.append(body)

    def _shape(self, shape, size):
        pb, kw = self.bullet, {'physicsClientId': self.cid}
        if shape == 'box':
            return pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[x / 2 for x in size], **kw)
        if shape == 'ball':
            return pb.createCollisionShape(pb.GEOM_SPHERE, radius=size[0], **kw)
        kind = pb.GEOM_CAPSULE if shape == 'capsule' else pb.GEOM_CYLINDER
        return pb.createCollisionShape(kind, radius=size[0], height=size[1], **kw)

    def step(self):
        """One step of 1/240 s (kinematic colliders set to their next pose first)."""
        for f, con in self.kinematic:
            self.bullet.changeConstraint(con, f.pose_at(self.time + self.DT), f.quat,
                                     maxForce=1e4, physicsClientId=self.cid)
        self.bullet.stepSimulation(physicsClientId=self.cid)
        self.time += self.DT

    def state(self) -> Dict[str, list]:
        """The ``Track`` keys of every solid."""
        pb, kw = self.bullet, {'physicsClientId': self.cid}
        rows = {k: [] for k in Track.KEYS}
        for s, body in zip(self.case.solids, self.ids):
            pos, quat = pb.getBasePositionAndOrientation(body, **kw)
            vel, spin = pb.getBaseVelocity(body, **kw)
            rot = np.array(pb.getMatrixFromQuaternion(quat)).reshape(3, 3)
            inertia = rot @ np.diag(pb.getDynamicsInfo(body, -1, **kw)[2]) @ rot.T
            _rigid_row(s.mass, np.array(pos), rot, np.array(vel), np.array(spin), inertia,
                       rows)
        return rows

    def close(self):
        """Disconnect."""
        self.bullet.disconnect(self.cid)


def _wxyz(q) -> str:
    return f'{q[3]} {q[0]} {q[1]} {q[2]}'


def _vec(v) -> str:
    return ' '.join(f'{float(x):.9g}' for x in v)


def mj_geom(shape, size, mat: str, extra: str = '') -> str:
    """An MJCF geom of a case shape (sizes as MuJoCo wants them: halves, radius)."""
    if shape == 'box':
        return f'<geom type="box" size="{_vec(np.asarray(size) / 2)}" {mat} {extra}/>'
    if shape == 'ball':
        return f'<geom type="sphere" size="{size[0]}" {mat} {extra}/>'
    return f'<geom type="{shape}" size="{size[0]} {size[1] / 2}" {mat} {extra}/>'


def mj_material(friction: float, restitution: float) -> str:
    """Geom attributes giving every contact ``friction`` and a bounce of ``restitution``."""
    out = f'friction="{friction} 0.005 0.0001"'
    if restitution > 0:
        zeta = abs(math.log(restitution)) / math.hypot(math.pi, math.log(restitution))
        stiff = 1e4
        out += f' solref="-{stiff:g} -{2 * zeta * math.sqrt(stiff):.6g}"'
    return out


class MuJoCo:
    """A case in MuJoCo (its default step 0.002 s)."""

    label = 'MuJoCo'

    def __init__(self, case: Case):
        import mujoco
        self.mujoco, self.case = mujoco, case
        mat = mj_material(case.friction, case.restitution)
        parts = []
        if case.ground:
            parts.append(f'<geom type="plane" size="0 0 1" {mat}/>')
        self.mocap = []
        for f in case.fixed:
            geom = mj_geom(f.shape, f.size, mat)
            if f.path:
                parts.append(f'<body name="{f.name}" mocap="true" pos="{_vec(f.position)}" '
                             f'quat="{_wxyz(f.quat)}">{geom}</body>')
                self.mocap.append(f)
            else:
                parts.append(mj_geom(f.shape, f.size, mat, f'pos="{_vec(f.position)}" '
                                     f'quat="{_wxyz(f.quat)}"'))
        for s in case.solids:
            geom = mj_geom(s.shape, s.size, mat, f'mass="{s.mass}"')
            parts.append(f'<body name="{s.name}" pos="{_vec(s.position)}" '
                         f'quat="{_wxyz(s.quat)}"><freejoint/>{geom}</body>')
        xml = (f'<mujoco><option gravity="{_vec(case.gravity)}"/><worldbody>'
               f'{"".join(parts)}</worldbody></mujoco>')
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.bids = [self.model.body(s.name).id for s in case.solids]
        for s, bid in zip(case.solids, self.bids):
            dof = self.model.jnt_dofadr[self.model.body_jntadr[bid]]
            rot = np.array(_quat_rot(s.quat))
            self.data.qvel[dof:dof + 3] = s.velocity
            self.data.qvel[dof + 3:dof + 6] = rot.T @ np.asarray(s.spin)   # body frame
        mujoco.mj_forward(self.model, self.data)

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return float(self.data.time)

    def step(self):
        """One step (mocap bodies set to their next pose first)."""
        for k, f in enumerate(self.mocap):
            self.data.mocap_pos[k] = f.pose_at(self.time + self.model.opt.timestep)
        self.mujoco.mj_step(self.model, self.data)

    def state(self) -> Dict[str, list]:
        """The ``Track`` keys of every solid."""
        rows = {k: [] for k in Track.KEYS}
        m, d = self.model, self.data
        for s, bid in zip(self.case.solids, self.bids):
            dof = m.jnt_dofadr[m.body_jntadr[bid]]
            rot = d.xmat[bid].reshape(3, 3).copy()
            spin = rot @ d.qvel[dof + 3:dof + 6]
            irot = d.ximat[bid].reshape(3, 3)
            inertia = irot @ np.diag(m.body_inertia[bid]) @ irot.T
            _rigid_row(float(m.body_mass[bid]), d.xipos[bid].copy(), rot,
                       d.qvel[dof:dof + 3].copy(), spin, inertia, rows)
        return rows

    def close(self):
        """Nothing to release."""


def _quat_rot(q):
    from sm_ros.shapes import quat_to_matrix
    return quat_to_matrix(q if q is not None else IDENTITY)


# --- the soft cube (PyBullet's Neo-Hookean tetrahedra, MuJoCo's 3-D flex) ---

#: The ``default`` scene's block: 13^3 nodes 2.5 cm apart, 2 kg, centre 0.6 m high,
#: roll 0.2 and pitch 0.15 rad; Young's modulus and Poisson ratio of the engines' material
#: (MuJoCo's flex at 1e5 Pa diverged within 7 ms at the 0.25 ms step).
CUBE_NODES, CUBE_SPACING, CUBE_MASS, CUBE_HEIGHT = 13, 0.025, 2.0, 0.6
CUBE_RPY = (0.2, 0.15, 0.0)
CUBE_YOUNG, CUBE_POISSON = 1e4, 0.3
#: MuJoCo's flex needs this step to stay stable.
MUJOCO_SOFT_DT = 0.00025


def cube_nodes() -> np.ndarray:
    """The cube's nodes in world coordinates (C order over i, j, k)."""
    from sm_ros.shapes import rpy_to_matrix
    n = CUBE_NODES
    axis = (np.arange(n) - (n - 1) / 2.0) * CUBE_SPACING
    g = np.stack(np.meshgrid(axis, axis, axis, indexing='ij'), -1).reshape(-1, 3)
    return g @ rpy_to_matrix(CUBE_RPY).T + (0.0, 0.0, CUBE_HEIGHT)


def cube_tets() -> np.ndarray:
    """Each lattice cell split into six positively oriented tetrahedra (Kuhn)."""
    n = CUBE_NODES
    corner = np.stack(np.meshgrid(*[np.arange(n - 1)] * 3, indexing='ij'), -1).reshape(-1, 3)
    tets = []
    for order in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        step, path = np.zeros(3, dtype=np.int64), [corner]
        for ax in order:
            step[ax] = 1
            path.append(corner + step)
        tets.append(np.stack([(p[:, 0] * n + p[:, 1]) * n + p[:, 2] for p in path], -1))
    tets = np.concatenate(tets)
    x = cube_nodes()
    e1, e2, e3 = (x[tets[:, m]] - x[tets[:, 0]] for m in (1, 2, 3))
    flip = np.einsum('ij,ij->i', np.cross(e1, e2), e3) < 0
    tets[flip, 1], tets[flip, 2] = tets[flip, 2], tets[flip, 1].copy()
    return tets


def write_vtk(path) -> None:
    """The cube as a legacy VTK unstructured grid of tetrahedra (PyBullet's soft body)."""
    x, tets = cube_nodes(), cube_tets()
    lines = ['# vtk DataFile Version 2.0', 'cube', 'ASCII', 'DATASET UNSTRUCTURED_GRID',
             f'POINTS {len(x)} double'] + [' '.join(f'{c:.9g}' for c in p) for p in x]
    lines += [f'CELLS {len(tets)} {5 * len(tets)}'] + [f'4 {a} {b} {c} {d}' for a, b, c, d in tets]
    lines += [f'CELL_TYPES {len(tets)}'] + ['10'] * len(tets)
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines) + '\n')


def _timed_steps(step, dt: float, seconds: float) -> float:
    """Wall seconds per simulated second of ``step`` (one of ``dt``) over ``seconds``."""
    import time
    steps = max(1, int(round(seconds / dt)))
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    return (time.perf_counter() - t0) / (steps * dt)


def bullet_soft_cube(seconds: float, folder) -> Dict[str, float]:
    """The cube as PyBullet's Neo-Hookean soft body dropped on its plane, default step."""
    import os
    import pybullet as pb
    cid = pb.connect(pb.DIRECT)
    kw = {'physicsClientId': cid}
    try:
        pb.resetSimulation(pb.RESET_USE_DEFORMABLE_WORLD, **kw)
        pb.setGravity(0, 0, -9.81, **kw)
        pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, **kw), **kw)
        path = os.path.join(str(folder), 'peers_cube.vtk')
        write_vtk(path)
        mu = CUBE_YOUNG / (2 * (1 + CUBE_POISSON))
        lam = CUBE_YOUNG * CUBE_POISSON / ((1 + CUBE_POISSON) * (1 - 2 * CUBE_POISSON))
        body = pb.loadSoftBody(path, mass=CUBE_MASS, useNeoHookean=1, NeoHookeanMu=mu,
                               NeoHookeanLambda=lam, NeoHookeanDamping=0.01,
                               collisionMargin=0.003, useSelfCollision=0, frictionCoeff=0.5,
                               useFaceContact=1, **kw)
        nodes = pb.getMeshData(body, -1, flags=pb.MESH_DATA_SIMULATION_MESH, **kw)[0]
        wall = _timed_steps(lambda: pb.stepSimulation(**kw), Bullet.DT, seconds)
        x = np.array(pb.getMeshData(body, -1, flags=pb.MESH_DATA_SIMULATION_MESH, **kw)[1])
        return {'wall_per_sim_s': wall, 'nodes': nodes, 'dt': Bullet.DT,
                'com_z_end': float(x[:, 2].mean()), 'lowest_z_end': float(x[:, 2].min())}
    finally:
        pb.disconnect(cid)


def mujoco_soft_cube(seconds: float) -> Dict[str, float]:
    """The cube as MuJoCo's 3-D flex (linear elasticity) dropped on a plane, 0.25 ms step."""
    import mujoco
    from sm_ros.shapes import rpy_to_matrix
    n, s = CUBE_NODES, CUBE_SPACING
    q = _matrix_quat(rpy_to_matrix(CUBE_RPY))
    xml = (f'<mujoco><option timestep="{MUJOCO_SOFT_DT}"/><worldbody>'
           '<geom type="plane" size="0 0 1"/>'
           f'<flexcomp name="cube" type="grid" count="{n} {n} {n}" spacing="{s} {s} {s}" '
           f'pos="0 0 {CUBE_HEIGHT}" quat="{_wxyz(q)}" radius="0.001" dim="3" '
           f'mass="{CUBE_MASS}"><elasticity young="{CUBE_YOUNG:g}" poisson="{CUBE_POISSON}" '
           'damping="0.001"/><contact selfcollide="none"/><edge equality="false"/>'
           '</flexcomp></worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    wall = _timed_steps(lambda: mujoco.mj_step(model, data), MUJOCO_SOFT_DT, seconds)
    x = data.flexvert_xpos
    return {'wall_per_sim_s': wall, 'nodes': int(model.nflexvert), 'dt': MUJOCO_SOFT_DT,
            'com_z_end': float(x[:, 2].mean()), 'lowest_z_end': float(x[:, 2].min())}


def _matrix_quat(rot) -> tuple:
    """(x, y, z, w) of a rotation matrix."""
    import mujoco
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot).reshape(-1))
    return (q[1], q[2], q[3], q[0])
