"""Sleeping bodies: a body at rest in a contact world is not stepped until something
wakes it (doc/sleeping.md).

Physics engines put bodies that have come to rest to sleep (Box2D, Bullet, PhysX): a heap
at rest then costs almost nothing.  Here, in a world where body-body contact runs
(``Contact.needed``: two colliding bodies or more), with ``ContactParams.sleep``:

* **Falling asleep.** After each step every awake body's particle moves are measured
  (``sleep_update``).  A body is *settled* once none of its particles got farther than
  ``sleep_speed`` times ``sleep_time`` from where they were ``sleep_time`` seconds ago (a
  still spell: jiggling in place is still, a drift at ``sleep_speed`` is not).  A settled
  body falls asleep unless a restless body touches it (one moving faster than
  ``tuning.WAKE_FACTOR`` times ``sleep_speed`` in two steps in a row, or held awake by a force,
  torque or grab) or an unsettled one supports it (touches it from below): its velocities are set
  to zero and it is no longer stepped (``Body._flags[SLEEP]`` = 1: the compiled steps skip
  it).  So no body falls asleep on a support that still slides or sinks (it would float
  once the support moved on), while bodies beside a slowly creeping one may.
* **Asleep** it is an obstacle of infinite mass for contact (its inverse masses ``W`` are
  0 in the flat state, as for pinned particles) and keeps its state bit for bit.
* **Waking.** A sleeping body wakes when a restless body touches it (a pair closer than
  ``tuning.TOUCH_FACTOR`` times the contact distance; it stays put for the step in which that is
  found and is stepped from the next), and whenever an input changes it
  (``Body.wake``: state, parameters, wrench, grabs, reset) or the world (gravity, the
  colliders, the bodies, the contact settings).  A body with a force, torque or grab is
  held awake (``_flags[SLEEP]`` = -1) while it acts.
* A world of one colliding body (no contact pass) never sleeps: it pays nothing.  Nor
  does a world without gravity (nothing rests; freezing a drift would take momentum out
  of a conservative world) or with collider-pass colliders (``World._sleep_check``).

The pass over the awake bodies' particles (reads of X, the previous positions and the
spell's anchors, one write) costs about as much as the gather copy; the pass over the
pair list (who touches whom) runs only while a
body sleeps or has settled, so not while the bodies pour; the gather skips sleeping
bodies, and a world whose bodies are all asleep skips the bodies' step, the contact pass
and this pass.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from .kernels import JIT
from .kernels.flags import SLEEP
from .tuning import TOUCH_FACTOR, WAKE_FACTOR

@njit(**JIT)
def sleep_sync(flags, slept, off, W, awake_W, calm):
    """Bodies woken from outside since the last step (``flags[b][SLEEP]`` <= 0 while
    ``slept[b]``): their inverse masses back from ``awake_W``; returns how many."""
    woken = 0
    for b in range(len(flags)):
        if slept[b] and flags[b][SLEEP] <= 0.0:
            slept[b] = 0
            calm[b] = 0.0
            for k in range(off[b], off[b + 1]):
                W[k] = awake_W[k]
            woken += 1
    return woken


@njit(**JIT)
def all_asleep(flags):
    """Whether every body is asleep (then a step has nothing to do)."""
    for b in range(len(flags)):
        if not flags[b][SLEEP] > 0.0:
            return False
    return len(flags) > 0


@njit(**JIT)
def body_moves(X, Xp, Xa, off, flags, step2, drift2):
    """For each awake body b: ``step2[b]`` the largest squared move of a particle from
    ``Xp`` (the last step's positions; ``Xp`` = ``X`` after), ``drift2[b]`` the largest
    from ``Xa`` (where its still spell started); both 0 for a sleeping body."""
    for b in range(len(flags)):
        if flags[b][SLEEP] > 0.0:
            step2[b] = 0.0
            drift2[b] = 0.0
            continue
        s2 = 0.0
        a2 = 0.0
        # max-reductions over the body's particles, unit stride in each row of X, Xp, Xa
        # (vectorises: nine loads, three stores, two max per particle)
        for k in range(off[b], off[b + 1]):
            x0, x1, x2 = X[0, k], X[1, k], X[2, k]
            dx = x0 - Xp[0, k]
            dy = x1 - Xp[1, k]
            dz = x2 - Xp[2, k]
            ex = x0 - Xa[0, k]
            ey = x1 - Xa[1, k]
            ez = x2 - Xa[2, k]
            Xp[0, k] = x0
            Xp[1, k] = x1
            Xp[2, k] = x2
            s2 = max(s2, dx * dx + dy * dy + dz * dz)
            a2 = max(a2, ex * ex + ey * ey + ez * ez)
        step2[b] = s2
        drift2[b] = a2


@njit(**JIT)
def touch_restless(flat, body_x, pairs, level, up, near, touch):
    """near[b] = the largest ``level`` of the other bodies a particle of body b touches
    (closer than ``touch`` times the pair's contact distance), where a level 1
    (unsettled) counts only from a body below b's particle (along ``up``, the unit vector
    against gravity; every direction when it is zero: a support that still moves); 0
    where none counts.  Positions from ``body_x`` (the bodies' own (3, n) blocks):
    before the contact pass, where a body thrown at a sleeping one overlaps it (the pass
    then stops it where the step began, a gap away).  A pass over the pair list that
    reads positions only of pairs with a side above 0."""
    xs, off, R, B = body_x, flat.offset, flat.radius, flat.body
    near[:] = 0
    anyway = up[0] == 0.0 and up[1] == 0.0 and up[2] == 0.0
    for p in range(pairs.count):
        i = pairs.first[p]
        j = pairs.second[p]
        bi = B[i]
        bj = B[j]
        li = level[bi]
        lj = level[bj]
        if bi == bj or (li == 0 and lj == 0) or (lj <= near[bi] and li <= near[bj]):
            continue
        s = touch * (R[i] + R[j])
        xi = xs[bi]
        xj = xs[bj]
        ki = i - off[bi]
        kj = j - off[bj]
        dx = xi[0, ki] - xj[0, kj]
        dy = xi[1, ki] - xj[1, kj]
        dz = xi[2, ki] - xj[2, kj]
        if dx * dx + dy * dy + dz * dz < s * s:
            above = dx * up[0] + dy * up[1] + dz * up[2]      # > 0: i above j
            if lj > near[bi] and (lj == 2 or anyway or above > 0.0):
                near[bi] = lj
            if li > near[bj] and (li == 2 or anyway or above < 0.0):
                near[bj] = li
    for p in range(pairs.bodies.shape[0]):
        a, b, above = pairs.bodies[p, 0], pairs.bodies[p, 1], pairs.bodies[p, 2]
        if level[b] > near[a] and (level[b] == 2 or anyway or above > 0):
            near[a] = level[b]
        if level[a] > near[b] and (level[a] == 2 or anyway or above < 0):
            near[b] = level[a]


class FlatArrays(NamedTuple):
    """The flat state's arrays the sleep pass reads and writes (``FlatState``; its typed
    lists, the bodies' positions and flags, go beside it: in a tuple they would cost the
    call a slow typing of every array)."""

    x: np.ndarray               # (3, N) positions after the contact pass
    v: np.ndarray               # (3, N) velocities after it
    inv_mass: np.ndarray        # (N,) inverse masses (0 while asleep)
    awake_inv_mass: np.ndarray  # (N,) inverse masses of the bodies awake
    radius: np.ndarray          # (N,) contact radii
    body: np.ndarray            # (N,) body index of each particle
    offset: np.ndarray          # (bodies + 1,) first particle of each body
    touched: np.ndarray         # (bodies,) 1: the scatter writes the body back


class SleepArrays(NamedTuple):
    """Sleep bookkeeping of each body (``Sleep`` owns it; see ``sleep_update``)."""

    prev: np.ndarray            # (3, N) positions after the last step
    anchor: np.ndarray          # (3, N) positions where the still spell began
    slept: np.ndarray           # (bodies,) uint8: asleep as of the last step
    calm: np.ndarray            # (bodies,) seconds still in a row
    fast: np.ndarray            # (bodies,) uint8: steps above the restless speed in a row
    step2: np.ndarray           # (bodies,) scratch: largest squared move in the step
    drift2: np.ndarray          # (bodies,) scratch: largest squared move from the anchor
    level: np.ndarray           # (bodies,) uint8 scratch: 0 settled, 1 unsettled, 2 restless
    near: np.ndarray            # (bodies,) uint8 scratch: largest level touching the body


#: No body pairs in contact (``Pairs.bodies``).
NO_TOUCHES = np.zeros((0, 3), dtype=np.int64)


class Pairs(NamedTuple):
    """Who may touch whom: the contact pass's pair list (particles ``first[p]``,
    ``second[p]``, p < count) and the stiff pass's body pairs in contact (``bodies``:
    rows of a, b and 1 where a lies above b, -1 where below, 0 neither;
    ``stiff_contacts.touches``), whose particle pairs the list leaves out."""

    first: np.ndarray
    second: np.ndarray
    count: int
    bodies: np.ndarray = NO_TOUCHES


class SleepRule(NamedTuple):
    """The settings of one step's sleep pass."""

    up: np.ndarray              # unit vector against gravity (zero without gravity)
    h: float                    # step (s)
    speed: float                # ``sleep_speed`` (m/s)
    t_sleep: float              # ``sleep_time`` (s)
    allow: bool                 # whether bodies may fall asleep (False: only waking)
    wake_factor: float = WAKE_FACTOR    # restless above this many times ``speed``
    touch_factor: float = TOUCH_FACTOR  # touching within this many contact distances


