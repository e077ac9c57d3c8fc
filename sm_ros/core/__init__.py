"""sm_ros.core: meshless shape matching (Müller et al. 2005) as a NumPy/Numba library.

No ROS here: the node, the scene loader, the benchmarks and the tests drive this API
(documented in ``doc/core_api.md``).
"""

from .body import Body
from .params import BodyParams, Box, Capsule, Ground, MODES, Sphere
from .world import World

__all__ = ['Body', 'BodyParams', 'Box', 'Capsule', 'Ground', 'MODES', 'Sphere', 'World']
