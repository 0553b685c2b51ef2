"""landing_zone: where can a helicopter land? Per-tile P(safe) from LiDAR with a 3D CNN.

The core takes numpy arrays and poses and never imports ROS; the ROS node
(:mod:`landing_zone.ros.node`) and bag replay (:mod:`landing_zone.replay`) are
thin front ends.

    from landing_zone import Assessor
    a = Assessor()
    a.integrate(points_xyz, sensor_origin)
    result = a.assess()
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = '0.3.0'
__all__ = ['Assessor', 'AssessorConfig', 'DensityMap', '__version__']

if TYPE_CHECKING:
    from landing_zone.assessor import Assessor
    from landing_zone.config import AssessorConfig
    from landing_zone.mapping.density_map import DensityMap


def __getattr__(name: str) -> Any:
    # Lazy: `import landing_zone` stays cheap (no numba/torch start-up) until used.
    if name == 'Assessor':
        from landing_zone.assessor import Assessor
        return Assessor
    if name == 'AssessorConfig':
        from landing_zone.config import AssessorConfig
        return AssessorConfig
    if name == 'DensityMap':
        from landing_zone.mapping.density_map import DensityMap
        return DensityMap
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
