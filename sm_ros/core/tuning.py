"""Tuning constants of the solver core, one line each (the kernels get them as arguments,
so that a change here needs no recompilation)."""

#: Sleeping: restless above this many times ``sleep_speed``, two steps in a row.
WAKE_FACTOR = 4.0
#: Sleeping: a pair touches when closer than this many times its contact distance.
TOUCH_FACTOR = 1.1
