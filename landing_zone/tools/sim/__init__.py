"""The LiDAR simulator: vegetated landing sites, a nodding line scanner, datasets, flights.

One concept per module, in the order the data flows:

=====================  ========================================================================
**world**
``mesh``               labelled triangle meshes (every face is ground, grass or obstacle)
``terrain``            Perlin-noise ground (height field and mesh)
``grass``              grass blades (3-triangle strips) by a spatial Poisson process, shrubs
``leafy``              leafy crowns and forbs: leaves on twigs and stems
``vegetation``         the vegetation families of the datasets, drawn and built
``shapes``             mesh building blocks of the obstacles: bodies, hulls, poses
``obstacles``          an obstacle: a model, the model placed, placing it on the ground
``library``            the fixed obstacle library (box, 12 rocks, 2 tires, 2 cinder blocks)
``family_shape``       what a family's generator returns, and every instance's bounds
``family_natural``     the generators of the natural families (and rubble)
``family_manmade``     the generators of the closed and hollow man-made families
``family_open``        the generators of the open families of thin structure
``assembly``           the ``assembly`` family: random assemblies of parts
``families``           the catalogue of obstacle families and their instances
**sensing**
``raycast``            first-hit ray casting with Embree
``sensor``             the scanner: scan lines, nodding, patterns, noise, path scans
``hover``              the nodding scanner hovering over an area until it holds the density
``flyover``            a pass of any scanner over a patch
**datasets**
``scene``              worlds and simulated patches (one dataset scene)
``hashing``            the integer hash that splits scenes and pairs
``sweeps``             the paper's Table I sweeps: which scenes, and how each is simulated
``synth3``             the synth3 dataset's plan: pairs, families, splits, meta.json
``synth3_scene``       one synth3 scene drawn from its plan
``shards``             the datasets on disk: shards written and read back (``SceneDataset``)
``dataset``            ``simulate --dataset``: a dataset simulated into shards
**flights**
``flight_settings``    a flight's configuration and its presets of vegetation and scanner
``flight_site``        a flight's site: ground, vegetation, obstacles, tile labels
``flight_path``        a flight's lawnmower path and speed
``flight``             a flight flown and written as a ROS 2 bag with ground truth
``recorded``           a recorded flight's returns with their sensor origins; cloud rewriting
``alteration``         rays cut short at virtual obstacles (the array core of insertion)
``placement``          where virtual obstacles stand on a recorded flight's ground
``insert``             ``insert-obstacles``: virtual obstacles in a recorded bag
``hybrid``             patches cut from recorded flights, obstacles inserted (shards' format)
``render``             pictures of patches and flights (returns coloured by what they hit)
=====================  ========================================================================

The dataset path imports only numpy, scipy, numba, trimesh, embreex and tqdm, so datasets can
be generated on a machine without ROS or torch (``landing-zone simulate --dataset synth2 --out
DIR``).
"""
from __future__ import annotations

__all__ = ['SimulationError']

from landing_zone.errors import SimulationError
