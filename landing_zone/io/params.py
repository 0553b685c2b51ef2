"""ROS 2 parameters files (``config/assessor.yaml``), read as the node's dotted names."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from landing_zone.errors import ConfigError

__all__ = ['read_params_file']


def read_params_file(path: str | os.PathLike[str], node: str = 'assessor') -> dict[str, Any]:
    """The parameters of one node in a ROS 2 parameters file, as dotted names.

    The file has the standard layout (``<node>: ros__parameters: {...}``, nested sections
    flattened with dots as rcl does, or ``/**`` for every node), so the node (``--ros-args
    --params-file``) and replay (``--params``) read the same file.

    Raises:
        ConfigError: the file is missing, not YAML, or has no parameters for ``node``.
    """
    import yaml

    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text(encoding='utf-8'))
    except OSError as err:
        raise ConfigError(f'cannot read parameters file {p}: {err.strerror}') from err
    except yaml.YAMLError as err:
        raise ConfigError(f'{p} is not valid YAML: {" ".join(str(err).split())}') from err
    flat: dict[str, Any] = {}
    found = False
    for key in ('/**', node, '/' + node):
        section = doc.get(key) if isinstance(doc, dict) else None
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if isinstance(params, dict):
            found = True
            _flatten(params, '', flat)
    if not found:
        raise ConfigError(f'{p} has no "{node}: ros__parameters:" section')
    return flat


def _flatten(tree: dict[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            _flatten(value, name + '.', out)
        else:
            out[name] = value
