"""Which obstacles the network passes: the obstacle scenes of synth3 split by what they are.

Reads the per-scene scores ``landing-zone evaluate --scores`` writes (one tile per scene, the
same voxelization and scoring as ``evaluate --by-family``) and the scenes' parameters, and
gives, pooled over the obstacle families, the share of **obstacle scenes** judged at
P(safe) >= 0.5 and >= 0.9 by:

* exposed height above the ground: the obstacle's height less its burial
  (``obstacle.size[2] - obstacle.embed``), in bands of 10-15, 15-30, 30-60 cm (and below /
  above where there are any);
* burial (``obstacle.embed``): below 1, 1-3, 3 cm and more;
* hidden in vegetation or not (``hide``: the vegetation raised to 0.6-1.1 x the exposed
  height around it);
* placement: wholly inside the tile, or straddling its edge with half its radius inside;
* vegetation family, terrain family, scan pattern, density band (returns/m^2 the scan gave),
  sensor height band;
* the evidence inside the tile, from the returns labelled by what they hit: how many returns
  the obstacle gave inside the tile's column (bands 1, 5, 20, 100), and the height of its part
  there (the 95th percentile of those returns above a plane fitted to the ground returns
  within a tile's width around the tile; bands 5, 10, 15, 30 cm).

Every row is given for all obstacle scenes and for those exposed 15 cm or more (issue 15's bar
is about solid obstacles of 15-50 cm, even hidden in grass). With ``--lofo RESULTS.json``
(``evaluate --by-family --json`` of the same run) each scene is scored instead by the model
that never saw its obstacle family (the 'lofo' table's model), as the headline table is; with
``--lofo-axis vegetation``, by the model that never saw its vegetation family.
``--vegetation F...`` keeps the scenes in those vegetation families. ``--matched F1 F2`` judges at
the thresholds that flag those shares of the safe scenes instead of at 0.5 and 0.9: the ranking
of models calibrated differently, side by side::

    landing-zone evaluate --data DIR --by-family --model M [--model FOLD...] \\
        --json results.json --scores scores.json
    python scripts/pass_breakdown.py DIR scores.json [--method NAME | --lofo results.json \\
        [--lofo-axis vegetation]] [--families F... | --exclude F...] [--vegetation F...] \\
        [--max-height M] [--matched F1 F2] [--json breakdown.json]
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from landing_zone.config import TileConfig
from landing_zone.tools.sim.mesh import GROUND, OBSTACLE

HEIGHT_BANDS = (0.10, 0.15, 0.30, 0.60)  # [m] exposed height band edges
BURIAL_BANDS = (0.01, 0.03)  # [m]; synth3 test obstacles are buried 0-9 cm, a quarter < 0.5 cm
DENSITY_BANDS = (1700.0, 2900.0)  # [returns/m^2] log-thirds of synth3's 1000-5000
SENSOR_HEIGHT_BANDS = (8.0, 12.0, 16.0)  # [m] of synth3's 4-20
BAR_HEIGHT = 0.15  # [m] issue 15's bar starts at obstacles of 15 cm
EVIDENCE_BANDS = (1.0, 5.0, 20.0, 100.0)  # obstacle returns inside the tile's column
INTRUSION_BANDS = (0.05, 0.10, 0.15, 0.30)  # [m] top of the obstacle's part inside the tile


def band(v: float, edges: tuple[float, ...], unit: Callable[[float], str]) -> str:
    """The band of ``v``: 'a-b', '< first' or '>= last' (edges ascending)."""
    if v < edges[0]:
        return f'< {unit(edges[0])}'
    for lo, hi in zip(edges[:-1], edges[1:]):
        if v < hi:
            return f'{unit(lo)}-{unit(hi)}'
    return f'>= {unit(edges[-1])}'


def exposed_height(params: dict[str, Any]) -> float:
    ob = params['obstacle']
    return float(ob['size'][2]) - float(ob.get('embed', 0.0))


def in_tile(points: np.ndarray, hit_class: np.ndarray,
            tile_size: float = TileConfig().tile_size) -> tuple[int, float]:
    """The obstacle's returns inside the tile's column (the tile centred at the origin), and
    the top of that part above the ground: the 95th percentile of their heights over a plane
    fitted by least squares to the ground returns within a tile's width around the tile (the
    scene's own z where there are fewer than 3); (0, 0.0) where it gave none."""
    half = 0.5 * tile_size
    inside = (np.abs(points[:, 0]) <= half) & (np.abs(points[:, 1]) <= half)
    near = (np.abs(points[:, 0]) <= 2 * half) & (np.abs(points[:, 1]) <= 2 * half)
    ob = points[inside & (hit_class == OBSTACLE)]
    if not len(ob):
        return 0, 0.0
    ground = points[near & (hit_class == GROUND)]
    plane = np.zeros(3)
    if len(ground) >= 3:
        a = np.c_[ground[:, :2], np.ones(len(ground))]
        plane = np.linalg.lstsq(a, ground[:, 2], rcond=None)[0]
    h = ob[:, 2] - (ob[:, :2] @ plane[:2] + plane[2])
    return len(ob), float(np.quantile(h, 0.95))


