"""Random search over the paper's architecture space (its Sec. IV-D), resumable.

Run::

    landing-zone tune --data data/synth1 --trials 10                        # small budget
    landing-zone tune --data data/synth1 --trials 50 --paper-budget         # the paper's
    landing-zone tune --data data/synth1 --storage sqlite:///tune.db        # carry on later

The space: one or two convolution layers, each with a kernel of 3, 5 or 7, 32, 64 or 128
filters and max-pooling of 1, 2 or 4, then one dense layer of 2^7 ... 2^12 units. Draw ``k``
of the search comes from its own generator (:func:`draw_params`: ``SeedSequence([seed, k])``),
so the draws do not depend on how many trials run at once or on which worker; each draw is
one task (:mod:`landing_zone.tools.engines`: processes here, or Ray tasks), which trains its net
and
records the trial in the study's Optuna storage. A rerun with the same storage continues until
draws ``0 ... trials - 1`` are recorded; a draw whose model is already written is recorded
without training it again. A spec whose layers shrink the 32^3 input to nothing, or whose net
would exceed ``max_params``, is recorded as pruned.

Why Optuna's storage and not Ray Tune: a random search needs no scheduler, only a place the
finished trials go that every worker can write; Optuna's journal file storage
(``journal:PATH`` on a shared file system) is that, with its file lock, and keeps the one
code path for one machine and a cluster. Ray Tune would add its own trainable API, experiment
directories and restore logic, and the ``ray[tune]`` extra's dependencies, for nothing this
search uses.

The objective is the validation AUC of :func:`landing_zone.tools.learn.train.train` on the
dataset's
training split with a small sample budget by default; each trial also records the net's
multiply-adds per volume, its parameters and its training time, since a net as accurate for
fewer operations is what the on-board budget needs.
"""
from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from landing_zone.errors import ConfigError

__all__ = ['TuneConfig', 'SPACE', 'spec_from_params', 'draw_params', 'open_storage', 'tune']

# The paper's search space.
SPACE = {
    'conv_layers': (1, 2),
    'kernel': (3, 5, 7),
    'filters': (32, 64, 128),
    'pool': (1, 2, 4),
    'log2_hidden': (7, 12),
}


@dataclass
class TuneConfig:
    """Budget of each trial (the default is small; ``paper()`` gives the paper's)."""

    trials: int = 10  # finished trials the study should hold
    epochs: int = 2
    augment_copies: int = 4
    max_samples: int = 2000  # per epoch (0 = no cap)
    out_dir: str = 'tune_models'  # set by tune(): where the draws' models go
    batch_size: int = 20
    lr: float = 0.01
    workers: int = 0
    device: str = 'cpu'
    seed: int = 0
    max_params: int = 20_000_000  # larger nets are pruned unseen
    parallel: int = 1  # trials at once (processes, or Ray tasks)
    threads: int = 0  # torch threads of each trial (0: the usable cores / parallel)
    checkpoint_minutes: float = 0.0  # training state saved within an epoch (0: per epoch)

    @classmethod
    def paper(cls, **kw: Any) -> TuneConfig:
        """The paper's budget: full training (6 epochs of 20 augmented copies) per trial."""
        base = dict(epochs=6, augment_copies=20, max_samples=0)
        base.update(kw)
        return cls(**base)

    def validate(self) -> None:
        if self.trials < 1:
            raise ConfigError(f'trials must be >= 1, got {self.trials}')
        if self.epochs < 1 or self.augment_copies < 1 or self.max_samples < 0:
            raise ConfigError('epochs and augment_copies must be >= 1, max_samples >= 0')
        if self.max_params < 1:
            raise ConfigError(f'max_params must be >= 1, got {self.max_params}')
        if self.parallel < 1 or self.threads < 0:
            raise ConfigError('parallel must be >= 1 and threads >= 0')


def spec_from_params(params: dict[str, int]) -> str:
    """The spec string of one point of the space (Optuna's trial.params)."""
    parts = []
    for i in range(int(params['conv_layers'])):
        parts += [f'C{params[f"kernel_{i}"]}', f'F{params[f"filters_{i}"]}',
                  f'P{params[f"pool_{i}"]}']
    parts.append(f'D{2 ** int(params["log2_hidden"])}')
    return '-'.join(parts)


def draw_params(seed: int, draw: int) -> dict[str, int]:
    """Point ``draw`` of the random search with ``seed``: from its own generator
    (``SeedSequence([seed, draw])``), so it does not depend on which worker draws it, when, or
    how many draws ran before."""
    import numpy as np

    rng = np.random.default_rng([seed, draw])
    lo, hi = SPACE['conv_layers']
    params = {'conv_layers': int(rng.integers(lo, hi + 1))}
    for i in range(params['conv_layers']):
        for name in ('kernel', 'filters', 'pool'):
            options = SPACE[name]
            params[f'{name}_{i}'] = int(options[int(rng.integers(len(options)))])
    lo, hi = SPACE['log2_hidden']
    params['log2_hidden'] = int(rng.integers(lo, hi + 1))
    return params


