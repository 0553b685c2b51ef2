"""landing-zone ensemble: one model file from trained members.

The members are checkpoints of one architecture trained on the same inputs (voxel size, tiles),
typically the model trained on everything and the fold models of
:func:`landing_zone.tools.evaluate.lofo.family_folds` (``landing-zone train-fleet --lofo``).
The file written is a
:class:`~landing_zone.judging.ensemble.SafetyEnsemble` checkpoint whose metadata records every
member (file name, weights' SHA-256, what it held out) and, as ``training.hold_out``, the
families **no** member trained on: so ``evaluate --by-family`` judges a family by an ensemble
only where none of its members saw it, and ``calibrate`` takes such ensembles as fold models.

The members' own calibrations are not used: the ensemble's mean logit gets its own, fitted by
``landing-zone calibrate`` on ensembles of members that never saw the families it is fitted
on.
"""
from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

from landing_zone.errors import ConfigError

__all__ = ['assemble']


def assemble(members: Sequence[str | os.PathLike], out: str | os.PathLike) -> dict[str, Any]:
    """Write the ensemble of ``members`` to ``out``; returns its metadata.

    Raises:
        ConfigError: fewer than two members, or members of other inputs or architectures.
        ModelError: a member that is no readable model.
    """
    from landing_zone.judging.checkpoint import (input_configs, load_model, read_metadata,
                                                 save_model)
    from landing_zone.judging.ensemble import SafetyEnsemble
    from landing_zone.judging.net import SafetyNet
    from landing_zone.tools.evaluate.lofo import parse_hold_out

    if len(members) < 2:
        raise ConfigError(f'an ensemble wants at least two --member models, got {len(members)}')
    nets: list[SafetyNet] = []
    records = []
    held: set[tuple[str, str]] | None = None
    datasets: set[str] = set()
    inputs = None
    for path in members:
        net, meta = load_model(path)
        if not isinstance(net, SafetyNet):
            raise ConfigError(f'{path} is an ensemble itself; give its members')
        made = input_configs(meta)  # the defaults where a file predates a setting
        if inputs is None:
            inputs = made
        elif made != inputs:
            raise ConfigError(f'{path} was trained on other inputs (voxel size, tiles) than '
                              f'{members[0]}')
        training = meta.get('training') or {}
        out_of = parse_hold_out(training.get('hold_out') or [])
        held = set(out_of) if held is None else held & set(out_of)
        datasets |= set(meta.get('datasets') or [])
        records.append({'file': Path(path).name, 'weights_sha256': meta['weights_sha256'],
                        'hold_out': [f'{a}:{f}' for a, f in out_of],
                        'seed': training.get('seed'), 'spec': net.spec})
        nets.append(net)
    ensemble = SafetyEnsemble(nets)  # refuses members of different architectures
    assert inputs is not None
    voxel_size, tiles = inputs[0].voxel_size, asdict(inputs[1])
    hold = sorted(f'{a}:{f}' for a, f in (held or set()))
    meta_out: dict[str, Any] = {
        'voxel_size': voxel_size, 'tiles': tiles, 'datasets': sorted(datasets),
        'training': {'hold_out': hold, 'kind': 'ensemble (mean logit of the members)'},
        'ensemble': {'members': len(nets), 'member_files': records},
    }  # no 'calibration' record until landing-zone calibrate fits one
    save_model(out, ensemble, meta_out)
    return read_metadata(out)
