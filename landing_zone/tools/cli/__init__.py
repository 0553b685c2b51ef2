"""The `landing-zone` command line (also `python -m landing_zone`).

Each command parses its options and calls one library function; heavy imports (torch, numba,
rosbags) happen inside the commands so that `landing-zone --help` is instant. Errors the core
raises on bad input (:class:`landing_zone.errors.LandingZoneError`) end the program with one
line on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import sys
import time
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer

from landing_zone.errors import LandingZoneError

app = typer.Typer(
    name='landing-zone',
    help='Landing zone detection from LiDAR with a 3D CNN.\n\n'
         'Examples:\n\n'
         '  landing-zone demo\n\n'
         '  landing-zone simulate-flight --out site.mcap --seed 3\n\n'
         '  landing-zone replay site.mcap --out assessed.mcap --report report.json\n\n'
         '  landing-zone insert-obstacles site.mcap --out hybrid.mcap --count 6\n\n'
         '  landing-zone simulate --dataset synth2 --out data/synth2 --scenes 2000\n\n'
         '  landing-zone train --data data/synth2 --out model.safetensors\n\n'
         '  landing-zone evaluate --data data/synth2 --baselines --json results.json\n\n'
         '  landing-zone bench integrate',
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


class DatasetName(str, Enum):
    synth1 = 'synth1'
    synth2 = 'synth2'
    synth3 = 'synth3'
    hybrid = 'hybrid'


class Engine(str, Enum):
    local = 'local'
    ray = 'ray'


_ENGINE_HELP = ('local: processes on this machine; ray: Ray tasks on a cluster (--address, '
                'else RAY_ADDRESS, else a local one); needs pip install \'landing_zone[ray]\'.')
_ADDRESS_HELP = ('Ray cluster address (ray://HOST:10001, HOST:6379 or auto); default '
                 'RAY_ADDRESS, else a local cluster of --workers CPUs.')


class Reliability(str, Enum):
    reliable = 'reliable'
    best_effort = 'best_effort'


@app.callback()
def _root() -> None:
    # A callback keeps typer in command-group mode even while few commands exist.
    pass


# --- bench ------------------------------------------------------------------------------------

@app.command(help='Run the project\'s performance benchmarks and print their figures.\n\n'
                  'Examples:\n\n  landing-zone bench\n\n  landing-zone bench integrate\n\n'
                  '  landing-zone bench integrate --batches 50\n\n'
                  '  landing-zone bench live\n\n  landing-zone bench soak --minutes 30\n\n'
                  '  landing-zone bench engines  (local processes beside a local Ray cluster)\n\n'
                  '  landing-zone bench assess --model candidate.safetensors')
def bench(
    which: Annotated[Optional[list[str]], typer.Argument(
        help='Benchmarks to run (integrate, simulate, assess, replay, insert, live, soak, '
             'engines); default all but live, soak and engines.')] = None,
    batches: Annotated[int, typer.Option(
        help='Batches of returns per measurement (live: 3 per second of each rate).')] = 30,
    seed: Annotated[int, typer.Option(help='Seed of the benchmark scenes.')] = 0,
    minutes: Annotated[Optional[float], typer.Option(
        help='Length of the soak [min] (default 2).', min=0.1)] = None,
    model: Annotated[Optional[list[Path]], typer.Option(
        help='assess: also time this model\'s judgement of the map and of a strip, as the '
             'assessor runs it (with NAME.ood.safetensors beside it, else a random reference '
             'of its size); repeat for more.')] = None,
) -> None:
    from landing_zone.tools import bench as bench_mod
    bench_mod.run(which or [], batches=batches, seed=seed, minutes=minutes,
                  models=tuple(str(m) for m in model or ()))


# --- replay -----------------------------------------------------------------------------------

@app.command(help='Run the node\'s pipeline offline on a recorded bag: the node\'s output topics '
                  'go into OUT.mcap at the stamps it would have published them, the final '
                  'tiles into REPORT.json.\n\n'
                  'Examples:\n\n  landing-zone replay site.mcap --out assessed.mcap '
                  '--report report.json\n\n'
                  '  landing-zone replay flight.bag --out a.mcap --report r.json '
                  '--points-topic /velodyne_points --pose-topic /pose --png map.png\n\n'
                  '  landing-zone replay site.mcap --out a.mcap --report r.json --center 10 -4'
                  '\n\nA survey file (.las / .laz) replays too, with its sensor trajectory '
                  '(--trajectory t,x,y,z CSV or SBET, in the file\'s CRS); without one the '
                  'sensor origins are derived from per-point GPS time and scan angle, assuming '
                  'each flight line straight, level, at constant speed and scanned across the '
                  'track (scan angle from nadir, positive to the side that puts the sensor above '
                  'its returns). Coordinates are kept '
                  'in float64 around a local origin the report states (survey.origin); '
                  '--center is then in the file\'s CRS and units.\n\n'
                  '  landing-zone replay autzen_trim.laz --out a.mcap --report r.json')
def replay(
    bag: Annotated[Path, typer.Argument(
        help='ROS 2 bag (.mcap, .db3 or directory), ROS 1 .bag with the clouds and poses, or '
             'a LAS / LAZ survey.')],
    out: Annotated[Path, typer.Option(help='Output bag of the node\'s topics (.mcap).')],
    report: Annotated[Path, typer.Option(help='REPORT.json with the final tiles and sites.')],
    points_topic: Annotated[str, typer.Option(
        help='PointCloud2 topic (fixed frame).')] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(
        help='PoseStamped topic of the sensor.')] = '/lidar/pose',
    model: Annotated[Optional[Path], typer.Option(
        help='Model file; default the shipped one.')] = None,
    center: Annotated[Optional[tuple[float, float]], typer.Option(
        help='X Y of a fixed region of interest; default: the map follows the sensor.')] = None,
    png: Annotated[Optional[Path], typer.Option(help='PNG of the final safety map.')] = None,
    params: Annotated[Optional[Path], typer.Option(
        help='ROS 2 parameters file (config/assessor.yaml layout) for the pipeline.')] = None,
    labels: Annotated[Optional[Path], typer.Option(
        help='SITE.labels.json: mark the true obstacles in the PNG.')] = None,
    trajectory: Annotated[Optional[Path], typer.Option(
        help='LAS / LAZ only: sensor positions over time, CSV t,x,y,z or SBET; default: '
             'derived from GPS time and scan angle.')] = None,
) -> None:
    from landing_zone.replay import replay as run_replay
    from landing_zone.config import configs_from_flat
    from landing_zone.io.params import read_params_file
    from landing_zone.judging.ood import REASON_OOD

    config = stream_config = None
    if params is not None:
        config, stream_config, _ = configs_from_flat(read_params_file(params))
    result = run_replay(bag, out, report, png, points_topic=points_topic, pose_topic=pose_topic,
                        model=model, center=center, config=config,
                        stream_config=stream_config, labels=labels, trajectory=trajectory,
                        log=lambda line: print(f'note: {line}'))
    st = result.stats
    a = result.assessment
    judged = int(a.known.sum())
    print(f'replayed {st["clouds"]} clouds ({st["points"]:,} returns, {st["dropped_clouds"]} '
          f'clouds and {st["dropped_points"]:,} returns dropped) covering '
          f'{result.bag_seconds:.1f} s in {result.timings["loop"]:.1f} s: '
          f'{result.realtime_factor:.1f}x real time (set-up {result.timings["setup"]:.1f} s; '
          f'assessing {result.timings["assess"]:.1f} s, integrating '
          f'{result.timings["ingest"]:.1f} s)')
    print(f'{result.assessments} assessments; final map: {judged} of {len(a)} tiles judged, '
          f'{len(a.sites)} landing site(s)'
          + (f', best at ({a.sites[0].x:.1f}, {a.sites[0].y:.1f}) with P(safe) '
             f'{a.sites[0].p_safe:.2f}' if a.sites else ''))
    if result.survey is not None:
        o = result.survey['origin']
        print(f'survey {result.survey["crs"] or "(no CRS)"}: local origin ({o[0]:.2f}, '
              f'{o[1]:.2f}, {o[2]:.2f}) in the file\'s units '
              f'({result.survey["metres_per_unit"]:g} m); trajectory '
              f'{result.survey["trajectory"]}; unknown tiles {len(a) - judged} of {len(a)}')
    if result.ood_reference is None:
        print('OOD reference: none (the signal is off: no tile is unknown for looking unlike '
              'the training data)')
    else:
        unlike = sum(r is not None and r.startswith(REASON_OOD) for r in a.reasons())
        print(f'OOD reference {result.ood_reference}: {unlike} tile(s) unknown as unlike the '
              'training data')
    print(f'wrote {out}, {report}' + (f', {png}' if png is not None else ''))


# --- insert-obstacles -------------------------------------------------------------------------

@app.command(name='insert-obstacles',
             help='Insert virtual obstacles of the simulator\'s library or its obstacle families '
                  'into a recorded flight: '
                  'every return whose ray meets an obstacle first moves onto its surface (plus '
                  'range noise), every other byte of the bag stays as it was. Writes OUT.mcap '
                  'and OUT.labels.json (the flight\'s labels, or its covered tiles as safe, '
                  'with the tiles under the inserted obstacles unsafe).\n\n'
                  'Examples:\n\n  landing-zone insert-obstacles site.mcap --out hybrid.mcap '
                  '--count 6\n\n'
                  '  landing-zone insert-obstacles flight.bag --out h.mcap --region -5 -5 5 5 '
                  '--kinds rock,tire --group train --seed 2\n\n'
                  '  landing-zone insert-obstacles site.mcap --out f.mcap --families all '
                  '--count 17\n\n'
                  '  landing-zone insert-obstacles site.mcap --out h.mcap --labels '
                  'site.labels.json --points-topic /points --pose-topic /sensor_pose')
def insert_obstacles(
    bag: Annotated[Path, typer.Argument(
        help='ROS 2 bag (.mcap, .db3 or directory) or ROS 1 .bag with the clouds and poses.')],
    out: Annotated[Path, typer.Option(help='Output bag (.mcap); labels go beside it.')],
    count: Annotated[int, typer.Option(help='Obstacles to insert.')] = 6,
    kinds: Annotated[Optional[str], typer.Option(
        help='Obstacle kinds of the library, comma separated (rock, tire, cinder_block, '
             'box), cycled [default: all four, unless --families is given].')] = None,
    families: Annotated[Optional[str], typer.Option(
        help='Obstacle families, comma separated (e.g. log,bucket,coil; all, train, test), '
             'cycled after the kinds: random instances of --group.')] = None,
    group: Annotated[str, typer.Option(
        help='train or test: the obstacle models of that dataset split.')] = 'test',
    region: Annotated[Optional[tuple[float, float, float, float]], typer.Option(
        help='X0 Y0 X1 Y1 where obstacles may stand; default the labels\' safe tiles.')]
    = None,
    labels: Annotated[Optional[Path], typer.Option(
        help='SITE.labels.json of the flight; default BAG.labels.json beside the bag.')]
    = None,
    seed: Annotated[int, typer.Option(help='Seed of placement and range noise.')] = 0,
    range_noise: Annotated[float, typer.Option(
        help='Range noise (standard deviation) of the moved returns [m].')] = 0.025,
    points_topic: Annotated[str, typer.Option(
        help='PointCloud2 topic (fixed frame).')] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(
        help='PoseStamped topic of the sensor.')] = '/lidar/pose',
    frame_id: Annotated[str, typer.Option(help='The fixed frame of clouds and poses.')] = 'map',
    overwrite: Annotated[bool, typer.Option(help='Replace existing outputs.')] = False,
) -> None:
    from landing_zone.tools.sim.insert import DEFAULT_KINDS, insert_obstacles as run_insert

    kinds_t = (tuple(k.strip() for k in kinds.split(',') if k.strip()) if kinds is not None
               else () if families else DEFAULT_KINDS)
    r = run_insert(bag, out, count=count, seed=seed, kinds=kinds_t,
                   families=tuple(f.strip() for f in (families or '').split(',') if f.strip()),
                   group=group,
                   region=region, labels=labels, points_topic=points_topic,
                   pose_topic=pose_topic, frame_id=frame_id, range_sigma=range_noise,
                   overwrite=overwrite)
    names = ', '.join(f'{o.model.name} at ({o.x:.1f}, {o.y:.1f})' for o in r.obstacles)
    print(f'inserted {len(r.obstacles)} obstacle(s): {names}')
    print(f'{r.altered:,} of {r.returns:,} returns moved onto them, in {r.altered_clouds} of '
          f'{r.clouds} clouds ({r.skipped_clouds} left as they were: no pose or other frame); '
          f'{r.messages} messages in {r.seconds:.1f} s')
    print(f'wrote {r.bag}, {r.labels}')


# --- play -------------------------------------------------------------------------------------

@app.command(help='Publish a bag\'s messages over ROS 2 at the recorded rate (there is no '
                  '`ros2 bag` in a pip-installed ROS), to drive the live `assessor` node.\n\n'
                  'Examples:\n\n  landing-zone play site.mcap\n\n'
                  '  landing-zone play site.mcap --rate 2 --remap /lidar/points:=/points '
                  '--remap /lidar/pose:=/sensor_pose\n\n'
                  '  landing-zone play flight.bag --topics /velodyne_points --wait 5')
def play(
    bag: Annotated[Path, typer.Argument(
        help='ROS 2 bag (.mcap, .db3 or directory) or ROS 1 .bag.')],
    rate: Annotated[float, typer.Option(help='Playback speed (2.0: twice as fast).')] = 1.0,
    topics: Annotated[Optional[list[str]], typer.Option(
        help='Only this topic (repeat for more); default all.')] = None,
    remap: Annotated[Optional[list[str]], typer.Option(
        help='FROM:=TO topic rename (repeat for more).')] = None,
    wait: Annotated[float, typer.Option(
        help='Wait up to this many seconds for a subscriber on every topic first.')] = 0.0,
    reliability: Annotated[Reliability, typer.Option(
        help='QoS reliability of the publishers (a LiDAR driver\'s is best_effort).')
    ] = Reliability.reliable,
    loops: Annotated[int, typer.Option(
        help='Passes over the bag; 0: until --duration ends.', min=0)] = 1,
    restamp: Annotated[bool, typer.Option(
        help='Shift the stamps of every pass after the first, so they keep increasing.')
    ] = False,
    duration: Annotated[Optional[float], typer.Option(
        help='Stop after this many seconds.', min=0.0)] = None,
) -> None:
    from landing_zone.ros.play import parse_remaps
    from landing_zone.ros.play import play as run_play

    if not rate > 0:
        raise typer.BadParameter(f'must be positive, got {rate}', param_hint='--rate')
    if loops == 0 and duration is None:
        raise typer.BadParameter('--loops 0 plays until --duration ends; give --duration',
                                 param_hint='--loops')
    stats = run_play(bag, rate=rate, topics=topics, remap=parse_remaps(remap),
                     wait_subscribers=wait, reliability=reliability.value, loops=loops,
                     restamp=restamp, duration=duration)
    per = ', '.join(f'{n} on {t}' for t, n in sorted(stats.by_topic.items()))
    print(f'published {stats.messages} messages ({per}) covering {stats.bag_seconds:.1f} s in '
          f'{stats.seconds:.1f} s; at most {stats.late * 1000:.0f} ms late')


# --- train / tune / evaluate ------------------------------------------------------------------

class Device(str, Enum):
    cpu = 'cpu'
    cuda = 'cuda'


class Calibration(str, Enum):
    auto = 'auto'
    refit = 'refit'
    guarded = 'guarded'


class LrSchedule(str, Enum):
    constant = 'constant'
    cosine = 'cosine'


@app.command(help='Train the safety CNN on a dataset\'s train split (augmented on the fly), '
                  'calibrate it on held-out scenes and write it with its configuration.\n\n'
                  'Beside OUT: OUT.train.safetensors (state for --resume), OUT.log.csv.\n\n'
                  'Examples:\n\n  landing-zone train --data data/synth2 '
                  '--arch C7-F32-P2-C5-F64-P2-D512 --out model.safetensors\n\n'
                  '  landing-zone train --data data/synth2 --out model.safetensors --resume\n\n'
                  '  landing-zone train --data data/synth2 --out m.safetensors --device cuda '
                  '--workers 15 --cache-voxels 20\n\n'
                  '  landing-zone train --init models/landing_zone.safetensors --data hybrid/ '
                  '--data synth3_some/ --out site.safetensors --lr 0.001 --epochs 4  (site '
                  'adaptation; never more lenient on obstacles than the --init model: see '
                  '--leniency-penalty, --calibration, --guard-data)\n\n'
                  '  landing-zone train --data data/synth3 --hold-out obstacle:log --out '
                  'lofo_log.safetensors  (leave one family out)')
def train(
    data: Annotated[list[Path], typer.Option(
        help='Dataset directory (landing-zone simulate); repeat to train on the train splits '
             'of several, e.g. a hybrid set and some synth2 when fine-tuning.')],
    out: Annotated[Path, typer.Option(help='Model file to write (.safetensors).')],
    arch: Annotated[Optional[str], typer.Option(
        help='Network spec; default the --init model\'s, else the shipped model\'s '
             '(P2-C5-F32-P2-C3-F64-D128; the paper\'s best is C7-F32-P2-C5-F64-P2-D512; '
             'S2-F4 is a 2^3 convolution of stride 2, in place of a P2).',
        show_default=False)] = None,
    epochs: Annotated[int, typer.Option(help='Passes over the augmented training set.')] = 6,
    lr: Annotated[float, typer.Option(help='SGD learning rate.')] = 0.01,
    lr_schedule: Annotated[LrSchedule, typer.Option(
        help="constant (the paper's) or cosine (the rate falls to 0 over the run).")
    ] = LrSchedule.constant,
    momentum: Annotated[float, typer.Option(help='SGD momentum.')] = 0.9,
    weight_decay: Annotated[float, typer.Option(help='L2 penalty.')] = 5e-4,
    batch_size: Annotated[int, typer.Option(help='Samples per minibatch.')] = 20,
    augment_copies: Annotated[int, typer.Option(
        help='Augmented samples of every scene per epoch.')] = 20,
    max_samples: Annotated[int, typer.Option(
        help='Cap on samples per epoch (0: none).')] = 0,
    max_scenes: Annotated[int, typer.Option(
        help='Train on an even subset of this many scenes (whole twin pairs; 0: all): bounds '
             'the memory, about 16 bytes per return.')] = 0,
    val_fraction: Annotated[float, typer.Option(
        help='Share of training scenes held out for validation and calibration.')] = 0.1,
    workers: Annotated[int, typer.Option(help='Data loader processes (0: in-process).')] = 0,
    seed: Annotated[int, typer.Option(
        help='Seed of initialisation, split and augmentation.')] = 0,
    device: Annotated[Device, typer.Option(help='Where to train.')] = Device.cpu,
    dropout: Annotated[float, typer.Option(help='Dropout after each layer.')] = 0.5,
    cache_voxels: Annotated[int, typer.Option(
        help='Pre-voxelize this many augmented copies per scene once (0: on the fly).')] = 0,
    edge_drop: Annotated[float, typer.Option(
        help='Share of samples whose context is cut off beyond a random line in the padding, '
             'as at the edge of a scanned area.')] = 0.3,
    checkpoint_minutes: Annotated[float, typer.Option(
        help='Also save the training state this often within an epoch.')] = 10.0,
    precision: Annotated[str, typer.Option(
        help='auto (bf16 on CUDA, fp32 on CPU), fp32 or bf16.')] = 'auto',
    resume: Annotated[bool, typer.Option(
        help='Continue from OUT.train.safetensors if it exists.')] = False,
    init: Annotated[Optional[Path], typer.Option(
        help='Start from this model\'s weights (same spec): fine-tuning, e.g. to a site; see '
             '--leniency-penalty and --calibration.')] = None,
    leniency_penalty: Annotated[float, typer.Option(
        help='With --init: weight of a penalty on every obstacle sample the net judges safer '
             'than the --init model does (the squared excess of its logit), so that adapting '
             'to a site does not make it more lenient on obstacles; 0: none.')] = 1.0,
    calibration: Annotated[Calibration, typer.Option(
        help='refit: the temperature fitted on the validation scenes (of the training '
             'families only); guarded: the --init model\'s T and b (fitted out of family by '
             'landing-zone calibrate), b lowered until, on the validation obstacles of each '
             '--data, no more pass at P(safe) >= 0.5 or 0.9 than under the --init model; '
             'auto: guarded with --init, else refit.')] = Calibration.auto,
    hold_out: Annotated[Optional[list[str]], typer.Option(
        help='Leave a family out of training, AXIS:FAMILY (obstacle:log, vegetation:lodged, '
             'terrain:sloped, sensor:rosette; synth3 data); repeat for more.')] = None,
    guard_data: Annotated[Optional[list[Path]], typer.Option(
        help='With the guarded calibration: a dataset never trained on (e.g. synth3 of '
             '--families frame,mesh) whose obstacle scenes the guard also holds on, as a '
             'group of its own; repeat for more.')] = None,
) -> None:
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.judging.net import DEFAULT_SPEC
    from landing_zone.tools.learn.train import TrainConfig, train as run_train

    if arch is None:
        arch = read_metadata(init)['model']['spec'] if init is not None else DEFAULT_SPEC
    cfg = TrainConfig(arch=arch, epochs=epochs, lr=lr, lr_schedule=lr_schedule.value,
                      momentum=momentum,
                      weight_decay=weight_decay, batch_size=batch_size,
                      augment_copies=augment_copies, max_samples=max_samples,
                      max_scenes=max_scenes,
                      val_fraction=val_fraction, workers=workers, seed=seed,
                      device=device.value, dropout=dropout, cache_voxels=cache_voxels,
                      edge_drop=edge_drop, checkpoint_minutes=checkpoint_minutes,
                      precision=precision, hold_out=list(hold_out or []),
                      leniency_penalty=leniency_penalty, calibration=calibration.value)
    s = run_train(data, out, cfg, resume=resume, init=init, guard_data=guard_data or None)
    print(f'wrote {s["out"]}: {s["spec"]}, {s["epochs"]} epochs, {s["samples"]:,} samples in '
          f'{s["train_seconds"]:.0f} s; validation AUC {s["val_auc"]}, ECE {s["val_ece"]} '
          f'at temperature {s["temperature"]:.3f}, offset {s["offset"]:+.3f} '
          f'({s["calibration"]}); log {s["log"]}')


@app.command(help='Random search over the paper\'s architecture space, resumable from its '
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
    engine: Annotated[Engine, typer.Option(help=_ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=_ADDRESS_HELP)] = None,
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


@app.command(name='train-fleet',
             help='Many trainings at once, as processes here or as Ray tasks on a cluster: one '
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
    arch: Annotated[Optional[str], typer.Option(
        help='Network spec; default the shipped model\'s.', show_default=False)] = None,
    epochs: Annotated[int, typer.Option(help='Passes over the augmented training set.')] = 3,
    augment_copies: Annotated[int, typer.Option(
        help='Augmented samples of every scene per epoch.')] = 4,
    max_samples: Annotated[int, typer.Option(help='Cap on samples per epoch (0: none).')] = 0,
    cache_voxels: Annotated[int, typer.Option(
        help='Pre-voxelize this many augmented copies per scene once (0: on the fly).')] = 0,
    batch_size: Annotated[int, typer.Option(help='Samples per minibatch.')] = 20,
    lr: Annotated[float, typer.Option(help='SGD learning rate.')] = 0.01,
    seed: Annotated[int, typer.Option(help='Seed of the first member.')] = 0,
    checkpoint_minutes: Annotated[float, typer.Option(
        help='Save each training\'s state this often within an epoch.')] = 10.0,
    workers: Annotated[Optional[int], typer.Option(
        help='Trainings at once (processes, or the CPUs of a local Ray cluster); default one '
             'per core.', min=1)] = None,
    threads: Annotated[int, typer.Option(help='Torch threads of each training.', min=1)] = 1,
    engine: Annotated[Engine, typer.Option(help=_ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=_ADDRESS_HELP)] = None,
) -> None:
    from landing_zone.tools.engines import check_engine
    from landing_zone.judging.net import DEFAULT_SPEC
    from landing_zone.tools.learn.fleet import fleet_jobs, lofo_families, markdown_fleet
    from landing_zone.tools.learn.fleet import train_fleet as run_fleet
    from landing_zone.tools.learn.train import TrainConfig

    check_engine(engine.value, address)
    cfg = TrainConfig(arch=arch or DEFAULT_SPEC, epochs=epochs, augment_copies=augment_copies,
                      max_samples=max_samples, cache_voxels=cache_voxels,
                      batch_size=batch_size, lr=lr, seed=seed,
                      checkpoint_minutes=checkpoint_minutes)
    holds = lofo_families() if lofo else []
    holds += [h for h in hold_out or [] if h not in holds]
    jobs = fleet_jobs(cfg, holds, members=members, everything=everything)
    doc = run_fleet(data, out_dir, jobs, engine=engine.value, address=address,
                    workers=workers, threads=threads)
    print(markdown_fleet(doc), end='')
    print(f'{len(jobs)} model(s) in {out_dir} in {doc["seconds"]:.0f} s on {doc["engine"]}; '
          f'figures in {Path(out_dir) / "fleet.json"}')


class Split(str, Enum):
    test = 'test'
    train = 'train'


@app.command(help='ROC / AUC, calibration (ECE) and timing on a dataset split, for the CNN and '
                  'with --baselines the paper\'s baselines; the table like the paper\'s Table '
                  'II on stdout.\n\n'
                  'Examples:\n\n  landing-zone evaluate --data data/synth2 --model '
                  'model.safetensors --out-dir eval\n\n'
                  '  landing-zone evaluate --data data/synth2 --baselines --json results.json'
                  '\n\n  landing-zone evaluate --data data/synth2 --model a.safetensors --model '
                  'b.safetensors --baselines\n\n'
                  '  landing-zone evaluate --data data/synth3 --by-family --model '
                  'final.safetensors --model lofo_log.safetensors --json lofo.json')
def evaluate(
    data: Annotated[Path, typer.Option(help='Dataset directory.')],
    model: Annotated[Optional[list[Path]], typer.Option(
        help='Model file; repeat for more CNNs in one table; default the shipped one.')] = None,
    baselines: Annotated[bool, typer.Option(help='Also evaluate the baselines.')] = False,
    json_path: Annotated[Optional[Path], typer.Option(
        '--json', help='Write RESULTS.json here.')] = None,
    out_dir: Annotated[Optional[Path], typer.Option(
        help='Write table.md, ROC and reliability plots and the look inside here.')] = None,
    split: Annotated[Split, typer.Option(help='Dataset split.')] = Split.test,
    workers: Annotated[int, typer.Option(help='Voxelizing processes.')] = 0,
    fit_scenes: Annotated[int, typer.Option(
        help='Train scenes the baselines are fitted on.')] = 2000,
    max_scenes: Annotated[int, typer.Option(
        help='Evaluate an even subset of this many scenes (0: all).')] = 0,
    seed: Annotated[int, typer.Option(help='Seed of the baselines.')] = 0,
    by_family: Annotated[bool, typer.Option(
        help='synth3: the figures per obstacle, vegetation, terrain and sensor family, and '
             'the leave-one-family-out table (each family judged by a --model that never '
             'saw it).')] = False,
    scores: Annotated[Optional[Path], typer.Option(
        help='Write every scene\'s score by every method here (JSON: scene indices, labels, '
             'scores per method), for breakdowns by scene parameters.')] = None,
    guard: Annotated[bool, typer.Option(
        help='Judge every CNN as the assessor does: P(safe) capped where the guard finds '
             'opaque structure above the tile\'s ground plane (rows named "... + guard").')
    ] = False,
) -> None:
    from landing_zone.tools.evaluate.roc import evaluate as run_evaluate

    res = run_evaluate(data, model, baselines=baselines, json_path=json_path, out_dir=out_dir,
                       split=split.value, workers=workers, fit_scenes=fit_scenes,
                       max_scenes=max_scenes, seed=seed, by_family=by_family,
                       scores_path=scores, guard=guard)
    print(res['table'], end='')


@app.command(help='Fit a model\'s calibration on families it never saw: the logits of '
                  'leave-groups-out models (scripts/lofo.sh FOLDS=K) on the train scenes of the '
                  'families each held out, pooled; P(safe) = sigmoid(logit / T + b) fitted by '
                  'maximum likelihood and written into OUT (the weights unchanged). A model '
                  'fine-tuned from a calibrated one (train --init) has no fold models: --like '
                  'INITIAL carries the initial model\'s out-of-family correction over to it, '
                  'both nets fitted in family on the train scenes of --data (families both '
                  'trained on, instances neither saw).\n\n'
                  'Examples:\n\n  landing-zone calibrate --model runs/lofo/final.safetensors '
                  '--fold-model runs/lofo/fold0_of_4.safetensors --fold-model '
                  'runs/lofo/fold1_of_4.safetensors --data data/synth3 --out '
                  'models/landing_zone.safetensors\n\n'
                  '  landing-zone calibrate --model tuned.safetensors --like '
                  'models/landing_zone.safetensors --data data/synth3_fresh --out '
                  'tuned_cal.safetensors')
def calibrate(
    model: Annotated[Path, typer.Option(help='The model to calibrate.')],
    data: Annotated[Path, typer.Option(
        help='synth3 directory: the one the fold models were trained on; with --like, fresh '
             'scenes of families both models trained on.')],
    out: Annotated[Path, typer.Option(help='Model file to write (may be --model).')],
    fold_model: Annotated[Optional[list[Path]], typer.Option(
        help='A model trained with --hold-out; repeat for each fold.')] = None,
    like: Annotated[Optional[Path], typer.Option(
        help='The calibrated model --model was fine-tuned from (instead of --fold-model).')]
    = None,
    scenes: Annotated[int, typer.Option(
        help='At most this many scenes per fold model (with --like: in all).')] = 2000,
    offset: Annotated[bool, typer.Option(
        help='Fit an offset b beside the temperature (else b = 0; not with --like).')] = True,
    seed: Annotated[int, typer.Option(help='Which scenes.')] = 0,
    workers: Annotated[int, typer.Option(help='Voxelizing processes.')] = 0,
) -> None:
    from landing_zone.errors import ConfigError
    from landing_zone.tools.learn.recalibrate import calibrate as run_calibrate, calibrate_like

    if (like is None) == (not fold_model):
        raise ConfigError('give either --fold-model (one per fold) or --like INITIAL')
    if like is not None:
        if not offset:
            raise ConfigError('--like carries T and b over; --no-offset does not apply')
        s = calibrate_like(model, like, data, out, scenes=scenes, seed=seed, workers=workers,
                           progress=True)
        print(f'wrote {out}: T {s["temperature"]:.3f}, offset {s["offset"]:+.3f}, carried over '
              f'from {like} (in family on {s["n"]} scenes, {s["n_unsafe"]} unsafe: this model '
              f'T {s["in_family"]["model"]["temperature"]:.3f} b '
              f'{s["in_family"]["model"]["offset"]:+.3f}, the initial T '
              f'{s["in_family"]["initial"]["temperature"]:.3f} b '
              f'{s["in_family"]["initial"]["offset"]:+.3f})')
        return
    s = run_calibrate(model, fold_model or [], data, out, per_model=scenes, seed=seed,
                      offset=offset, workers=workers, progress=True)
    print(f'wrote {out}: T {s["temperature"]:.3f}, offset {s["offset"]:+.3f} fitted on {s["n"]} '
          f'out-of-family scenes ({s["n_unsafe"]} unsafe); there ECE '
          f'{s["out_of_family_ece"]["previous"]:.3f} -> {s["out_of_family_ece"]["fitted"]:.3f}, '
          f'obstacle scenes at P(safe) >= 0.5 '
          f'{100 * s["out_of_family_unsafe_ge_0.5"]["previous"]:.1f}% -> '
          f'{100 * s["out_of_family_unsafe_ge_0.5"]["fitted"]:.1f}%')


@app.command(help='One model file from trained members of one architecture: the mean of their '
                  'logits, judged as one net (landing_zone.judging.ensemble). Its metadata lists '
                  'the members and, as what it held out, the families no member trained on. '
                  'Calibrate it afterwards (calibrate, with ensembles of members that never saw '
                  'the families as --fold-model).\n\n'
                  'Example:\n\n  landing-zone ensemble --member runs/e/final.safetensors '
                  '--member runs/e/fold0_of_4.safetensors --member '
                  'runs/e/fold1_of_4.safetensors --out runs/e/ensemble.safetensors')
def ensemble(
    member: Annotated[list[Path], typer.Option(help='A member model; repeat for each.')],
    out: Annotated[Path, typer.Option(help='Ensemble model file to write.')],
) -> None:
    from landing_zone.tools.learn.ensembles import assemble

    meta = assemble(member, out)
    held = meta['training']['hold_out']
    print(f'wrote {out}: {meta["ensemble"]["members"]} members of {meta["model"]["spec"]}, '
          f'T {meta["temperature"]:.3f}, offset {meta["calibration_offset"]:+.3f}; no member '
          f'trained on: {", ".join(held) if held else "(none)"}')


# --- fit-ood ----------------------------------------------------------------------------------

@app.command(name='fit-ood',
             help='Fit the out-of-distribution reference of a model: the penultimate features '
                  'of tiles from the train split of its data, and the threshold (a quantile of '
                  'held-out scenes\' k-NN distance) past which a tile the model calls safe '
                  'becomes unknown. Write it as NAME.ood.safetensors beside NAME.safetensors '
                  'for the assessor to find it. Same seed, same bytes.\n\n'
                  'Example:\n\n'
                  '  landing-zone simulate --dataset synth2 --split train --scenes 1200 '
                  '--seed 1 --out data/s2ref\n\n'
                  '  landing-zone fit-ood --model models/landing_zone.safetensors --data '
                  'data/s2ref --out models/landing_zone.ood.safetensors --scenes 1200')
def fit_ood(
    model: Annotated[Path, typer.Option(help='Model file (.safetensors).')],
    data: Annotated[list[Path], typer.Option(
        help='Dataset directory; repeat for more (their train splits are pooled).')],
    out: Annotated[Path, typer.Option(help='Reference file (NAME.ood.safetensors).')],
    scenes: Annotated[int, typer.Option(
        help='Scenes to read, reference and held-out together.')] = 1000,
    held_out: Annotated[float, typer.Option(
        help='Share of the scenes that set the threshold, not in the reference.')] = 0.25,
    views: Annotated[int, typer.Option(help='Voxelizations of each scene at seeded yaws.')] = 3,
    seed: Annotated[int, typer.Option(help='Seed of the scene draw and the yaws.')] = 0,
    k: Annotated[int, typer.Option(help='The neighbour whose distance is the score.')] = 10,
    quantile: Annotated[float, typer.Option(
        help='Quantile [%] of the held-out distances taken as the threshold.')] = 99.5,
    quiet: Annotated[bool, typer.Option(help='No progress bar.')] = False,
) -> None:
    from landing_zone.tools.learn.ood_fit import fit_ood as run_fit

    res = run_fit(model, data, out, scenes=scenes, held_out=held_out, views=views, seed=seed,
                  k=k, quantile=quantile, progress=not quiet)
    ref = res.reference
    print(f'wrote {res.path}: {res.reference_tiles} reference tiles of {ref.dim} features '
          f'({res.path.stat().st_size / 1e6:.1f} MB), k {ref.k}, threshold {ref.threshold:.4f} '
          f'(the {ref.quantile:g}th percentile of {res.held_out_tiles} held-out tiles; '
          f'{res.held_out_past:.1%} of them past it), from {res.scenes} scenes in '
          f'{res.seconds:.0f} s')


@app.command(name='evaluate-flights',
             help='Replay recorded flights, each with its ground truth beside it '
                  '(SITE.labels.json for SITE.mcap, as simulate-flight writes it), and score '
                  'the final tiles per flight and pooled: AUC, ECE, the share of obstacle '
                  'tiles given P(safe) >= 0.5 and the share of labelled tiles unjudged. The '
                  'flights run in parallel, here or on a Ray cluster, with the same '
                  'figures.\n\n'
                  'Examples:\n\n  landing-zone evaluate-flights a.mcap b.mcap --json '
                  'flights.json\n\n'
                  '  landing-zone evaluate-flights flights/*.mcap --engine ray\n\n'
                  '  landing-zone evaluate-flights /shared/flights/*.mcap --engine ray '
                  '--address ray://head:10001 --model /shared/models/m.safetensors')
def evaluate_flights(
    bags: Annotated[list[Path], typer.Argument(
        help='Flight bags (.mcap, .db3 or directory; ROS 1 .bag), each with BAG.labels.json.')],
    engine: Annotated[Engine, typer.Option(help=_ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=_ADDRESS_HELP)] = None,
    json_path: Annotated[Optional[Path], typer.Option(
        '--json', help='Write the figures (per flight and pooled) here.')] = None,
    model: Annotated[Optional[Path], typer.Option(
        help='Model file; default the shipped one.')] = None,
    workers: Annotated[Optional[int], typer.Option(
        help='Processes, or the CPUs of a local Ray cluster; default one per core.', min=1)
    ] = None,
    points_topic: Annotated[str, typer.Option(
        help='PointCloud2 topic (fixed frame).')] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(
        help='PoseStamped topic of the sensor.')] = '/lidar/pose',
) -> None:
    from landing_zone.tools.evaluate.flights import evaluate_flights as run_flights, markdown_flights

    doc = run_flights(bags, engine=engine.value, address=address, workers=workers,
                      model=model, points_topic=points_topic, pose_topic=pose_topic,
                      json_path=json_path)
    print(markdown_flights(doc), end='')
    print(f'{len(doc["flights"])} flight(s) in {doc["seconds"]:.1f} s on {doc["engine"]} '
          f'({doc["workers"]} worker(s)): {doc["flights_per_s"]} flights/s'
          + (f'; wrote {json_path}' if json_path is not None else ''))


# --- simulate ---------------------------------------------------------------------------------

@app.command(help='Labelled training/test patches of the paper\'s Table I sweep (synth1: boxes, '
                  'synth2: rocks, tires, cinder blocks in grass), written as shards a rerun '
                  'resumes. Same seed, same bytes, whatever the number of workers.\n\n'
                  'hybrid: patches cut from recorded flights (--from, repeat for more; each with '
                  'BAG.labels.json beside it or a --region of clear ground), half of them with an '
                  'obstacle inserted by cutting short the rays that meet it; split by flight '
                  '(--test-from, or the last --from).\n\n'
                  'Examples:\n\n  landing-zone simulate --dataset synth2 --out data/synth2\n\n'
                  '  landing-zone simulate --dataset synth1 --out data/s1 --scenes 2000 '
                  '--workers 2 --seed 1\n\n'
                  '  landing-zone simulate --dataset synth2 --out data/s2test --split test\n\n'
                  '  landing-zone simulate --dataset hybrid --from a.mcap --from b.mcap '
                  '--test-from c.mcap --out data/hybrid --patches 500')
def simulate(
    dataset: Annotated[DatasetName, typer.Option(help='Which sweep of Table I, or hybrid.')],
    out: Annotated[Path, typer.Option(help='Output directory (a rerun resumes).')],
    scenes: Annotated[Optional[int], typer.Option(
        help='Subsample the sweep evenly to this many scenes; default all.')] = None,
    workers: Annotated[Optional[int], typer.Option(
        help='Processes; default one per core.')] = None,
    seed: Annotated[int, typer.Option(help='Seed of the dataset.')] = 0,
    split: Annotated[str, typer.Option(help='train, test or both.')] = 'both',
    quiet: Annotated[bool, typer.Option(help='No progress bar.')] = False,
    from_: Annotated[Optional[list[Path]], typer.Option(
        '--from', help='hybrid: a flight bag to cut patches from (repeat for more).')] = None,
    test_from: Annotated[Optional[list[Path]], typer.Option(
        help='hybrid: a flight whose patches form the test split (repeat for more).')] = None,
    patches: Annotated[int, typer.Option(help='hybrid: at most this many per flight.')] = 1000,
    region: Annotated[Optional[tuple[float, float, float, float]], typer.Option(
        help='hybrid: X0 Y0 X1 Y1, the clear area patches come from.')] = None,
    points_topic: Annotated[str, typer.Option(
        help='hybrid: PointCloud2 topic.')] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(help='hybrid: PoseStamped topic.')] = '/lidar/pose',
    engine: Annotated[Engine, typer.Option(
        help='Where the shards are simulated (same bytes either way). ' + _ENGINE_HELP)
    ] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=_ADDRESS_HELP)] = None,
    families: Annotated[Optional[str], typer.Option(
        help='synth3: draw obstacles from these families, comma separated (e.g. frame,mesh; '
             'all, train, test) instead of the 17 synth3 was made with; such a dataset shares '
             'no draw with the default one.')] = None,
    edge: Annotated[float, typer.Option(
        help='synth3: the share of twin pairs (0-1) whose obstacle stands at the tile\'s edge: '
             '5-30 cm in in the unsafe scene, 15-30 cm beyond it in the safe one (an obstacle '
             'in the next tile); such a dataset shares no draw with the default one.')] = 0.0,
    vegetation: Annotated[Optional[str], typer.Option(
        help='synth3: draw the vegetation from these families, comma separated (e.g. meadow, '
             'the continuous prior of blade layers; forb, broadleaf plants; canopy, leafy crowns; '
             'or uniform,lodged) instead of synth3\'s six; '
             'such a dataset shares no draw with the default one.')] = None,
) -> None:
    from landing_zone.tools.engines import check_engine
    from landing_zone.errors import ConfigError

    check_engine(engine.value, address)

    if dataset is DatasetName.hybrid:
        from landing_zone.tools.sim.hybrid import simulate_hybrid

        if not from_ and not test_from:
            raise ConfigError('--dataset hybrid needs the flights: --from BAG (repeat for more)')
        if engine is not Engine.local:
            raise ConfigError('--dataset hybrid runs on this machine only (--engine local)')
        if scenes is not None or split != 'both':
            raise ConfigError('--dataset hybrid takes --patches (per flight) and splits by '
                              'flight: not --scenes or --split')
        if families is not None or edge or vegetation is not None:
            # (synth1/synth2: simulate_dataset refuses them)
            raise ConfigError('--families, --edge and --vegetation are synth3 options; hybrid '
                              'inserts the library\'s obstacles into recorded ground')
        s = simulate_hybrid(from_ or [], out, test_flights=test_from or [], patches=patches,
                            seed=seed, region=region, points_topic=points_topic,
                            pose_topic=pose_topic, progress=not quiet)
    else:
        from landing_zone.tools.sim.dataset import simulate_dataset

        if from_ or test_from or region is not None:
            raise ConfigError('--from, --test-from and --region are for --dataset hybrid')
        from landing_zone.tools.sim.families import parse_families

        s = simulate_dataset(dataset.value, out, scenes=scenes, workers=workers, seed=seed,
                             split=split, progress=not quiet, engine=engine.value,
                             address=address,
                             families=None if families is None else parse_families(families),
                             edge=edge,
                             vegetation=None if vegetation is None else tuple(
                                 f.strip() for f in vegetation.split(',') if f.strip()))
    print(f'{s["dataset"]}: {s["scenes"]} scenes in {s["out"]} ({s["generated"]} simulated, '
          f'{s["skipped"]} already there) in {s["seconds"]:.1f} s with {s["workers"]} '
          f'worker(s){" on Ray" if engine is Engine.ray else ""}, {s["scenes_per_s"]:.1f} '
          f'scenes/s; {s["bytes"] / 1e6:.1f} MB')


_KINDS = 'rock,tire,cinder_block,box'


@app.command(name='simulate-flight',
             help='A flight over a simulated landing site (grass patches, obstacles) as a ROS 2 '
                  'bag: /lidar/points (PointCloud2) and /lidar/pose (PoseStamped) in frame map; '
                  'the ground truth goes to SITE.labels.json beside it.\n\n'
                  'Other vegetation and scanners than the training sets\' stand in for real '
                  'flights: --vegetation clumped (tussocks), tall (curving blades up to '
                  '0.45 m), bushy (shrubs of 0.2-0.4 m, vegetation: safe), mixed; --scan-pattern '
                  'spinning (16-beam) or rosette (Livox-like). The same seed keeps the ground, '
                  'obstacles and noise whatever the vegetation.\n\n'
                  'Examples:\n\n  landing-zone simulate-flight --out site.mcap\n\n'
                  '  landing-zone simulate-flight --out big.mcap --size 40 --obstacles 12 '
                  '--kinds rock,tire --grass-density 1200 --seed 3\n\n'
                  '  landing-zone simulate-flight --out v.mcap --vegetation mixed '
                  '--scan-pattern spinning --density 2000\n\n'
                  '  landing-zone simulate-flight --out f.mcap --families test --obstacles 8 '
                  '--vegetation lodged --slope 10 --scan-pattern elliptical --height 15')
def simulate_flight(
    out: Annotated[Path, typer.Option(help='SITE.mcap to write.')],
    size: Annotated[float, typer.Option(help='Edge of the square site [m].')] = 20.0,
    obstacles: Annotated[int, typer.Option(help='Number of obstacles.')] = 6,
    kinds: Annotated[Optional[str], typer.Option(
        help='Obstacle kinds of the library, comma separated (rock, tire, cinder_block, box) '
             '[default: all four, unless --families is given].')] = None,
    families: Annotated[Optional[str], typer.Option(
        help='Obstacle families, comma separated (rock, slab, rubble, log, stump, brush, box, '
             'crate, bucket, pipe, tire, cinder_block, post, cone, coil, pallet, sack, frame, '
             'mesh, hoop, assembly; or all, train, test): random test instances, cycled after '
             'the kinds.')] = None,
    vegetation: Annotated[str, typer.Option(
        help='Vegetation preset: default (the training sets\' grass), clumped, tall, bushy, '
             'mixed; or a vegetation family: uniform, tussock, lodged, layered, bare '
             '(gravel), shrub (synth3\'s six); the priors meadow (blade layers), forb '
             '(broadleaf plants), canopy (leafy crowns).')] = 'default',
    grass_density: Annotated[Optional[float], typer.Option(
        help='Blades per m^2 of a typical patch [default: 600].')] = None,
    grass_height: Annotated[Optional[float], typer.Option(
        help='Mean blade height [m] [default: the preset\'s, else 0.25].')] = None,
    clump_size: Annotated[Optional[float], typer.Option(
        help='Mean blades per tussock (0: independent blades) [default: the preset\'s].')
    ] = None,
    clump_radius: Annotated[Optional[float], typer.Option(
        help='Standard deviation of a blade from its tussock\'s centre [m].')] = None,
    lean: Annotated[Optional[float], typer.Option(
        help='Standard deviation of the blades\' lean from the vertical [deg].')] = None,
    max_grass_height: Annotated[Optional[float], typer.Option(
        help='No blade tip higher than this above its base [m].')] = None,
    bushes: Annotated[Optional[float], typer.Option(
        help='Shrubs per m^2 (0.2-0.4 m high, 0.3-0.6 m across).')] = None,
    scan_pattern: Annotated[str, typer.Option(
        help='Scanner: line (the default nodding line scanner), spinning (16 beams), '
             'rosette, elliptical (a nutating mirror\'s 40 degree cone).')] = 'line',
    height: Annotated[float, typer.Option(help='Flight height above the ground [m].')] = 8.0,
    slope: Annotated[float, typer.Option(
        help='The site lies on a plane this steep [deg].')] = 0.0,
    slope_azimuth: Annotated[float, typer.Option(
        help='... rising towards this direction [deg from x].')] = 0.0,
    roughness: Annotated[Optional[float], typer.Option(
        help='Amplitude of the ground\'s bumps [m] [default: 0.05].')] = None,
    tilt: Annotated[Optional[float], typer.Option(
        help='Forward tilt of the scan\'s centre from the nadir [deg] [default: 45, rosette '
             '20].')] = None,
    line_spacing: Annotated[Optional[float], typer.Option(
        help='Distance between passes [m] [default: from the scanner\'s swath].')] = None,
    density: Annotated[Optional[float], typer.Option(
        help='Target returns per m^2 (sets the speed) [default: 3000].')] = None,
    speed: Annotated[Optional[float], typer.Option(
        help='Flight speed [m/s]; default: the speed that gives the target density.')] = None,
    seed: Annotated[int, typer.Option(help='Seed of the site and the flight.')] = 0,
    overwrite: Annotated[bool, typer.Option(help='Replace existing outputs.')] = False,
) -> None:
    from landing_zone.tools.sim.flight import flight_config, simulate_flight as run_flight

    import math

    fams = tuple(f.strip() for f in (families or '').split(',') if f.strip())
    kinds_t = (tuple(k.strip() for k in kinds.split(',') if k.strip()) if kinds is not None
               else () if fams else tuple(_KINDS.split(',')))
    cfg = flight_config(vegetation, scan_pattern, density=density, size=size,
                        obstacles=obstacles, kinds=kinds_t, families=fams,
                        slope=slope, slope_azimuth=math.radians(slope_azimuth),
                        amplitude=roughness,
                        grass_density=grass_density, grass_height=grass_height,
                        clump_size=clump_size, clump_radius=clump_radius,
                        inclination_std=lean, max_height=max_grass_height,
                        bush_density=bushes, height=height, tilt=tilt,
                        line_spacing=line_spacing, speed=speed, seed=seed)
    r = run_flight(cfg, out, overwrite=overwrite)
    print(f'wrote {r.bag} ({r.clouds} clouds, {r.points:,} returns, {r.duration:.1f} s of '
          f'flight at {r.speed:.1f} m/s in {r.passes} pass(es), {r.density:.0f} returns/m^2 '
          f'over the site; vegetation {vegetation}, scan pattern {scan_pattern}) and '
          f'{r.labels} ({r.unsafe_tiles} of {r.tiles} tiles unsafe)')


@app.command(help='Side and top view of simulated returns coloured by what they hit (ground, '
                  'grass, obstacle): a scene of a dataset directory or a flight bag (with its '
                  'obstacles and unsafe tiles from SITE.labels.json); or the obstacle '
                  'library.\n\n'
                  'Examples:\n\n  landing-zone render site.mcap --out site.png\n\n'
                  '  landing-zone render data/synth2 --index 12 --split test --out scene.png\n\n'
                  '  landing-zone render library --out obstacles.png')
def render(
    source: Annotated[Path, typer.Argument(
        help='Dataset directory, SITE.mcap or the word library.')],
    out: Annotated[Path, typer.Option(help='PNG to write.')],
    index: Annotated[int, typer.Option(help='Scene of a dataset (within --split).')] = 0,
    split: Annotated[str, typer.Option(help='train, test or all.')] = 'all',
) -> None:
    from landing_zone.tools.sim.render import render as run_render

    print(f'wrote {run_render(source, out, index=index, split=split)}')


# --- demo -------------------------------------------------------------------------------------

@app.command(help='The main job on the embedded default: simulate a vegetated landing-site '
                  'flight, assess it with the shipped model, print the tile map, the AUC '
                  'against the ground truth, and write a PNG and a report.\n\n'
                  'Examples:\n\n  landing-zone demo\n\n'
                  '  landing-zone demo --out-dir /tmp/lz --seed 3\n\n'
                  '  landing-zone demo --families test  (obstacles the shipped model never '
                  'saw)')
def demo(
    out_dir: Annotated[Path, typer.Option(help='Where the bags, report and PNG go.')]
    = Path('lz_demo'),
    seed: Annotated[int, typer.Option(help='Seed of the simulated site and flight.')] = 0,
    model: Annotated[Optional[Path], typer.Option(
        help='Model file; default the shipped one.')] = None,
    families: Annotated[str, typer.Option(
        help='Obstacle families whose test instances join the site (comma separated; all, '
             'train, test; none for the library\'s six alone), one obstacle each. The default, '
             'the test families, the shipped model never trained on.')] = 'test',
) -> None:
    from landing_zone.tools.demo import run_demo
    from landing_zone.tools.sim.families import parse_families

    t0 = time.perf_counter()
    run_demo(out_dir, seed=seed, model=model,
             families=() if families == 'none' else parse_families(families))
    print(f'demo done in {time.perf_counter() - t0:.0f} s')


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning core errors into one line and exit 2."""
    try:
        app(args=argv, prog_name='landing-zone', standalone_mode=True)
    except LandingZoneError as err:
        print(f'landing-zone: error: {err}', file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print('landing-zone: interrupted', file=sys.stderr)
        sys.exit(130)


if __name__ == '__main__':
    main()