def _distributions(params: dict[str, int]) -> dict[str, Any]:
    from optuna.distributions import CategoricalDistribution, IntDistribution

    out: dict[str, Any] = {}
    for name in params:
        if name in ('conv_layers', 'log2_hidden'):
            out[name] = IntDistribution(*SPACE[name])
        else:
            out[name] = CategoricalDistribution(list(SPACE[name.rsplit('_', 1)[0]]))
    return out


def open_storage(storage: str) -> Any:
    """An Optuna storage: ``journal:PATH`` (or a path ending in ``.journal``) is a journal file,
    which many processes on many machines may share through a common file system; anything
    else is an RDB URL (``sqlite:///tune.db``: one machine).

    Raises:
        ConfigError: the storage cannot be opened.
    """
    import optuna

    path = storage[len('journal:'):] if storage.startswith('journal:') else (
        storage if storage.endswith('.journal') else None)
    try:
        if path is not None:
            from optuna.storages.journal import JournalFileBackend
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            return optuna.storages.JournalStorage(JournalFileBackend(path))
        return optuna.storages.get_storage(storage)
    except (OSError, ValueError, ImportError) as err:
        raise ConfigError(f'cannot open the tuning storage {storage!r}: {err}') from None


def _finished_draws(study: Any) -> set[int]:
    import optuna

    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    return {int(t.user_attrs['draw']) for t in study.get_trials(deepcopy=False, states=done)
            if 'draw' in t.user_attrs}


def _trial_task(task: tuple[Any, str, str, int, dict[str, Any], bool]) -> dict[str, Any]:
    """Worker: train the net of one draw and record it in the study (once: a draw another
    worker or run recorded meanwhile is not recorded again)."""
    import torch

    data, storage, study_name, draw, c, progress = task
    cfg = TuneConfig(**c)
    restore = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _run_trial(data, storage, study_name, draw, cfg, progress)
    finally:
        torch.set_num_threads(restore)  # the task may run in the caller's process


def _sized(cfg: TuneConfig, draw: int) -> dict[str, Any]:
    """The draw's spec and sizes, and why it is pruned unseen (``pruned_because``) if it is."""
    import torch

    from landing_zone.judging.net import SafetyNet, SafetyNetConfig
    from landing_zone.judging.spec import parse_spec

    spec = spec_from_params(draw_params(cfg.seed, draw))
    attrs: dict[str, Any] = {'draw': draw, 'spec': spec}
    try:
        parse_spec(spec, 32)
    except ConfigError as err:
        attrs['pruned_because'] = str(err)
        return attrs
    with torch.device('meta'):  # sizes only: a pruned draw may have billions of weights
        net = SafetyNet(SafetyNetConfig(spec))
    attrs['mmac'] = round(net.flops() / 1e6, 2)
    attrs['params'] = net.num_params()
    if net.num_params() > cfg.max_params:
        attrs['pruned_because'] = f'{net.num_params():,} parameters'
    return attrs


def _record(storage: str, study_name: str, cfg: TuneConfig, attrs: dict[str, Any],
            value: float | None) -> None:
    """Add the draw's trial to the study, unless another worker or run recorded it."""
    import optuna

    study = optuna.load_study(study_name=study_name, storage=open_storage(storage))
    if attrs['draw'] in _finished_draws(study):
        return
    params = draw_params(cfg.seed, attrs['draw'])
    state = optuna.trial.TrialState.PRUNED if value is None else optuna.trial.TrialState.COMPLETE
    study.add_trial(optuna.trial.create_trial(
        state=state, value=value, params=params, distributions=_distributions(params),
        user_attrs=attrs))


def _run_trial(data: Any, storage: str, study_name: str, draw: int, cfg: TuneConfig,
               progress: bool) -> dict[str, Any]:
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.tools.learn.train import TrainConfig, train

    attrs = _sized(cfg, draw)
    value = None
    spec = attrs['spec']
    out = Path(cfg.out_dir) / f'draw-{draw:04d}.safetensors'
    if out.is_file():  # trained by an earlier run that ended before recording it
        m = read_metadata(out).get('metrics', {})
        auc, seconds = m.get('val_auc'), m.get('train_seconds')
    else:
        tcfg = TrainConfig(arch=spec, epochs=cfg.epochs, augment_copies=cfg.augment_copies,
                           max_samples=cfg.max_samples, batch_size=cfg.batch_size,
                           lr=cfg.lr, workers=cfg.workers, device=cfg.device,
                           seed=cfg.seed, checkpoint_minutes=cfg.checkpoint_minutes)
        if progress:
            print(f'tune: draw {draw}: {spec}', file=sys.stderr)
        summary = train(data, out, tcfg, resume=True, progress=progress)
        auc, seconds = summary['val_auc'], summary['train_seconds']
    attrs['seconds'] = seconds
    attrs['model'] = str(out)
    if auc is None:  # one class held out: nothing to compare
        attrs['pruned_because'] = 'validation AUC undefined'
    else:
        value = float(auc)
    _record(storage, study_name, cfg, attrs, value)
    return attrs


