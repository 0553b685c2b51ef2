"""Checkpoints of the safety CNN: safetensors files with everything needed to rebuild the net.

The weights go through the ``safetensors`` package; the header's metadata holds a JSON
document with the net's :class:`~landing_zone.judging.net.SafetyNetConfig` (spec, input size,
dropout), how its inputs were made (voxel size, tile configuration), how it was trained
(configuration, seed, metrics), the calibration temperature and a SHA-256 of the weights, so a
damaged file is refused rather than silently mis-scoring tiles. An ensemble
(:class:`~landing_zone.judging.ensemble.SafetyEnsemble`) is one file too: its members' weights
under ``members.K.`` and ``ensemble.members`` = K in the metadata. Loading never executes code
from the file (safetensors holds raw tensors only; no pickle).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, ModelError
from landing_zone.judging.ensemble import MAX_MEMBERS, AnyNet, SafetyEnsemble
from landing_zone.judging.net import SafetyNet, SafetyNetConfig

__all__ = ['FORMAT', 'save_model', 'load_model', 'read_metadata', 'weights_sha256',
           'input_configs']

FORMAT = 'landing_zone.safety_net/1'  # checkpoint format tag in the metadata
_META_KEY = 'landing_zone'


def _weights_digest(tensors: dict[str, torch.Tensor]) -> str:
    sha = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        sha.update(name.encode())
        sha.update(str(tuple(t.shape)).encode())
        sha.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return sha.hexdigest()


def _state_tensors(model: AnyNet) -> dict[str, torch.Tensor]:
    return {k: v.detach().to('cpu', torch.float32).contiguous()
            for k, v in model.state_dict().items()}


def weights_sha256(model: AnyNet) -> str:
    """The SHA-256 of a net's weights as :func:`save_model` records it (what an OOD
    reference is bound to, :mod:`landing_zone.judging.ood`)."""
    return _weights_digest(_state_tensors(model))


def save_model(path: str | os.PathLike[str], model: AnyNet,
               metadata: dict[str, Any] | None = None,
               extra_tensors: dict[str, torch.Tensor] | None = None) -> None:
    """Write the weights and their metadata to a safetensors file (atomically).

    Args:
        path: destination file.
        model: the net; its config and temperature are stored with ``metadata``.
        metadata: JSON-serialisable facts to keep beside the weights (voxel size, tile config,
            training config, seed, metrics, ...).
        extra_tensors: more tensors to store under their own names (training state); they must
            not collide with the weights' names.
    """
    tensors = _state_tensors(model)
    meta = dict(metadata or {})
    meta.update(format=FORMAT, model=asdict(model.config), temperature=float(model.temperature),
                calibration_offset=float(model.offset),
                weights_sha256=_weights_digest(tensors))
    if isinstance(model, SafetyEnsemble):
        meta['ensemble'] = dict(meta.get('ensemble') or {}, members=model.size)
    else:
        meta.pop('ensemble', None)
    if extra_tensors:
        clash = set(extra_tensors) & set(tensors)
        if clash:
            raise ModelError(f'extra tensor names collide with weights: {sorted(clash)[0]}')
        tensors.update({k: v.detach().cpu().contiguous() for k, v in extra_tensors.items()})
    try:
        header = json.dumps(meta, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise ModelError(f'model metadata is not JSON-serialisable: {err}') from err
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=dest.name + '.', suffix='.tmp', dir=dest.parent)
    os.close(fd)
    try:
        save_file(tensors, tmp, metadata={_META_KEY: header})
        os.replace(tmp, dest)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The metadata of a checkpoint without reading its weights.

    Raises:
        ModelError: the file is missing, not safetensors, or has no landing_zone metadata.
    """
    p = Path(path)
    if not p.is_file():
        raise ModelError(f'model file not found: {p}')
    try:
        with safe_open(str(p), framework='pt', device='cpu') as f:
            raw = (f.metadata() or {}).get(_META_KEY)
    except Exception as err:  # safetensors raises its own and OS errors; all mean unreadable
        raise ModelError(f'{p}: not a readable safetensors model ({_one_line(err)})') from err
    if raw is None:
        raise ModelError(f'{p}: safetensors file without landing_zone metadata')
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError as err:
        raise ModelError(f'{p}: corrupt model metadata ({_one_line(err)})') from err
    found = meta.get('format') if isinstance(meta, dict) else None
    if found != FORMAT:
        raise ModelError(f'{p}: unknown model format {found!r}, expected {FORMAT!r}')
    out: dict[str, Any] = meta
    return out


