"""Configuration of landing_zone: one dataclass per stage, SI units, and every parameter fact.

Each field that is a parameter of the ``assessor`` node carries its facts as field metadata
(:class:`Param`: description, unit, range, read-only), here and nowhere else. From them come
the checks of :meth:`validate`, the node's ``ParameterDescriptor``\\ s (:data:`PARAMETERS`) and
the text of ``config/assessor.yaml`` (:func:`params_yaml`; a test holds the file to it).

The node declares the pipeline's fields as dotted parameters (``map.voxel_size``,
``tiles.tile_size``, ...) and copies them onto :class:`AssessorConfig` mechanically
(:func:`AssessorConfig.from_flat` / :meth:`AssessorConfig.to_flat`), so the names in
``config/assessor.yaml``, the node and the Python API are the same. :class:`StreamConfig` (the
stream node and replay share) and :class:`NodeConfig` (the node's own) are flat.

The facts and checks are in :mod:`.facts`, the pipeline's stages in :mod:`.pipeline`, the front
ends' settings in :mod:`.frontend`, the parameter table and the YAML in :mod:`.parameters`.
"""
from __future__ import annotations

from landing_zone.config.facts import Param, param
from landing_zone.config.frontend import (CLOUD_FRAMES, QOS_RELIABILITY, LiveConfig, NodeConfig,
                                          StreamConfig, live_config)
from landing_zone.config.parameters import (PARAMETERS, closest_parameter, configs_from_flat,
                                            default_parameters, params_yaml,
                                            unknown_parameter_error)
from landing_zone.config.pipeline import (SECTIONS, AssessorConfig, GuardConfig, MapConfig,
                                          ModelConfig, OODConfig, SiteConfig, TileConfig)

__all__ = [
    'Param',
    'MapConfig',
    'TileConfig',
    'ModelConfig',
    'SiteConfig',
    'GuardConfig',
    'OODConfig',
    'AssessorConfig',
    'StreamConfig',
    'NodeConfig',
    'LiveConfig',
    'QOS_RELIABILITY',
    'PARAMETERS',
    'live_config',
    'default_parameters',
    'configs_from_flat',
    'params_yaml',
    'SECTIONS',
    'param',
    'closest_parameter',
    'unknown_parameter_error',
    'CLOUD_FRAMES',
]
