"""Calibration fitted on families a model never saw.

``train`` fits the temperature on validation scenes of the families it trained on: P(safe) then
means what it says on data like the training set, and nothing more. On an obstacle of a shape
the net never saw it stays as sure as on a familiar one, and that is the failure a planner pays
for. The leave-groups-out models (``landing-zone train-fleet``) give, for every train
family, the logits of a net that never saw it: pooled, they are this project's best stand-in for
a site nobody simulated. :func:`calibrate` fits ``P(safe) = sigmoid(logit / T + b)``
(:func:`~landing_zone.tools.learn.calibration.fit_platt`) on them and writes ``T`` and ``b`` into
the
final model, which trained on every family; its weights stay bit for bit.

The fit is a transfer: the fold models saw fewer families than the final one, so their logits
are, if anything, less sure than its own. Whether the transfer holds is measured where nothing
was fitted: on the test families (never in any training) of synth3's test split, by
``landing-zone evaluate --by-family``; the model card records both.

A model fine-tuned from a calibrated one (``train --init``) has no fold models of its own.
:func:`calibrate_like` carries the initial model's out-of-family correction over to it: both
nets are fitted in family on the same scenes (scenes of families both trained on, neither saw
these instances), and the map from the initial net's in-family calibration to its out-of-family
one is applied to the fine-tuned net's in-family calibration. The assumption (the fine-tuned
net is as much surer on familiar families than on unfamiliar ones as its initial model) is
checked where nothing was fitted, as above.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from landing_zone.errors import ConfigError, DatasetError

__all__ = ['out_of_family_logits', 'calibrate', 'calibrate_like']


def out_of_family_logits(fold_models: Sequence[str | os.PathLike], data: str | os.PathLike,
                         per_model: int = 2000, seed: int = 0, workers: int = 0,
                         progress: bool = False) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Logits of every fold model on the train-split scenes of the families it held out.

    Args:
        fold_models: models trained with ``--hold-out`` (their metadata name what they left out).
        data: the synth3 directory they were trained on (its train split is read).
        per_model: at most this many scenes per model, drawn evenly by ``seed``.
        seed: which scenes.
        workers: voxelizing processes.

    Returns:
        ``(logits, labels, per-model info)``; labels 1 safe, 0 unsafe.

    Raises:
        ConfigError: a model that held nothing out.
        DatasetError: data without families, or no held-out scene.
    """
    from landing_zone.judging.checkpoint import input_configs, load_model
    from landing_zone.tools.evaluate.lofo import parse_hold_out, scene_families
    from landing_zone.tools.sim.shards import SceneDataset

    ds = SceneDataset(data, 'train')
    fams = scene_families(ds)
    logits, labels, info = [], [], []
    for k, path in enumerate(fold_models):
        net, meta = load_model(path, 'cpu')
        held = parse_hold_out((meta.get('training') or {}).get('hold_out') or [])
        if not held:
            raise ConfigError(f'{path}: held no family out of training; out-of-family '
                              'calibration wants fold models (train --hold-out)')
        unseen = np.zeros(len(ds), dtype=bool)
        for axis, family in held:
            unseen |= fams[axis] == family
        idx = np.flatnonzero(unseen)
        if not idx.size:
            raise DatasetError(f'{data}: no train scene of the families {path} held out')
        if idx.size > per_model:
            rng = np.random.default_rng([seed, k])
            idx = np.sort(rng.choice(idx, per_model, replace=False))
        (z,), y = _scored([net], ds, idx, input_configs(meta), workers, progress,
                          Path(path).name)
        logits.append(z)
        labels.append(y)
        info.append({'model': str(path), 'hold_out': [f'{a}:{f}' for a, f in held],
                     'scenes': int(idx.size), 'unsafe': int((labels[-1] == 0).sum())})
    return np.concatenate(logits), np.concatenate(labels), info


