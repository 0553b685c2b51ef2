"""The LiDAR simulator: vegetated landing sites, a nodding line scanner, datasets, flights.

One concept per module, in the order the data flows:

=================  ============================================================================
``mesh``           labelled triangle meshes (every face is ground, grass or obstacle)
``terrain``        Perlin-noise ground (height field and mesh)
``grass``          grass blades (3-triangle strips) by a spatial Poisson process
``obstacles``      the obstacle library (box, 12 rocks, 2 tires, 2 cinder blocks) and placement
``raycast``        first-hit ray casting with Embree
``sensor``         the scanner: scan lines, nodding, noise, hover and path scans
``scene``          worlds and simulated patches (one dataset scene)
``dataset``        the paper's Table I sweeps as sharded datasets; ``SceneDataset``
``hybrid``         patches cut from recorded flights, obstacles inserted (same format)
``flight``         a flight over a site, written as a ROS 2 bag with ground truth
``render``         pictures of patches and flights (returns coloured by what they hit)
=================  ============================================================================

The dataset path imports only numpy, scipy, numba, trimesh, embreex and tqdm, so datasets can
be generated on a machine without ROS or torch (``landing-zone simulate --dataset synth2 --out
DIR``).
"""
from __future__ import annotations

__all__ = ['SimulationError']

from landing_zone.errors import SimulationError
