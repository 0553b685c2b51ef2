"""Simulating: datasets of labelled patches (simulate), flights as bags (simulate-flight),
the sets of flights the product is judged on (simulate-flights) and pictures of what the
simulator made (render). The simulator (trimesh, embreex) is the `[sim]` extra, imported by
each command."""
from __future__ import annotations

import math
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer

from landing_zone.tools.cli.options import (ADDRESS_HELP, ENGINE_HELP, Engine, comma_list,
                                            obstacle_choice)

app = typer.Typer()


class DatasetName(str, Enum):
    synth1 = 'synth1'
    synth2 = 'synth2'
    synth3 = 'synth3'
    hybrid = 'hybrid'


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
        help='Where the shards are simulated (same bytes either way). ' + ENGINE_HELP)
    ] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=ADDRESS_HELP)] = None,
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
                             vegetation=None if vegetation is None else comma_list(vegetation))
    print(f'{s["dataset"]}: {s["scenes"]} scenes in {s["out"]} ({s["generated"]} simulated, '
          f'{s["skipped"]} already there) in {s["seconds"]:.1f} s with {s["workers"]} '
          f'worker(s){" on Ray" if engine is Engine.ray else ""}, {s["scenes_per_s"]:.1f} '
          f'scenes/s; {s["bytes"] / 1e6:.1f} MB')


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
    odometry: Annotated[bool, typer.Option(
        help='Write the flight as LiDAR-inertial odometry publishes it: nav_msgs/Odometry of '
             'a body frame and clouds in the body (or sensor) frame, the LiDAR mounted at '
             '--sensor-offset.')] = False,
    cloud_frame: Annotated[str, typer.Option(
        help='With --odometry: body or sensor.')] = 'body',
    sensor_offset: Annotated[Optional[tuple[float, float, float, float, float, float]],
                             typer.Option(metavar='X Y Z ROLL PITCH YAW', help=(
                                 'With --odometry: the LiDAR\'s pose in the body frame [m, '
                                 'rad]; default a small, non-zero mount.'))] = None,
) -> None:
    from landing_zone.tools.sim.flight import flight_config, simulate_flight as run_flight
    from landing_zone.tools.sim.placement import DEFAULT_KINDS

    kinds_t, fams = obstacle_choice(kinds, families, DEFAULT_KINDS)
    cfg = flight_config(vegetation, scan_pattern, density=density, size=size,
                        obstacles=obstacles, kinds=kinds_t, families=fams,
                        slope=slope, slope_azimuth=math.radians(slope_azimuth),
                        amplitude=roughness,
                        grass_density=grass_density, grass_height=grass_height,
                        clump_size=clump_size, clump_radius=clump_radius,
                        inclination_std=lean, max_height=max_grass_height,
                        bush_density=bushes, height=height, tilt=tilt,
                        line_spacing=line_spacing, speed=speed, seed=seed)
    if odometry:
        _odometry_flight(cfg, out, cloud_frame, sensor_offset, overwrite)
        return
    r = run_flight(cfg, out, overwrite=overwrite)
    print(f'wrote {r.bag} ({r.clouds} clouds, {r.points:,} returns, {r.duration:.1f} s of '
          f'flight at {r.speed:.1f} m/s in {r.passes} pass(es), {r.density:.0f} returns/m^2 '
          f'over the site; vegetation {vegetation}, scan pattern {scan_pattern}) and '
          f'{r.labels} ({r.unsafe_tiles} of {r.tiles} tiles unsafe)')


def _odometry_flight(cfg: object, out: Path, cloud_frame: str,
                     sensor_offset: Optional[tuple[float, ...]], overwrite: bool) -> None:
    from landing_zone.tools.sim.odometry_flight import DEFAULT_OFFSET, simulate_odometry_flight

    if cloud_frame not in ('body', 'sensor'):
        raise typer.BadParameter(f'body or sensor, got {cloud_frame!r}',
                                 param_hint='--cloud-frame')
    r, odo = simulate_odometry_flight(cfg, out, cloud_frame=cloud_frame, overwrite=overwrite,
                                      sensor_offset=sensor_offset or DEFAULT_OFFSET)
    print(f'wrote {odo.bag} ({r.clouds} clouds, {r.points:,} returns, odometry on '
          f'{odo.pose_topic}, clouds in the {odo.cloud_frame} frame on {odo.points_topic}) and '
          f'{r.labels}; replay it with: landing-zone replay {odo.bag} '
          + ' '.join(odo.replay_args()))


class FlightSet(str, Enum):
    heldout = 'heldout'
    development = 'development'


@app.command(name='simulate-flights',
             help='A set of flights, one obstacle family and one vegetation each, with their '
                  'ground truth, for evaluate-flights. heldout: obstacle families and '
                  'vegetation no shipped training saw (the yardstick: never tune on it, and '
                  'publish from a fresh seed); development: the training families, for tuning '
                  'what comes after the network. Scan pattern, height, density, slope and '
                  'roughness are drawn from the seed. Flights already in OUT are kept, so an '
                  'interrupted run resumes.\n\n'
                  'Examples:\n\n  landing-zone simulate-flights --set heldout --seed 7 --out '
                  'heldout\n\n  landing-zone evaluate-flights heldout/*.mcap --json '
                  'heldout.json')
def simulate_flights(
    out: Annotated[Path, typer.Option(help='Directory of the set.')],
    set_name: Annotated[FlightSet, typer.Option('--set', help='Which set.')] = FlightSet.heldout,
    seed: Annotated[int, typer.Option(help='Seed of the set.')] = 0,
    repeats: Annotated[int, typer.Option(
        help='Flights of each obstacle family and vegetation.')] = 2,
    workers: Annotated[Optional[int], typer.Option(
        help='Processes (default: one per core).')] = None,
    engine: Annotated[Engine, typer.Option(help=ENGINE_HELP)] = Engine.local,
    address: Annotated[Optional[str], typer.Option(help=ADDRESS_HELP)] = None,
) -> None:
    from landing_zone.tools.sim.flight_sets import simulate_set

    bags = simulate_set(set_name.value, seed, out, repeats=repeats, workers=workers,
                        engine=engine.value, address=address)
    print(f'{len(bags)} flights of the {set_name.value} set (seed {seed}) in {out}; score '
          f'them with: landing-zone evaluate-flights {out}/*.mcap')


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