def groups(params: dict[str, Any], evidence: tuple[int, float] | None = None
           ) -> dict[str, str]:
    """The scene's group on every axis of the breakdown (the evidence axes with
    ``evidence``, :func:`in_tile`'s)."""
    cm = (lambda m: f'{round(100 * m)} cm')
    s = params['sensor']
    extra = {} if evidence is None else {
        'obstacle returns in the tile': band(float(evidence[0]), EVIDENCE_BANDS,
                                             lambda v: f'{v:.0f}'),
        'height of its part in the tile': band(evidence[1], INTRUSION_BANDS, cm)}
    return {
        'exposed height': band(exposed_height(params), HEIGHT_BANDS, cm),
        'burial': band(float(params['obstacle'].get('embed', 0.0)), BURIAL_BANDS, cm),
        'hidden in vegetation': 'hidden' if params.get('hide') is not None else 'not hidden',
        'placement': 'inside the tile' if params.get('inside') else 'straddling the edge',
        'vegetation': params['vegetation']['family'],
        'terrain': params['terrain']['family'],
        'scan pattern': s['family'],
        'density [returns/m^2]': band(float(params['density']), DENSITY_BANDS,
                                      lambda v: f'{v:.0f}'),
        'sensor height': band(float(s['height']), SENSOR_HEIGHT_BANDS, lambda v: f'{v:.0f} m'),
        **extra,
    }


THRESHOLDS = (0.5, 0.9)  # P(safe) from which an obstacle scene counts as passed (confidently)


def shares(p: np.ndarray, at: tuple[float, float] = THRESHOLDS) -> dict[str, Any]:
    """How many scores ``p``, and the shares of them at or above the thresholds ``at``
    (keyed 'ge_0.5' and 'ge_0.9' whatever ``at`` is: the first and the second threshold)."""
    return {'n': int(len(p)),
            'ge_0.5': float(np.mean(p >= at[0])) if len(p) else None,
            'ge_0.9': float(np.mean(p >= at[1])) if len(p) else None}


def breakdown(p: np.ndarray, rows: list[dict[str, str]], tall: np.ndarray,
              at: tuple[float, float] = THRESHOLDS) -> dict[str, Any]:
    """Per axis and group: the shares of all obstacle scenes and of those exposed >= 15 cm
    at or above the thresholds ``at``."""
    out: dict[str, Any] = {'all': {'all': {'all': shares(p, at),
                                           'exposed >= 15 cm': shares(p[tall], at)}}}
    for axis in rows[0]:
        names = np.array([r[axis] for r in rows], dtype=object)
        out[axis] = {}
        for g in sorted(set(names), key=_order):
            sel = names == g
            out[axis][g] = {'all': shares(p[sel], at),
                            'exposed >= 15 cm': shares(p[sel & tall], at)}
    return out


def _order(g: str) -> tuple[float, str]:
    """Bands by their lower edge ('< x' first), names alphabetically."""
    head = g.split()[0].split('-')[0]
    if g.startswith('<'):
        return (-math.inf, g)
    if g.startswith('>='):
        return (math.inf, g)
    try:
        return (float(head), g)
    except ValueError:
        return (0.0, g)


def markdown(report: dict[str, Any], heads: tuple[str, str] = ('P(safe) >= 0.5', '>= 0.9')
             ) -> str:
    def pct(v: float | None) -> str:
        return '-' if v is None else f'{100 * v:.1f} %'

    lines = [f'| group | obstacle scenes | {heads[0]} | {heads[1]} | of them exposed >= 15 cm '
             f'| {heads[0]} | {heads[1]} |', '|---|---:|---:|---:|---:|---:|---:|']
    for axis, per in report.items():
        for g, v in per.items():
            a, t = v['all'], v['exposed >= 15 cm']
            name = 'all' if axis == 'all' else f'{axis}: {g}'
            lines.append(f'| {name} | {a["n"]} | {pct(a["ge_0.5"])} | {pct(a["ge_0.9"])} | '
                         f'{t["n"]} | {pct(t["ge_0.5"])} | {pct(t["ge_0.9"])} |')
    return '\n'.join(lines) + '\n'