def tune(data: str | os.PathLike, config: TuneConfig | None = None,
         storage: str = 'sqlite:///tune.db', study_name: str = 'landing_zone',
         out_dir: str | os.PathLike = 'tune_models', progress: bool = True, *,
         engine: str = 'local', address: str | None = None
         ) -> list[dict[str, Any]]:
    """Run (or continue) the random search and return every finished trial, best first.

    Args:
        data: dataset directory (the paper searches on synth1); its train split is used.
            On a cluster, a path every worker reads.
        config: budget per trial; ``config.parallel`` trials at once.
        storage: the study's storage (:func:`open_storage`); the study there is continued.
            With several workers on a cluster, a ``journal:PATH`` on a shared file system.
        study_name: name of the study in the storage.
        out_dir: where each draw's model is written (``draw-NNNN.safetensors``); on a cluster a
            path every worker mounts.
        progress: messages on stderr.
        engine: ``local`` (processes here) or ``ray`` (one Ray task per draw).
        address: the Ray cluster (:func:`landing_zone.tools.engines.run_tasks`).

    Returns:
        One dict per finished trial: number, draw, state, spec, val_auc, mmac, params,
        seconds, note.

    Raises:
        ConfigError: a bad budget or storage.
        EngineError: an unknown engine, Ray missing, a worker that died after its retries.
    """
    import optuna

    from landing_zone.tools.engines import check_engine, run_tasks

    cfg = config if config is not None else TuneConfig()
    cfg.validate()
    check_engine(engine, address)
    if '://' in str(out_dir):
        raise ConfigError(f'--out-dir {out_dir}: give a path every worker mounts')
    optuna.logging.set_verbosity(optuna.logging.INFO if progress else optuna.logging.WARNING)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    study = optuna.create_study(study_name=study_name, storage=open_storage(storage),
                                direction='maximize', load_if_exists=True)
    done = _finished_draws(study)
    from landing_zone.judging.inference import usable_cores

    threads = cfg.threads or max(1, usable_cores() // cfg.parallel)
    cfg_dict = {**asdict(cfg), 'out_dir': str(out.resolve()), 'threads': threads}
    if not isinstance(data, (str, os.PathLike)):
        todo_data: Any = data
    else:
        todo_data = str(Path(data).resolve())
    tasks = []
    for d in range(cfg.trials):
        if d in done:
            continue
        attrs = _sized(TuneConfig(**cfg_dict), d)
        if 'pruned_because' in attrs:  # recorded here: no worker needed to say so
            _record(storage, study_name, TuneConfig(**cfg_dict), attrs, None)
        else:
            tasks.append((todo_data, storage, study_name, d, cfg_dict,
                          progress and cfg.parallel == 1))
    for _, attrs in run_tasks(_trial_task, tasks, engine=engine, workers=cfg.parallel,
                              address=address, start_method='spawn', fresh=True):
        if progress:
            print(f'tune: draw {attrs["draw"]} ({attrs["spec"]}) recorded', file=sys.stderr)
    study = optuna.load_study(study_name=study_name, storage=open_storage(storage))
    finished = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    rows = []
    for t in study.get_trials(deepcopy=False, states=finished):
        rows.append({'number': t.number, 'draw': t.user_attrs.get('draw'), 'state': t.state.name,
                     'spec': t.user_attrs.get('spec'), 'val_auc': t.value,
                     'mmac': t.user_attrs.get('mmac'), 'params': t.user_attrs.get('params'),
                     'seconds': t.user_attrs.get('seconds'),
                     'note': t.user_attrs.get('pruned_because', '')})
    rows.sort(key=lambda r: (r['val_auc'] is None, -(r['val_auc'] or 0.0),
                             r['draw'] if r['draw'] is not None else -1))
    study.set_user_attr('budget', asdict(cfg))
    return rows


def format_rows(rows: list[dict[str, Any]]) -> str:
    """The search's trials as a markdown table, best first."""
    lines = ['| trial | spec | val AUC | MMAC / volume | params | train s | note |',
             '|---:|---|---:|---:|---:|---:|---|']
    for r in rows:
        auc = '-' if r['val_auc'] is None else f'{r["val_auc"]:.4f}'
        params = '-' if r['params'] is None else f'{r["params"]:,}'
        lines.append(f'| {r["number"]} | {r["spec"]} | {auc} | {r["mmac"] or "-"} | {params} '
                     f'| {r["seconds"] or "-"} | {r["note"][:60]} |')
    return '\n'.join(lines)