def load_model(path: str | os.PathLike[str], device: str | torch.device = 'cpu',
               with_extra: bool = False) -> Any:
    """Rebuild a net from a checkpoint's metadata alone and load its weights.

    Args:
        path: a file written by :func:`save_model`.
        device: where to put the net.
        with_extra: also return the extra tensors stored beside the weights.

    Returns:
        ``(model, metadata)`` (plus the extra tensors with ``with_extra``); the model is in
        eval mode and carries the stored temperature and offset.

    Raises:
        ModelError: missing or corrupt file, or weights that do not fit the stored spec.
    """
    p = Path(path)
    meta = read_metadata(p)
    model: AnyNet
    try:
        cfg = SafetyNetConfig(**meta['model'])
        ensemble = meta.get('ensemble')
        if ensemble is None:
            model = SafetyNet(cfg)
        else:
            k = ensemble.get('members') if isinstance(ensemble, dict) else None
            if not isinstance(k, int) or not 1 <= k <= MAX_MEMBERS:
                raise ConfigError(f'ensemble.members must be 1 to {MAX_MEMBERS}, got {k!r}')
            model = SafetyEnsemble([SafetyNet(SafetyNetConfig(**meta['model']))
                                    for _ in range(k)])
    except (KeyError, TypeError, ConfigError) as err:
        raise ModelError(f'{p}: bad architecture in metadata ({_one_line(err)})') from err
    try:
        tensors = load_file(str(p), device='cpu')
    except Exception as err:  # see read_metadata
        raise ModelError(f'{p}: not a readable safetensors model ({_one_line(err)})') from err
    expected = model.state_dict()
    weights = {k: v for k, v in tensors.items() if k in expected}
    for name, ref in expected.items():
        got = weights.get(name)
        if got is None:
            raise ModelError(f'{p}: weights do not match architecture {cfg.spec}: tensor '
                             f'{name!r} is missing')
        if tuple(got.shape) != tuple(ref.shape):
            raise ModelError(f'{p}: weights do not match architecture {cfg.spec}: tensor '
                             f'{name!r} has shape {tuple(got.shape)}, expected '
                             f'{tuple(ref.shape)}')
    if _weights_digest(weights) != meta.get('weights_sha256'):
        raise ModelError(f'{p}: weights are corrupt (SHA-256 differs from the one recorded)')
    model.load_state_dict(weights, strict=True)
    temperature = float(meta.get('temperature', 1.0))
    if not (math.isfinite(temperature) and temperature > 0):
        raise ModelError(f'{p}: bad calibration temperature {temperature!r}')
    model.temperature = temperature
    offset = float(meta.get('calibration_offset', 0.0))  # files before it: no offset
    if not math.isfinite(offset):
        raise ModelError(f'{p}: bad calibration offset {offset!r}')
    model.offset = offset
    model.to(device).eval()
    if with_extra:
        return model, meta, {k: v for k, v in tensors.items() if k not in expected}
    return model, meta


def input_configs(meta: dict[str, Any]) -> tuple[MapConfig, TileConfig]:
    """The voxel size and tiles a model's inputs were made with (its metadata; the defaults
    where a file predates them).

    Raises:
        ConfigError: a tile configuration this version cannot read.
    """
    vs = float(meta.get('voxel_size', MapConfig().voxel_size))
    tiles = meta.get('tiles')
    try:
        return MapConfig(voxel_size=vs), (TileConfig(**tiles) if isinstance(tiles, dict)
                                          else TileConfig())
    except TypeError as err:
        raise ConfigError(f'model metadata has a tile configuration this version cannot '
                          f'read: {err}') from None
