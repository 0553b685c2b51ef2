"""``python -m landing_zone.sim``: the simulator's commands without typer.

The dataset machine has only numpy, scipy, numba, trimesh and embreex, so the dataset command
is parsed here with argparse and imports nothing else (``landing-zone simulate`` is the same
command behind the project's typer CLI)::

    python -m landing_zone.sim simulate --dataset synth2 --out data/synth2 --workers 16
    python -m landing_zone.sim simulate --dataset synth3 --split train --out data/synth3
    python -m landing_zone.sim simulate --dataset hybrid --from a.mcap b.mcap --out data/hybrid
    python -m landing_zone.sim simulate-flight --out site.mcap        (needs rosbags)
    python -m landing_zone.sim simulate-flight --out v.mcap --vegetation clumped \
        --scan-pattern spinning
    python -m landing_zone.sim render data/synth2 --out patch.png     (needs matplotlib)

Errors on bad input print one line and exit with status 2.
"""
from __future__ import annotations

import argparse
import json
import sys

from landing_zone.errors import LandingZoneError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m landing_zone.sim',
                                description='LiDAR simulator: datasets, flights, pictures.')
    sub = p.add_subparsers(dest='command', required=True)
    s = sub.add_parser('simulate', help="labelled patches of the paper's Table I sweep")
    s.add_argument('--dataset', required=True, choices=('synth1', 'synth2', 'synth3', 'hybrid'))
    s.add_argument('--out', required=True, help='output directory (a rerun resumes)')
    s.add_argument('--scenes', type=int, default=None, help='subsample the sweep evenly')
    s.add_argument('--workers', type=int, default=None, help='processes (default: all cores)')
    s.add_argument('--seed', type=int, default=0)
    s.add_argument('--split', default='both', choices=('train', 'test', 'both'))
    s.add_argument('--quiet', action='store_true', help='no progress bar')
    s.add_argument('--from', dest='from_', nargs='+', action='extend', default=[],
                   metavar='BAG', help='hybrid: flights to cut patches from (needs rosbags)')
    s.add_argument('--test-from', nargs='+', action='extend', default=[], metavar='BAG',
                   help='hybrid: flights whose patches form the test split')
    s.add_argument('--patches', type=int, default=1000, help='hybrid: at most per flight')
    s.add_argument('--region', type=float, nargs=4, default=None,
                   metavar=('X0', 'Y0', 'X1', 'Y1'), help='hybrid: the clear area')
    s.add_argument('--points-topic', default='/lidar/points')
    s.add_argument('--pose-topic', default='/lidar/pose')
    f = sub.add_parser('simulate-flight', help='a flight over a site as a ROS 2 bag')
    f.add_argument('--out', required=True, help='SITE.mcap (labels go to SITE.labels.json)')
    f.add_argument('--size', type=float, default=20.0)
    f.add_argument('--obstacles', type=int, default=6)
    f.add_argument('--kinds', default=None,
                   help='library kinds (default rock,tire,cinder_block,box unless --families)')
    f.add_argument('--families', default=None,
                   help='obstacle families, comma separated (or all, train, test)')
    f.add_argument('--vegetation', default='default',
                   help='default, clumped, tall, bushy or mixed; or a vegetation family: '
                        'uniform, tussock, lodged, layered, bare, shrub')
    f.add_argument('--grass-density', type=float, default=None, help='default 600')
    f.add_argument('--grass-height', type=float, default=None,
                   help="default: the preset's, else 0.25")
    f.add_argument('--clump-size', type=float, default=None)
    f.add_argument('--clump-radius', type=float, default=None)
    f.add_argument('--lean', type=float, default=None, help='blade lean std [deg]')
    f.add_argument('--max-grass-height', type=float, default=None)
    f.add_argument('--bushes', type=float, default=None, help='shrubs per m^2')
    f.add_argument('--scan-pattern', default='line',
                   help='line, spinning, rosette or elliptical')
    f.add_argument('--height', type=float, default=8.0)
    f.add_argument('--slope', type=float, default=0.0, help='site slope [deg]')
    f.add_argument('--slope-azimuth', type=float, default=0.0, help='rising towards [deg]')
    f.add_argument('--roughness', type=float, default=None, help='ground bumps [m]')
    f.add_argument('--tilt', type=float, default=None)
    f.add_argument('--line-spacing', type=float, default=None)
    f.add_argument('--density', type=float, default=None, help='target returns per m^2')
    f.add_argument('--speed', type=float, default=None)
    f.add_argument('--seed', type=int, default=0)
    f.add_argument('--overwrite', action='store_true')
    r = sub.add_parser('render', help='side and top view of a patch, dataset scene or flight')
    r.add_argument('source', help='dataset directory or SITE.mcap')
    r.add_argument('--out', required=True, help='PNG file')
    r.add_argument('--index', type=int, default=0, help='scene of a dataset')
    r.add_argument('--split', default='all', choices=('train', 'test', 'all'))
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == 'simulate' and args.dataset == 'hybrid':
            from landing_zone.sim.hybrid import simulate_hybrid
            if not args.from_ and not args.test_from:
                raise LandingZoneError('--dataset hybrid needs the flights: --from BAG [BAG ...]')
            summary = simulate_hybrid(args.from_, args.out, test_flights=args.test_from,
                                      patches=args.patches, seed=args.seed, region=args.region,
                                      points_topic=args.points_topic,
                                      pose_topic=args.pose_topic, progress=not args.quiet)
            print(json.dumps(summary, indent=1))
        elif args.command == 'simulate':
            from landing_zone.sim.dataset import simulate_dataset
            summary = simulate_dataset(args.dataset, args.out, scenes=args.scenes,
                                       workers=args.workers, seed=args.seed, split=args.split,
                                       progress=not args.quiet)
            print(json.dumps(summary, indent=1))
        elif args.command == 'simulate-flight':
            import math

            from landing_zone.sim.flight import flight_config, simulate_flight
            fams = tuple(f.strip() for f in (args.families or '').split(',') if f.strip())
            kinds = (tuple(k.strip() for k in args.kinds.split(',') if k.strip())
                     if args.kinds is not None else () if fams
                     else ('rock', 'tire', 'cinder_block', 'box'))
            cfg = flight_config(args.vegetation, args.scan_pattern, density=args.density,
                                size=args.size, obstacles=args.obstacles, kinds=kinds,
                                families=fams, slope=args.slope,
                                slope_azimuth=math.radians(args.slope_azimuth),
                                amplitude=args.roughness,
                                grass_density=args.grass_density,
                                grass_height=args.grass_height, clump_size=args.clump_size,
                                clump_radius=args.clump_radius, inclination_std=args.lean,
                                max_height=args.max_grass_height, bush_density=args.bushes,
                                height=args.height, tilt=args.tilt,
                                line_spacing=args.line_spacing, speed=args.speed,
                                seed=args.seed)
            print(json.dumps(simulate_flight(cfg, args.out, overwrite=args.overwrite).summary(),
                             indent=1))
        else:
            from landing_zone.sim.render import render
            print(render(args.source, args.out, index=args.index, split=args.split))
    except LandingZoneError as err:
        print(f'landing-zone: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('landing-zone: interrupted (rerun the same command to resume)', file=sys.stderr)
        return 130
    return 0


if __name__ == '__main__':
    sys.exit(main())