def calibrate(model: str | os.PathLike, fold_models: Sequence[str | os.PathLike],
              data: str | os.PathLike, out: str | os.PathLike, per_model: int = 2000,
              seed: int = 0, offset: bool = True, workers: int = 0,
              progress: bool = False) -> dict[str, Any]:
    """Fit the calibration of ``model`` on the fold models' out-of-family logits; write ``out``.

    Args:
        model: the final model (trained on every family).
        fold_models, data, per_model, seed, workers: see :func:`out_of_family_logits`.
        out: the recalibrated model file (may be ``model`` itself).
        offset: fit the offset ``b`` too (else the temperature alone, ``b = 0``).

    Returns:
        What was fitted and on what (also stored in the model's metadata, ``calibration``).
    """
    from landing_zone.judging.checkpoint import load_model
    from landing_zone.tools.learn.calibration import (binary_nll, expected_calibration_error,
                                                      fit_platt, fit_temperature)

    if not fold_models:
        raise ConfigError('give at least one fold model (--fold-model)')
    z, y, info = out_of_family_logits(fold_models, data, per_model, seed, workers, progress)
    if offset:
        t, b = fit_platt(z, y)
    else:
        t, b = fit_temperature(z, y), 0.0
    net, meta = load_model(model, 'cpu')

    def p(temp: float, off: float) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-(z / temp + off)))

    before = (float(net.temperature), float(net.offset))
    summary = {
        'method': 'platt' if offset else 'temperature',
        'fitted_on': 'out-of-family logits of leave-groups-out models',
        'data': str(data), 'seed': seed, 'per_model': per_model, 'folds': info,
        'n': int(z.size), 'n_unsafe': int((y == 0).sum()),
        'temperature': t, 'offset': b,
        'previous': {'temperature': before[0], 'offset': before[1]},
        'out_of_family_nll': {'previous': binary_nll(z, y, *before),
                              'fitted': binary_nll(z, y, t, b)},
        'out_of_family_ece': {'previous': expected_calibration_error(p(*before), y),
                              'fitted': expected_calibration_error(p(t, b), y)},
        'out_of_family_unsafe_ge_0.5': {'previous': float((p(*before)[y == 0] >= 0.5).mean()),
                                        'fitted': float((p(t, b)[y == 0] >= 0.5).mean())},
    }
    _write(net, meta, out, summary, progress, f'on {z.size} out-of-family scenes')
    return summary


def _write(net: Any, meta: dict[str, Any], out: str | os.PathLike, summary: dict[str, Any],
           progress: bool, what: str) -> None:
    """Write ``net`` with the calibration of ``summary`` to ``out``, its weights unchanged."""
    from landing_zone.judging.checkpoint import save_model

    before = (float(net.temperature), float(net.offset))
    net.temperature, net.offset = summary['temperature'], summary['offset']
    # save_model writes the format, spec, temperature, offset and digest afresh
    save_model(out, net, {**meta, 'calibration': summary})
    if progress:
        print(f'calibrate: T {before[0]:.3f} -> {net.temperature:.3f}, offset '
              f'{before[1]:+.3f} -> {net.offset:+.3f} {what}', file=sys.stderr)


def _in_family_logits(nets: Sequence[Any], inputs: tuple[Any, Any], data: str | os.PathLike,
                      scenes: int, seed: int, workers: int, progress: bool
                      ) -> tuple[list[np.ndarray], np.ndarray]:
    """Each net's logits on the same train-split scenes of ``data``, voxelized once with
    ``inputs`` (their map and tile configurations)."""
    from landing_zone.tools.sim.shards import SceneDataset

    ds = SceneDataset(data, 'train')
    idx = np.arange(len(ds))
    if scenes and idx.size > scenes:
        idx = np.sort(np.random.default_rng(seed).choice(idx, scenes, replace=False))
    if not idx.size:
        raise DatasetError(f'{data}: no train scene')
    return _scored(nets, ds, idx, inputs, workers, progress, Path(data).name)


