"""Parameter facts live once, as field metadata in landing_zone/config/: the YAML file, the
node's descriptors and the checks of validate() all come from them."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from landing_zone.config import (PARAMETERS, AssessorConfig, LiveConfig, NodeConfig,
                                 StreamConfig, configs_from_flat, default_parameters, live_config,
                                 params_yaml)
from landing_zone.errors import ConfigError
from landing_zone.io.params import read_params_file

YAML = Path(__file__).resolve().parents[2] / 'config' / 'assessor.yaml'


def test_the_yaml_file_is_the_one_the_metadata_gives():
    # comments (description, unit, read-only) and defaults: any drift fails here
    assert YAML.read_text(encoding='utf-8') == params_yaml()
    assert read_params_file(YAML) == default_parameters()


def test_every_parameter_has_its_facts_and_a_default_inside_its_range():
    # 28 + the guard section's 10 + the ood section's 2 + the live node's receive_queue,
    # receive_queue_mb, qos_reliability, snapshot.path and snapshot.period + the landing
    # sites' limits (max_slope_deg, max_step, min_clearance, clutter_height) +
    # tiles.align_to_ground + the stream's cloud_frame and sensor_offset + the node's
    # stale_after and stale_error + the receive path's eager_interval +
    # tiles.min_ray_depression_deg + model.obstacle_prior
    assert len(PARAMETERS) == 57
    for name, (default, p) in PARAMETERS.items():
        assert p.description and not p.description.endswith('.'), name
        if p.range is not None:
            p.check(name, default)  # the default itself is allowed
            assert p.range[0] < p.range[1], name
    # every field of the stream's and the node's configs is a parameter
    for cls in (StreamConfig, NodeConfig, LiveConfig):
        for f in dataclasses.fields(cls):
            assert (f.metadata['param'].name or f.name) in PARAMETERS


@pytest.mark.parametrize('name', [n for n, (_, p) in PARAMETERS.items() if p.range is not None])
def test_validate_refuses_what_the_range_refuses(name):
    default, p = PARAMETERS[name]
    lo, hi = p.range
    outside = [lo - 1 if not p.open_lo else lo]
    if math.isfinite(hi):
        outside.append(hi if p.open_hi else hi + 1)
    for value in outside:
        value = type(default)(value)
        flat = default_parameters()
        flat[name] = value
        node_own = {f.metadata['param'].name or f.name: cls
                    for cls in (NodeConfig, LiveConfig) for f in dataclasses.fields(cls)}
        if name in node_own:
            # the node's own: rcl and the node's configs refuse it
            with pytest.raises(ConfigError, match=name.replace('.', r'\.')):
                NodeConfig.from_flat(flat) if node_own[name] is NodeConfig else \
                    live_config(flat)
            continue
        with pytest.raises(ConfigError, match=name.replace('.', r'\.')):
            configs_from_flat(flat)


def test_the_node_configs_read_their_parameter_names():
    flat = default_parameters()
    flat.update({'snapshot.path': '/tmp/map.safetensors', 'snapshot.period': 30.0,
                 'qos_reliability': 'reliable', 'receive_queue': 7})
    node = NodeConfig.from_flat(flat)
    assert (node.snapshot_path, node.snapshot_period, node.qos_reliability, node.qos_depth) == \
        ('/tmp/map.safetensors', 30.0, 'reliable', 50)
    assert live_config(flat).receive_queue == 7
    flat['qos_reliability'] = 'sometimes'
    with pytest.raises(ConfigError, match='qos_reliability must be one of best_effort, reliable'):
        NodeConfig.from_flat(flat)


def test_open_ends_are_refused_and_closed_ones_allowed():
    flat = default_parameters()
    flat['tiles.occupied_density'] = 1.0
    with pytest.raises(ConfigError, match=r'occupied_density must lie in \[0.5, 1\)'):
        configs_from_flat(flat)
    flat['tiles.occupied_density'] = 0.5
    cfg, _, _ = configs_from_flat(flat)
    assert cfg.tiles.occupied_density == 0.5
    with pytest.raises(ConfigError, match='map.voxel_size must be a number'):
        PARAMETERS['map.voxel_size'][1].check('map.voxel_size', 'x')
    with pytest.raises(ConfigError, match='map.size_xy must lie in'):
        AssessorConfig.from_flat({'map.size_xy': 500.0})


def test_a_misspelt_name_is_refused_with_the_closest_real_one():
    flat = default_parameters()
    flat['landing_sites.footprint_radus'] = 2.0
    with pytest.raises(ConfigError, match=r"unknown parameter 'landing_sites.footprint_radus' "
                                          r"\(did you mean 'landing_sites.footprint_radius'\?\)"):
        configs_from_flat(flat)
    # rclpy's own are no misspelling
    flat.pop('landing_sites.footprint_radus')
    flat['use_sim_time'] = True
    configs_from_flat(flat)


def test_the_input_frames_and_the_stale_thresholds_are_checked():
    flat = default_parameters()
    _, stream, _ = configs_from_flat(dict(flat, sensor_offset=[0.1, 0, -0.2, 0, 0, 1.5],
                                          cloud_frame='body'))
    assert stream.sensor_offset == (0.1, 0.0, -0.2, 0.0, 0.0, 1.5) and stream.needs_child_frame
    assert not configs_from_flat(flat)[1].needs_child_frame
    with pytest.raises(ConfigError, match='cloud_frame must be one of fixed, body, sensor'):
        configs_from_flat(dict(flat, cloud_frame='lidar'))
    with pytest.raises(ConfigError, match='sensor_offset must be six finite numbers'):
        configs_from_flat(dict(flat, sensor_offset=[0.0, 0.0, 0.0]))
    with pytest.raises(ConfigError, match='stale_error .* must not be shorter than stale_after'):
        NodeConfig.from_flat(dict(flat, stale_after=5.0, stale_error=2.0))