def main() -> None:
    from landing_zone.tools.evaluate.lofo import lofo_scores
    from landing_zone.tools.sim.shards import SceneDataset
    from landing_zone.tools.sim.synth3 import families_of

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data', type=Path, help='the synth3 directory the scores were made on')
    ap.add_argument('scores', type=Path, help='landing-zone evaluate --scores output')
    ap.add_argument('--method', default=None,
                    help='the scores of this method (default: the first)')
    ap.add_argument('--lofo', type=Path, default=None,
                    help='evaluate --by-family --json of the same run: score each scene by '
                         'the model that never saw its obstacle family')
    ap.add_argument('--lofo-axis', choices=('obstacle', 'vegetation'), default='obstacle',
                    help='with --lofo: the axis whose held-out model scores a scene (vegetation: '
                         'the model that never saw its vegetation family)')
    ap.add_argument('--families', nargs='*', default=None,
                    help='only these obstacle families (default: all)')
    ap.add_argument('--vegetation', nargs='*', default=None,
                    help='only scenes in these vegetation families (default: all)')
    ap.add_argument('--exclude', nargs='*', default=(),
                    help='leave these obstacle families out (e.g. coil: see-through, not solid)')
    ap.add_argument('--max-height', type=float, default=math.inf,
                    help='only obstacles exposed less than this [m] (0.5: the bar\'s 15-50 cm)')
    ap.add_argument('--matched', type=float, nargs=2, default=None, metavar=('F1', 'F2'),
                    help='judge at the thresholds that flag these shares of the safe scenes '
                         '(e.g. 0.05 0.2) instead of at P(safe) 0.5 and 0.9: the ranking of '
                         'models calibrated differently, compared at matched false alarms')
    ap.add_argument('--json', type=Path, default=None)
    args = ap.parse_args()
    if args.matched is not None and args.lofo is not None:
        raise SystemExit('pass_breakdown: --matched takes the scores of one method, not --lofo')
    doc = json.loads(args.scores.read_text())
    ds = SceneDataset(args.data, doc['split'])
    scenes = np.asarray(doc['scenes'], np.int64)
    labels = np.asarray(doc['labels'], np.int64)
    methods = doc['methods']
    # each obstacle scene read once: its params and the evidence in its tile (not its returns)
    params: list[dict[str, Any] | None] = [None] * len(scenes)
    evidence: list[tuple[int, float] | None] = [None] * len(scenes)
    for k, (i, y) in enumerate(zip(scenes, labels)):
        if y == 0:
            scene = ds[int(i)]
            params[k] = scene.params
            if scene.hit_class is not None:
                evidence[k] = in_tile(scene.points, scene.hit_class)
    keep = [k for k, (y, q) in enumerate(zip(labels, params))
            if y == 0 and (args.families is None or q['family'] in args.families)
            and q['family'] not in args.exclude and exposed_height(q) < args.max_height
            and (args.vegetation is None
                 or families_of(q)['vegetation'] in args.vegetation)]
    if args.lofo is not None:
        axis = args.lofo_axis
        table = json.loads(args.lofo.read_text())['families']['lofo'].get(axis, {})
        fams = np.array([families_of(params[k])[axis] for k in keep], dtype=object)
        missing = sorted(set(fams) - set(table))
        if missing:
            raise SystemExit(f'{args.lofo}: no model held out {axis} {", ".join(missing)}')
        p = lofo_scores(table, fams, {m: np.asarray(v)[keep] for m, v in methods.items()})
        scored_by = f'per {axis} family, the model that never saw it'
    else:
        name = args.method or next(iter(methods))
        if name not in methods:
            raise SystemExit(f'{args.scores}: no method {name!r}; there are '
                             f'{", ".join(methods)}')
        p = np.asarray(methods[name], np.float64)[keep]
        scored_by = name
    at, heads = THRESHOLDS, ('P(safe) >= 0.5', '>= 0.9')
    if args.matched is not None:
        safe = np.asarray(methods[name], np.float64)[labels == 1]
        at = (float(np.quantile(safe, args.matched[0])), float(np.quantile(safe, args.matched[1])))
        heads = (f'{args.matched[0]:.0%} flagged', f'{args.matched[1]:.0%} flagged')
        scored_by += (f'; thresholds {at[0]:.3f} / {at[1]:.3f} flag {args.matched[0]:.0%} / '
                      f'{args.matched[1]:.0%} of the {len(safe)} safe scenes')
    rows = [groups(params[k], evidence[k]) for k in keep]
    tall = np.array([exposed_height(params[k]) >= BAR_HEIGHT for k in keep])
    report = breakdown(p, rows, tall, at)
    print(f'{len(keep)} obstacle scenes of {args.data} ({doc["split"]}), scored by '
          f'{scored_by}\n')
    print(markdown(report, heads), end='')
    if args.json is not None:
        args.json.write_text(json.dumps({'data': str(args.data), 'scored_by': scored_by,
                                         'thresholds': list(at), 'breakdown': report},
                                        indent=1) + '\n',
                             encoding='utf-8')


if __name__ == '__main__':
    main()
