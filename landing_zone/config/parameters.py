"""Every parameter of the node by name, the split of dotted parameters into the configs, and the
text of ``config/assessor.yaml``."""
from __future__ import annotations

import dataclasses
import difflib
from typing import Any

from landing_zone.config.facts import Param
from landing_zone.config.frontend import LiveConfig, NodeConfig, StreamConfig
from landing_zone.config.pipeline import SECTIONS, AssessorConfig
from landing_zone.errors import ConfigError

__all__ = ['PARAMETERS', 'default_parameters', 'configs_from_flat', 'params_yaml',
           'closest_parameter', 'unknown_parameter_error', 'ROS_PARAMETERS']

# Parameters rclpy declares on every node (or reads as QoS overrides): known, though not ours.
ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')


def _parameter_table() -> dict[str, tuple[Any, Param]]:
    """Every node parameter by name: (default, facts), in the order of the YAML file."""
    out: dict[str, tuple[Any, Param]] = {}

    def add(obj: Any, prefix: str) -> None:
        for f in dataclasses.fields(obj):
            p = f.metadata.get('param')
            if p is not None:
                out[p.name or prefix + f.name] = (getattr(obj, f.name), p)

    top = AssessorConfig()
    add(top, '')
    for section in SECTIONS:
        add(getattr(top, section), section + '.')
    add(StreamConfig(), '')
    add(NodeConfig(), '')
    add(LiveConfig(), '')
    return out


# name -> (default, Param) of every parameter of the node; region_center's default None = unset.
PARAMETERS: dict[str, tuple[Any, Param]] = _parameter_table()


def default_parameters() -> dict[str, Any]:
    """Every parameter with a default, by name (the pipeline's, the stream's, the node's);
    arrays as lists, as a parameters file and rclpy give them."""
    return {name: list(default) if isinstance(default, tuple) else default
            for name, (default, _) in PARAMETERS.items() if default is not None}


def is_ros_parameter(name: str) -> bool:
    """Whether rclpy itself knows the name (``use_sim_time``, ``qos_overrides.*``)."""
    return name in ROS_PARAMETERS or name.startswith('qos_overrides.')


def closest_parameter(name: str) -> str | None:
    """The real parameter name nearest to a misspelt one (difflib), None if none is close."""
    names = list(PARAMETERS)
    found = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    if not found:  # a typo in the section alone: compare the last part
        last = name.rpartition('.')[2]
        found = [n for n in names if n.rpartition('.')[2] in
                 difflib.get_close_matches(last, [m.rpartition('.')[2] for m in names], 1, 0.8)]
    return found[0] if found else None


def unknown_parameter_error(names: list[str]) -> ConfigError | None:
    """One line naming the unknown parameters among ``names`` and the closest real name of
    each; None when every name is known."""
    unknown = [n for n in names if n not in PARAMETERS and not is_ros_parameter(n)]
    if not unknown:
        return None
    parts = []
    for n in unknown:
        close = closest_parameter(n)
        parts.append(f'{n!r} (did you mean {close!r}?)' if close else repr(n))
    return ConfigError('unknown parameter ' + ', '.join(parts) + '; config/assessor.yaml '
                       'lists every parameter')


