"""Learning: train the safety CNN (train, train-fleet) and search architectures (tune). The
training (torch, scikit-learn, optuna: the `[learn]` extra) is imported by each command;
train's and train-fleet's options come from TrainConfig's fields, built when the command
runs."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from landing_zone.tools.cli.options import (ADDRESS_HELP, ENGINE_HELP, Device, Engine,
                                            LazyCommand, command_of, config_options,
                                            config_values, with_options)

app = typer.Typer()

TRAIN_HELP = ('Train the safety CNN on a dataset\'s train split (augmented on the fly), '
              'calibrate it on held-out scenes and write it with its configuration.\n\n'
              'Beside OUT: OUT.train.safetensors (state for --resume), OUT.log.csv.\n\n'
              'Fine-tuning (--init) is never more lenient on obstacles than the --init model: '
              'the loss adds the squared excess of the logit of every obstacle sample the net '
              'judges safer than the --init model does (weighted by --leniency-penalty), and '
              'the anchored calibration keeps the --init model\'s T and b (fitted out of family '
              'by landing-zone calibrate), b lowered until, on the validation obstacles of each '
              '--data and --anchor-data, no more pass at P(safe) >= 0.5 or 0.9 than under the '
              '--init model; refit fits T on the validation scenes (of the training families '
              'only).\n\n'
              'Examples:\n\n  landing-zone train --data data/synth2 '
              '--arch C7-F32-P2-C5-F64-P2-D512 --out model.safetensors\n\n'
              '  landing-zone train --data data/synth2 --out model.safetensors --resume\n\n'
              '  landing-zone train --data data/synth2 --out m.safetensors --device cuda '
              '--workers 15 --cache-voxels 20\n\n'
              '  landing-zone train --init models/landing_zone.safetensors --data hybrid/ '
              '--data synth3_some/ --out site.safetensors --lr 0.001 --epochs 4  (site '
              'adaptation; never more lenient on obstacles than the --init model: see '
              '--leniency-penalty, --calibration, --anchor-data)\n\n'
              '  landing-zone train --data data/synth3 --hold-out obstacle:log --out '
              'lofo_log.safetensors  (leave one family out)')
# TrainConfig's fields that train takes as options (the augmentation's z_shift and yaw are
# fixed); their defaults and help are TrainConfig's
TRAIN_FIELDS = ('arch', 'epochs', 'lr', 'lr_schedule', 'momentum', 'weight_decay', 'batch_size',
                'augment_copies', 'max_samples', 'max_scenes', 'val_fraction', 'workers', 'seed',
                'device', 'dropout', 'cache_voxels', 'edge_drop', 'checkpoint_minutes',
                'precision', 'leniency_penalty', 'calibration', 'hold_out')


def train(
    data: Annotated[list[Path], typer.Option(
        help='Dataset directory (landing-zone simulate); repeat to train on the train splits '
             'of several, e.g. a hybrid set and some synth2 when fine-tuning.')],
    out: Annotated[Path, typer.Option(help='Model file to write (.safetensors).')],
    resume: Annotated[bool, typer.Option(
        help='Continue from OUT.train.safetensors if it exists.')] = False,
    init: Annotated[Optional[Path], typer.Option(
        help='Start from this model\'s weights (same spec): fine-tuning, e.g. to a site; see '
             '--leniency-penalty and --calibration.')] = None,
    anchor_data: Annotated[Optional[list[Path]], typer.Option(
        '--anchor-data', '--guard-data',
        help='With the anchored calibration: a dataset never trained on (e.g. synth3 of '
             '--families frame,mesh) whose obstacle scenes the calibration also holds on, as '
             'a group of its own; repeat for more (--guard-data: its former name).')] = None,
    **options: Any,
) -> None:
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.judging.net import DEFAULT_SPEC
    from landing_zone.tools.learn.train import TrainConfig, train as run_train

    if options['arch'] is None:
        options['arch'] = (read_metadata(init)['model']['spec'] if init is not None
                           else DEFAULT_SPEC)
    cfg = TrainConfig(**config_values(TrainConfig, options))
    s = run_train(data, out, cfg, resume=resume, init=init, anchor_data=anchor_data or None)
    print(f'wrote {s["out"]}: {s["spec"]}, {s["epochs"]} epochs, {s["samples"]:,} samples in '
          f'{s["train_seconds"]:.0f} s; validation AUC {s["val_auc"]}, ECE {s["val_ece"]} '
          f'at temperature {s["temperature"]:.3f}, offset {s["offset"]:+.3f} '
          f'({s["calibration"]}); log {s["log"]}')


def _train_command() -> Any:
    from landing_zone.judging.net import DEFAULT_SPEC
    from landing_zone.tools.learn.train import TrainConfig

    arch = (f'Network spec; default the --init model\'s, else the shipped model\'s '
            f'({DEFAULT_SPEC}; the paper\'s best is C7-F32-P2-C5-F64-P2-D512; S2-F4 is a 2^3 '
            f'convolution of stride 2, in place of a P2).')
    options = config_options(TrainConfig, TRAIN_FIELDS, defaults={'arch': None},
                             helps={'arch': arch})
    return command_of(with_options(train, options), 'train', TRAIN_HELP)


FLEET_HELP = ('Many trainings at once, as processes here or as Ray tasks on a cluster: one '
              'model per held-out family (leave one family out, synth3 data) and/or '
              'ensemble members (seeds SEED ... SEED + MEMBERS - 1). Models, training '
              'states and logs go to --out-dir (on a cluster: a path every worker '
              'mounts); a rerun skips finished models and resumes the others, and a task '
              'whose Ray worker died resumes from its last training state. '
              'OUT_DIR/fleet.json holds every model\'s figures.\n\n'
              'Examples:\n\n  landing-zone train-fleet --data data/synth3 --out-dir '
              'runs/lofo --lofo\n\n'
              '  landing-zone train-fleet --data data/synth3 --out-dir runs/lofo '
              '--hold-out obstacle:log --hold-out vegetation:lodged --members 3\n\n'
              '  landing-zone train-fleet --data /shared/synth3 --out-dir /shared/lofo '
              '--lofo --engine ray --address auto')
# TrainConfig's fields that train-fleet takes as options, and its own smaller budget
FLEET_FIELDS = ('arch', 'epochs', 'augment_copies', 'max_samples', 'cache_voxels', 'batch_size',
                'lr', 'seed', 'checkpoint_minutes')
FLEET_DEFAULTS = {'arch': None, 'epochs': 3, 'augment_copies': 4}


def train_fleet(
    data: Annotated[list[Path], typer.Option(
        help='Dataset directory (repeat for more; on a cluster a path every worker reads).')],
    out_dir: Annotated[Path, typer.Option(help='Where the models go (NAME.safetensors).')],
    lofo: Annotated[bool, typer.Option(
        help='One model per train obstacle family and per vegetation family left out.')]
    = False,
    hold_out: Annotated[Optional[list[str]], typer.Option(
        help='AXIS:FAMILY: one model leaving that family out (repeat: one model each).')]
    = None,
    everything: Annotated[Optional[bool], typer.Option(
        '--everything/--no-everything',
        help='Also a model on every family [default: only without hold-outs].',
        show_default=False)] = None,
    members: Annotated[int, typer.Option(help='Models per job, seeds SEED + K.', min=1)] = 1,
    workers: Annotated[Optional[int], typer.Option(
        help='Trainings at once (processes, or the CPUs of a local Ray cluster); default one '
             'per core.', min=1)] = None,
    threads: Annotated[int, typer.Option(help='Torch threads of each training.', min=1)] = 1,
    engine: Annotated[Engine, typer.Option(help=ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=ADDRESS_HELP)] = None,
    **options: Any,
) -> None:
    from landing_zone.judging.net import DEFAULT_SPEC
    from landing_zone.tools.engines import check_engine
    from landing_zone.tools.learn.fleet import fleet_jobs, lofo_families, markdown_fleet
    from landing_zone.tools.learn.fleet import train_fleet as run_fleet
    from landing_zone.tools.learn.train import TrainConfig

    check_engine(engine.value, address)
    options['arch'] = options['arch'] or DEFAULT_SPEC
    cfg = TrainConfig(**config_values(TrainConfig, options))
    holds = lofo_families() if lofo else []
    holds += [h for h in hold_out or [] if h not in holds]
    jobs = fleet_jobs(cfg, holds, members=members, everything=everything)
    doc = run_fleet(data, out_dir, jobs, engine=engine.value, address=address,
                    workers=workers, threads=threads)
    print(markdown_fleet(doc), end='')
    print(f'{len(jobs)} model(s) in {out_dir} in {doc["seconds"]:.0f} s on {doc["engine"]}; '
          f'figures in {Path(out_dir) / "fleet.json"}')


def _fleet_command() -> Any:
    from landing_zone.tools.learn.train import TrainConfig

    options = config_options(TrainConfig, FLEET_FIELDS, defaults=FLEET_DEFAULTS, helps={
        'arch': 'Network spec; default the shipped model\'s.',
        'seed': 'Seed of the first member (initialisation, split and augmentation).'})
    return command_of(with_options(train_fleet, options), 'train-fleet', FLEET_HELP)


# built when run: TrainConfig lives beside torch
LAZY = (LazyCommand('train', TRAIN_HELP, _train_command),
        LazyCommand('train-fleet', FLEET_HELP, _fleet_command))


@app.command(name='tune',
             help='Random search over the paper\'s architecture space, resumable from its '
                  'Optuna storage; prints the trials best first. Draw K of the search does not '
                  'depend on how many run at once: --parallel trials run as processes here or '
                  'as Ray tasks (--engine ray) and record themselves in the storage.\n\n'
                  'Examples:\n\n  landing-zone tune --data data/synth1 --trials 10\n\n'
                  '  landing-zone tune --data data/synth1 --trials 50 --paper-budget '
                  '--storage sqlite:///tune.db\n\n'
                  '  landing-zone tune --data /shared/synth1 --trials 50 --engine ray --address '
                  'auto --parallel 16 --storage journal:/shared/tune.journal --out-dir '
                  '/shared/tune_models')
def tune(
    data: Annotated[Path, typer.Option(help='Dataset directory (the paper uses synth1).')],
    trials: Annotated[int, typer.Option(help='Draws the study should hold.')] = 10,
    storage: Annotated[str, typer.Option(
        help='Optuna storage: an RDB URL (sqlite:///tune.db: one machine) or journal:PATH, a '
             'journal file that workers on many machines share through a common file system.')
    ] = 'sqlite:///tune.db',
    budget_samples: Annotated[int, typer.Option(
        help='Training samples per epoch of each trial (0: all).')] = 2000,
    epochs: Annotated[int, typer.Option(help='Epochs per trial.')] = 2,
    paper_budget: Annotated[bool, typer.Option(
        help='Full training per trial (6 epochs x 20 copies, no cap).')] = False,
    out_dir: Annotated[Path, typer.Option(
        help='Where the trial models go (on a cluster: a path every worker mounts).')]
    = Path('tune_models'),
    workers: Annotated[int, typer.Option(help='Data loader processes of each trial.')] = 0,
    device: Annotated[Device, typer.Option(help='Where to train.')] = Device.cpu,
    seed: Annotated[int, typer.Option(help='Seed of the search and the trainings.')] = 0,
    parallel: Annotated[int, typer.Option(
        help='Trials at once (processes here, or Ray tasks).', min=1)] = 1,
    threads: Annotated[int, typer.Option(
        help='Torch threads of each trial (0: the cores / --parallel).', min=0)] = 0,
    engine: Annotated[Engine, typer.Option(help=ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=ADDRESS_HELP)] = None,
) -> None:
    from landing_zone.tools.engines import check_engine
    from landing_zone.tools.learn.tune import TuneConfig, format_rows, tune as run_tune

    check_engine(engine.value, address)
    common = dict(trials=trials, workers=workers, device=device.value, seed=seed,
                  parallel=parallel, threads=threads)
    cfg = (TuneConfig.paper(**common) if paper_budget
           else TuneConfig(epochs=epochs, max_samples=budget_samples, **common))
    print(format_rows(run_tune(data, cfg, storage=storage, out_dir=out_dir,
                               engine=engine.value, address=address)))
