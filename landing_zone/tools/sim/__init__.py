"""The LiDAR simulator: vegetated landing sites, a nodding line scanner, datasets, flights.

One concept per module, in the order the data flows:

=================  ============================================================================
``mesh``           labelled triangle meshes (every face is ground, grass or obstacle)
``terrain``        Perlin-noise ground (height field and mesh)
``grass``          grass blades (3-triangle strips) by a spatial Poisson process, vegetation
``obstacles``      the obstacle library (box, 12 rocks, 2 tires, 2 cinder blocks) and placement
``raycast``        first-hit ray casting with Embree
``sensor``         the scanner: scan lines, nodding, noise, hover and path scans
``scene``          worlds and simulated patches (one dataset scene)
``sweeps``         the paper's Table I sweeps: which scenes, and how each is simulated
``shards``         the datasets on disk: shards written and read back (``SceneDataset``)
``dataset``        ``simulate --dataset synth1|synth2``: a sweep simulated into shards
``flight``         a flight over a site, written as a ROS 2 bag with ground truth
``recorded``       a recorded flight's returns with their sensor origins; cloud byte rewriting
``alteration``     rays cut short at virtual obstacles (the array core of insertion)
``placement``      where virtual obstacles stand on a recorded flight's ground
``insert``         ``insert-obstacles``: virtual obstacles in a recorded bag
``hybrid``         patches cut from recorded flights, obstacles inserted (the shards' format)
``render``         pictures of patches and flights (returns coloured by what they hit)
=================  ============================================================================

The dataset path imports only numpy, scipy, numba, trimesh, embreex and tqdm, so datasets can
be generated on a machine without ROS or torch (``landing-zone simulate --dataset synth2 --out
DIR``).
"""
from __future__ import annotations

__all__ = ['SimulationError']

from landing_zone.errors import SimulationError