def configs_from_flat(flat: dict[str, Any]) -> tuple[AssessorConfig, StreamConfig,
                                                     dict[str, Any]]:
    """Split dotted parameters into the pipeline's config, the stream's and the rest.

    ``region_center`` (empty or two numbers) becomes ``AssessorConfig.center``; names of
    :class:`StreamConfig` fields go to the stream config; names :meth:`AssessorConfig.to_flat`
    knows go to the pipeline; the front ends' own settings (such as ``qos_depth``) are
    returned as they are. A name that is no parameter is refused, with the closest real name
    (a misspelt limit silently left at its default is worse than a refusal); rclpy's own
    (``use_sim_time``) are let through.

    Raises:
        ConfigError: an unknown name, a value of the wrong type or out of range.
    """
    err = unknown_parameter_error(list(flat))
    if err is not None:
        raise err
    known = set(AssessorConfig().to_flat())
    stream_fields = {f.name: f for f in dataclasses.fields(StreamConfig)}
    core: dict[str, Any] = {}
    stream = StreamConfig()
    rest: dict[str, Any] = {}
    for name, value in flat.items():
        if name in known:
            core[name] = value
        elif is_ros_parameter(name):
            continue
        elif name in stream_fields:
            current = getattr(stream, name)
            try:
                setattr(stream, name, type(current)(value))
            except (TypeError, ValueError) as err:
                raise ConfigError(f'{name} must be a {type(current).__name__}, got '
                                  f'{value!r}') from err
        elif name == 'region_center':
            center = list(value or [])
            if len(center) not in (0, 2):
                raise ConfigError(f'region_center must be empty or two numbers, got {value!r}')
            core['center'] = [float(c) for c in center] if center else None
        else:
            rest[name] = value
    try:
        cfg = AssessorConfig.from_flat(core)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f'bad parameter value: {err}') from err
    stream.validate()
    return cfg, stream, rest


_YAML_HEAD = '''\
# Parameters of the `assessor` node (landing_zone), with their defaults.
#
#   ros2 run landing_zone assessor --ros-args --params-file config/assessor.yaml
#   landing-zone replay SITE.mcap --out OUT.mcap --report REPORT.json --params config/assessor.yaml
#
# Nested sections are the dotted parameter names (map.voxel_size, ...), the same names as the
# fields of landing_zone.config.AssessorConfig. Write floats with a decimal point (20.0, not 20):
# ROS 2 parameters are typed. Parameters marked (read-only) size the map, the tiles or the
# network and cannot change while the node runs.
#
# Generated from the field metadata in landing_zone/config/ (landing_zone.config.params_yaml);
# test/core/test_config.py fails when the two differ.
assessor:
  ros__parameters:
'''


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return value if value else "''"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


def params_yaml() -> str:
    """The text of ``config/assessor.yaml``: every parameter, its default and its facts."""
    lines = [_YAML_HEAD.rstrip('\n')]

    def emit(indent: str, key: str, value: Any, p: Param, commented: bool = False) -> None:
        entry = f'{indent}{"# " if commented else ""}{key}: {value}'
        inline = f'{entry:<{len(indent) + 29}}  # {p.text}'
        if not commented and len(inline) <= 99:
            lines.append(inline)
        else:
            lines.append(f'{indent}# {p.text}')
            lines.append(entry)

    top = AssessorConfig()
    for f in dataclasses.fields(top):
        p = f.metadata.get('param')
        if p is None:
            continue
        if p.name == 'region_center':
            emit('    ', p.name, '[10.0, -4.0]', p, commented=True)
        else:
            emit('    ', f.name, _yaml_value(getattr(top, f.name)), p)
    for section in SECTIONS:
        lines.append('')
        lines.append(f'    {section}:')
        sub = getattr(top, section)
        for f in dataclasses.fields(sub):
            emit('      ', f.name, _yaml_value(getattr(sub, f.name)), f.metadata['param'])
    nested: dict[str, list[tuple[str, Any, Param]]] = {}
    for title, obj in (('The stream (landing_zone.config.StreamConfig), shared with replay.',
                        StreamConfig()),
                       ('The node only (landing_zone.config.NodeConfig).', NodeConfig()),
                       ('The live receive path, node only (landing_zone.config.LiveConfig).',
                        LiveConfig())):
        lines.append('')
        lines.append(f'    # {title}')
        for f in dataclasses.fields(obj):
            p = f.metadata['param']
            if '.' in p.name:  # a dotted name is a nested section in the YAML
                head, key = p.name.split('.', 1)
                nested.setdefault(head, []).append((key, getattr(obj, f.name), p))
                continue
            emit('    ', f.name, _yaml_value(getattr(obj, f.name)), p)
    for head, entries in nested.items():
        lines.append('')
        lines.append(f'    {head}:')
        for key, value, p in entries:
            emit('      ', key, _yaml_value(value), p)
    return '\n'.join(lines) + '\n'
