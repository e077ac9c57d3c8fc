"""Indices of a body's flag array (``Body._flags``; the same four columns of a pack row,
``packed.C_FLAGS``), read and written by Python and by the compiled steps."""

#: The per-cluster sums must be taken again before the next step (the state was changed).
DIRTY = 0
#: The last step's shape-error sums are not yet reduced (``Body.shape_error_rms``).
ERR_STALE = 1
#: The damping sums of the last particle pass are valid for the next step.
DAMP_SUMS = 2
#: Sleeping (``sm_ros.core.sleep``): 1 asleep (the steps skip the body), 0 awake, -1 held
#: awake (a force, torque or grab acts on it).
SLEEP = 3
#: The body's sums are the packed step's (``core/packed.py``: one-cluster sums), not the set
#: layout's: whichever step takes the body next from the other takes its sums afresh.
SUMS_PACKED = 4
#: Entries of a body's flag array.
NFLAGS = 5
