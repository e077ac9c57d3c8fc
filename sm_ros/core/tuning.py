"""Tuning constants of the solver core, one line each (the kernels get them as arguments,
so that a change here needs no recompilation).  The users read them at call time
(``tuning.NAME``), so a test may set them with ``monkeypatch.setattr(tuning, ...)``.

The block sizes that Numba kernels compile in (``packed.FUSED_BLOCK``, those in
``kernels/``) stay beside their kernels: Numba's on-disk cache is keyed on the kernel's own
source file, so such a constant edited here would leave a stale cached kernel."""

#: Sleeping: restless above this many times ``sleep_speed``, two steps in a row.
WAKE_FACTOR = 4.0
#: Sleeping: a pair touches when closer than this many times its contact distance.
TOUCH_FACTOR = 1.1

#: Bodies with this much work per step (particles or memberships) run multi-threaded kernels.
PARALLEL_MIN_WORK = 262144
#: Compiled-step records are shared with helper threads from this many particles in records.
RECORDS_PARALLEL_MIN_WORK = 16384

#: Clusters: each cube's enlargement on every side, in cube widths.
DEFAULT_MARGIN = 0.5
#: Clusters: particles two face-neighbouring cubes must share to count as joined.
MIN_SHARED = 3

#: Stiff bodies (contact as rigid bodies, ``stiff_contact.is_stiff``): the least rigid share
#: of the goal, alpha (1 - beta) (alpha in rigid mode) at the step.
STIFF_SHARE = 0.6
#: Stiff bodies: the most cluster cubes per axis (more bend between them, as a sheet does).
STIFF_CLUSTERS = 2

#: Contact: same-body pairs self-collide beyond this many contact distances apart at rest.
SELF_REST_FACTOR = 2.0
#: Contact: the pair list's Verlet skin, as a share of the largest contact radius.
SKIN_FACTOR = 0.5
#: Contact: a body whose goal pull alpha at the step reaches this is carried as a whole.
COUPLE_ALPHA = 0.5
#: Contact: the least sweeps a step over the pairs of bodies carried as a whole.
STACK_SWEEPS = 8
#: Contact: sweeps stop once no velocity changes by this share of the resting threshold.
SWEEP_TOL = 0.01
#: Contact: share of the last step's impulses of carried pairs a step starts from.
WARM_START = 0.5
#: Stiff bodies: the most sequential-impulse sweeps a step (they stop once settled).
STIFF_SWEEPS = 100
