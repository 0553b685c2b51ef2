"""Running the pipeline: demo (simulate, assess, show), replay (a recorded bag offline) and
play (a bag over ROS 2, for the live node). `replay` needs only the robot's install."""
from __future__ import annotations

import time
from enum import Enum
from pathlib import Path
from collections.abc import Callable
from typing import Annotated, Optional

import typer

from landing_zone.ros.play import WAIT_SUBSCRIBERS
from landing_zone.tools.cli.options import POINTS_HELP, POSE_HELP

app = typer.Typer()


class Reliability(str, Enum):
    reliable = 'reliable'
    best_effort = 'best_effort'


class CloudFrame(str, Enum):
    fixed = 'fixed'
    body = 'body'
    sensor = 'sensor'


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


@app.command(help='Run the node\'s pipeline offline on a recorded bag: the node\'s output topics '
                  'go into OUT.mcap at the stamps it would have published them, the final '
                  'tiles into REPORT.json, the final map into a PNG; each only when asked for.'
                  '\n\n'
                  'Examples:\n\n  landing-zone replay site.mcap --out assessed.mcap '
                  '--report report.json\n\n'
                  '  landing-zone replay site.mcap --png map.png\n\n'
                  '  landing-zone replay flight.bag --out a.mcap --report r.json '
                  '--points-topic /velodyne_points --pose-topic /pose --png map.png\n\n'
                  '  landing-zone replay site.mcap --report r.json --center 10 -4'
                  '\n\nA survey file (.las / .laz) replays too, with its sensor trajectory '
                  '(--trajectory t,x,y,z CSV or SBET, in the file\'s CRS); without one the '
                  'sensor origins are derived from per-point GPS time and scan angle, assuming '
                  'each flight line straight, level, at constant speed and scanned across the '
                  'track (scan angle from nadir, positive to the side that puts the sensor above '
                  'its returns). Coordinates are kept '
                  'in float64 around a local origin the report states (survey.origin); '
                  '--center is then in the file\'s CRS and units.\n\n'
                  '  landing-zone replay autzen_trim.laz --report r.json')
def replay(
    bag: Annotated[Path, typer.Argument(
        help='ROS 2 bag (.mcap, .db3 or directory), ROS 1 .bag with the clouds and poses, or '
             'a LAS / LAZ survey.')],
    out: Annotated[Optional[Path], typer.Option(
        help='Output bag of the node\'s topics (.mcap).')] = None,
    report: Annotated[Optional[Path], typer.Option(
        help='REPORT.json with the final tiles and sites.')] = None,
    points_topic: Annotated[str, typer.Option(help=POINTS_HELP)] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(help=POSE_HELP)] = '/lidar/pose',
    model: Annotated[Optional[Path], typer.Option(
        help='Model file; default the shipped one.')] = None,
    center: Annotated[Optional[tuple[float, float]], typer.Option(
        help='X Y of a fixed region of interest; default: the map follows the sensor.')] = None,
    png: Annotated[Optional[Path], typer.Option(
        help='PNG of the final safety map (needs matplotlib).')] = None,
    params: Annotated[Optional[Path], typer.Option(
        help='ROS 2 parameters file (config/assessor.yaml layout) for the pipeline.')] = None,
    labels: Annotated[Optional[Path], typer.Option(
        help='SITE.labels.json: mark the true obstacles in the PNG.')] = None,
    trajectory: Annotated[Optional[Path], typer.Option(
        help='LAS / LAZ only: sensor positions over time, CSV t,x,y,z or SBET; default: '
             'derived from GPS time and scan angle.')] = None,
    cloud_frame: Annotated[Optional[CloudFrame], typer.Option(
        help='Where the returns are: fixed (registered in the pose\'s frame), body (in the '
             'pose\'s child frame) or sensor (in the LiDAR\'s own frame); default: the '
             'parameters\' cloud_frame (fixed).')] = None,
    sensor_offset: Annotated[Optional[tuple[float, float, float, float, float, float]],
                             typer.Option(metavar='X Y Z ROLL PITCH YAW', help=(
                                 'The LiDAR\'s pose in the pose input\'s frame [m, rad]; '
                                 'default: the parameters\' sensor_offset (zeros).'))] = None,
) -> None:
    from landing_zone.config import configs_from_flat
    from landing_zone.io.params import read_params_file
    from landing_zone.judging.ood import REASON_OOD
    from landing_zone.replay import replay as run_replay

    render_png = _png_renderer() if png is not None else None
    config = stream_config = None
    if params is not None:
        config, stream_config, _ = configs_from_flat(read_params_file(params))
    result = run_replay(bag, out, report, points_topic=points_topic, pose_topic=pose_topic,
                        model=model, center=center, config=config,
                        stream_config=stream_config, trajectory=trajectory,
                        cloud_frame=None if cloud_frame is None else cloud_frame.value,
                        sensor_offset=sensor_offset,
                        log=lambda line: print(f'note: {line}'))
    if render_png is not None:
        render_png(result.assessment, result.top_view, png, labels=labels)
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
    written = [str(p) for p in (out, report, png) if p is not None]
    print(f'wrote {", ".join(written)}' if written else 'wrote nothing (no --out, --report '
          'or --png)')


def _png_renderer() -> Callable[..., None]:
    """The PNG renderer, refused before any work where matplotlib (not the robot's) is absent."""
    from landing_zone.errors import ConfigError

    try:
        import matplotlib  # noqa: F401
    except ModuleNotFoundError:
        raise ConfigError('--png draws with matplotlib: pip install matplotlib (or '
                          '\'landing_zone[sim]\')') from None
    from landing_zone.tools.map_png import render_png
    return render_png


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
        help='Wait up to this many seconds for a subscriber on every topic first (0: start at '
             'once).', min=0.0)] = WAIT_SUBSCRIBERS,
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