@njit(**JIT)
def sleep_update(flat, body_x, flags, state, pairs, rule):
    """One step's sleep bookkeeping after the contact pass (see the module: still spells,
    settled, restless, unsettled); returns how many bodies fell asleep or woke (their
    inverse masses changed).  ``body_x``: the bodies' own positions, before the contact
    pass (who touches whom, ``touch_restless``).  One function, not several: each compiled
    callee would add its own compile time to a cold start."""
    X, off, touched = flat.x, flat.offset, flat.touched
    prev, anchor, calm, fast, level = (state.prev, state.anchor, state.calm, state.fast,
                                       state.level)
    h, t_sleep = rule.h, rule.t_sleep
    body_moves(X, prev, anchor, off, flags, state.step2, state.drift2)
    quick = rule.wake_factor * rule.speed * h       # restless: a particle this far a step
    room = rule.speed * t_sleep                     # still: no particle this far in a spell
    for b in range(len(flags)):
        f = flags[b][SLEEP]
        if f > 0.0:
            level[b] = 0
            continue
        if state.drift2[b] <= room * room and f == 0.0:
            calm[b] += h
        else:                                  # a new still spell starts here
            calm[b] = 0.0
            for k in range(off[b], off[b + 1]):
                anchor[0, k] = X[0, k]
                anchor[1, k] = X[1, k]
                anchor[2, k] = X[2, k]
        # restless after two fast steps in a row: when a body falls asleep, the one resting
        # on it settles by up to g h^2 in one step
        fast[b] = min(fast[b] + 1, 2) if state.step2[b] > quick * quick else 0
        if fast[b] >= 2 or f < 0.0:
            level[b] = 2
        else:
            level[b] = 0 if calm[b] >= t_sleep else 1
    # who touches whom matters only to a sleeping body (woken?) or to a settled awake one
    # (falls asleep?); while bodies pour, none is either and the pair pass is skipped
    decide = False
    for b in range(len(flags)):
        if flags[b][SLEEP] > 0.0 or (flags[b][SLEEP] == 0.0 and calm[b] >= t_sleep):
            decide = True
            break
    if not decide:
        return 0
    touch_restless(flat, body_x, pairs, level, rule.up, state.near, rule.touch_factor)
    changed = 0
    for b in range(len(flags)):
        f = flags[b][SLEEP]
        if f > 0.0 and state.near[b] == 2:     # a restless body touches it: awake
            flags[b][SLEEP] = 0.0
            state.slept[b] = 0
            calm[b] = 0.0
            for k in range(off[b], off[b + 1]):
                flat.inv_mass[k] = flat.awake_inv_mass[k]
                for axis in range(3):
                    prev[axis, k] = X[axis, k]
                    anchor[axis, k] = X[axis, k]
            changed += 1
        elif (rule.allow and f == 0.0 and calm[b] >= t_sleep
              and state.near[b] == 0):         # asleep: infinite mass, at rest, written back
            flags[b][SLEEP] = 1.0
            state.slept[b] = 1
            for k in range(off[b], off[b + 1]):
                flat.inv_mass[k] = 0.0
                flat.v[0, k] = 0.0
                flat.v[1, k] = 0.0
                flat.v[2, k] = 0.0
            touched[b] = 1
            changed += 1
    return changed


