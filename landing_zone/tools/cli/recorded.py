"""Recorded flights: virtual obstacles inserted into a flight's returns (insert-obstacles). The
simulator's obstacles and ray casting (trimesh, embreex: the `[sim]` extra) are imported by the
command."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from landing_zone.tools.cli.options import POINTS_HELP, POSE_HELP, obstacle_choice

app = typer.Typer()


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
    points_topic: Annotated[str, typer.Option(help=POINTS_HELP)] = '/lidar/points',
    pose_topic: Annotated[str, typer.Option(help=POSE_HELP)] = '/lidar/pose',
    frame_id: Annotated[str, typer.Option(help='The fixed frame of clouds and poses.')] = 'map',
    overwrite: Annotated[bool, typer.Option(help='Replace existing outputs.')] = False,
) -> None:
    from landing_zone.tools.sim.insert import DEFAULT_KINDS, insert_obstacles as run_insert

    kinds_t, fams = obstacle_choice(kinds, families, DEFAULT_KINDS)
    r = run_insert(bag, out, count=count, seed=seed, kinds=kinds_t, families=fams, group=group,
                   region=region, labels=labels, points_topic=points_topic,
                   pose_topic=pose_topic, frame_id=frame_id, range_sigma=range_noise,
                   overwrite=overwrite)
    names = ', '.join(f'{o.model.name} at ({o.x:.1f}, {o.y:.1f})' for o in r.obstacles)
    print(f'inserted {len(r.obstacles)} obstacle(s): {names}')
    print(f'{r.altered:,} of {r.returns:,} returns moved onto them, in {r.altered_clouds} of '
          f'{r.clouds} clouds ({r.skipped_clouds} left as they were: no pose or other frame); '
          f'{r.messages} messages in {r.seconds:.1f} s')
    print(f'wrote {r.bag}, {r.labels}')
