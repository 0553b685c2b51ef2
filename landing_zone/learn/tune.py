"""Random search over the paper's architecture space (its Sec. IV-D), resumable.

Run::

    landing-zone tune --data data/synth1 --trials 10                        # small budget
    landing-zone tune --data data/synth1 --trials 50 --paper-budget         # the paper's
    landing-zone tune --data data/synth1 --storage sqlite:///tune.db        # carry on later

The space: one or two convolution layers, each with a kernel of 3, 5 or 7, 32, 64 or 128
filters and max-pooling of 1, 2 or 4, then one dense layer of 2^7 ... 2^12 units. Trials are
drawn by Optuna's RandomSampler and recorded in the study's storage, so a rerun with the same
storage continues until the study holds ``trials`` finished trials. A spec whose layers shrink
the 32^3 input to nothing, or whose net would exceed ``max_params``, is recorded as pruned.

The objective is the validation AUC of :func:`landing_zone.learn.train.train` on the dataset's
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

__all__ = ['TuneConfig', 'SPACE', 'spec_from_params', 'tune']

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
    batch_size: int = 20
    lr: float = 0.01
    workers: int = 0
    device: str = 'cpu'
    seed: int = 0
    max_params: int = 20_000_000  # larger nets are pruned unseen

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


def spec_from_params(params: dict[str, int]) -> str:
    """The spec string of one point of the space (Optuna's trial.params)."""
    parts = []
    for i in range(int(params['conv_layers'])):
        parts += [f'C{params[f"kernel_{i}"]}', f'F{params[f"filters_{i}"]}',
                  f'P{params[f"pool_{i}"]}']
    parts.append(f'D{2 ** int(params["log2_hidden"])}')
    return '-'.join(parts)


def _suggest(trial: Any) -> str:
    n = trial.suggest_int('conv_layers', *SPACE['conv_layers'])
    for i in range(n):
        trial.suggest_categorical(f'kernel_{i}', list(SPACE['kernel']))
        trial.suggest_categorical(f'filters_{i}', list(SPACE['filters']))
        trial.suggest_categorical(f'pool_{i}', list(SPACE['pool']))
    trial.suggest_int('log2_hidden', *SPACE['log2_hidden'])
    return spec_from_params(trial.params)


def tune(data: str | os.PathLike, config: TuneConfig | None = None,
         storage: str = 'sqlite:///tune.db', study_name: str = 'landing_zone',
         out_dir: str | os.PathLike = 'tune_models', progress: bool = True
         ) -> list[dict[str, Any]]:
    """Run (or continue) the random search and return every finished trial, best first.

    Args:
        data: dataset directory (the paper searches on synth1); its train split is used.
        config: budget per trial.
        storage: Optuna storage URL; the study there is continued.
        study_name: name of the study in the storage.
        out_dir: where each trial's model is written (``trial-NNNN.safetensors``).
        progress: messages on stderr.

    Returns:
        One dict per finished trial: number, state, spec, val_auc, mmac, params, seconds.
    """
    import optuna

    from landing_zone.judging.net import SafetyNet, SafetyNetConfig
    from landing_zone.judging.spec import parse_spec
    from landing_zone.learn.train import TrainConfig, train

    cfg = config if config is not None else TuneConfig()
    cfg.validate()
    if not progress:
        optuna.logging.set_verbosity(optuna.logging.WARNING)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    finished = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    study = optuna.create_study(study_name=study_name, storage=storage, direction='maximize',
                                load_if_exists=True)
    # Re-seed past the trials already drawn, so a resumed search does not repeat them.
    study.sampler = optuna.samplers.RandomSampler(seed=cfg.seed + len(study.trials))

    def objective(trial: Any) -> float:
        spec = _suggest(trial)
        trial.set_user_attr('spec', spec)
        try:
            parse_spec(spec, 32)
        except ConfigError as err:
            trial.set_user_attr('pruned_because', str(err))
            raise optuna.TrialPruned(str(err)) from None
        net = SafetyNet(SafetyNetConfig(spec))
        trial.set_user_attr('mmac', round(net.flops() / 1e6, 2))
        trial.set_user_attr('params', net.num_params())
        if net.num_params() > cfg.max_params:
            trial.set_user_attr('pruned_because', f'{net.num_params():,} parameters')
            raise optuna.TrialPruned(f'{spec}: {net.num_params():,} parameters')
        del net
        tcfg = TrainConfig(arch=spec, epochs=cfg.epochs, augment_copies=cfg.augment_copies,
                           max_samples=cfg.max_samples, batch_size=cfg.batch_size, lr=cfg.lr,
                           workers=cfg.workers, device=cfg.device, seed=cfg.seed,
                           checkpoint_minutes=0.0)
        if progress:
            print(f'tune: trial {trial.number}: {spec}', file=sys.stderr)
        summary = train(data, out / f'trial-{trial.number:04d}.safetensors', tcfg,
                        progress=progress)
        trial.set_user_attr('seconds', summary['train_seconds'])
        if summary['val_auc'] is None:  # one class held out: nothing to compare
            trial.set_user_attr('pruned_because', 'validation AUC undefined')
            raise optuna.TrialPruned('validation AUC undefined')
        return float(summary['val_auc'])

    def done() -> int:
        return sum(t.state in finished for t in study.get_trials(deepcopy=False))

    while done() < cfg.trials:
        study.optimize(objective, n_trials=1, catch=())
    rows = []
    for t in study.get_trials(deepcopy=False, states=finished):
        rows.append({'number': t.number, 'state': t.state.name, 'spec': t.user_attrs.get('spec'),
                     'val_auc': t.value, 'mmac': t.user_attrs.get('mmac'),
                     'params': t.user_attrs.get('params'),
                     'seconds': t.user_attrs.get('seconds'),
                     'note': t.user_attrs.get('pruned_because', '')})
    rows.sort(key=lambda r: (r['val_auc'] is None, -(r['val_auc'] or 0.0)))
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