class Sleep:
    """The sleep state of a ``FlatState``'s bodies (made by ``World`` with its contact
    pass; see the module)."""

    def __init__(self, flat):
        count = max(len(flat.bodies), 1)
        self.flat = flat
        self.state = SleepArrays(
            prev=flat.X.copy(), anchor=flat.X.copy(),
            slept=np.zeros(count, dtype=np.uint8), calm=np.zeros(count),
            fast=np.zeros(count, dtype=np.uint8), step2=np.zeros(count),
            drift2=np.zeros(count), level=np.zeros(count, dtype=np.uint8),
            near=np.zeros(count, dtype=np.uint8))
        for body in flat.bodies:                   # a new flat state: every body awake
            if body._flags[SLEEP] > 0.0:
                body._flags[SLEEP] = 0.0

    @property
    def slept(self) -> np.ndarray:
        """(bodies,) uint8: asleep as of the last step."""
        return self.state.slept

    @property
    def calm(self) -> np.ndarray:
        """(bodies,) seconds each body has been still in a row."""
        return self.state.calm

    @property
    def fast(self) -> np.ndarray:
        """(bodies,) uint8: steps above the restless speed in a row."""
        return self.state.fast

    @property
    def prev(self) -> np.ndarray:
        """(3, N) positions after the last step."""
        return self.state.prev

    @property
    def anchor(self) -> np.ndarray:
        """(3, N) positions where each body's still spell began."""
        return self.state.anchor

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): who sleeps, the still
        spells and restless counts, the last positions and the spells' anchors."""
        return ('slept', 'calm', 'fast', 'prev', 'anchor')

    def all_asleep(self) -> bool:
        """Whether every body is asleep (one compiled call over the flags)."""
        return bool(all_asleep(self.flat.flag_list()))

    def sync(self):
        """Restore the inverse masses of the bodies woken from outside (before contact)."""
        flat = self.flat
        if self.slept.any() and sleep_sync(flat.flag_list(), self.slept, flat.off, flat.W,
                                           flat.awake_W, self.calm):
            flat.w_version += 1

    def update(self, contact, h, params, gravity, touches):
        """After the contact pass, before the scatter (``sleep_update``); ``touches``:
        the stiff pass's body pairs in contact (``Pairs.bodies``)."""
        flat = self.flat
        norm = float(np.linalg.norm(gravity))
        up = -gravity / norm if norm > 0.0 else np.zeros(3)
        arrays = FlatArrays(x=flat.X, v=flat.V, inv_mass=flat.W, awake_inv_mass=flat.awake_W,
                            radius=flat.R, body=flat.B, offset=flat.off, touched=flat.touched)
        rule = SleepRule(up=up, h=float(h), speed=float(params.sleep_speed),
                         t_sleep=float(params.sleep_time), allow=bool(params.sleep))
        pairs = Pairs(contact._pair_i, contact._pair_j, contact.npairs, touches)
        if sleep_update(arrays, flat._x_blocks, flat.flag_list(), self.state, pairs, rule):
            flat.w_version += 1

    def wake_all(self):
        """Every body awake (the world changed); inverse masses restored."""
        for body in self.flat.bodies:
            if body._flags[SLEEP] > 0.0:
                body._flags[SLEEP] = 0.0
        self.sync()
        self.calm[:] = 0.0


__all__ = ['FlatArrays', 'Pairs', 'Sleep', 'SleepArrays', 'SleepRule', 'TOUCH_FACTOR',
           'WAKE_FACTOR', 'all_asleep', 'body_moves', 'sleep_sync', 'sleep_update',
           'touch_restless']
