"""
Body poses for publishing: centre of mass and the whole body's shape-match rotation.

``Body.rotation()`` of a body with several clusters sums ``m (x - c) x0^T`` with NumPy
``einsum`` over every particle, slow for large bodies; ``BodyPose.pose(body)``
gets the same rotation from one compiled pass (``com_apq``: the mass-weighted sums
``sum m x`` and ``sum m x x0^T`` together) and the core's own rotation extraction
(``extract_rotation``, warm-started from the previous answer like the core does). A
body with one cluster takes the rotation the solver already found in its step
(``Body.rotation()`` reads it). Nothing here changes the bodies.
"""

from typing import Dict, Tuple

from numba import njit
import numpy as np

from sm_ros.core.kernels import extract_rotation
from sm_ros.core.kernels.linalg import ZERO12, add_outer


@njit(cache=True, fastmath=False)
def com_apq(x, m, x0, com, apq):
    """
    One pass over the particles: ``com`` = sum m x / sum m and ``apq`` = sum m x x0^T.

    ``x0`` are the rest positions minus their centre of mass (so sum m x0 = 0 and
    ``apq`` equals sum m (x - com) x0^T). The loop body is 12 multiply-adds per particle
    into scalar accumulators (reduction over i; the compiler vectorises it when x and x0
    are contiguous rows).
    """
    sm = 0.0
    sums = ZERO12
    for i in range(x.shape[0]):
        mi = m[i]
        sm += mi
        sums = add_outer(sums, mi * x[i, 0], mi * x[i, 1], mi * x[i, 2], x0[i, 0], x0[i, 1],
                         x0[i, 2])
    com[0], com[1], com[2] = sums[0] / sm, sums[1] / sm, sums[2] / sm
    apq[0, 0], apq[0, 1], apq[0, 2] = sums[3], sums[4], sums[5]
    apq[1, 0], apq[1, 1], apq[1, 2] = sums[6], sums[7], sums[8]
    apq[2, 0], apq[2, 1], apq[2, 2] = sums[9], sums[10], sums[11]


def com_apq_numpy(x, m, x0):
    """The NumPy twin of ``com_apq`` (tests)."""
    com = (m @ x) / m.sum()
    return com, (x * m[:, None]).T @ x0


class BodyPose:
    """Per-body scratch (centred rest shape, warm-start quaternion) for ``pose``."""

    def __init__(self):
        """Start with no body seen."""
        self._state: Dict[int, Tuple[object, np.ndarray, np.ndarray]] = {}
        self._com = np.zeros(3)
        self._apq = np.zeros((3, 3))
        self._rotation = np.zeros((3, 3))
        self._quat_n = np.zeros((4, 4))
        self._quat_v = np.zeros((4, 4))

    def pose(self, body) -> Tuple[np.ndarray, np.ndarray]:
        """Return (centre of mass (3,), rotation (3, 3)) of ``body``'s current state."""
        if int(body.num_clusters) == 1:
            return np.asarray(body.com(), dtype=np.float64), body.rotation()
        entry = self._state.get(id(body))
        if entry is None or entry[0] is not body:
            rest = np.asarray(body._x_init, dtype=np.float64)
            m = np.asarray(body._m, dtype=np.float64)
            x0 = np.ascontiguousarray(rest - (m @ rest) / m.sum())
            entry = (body, x0, np.array([1.0, 0.0, 0.0, 0.0]))
            self._state[id(body)] = entry
        _, x0, quat = entry
        com_apq(body._x, body._m, x0, self._com, self._apq)
        extract_rotation(self._apq, quat, self._rotation, self._quat_n, self._quat_v)
        return self._com.copy(), self._rotation.copy()

    def forget(self, keep=()) -> None:
        """Drop the scratch of bodies not in ``keep`` (after a scene change)."""
        ids = {id(b) for b in keep}
        for k in [k for k in self._state if k not in ids]:
            del self._state[k]
