"""``landing-zone train-fleet``: many trainings at once, here or on a Ray cluster.

The leave-one-family-out protocol trains one model per held-out family
(:mod:`landing_zone.tools.evaluate.lofo`), and an ensemble multiplies that by its members. Each of
those
trainings is one task (:mod:`landing_zone.tools.engines`):
:func:`landing_zone.tools.learn.train.train`
with its own ``--hold-out`` and seed, writing its model, its training state (for resume) and
its log into ``out_dir``. On a cluster ``out_dir`` is a path every worker mounts (NFS, a
cluster file system): a task retried after its worker died resumes from the training state
its first attempt saved (every ``checkpoint_minutes``), and a rerun of the same command skips
the models already written and resumes the others. The summary of
every model goes to ``out_dir/fleet.json``.

Names: ``lofo_AXIS_FAMILY`` for a model that left a family out (``lofo_obstacle_log``),
``model`` for one trained on everything; with ``members`` > 1 each gets ``_mK``
(K = 0 ... members - 1) and the seed ``seed + K``.

Every task sets torch's thread count to ``threads`` (default 1: one training per CPU), so
a model's weights do not depend on the engine or the number of workers (same machine).
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from landing_zone.tools.engines import check_engine, run_tasks
from landing_zone.errors import ConfigError

__all__ = ['lofo_families', 'fleet_jobs', 'train_fleet', 'markdown_fleet']


def lofo_families() -> list[str]:
    """The hold-outs of the LOFO protocol: every train family of obstacles and every vegetation
    family of synth3 (its test families are never trained on)."""
    from landing_zone.tools.sim.synth3 import synth3_train_families
    from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION

    return ([f'obstacle:{f}' for f in synth3_train_families()]
            + [f'vegetation:{f}' for f in SYNTH3_VEGETATION])


def fleet_jobs(config: Any, hold_outs: Sequence[str] = (), members: int = 1,
               everything: bool | None = None) -> list[tuple[str, Any]]:
    """The trainings of a fleet: ``(name, TrainConfig)`` per model.

    Args:
        config: the :class:`~landing_zone.tools.learn.train.TrainConfig` every job starts from.
        hold_outs: ``AXIS:FAMILY`` per leave-one-out model (one model each).
        members: models per job, seeds ``config.seed + K``.
        everything: also a model on every family (default: only when ``hold_outs`` is empty).

    Raises:
        ConfigError: ``members`` < 1, or a malformed or unknown hold-out.
    """
    from landing_zone.tools.evaluate.lofo import parse_hold_out

    if not isinstance(members, int) or members < 1:
        raise ConfigError(f'members must be a positive integer, got {members!r}')
    pairs = parse_hold_out(hold_outs)
    bases: list[tuple[str, list[str]]] = [(f'lofo_{a}_{f}', [f'{a}:{f}']) for a, f in pairs]
    if everything or (everything is None and not pairs):
        bases.insert(0, ('model', []))
    jobs = []
    for name, hold in bases:
        for k in range(members):
            jobs.append((name if members == 1 else f'{name}_m{k}',
                         replace(config, hold_out=hold, seed=config.seed + k)))
    return jobs


def _train_task(task: tuple[list[str] | Any, str, dict[str, Any], int]) -> dict[str, Any]:
    """Worker: one training (resumed from its state if there is one)."""
    import torch

    from landing_zone.tools.learn.train import TrainConfig, train

    data, out, cfg, threads = task
    restore = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        summary = train(data, out, TrainConfig(**cfg), resume=True, progress=False)
    finally:
        torch.set_num_threads(restore)  # the task may run in the caller's process
    return {'out': out, 'trained': True, 'spec': summary['spec'],
            'val_auc': summary['val_auc'], 'val_ece': summary['val_ece'],
            'temperature': summary['temperature'], 'train_seconds': summary['train_seconds']}


def _finished(out: Path) -> dict[str, Any]:
    from landing_zone.judging.checkpoint import read_metadata

    meta = read_metadata(out)
    m = meta.get('metrics', {})
    return {'out': str(out), 'trained': False, 'spec': meta['model']['spec'],
            'val_auc': m.get('val_auc'), 'val_ece': m.get('val_ece'),
            'temperature': meta.get('temperature'), 'train_seconds': m.get('train_seconds')}


def train_fleet(data: Any, out_dir: str | os.PathLike[str], jobs: Sequence[tuple[str, Any]], *,
                engine: str = 'local', address: str | None = None, workers: int | None = None,
                threads: int = 1) -> dict[str, Any]:
    """Train every job of :func:`fleet_jobs` into ``out_dir`` (``NAME.safetensors``).

    Args:
        data: dataset directory or list of them (on a cluster: paths every worker reads).
        out_dir: where models, training states and logs go (created; shared on a cluster).
        jobs: ``(name, TrainConfig)`` pairs.
        engine: ``local`` (a process pool) or ``ray`` (one Ray task per training).
        address: the Ray cluster (:func:`landing_zone.tools.engines.run_tasks`).
        workers: trainings at once (processes, or the CPUs of a local Ray cluster).
        threads: torch threads of each training.

    Returns:
        ``{'out_dir', 'engine', 'models': {name: summary}, 'seconds'}``, also written to
        ``out_dir/fleet.json``.

    Raises:
        ConfigError: no jobs, duplicate names, bad threads, an ``out_dir`` that is a URI.
        EngineError: an unknown engine, Ray missing, a worker that died after its retries.
    """
    check_engine(engine, address)
    if not jobs:
        raise ConfigError('the fleet has no trainings')
    names = [n for n, _ in jobs]
    if len(set(names)) != len(names):
        raise ConfigError(f'two trainings of the fleet share a name: {names}')
    if not isinstance(threads, int) or threads < 1:
        raise ConfigError(f'threads must be a positive integer, got {threads!r}')
    if '://' in str(out_dir):
        raise ConfigError(f'--out-dir {out_dir}: give a path every worker mounts (NFS, a '
                          'cluster file system); object-store URIs are not supported')
    for _, cfg in jobs:
        cfg.validate()
    out = Path(out_dir).resolve()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f'cannot create {out}: {err.strerror}') from None
    if isinstance(data, (str, os.PathLike)):
        data = [data]
    # absolute: a worker's working directory is not the caller's
    data = [str(Path(d).resolve()) for d in data] if all(
        isinstance(d, (str, os.PathLike)) for d in data) else data
    models: dict[str, dict[str, Any]] = {}
    tasks, task_names = [], []
    for name, cfg in jobs:
        path = out / f'{name}.safetensors'
        if path.is_file():
            models[name] = _finished(path)
        else:
            tasks.append((data, str(path), asdict(cfg), threads))
            task_names.append(name)
    t0 = time.perf_counter()
    for i, summary in run_tasks(_train_task, tasks, engine=engine, workers=workers,
                                address=address, start_method='spawn', fresh=True):
        models[task_names[i]] = summary
    doc = {'out_dir': str(out), 'engine': engine,
           'models': {n: {**models[n], 'hold_out': list(c.hold_out), 'seed': c.seed}
                      for n, c in jobs},
           'seconds': round(time.perf_counter() - t0, 3)}
    tmp = out / 'fleet.json.tmp'
    tmp.write_text(json.dumps(doc, indent=1) + '\n', encoding='utf-8')
    os.replace(tmp, out / 'fleet.json')
    return doc


def markdown_fleet(doc: dict[str, Any]) -> str:
    """The fleet's models as a markdown table."""
    lines = ['| model | held out | seed | spec | val AUC | val ECE | train s | |',
             '|---|---|---:|---|---:|---:|---:|---|']
    for name, m in doc['models'].items():
        auc = '-' if m['val_auc'] is None else f'{m["val_auc"]:.4f}'
        ece = '-' if m['val_ece'] is None else f'{m["val_ece"]:.4f}'
        lines.append(f'| {name} | {", ".join(m["hold_out"]) or "-"} | {m["seed"]} | '
                     f'{m["spec"]} | {auc} | {ece} | {m["train_seconds"]} | '
                     f'{"trained" if m["trained"] else "already there"} |')
    return '\n'.join(lines) + '\n'