def _scored(nets: Sequence[Any], ds: Any, idx: np.ndarray, inputs: tuple[Any, Any],
            workers: int, progress: bool, name: str) -> tuple[list[np.ndarray], np.ndarray]:
    """Each net's logits on scenes ``idx`` of ``ds``, voxelized once with ``inputs``, and the
    scenes' labels (1 safe, 0 unsafe); ``name`` labels the progress bars."""
    from landing_zone.judging.inference import Predictor
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.learn.scenes import ScenePack

    pack = ScenePack.from_scenes(ds, idx, progress, f'loading {name}')
    x, y = voxelize(pack, *inputs, workers, progress, f'voxelizing {name}')
    logits = []
    for net in nets:
        with Predictor(net) as predict:
            logits.append(predict(x, logits=True))
    return logits, y.numpy().astype(np.int64)


def calibrate_like(model: str | os.PathLike, initial: str | os.PathLike,
                   data: str | os.PathLike, out: str | os.PathLike, scenes: int = 2000,
                   seed: int = 0, workers: int = 0, progress: bool = False) -> dict[str, Any]:
    """Calibrate a fine-tuned ``model`` as its ``initial`` model was calibrated out of family.

    On the same scenes (train split of ``data``: families both nets trained on, instances
    neither saw), both nets get an in-family Platt fit, ``(T_m, b_m)`` and ``(T_i, b_i)``. The
    initial model's file carries its out-of-family calibration ``(T_o, b_o)``; in logits the
    step from its in-family calibration to that one is ``u -> a u + c`` with
    ``a = T_i / T_o`` and ``c = b_o - a b_i``. Applied to the fine-tuned net's in-family
    calibration: ``T = T_m / a``, ``b = a b_m + c``. For the initial model itself this gives back
    ``(T_o, b_o)``. The fine-tuned weights are written to ``out`` unchanged.

    Returns:
        What was fitted and on what (also stored in the model's metadata, ``calibration``).

    Raises:
        ConfigError: the models read different inputs.
        DatasetError: ``data`` has no train scene.
    """
    from landing_zone.judging.checkpoint import input_configs, load_model
    from landing_zone.tools.learn.calibration import expected_calibration_error, fit_platt

    net, meta = load_model(model, 'cpu')
    init_net, init_meta = load_model(initial, 'cpu')
    inputs = input_configs(meta)
    if input_configs(init_meta) != inputs:
        raise ConfigError(f'{model} and {initial} read different inputs (voxel or tile '
                          'settings)')
    (z_m, z_i), y = _in_family_logits([net, init_net], inputs, data, scenes, seed, workers,
                                      progress)
    t_m, b_m = fit_platt(z_m, y)
    t_i, b_i = fit_platt(z_i, y)
    t_o, b_o = float(init_net.temperature), float(init_net.offset)
    a = t_i / t_o
    c = b_o - a * b_i
    t, b = t_m / a, a * b_m + c
    before = (float(net.temperature), float(net.offset))

    def p(z: np.ndarray, temp: float, off: float) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-(z / temp + off)))

    summary = {
        'method': 'like',
        'fitted_on': 'in-family logits of this model and of its initial model on the same '
                     'scenes; the initial model\'s out-of-family correction carried over',
        'initial': str(initial), 'data': str(data), 'seed': seed, 'n': int(y.size),
        'n_unsafe': int((y == 0).sum()),
        'in_family': {'model': {'temperature': t_m, 'offset': b_m},
                      'initial': {'temperature': t_i, 'offset': b_i}},
        'initial_calibration': {'temperature': t_o, 'offset': b_o},
        'temperature': t, 'offset': b,
        'previous': {'temperature': before[0], 'offset': before[1]},
        # on the fitting scenes, both calibrated as shipped: the two should read alike
        'in_family_ece': {'model': expected_calibration_error(p(z_m, t, b), y),
                          'initial': expected_calibration_error(p(z_i, t_o, b_o), y)},
        'in_family_unsafe_ge_0.9': {'model': float((p(z_m, t, b)[y == 0] >= 0.9).mean()),
                                    'initial': float((p(z_i, t_o, b_o)[y == 0] >= 0.9).mean())},
    }
    _write(net, meta, out, summary, progress,
           f'(like {Path(initial).name}) on {y.size} in-family scenes')
    return summary
