"""Models compared where a planner would use them: at matched operating points, and at the
tile's edge.

Two models can differ in calibration only: the shares at P(safe) >= 0.5 and >= 0.9 then move
while nothing is judged better. This prints, per source and method, the figures at the fixed
thresholds (AUC, ECE, obstacle tiles at >= 0.5 / >= 0.9, safe tiles flagged, and the share of
safe tiles that reach 0.9, without which a planner acting on 0.9 finds nowhere to land), then
the obstacle tiles passed at the threshold that keeps a given share of the safe tiles (the
same for every model: a ranking, not a calibration). A source is a score file of
``landing-zone evaluate --scores`` or ``scripts/ood_families.py --scores`` (every method in
it), or a ``scripts/guard_eval.py`` WORKDIR (its tiles' final P(safe), net + guard + OOD, all
conditions pooled). With ``--edge DIR SCORES...`` (a ``simulate --dataset synth3 --edge``
directory and score files made on it) those scores' edge pairs are also split by how far
beyond the edge the safe scene's obstacle stands and how far in the unsafe one's reaches.
With ``--bar DIR`` (the synth3 directory the score files were made on), per obstacle family
the share of its safe scenes flagged at the threshold that passes 2 % and 0.5 % of its
obstacle tiles: issue 15's bar at 0.5 and 0.9 read as a ranking, which no calibration of the
scores meets unless these shares are small::

    python scripts/operating_points.py runs/eval/a.scores.json runs/eval/b.scores.json \\
        [--edge data/edge_test runs/eval/a.scores.json] [--keep 0.5 0.85] \\
        [--bar data/synth3_test]
    python scripts/operating_points.py runs/ge_shipped runs/ge_edge --keep 0.95 0.9
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from guard_eval import workdir_tiles  # scripts/ is this script's first import path

BANDS = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.3))  # [m] gap / reach bands of the edge pairs
BAR = (0.02, 0.005)  # issue 15: obstacle tiles passed at 0.5 and at 0.9, at most


def sources(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray, list[int] | None]:
    """Per method the scores, the labels (1 safe) and the scenes' indices (None: flights)."""
    if path.is_dir():  # guard_eval workdir: NAME_SEED.json per flight
        p, y = workdir_tiles(path)
        return {'net + guard + OOD': p}, y.astype(int), None
    doc = json.loads(path.read_text())
    return ({m: np.asarray(s, float) for m, s in doc['methods'].items()},
            np.asarray(doc['labels']), doc.get('scenes'))


def read(src: Path) -> tuple[dict[str, np.ndarray], np.ndarray, list[int] | None] | None:
    """:func:`sources`, or None with one line on stderr when ``src`` cannot be read."""
    try:
        return sources(src)
    except (OSError, ValueError, KeyError) as err:
        print(f'operating_points: {src}: {err}', file=sys.stderr)
        return None


def pct(v: float | None) -> str:
    return 'n/a' if v is None else f'{100 * v:.1f} %'


def main() -> int:
    from landing_zone.tools.evaluate.lofo import family_figures
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('sources', type=Path, nargs='+')
    ap.add_argument('--keep', type=float, nargs='+', default=[0.5, 0.85],
                    help='shares of the safe tiles kept (judged at or above the threshold)')
    ap.add_argument('--edge', type=Path, nargs='+', default=None, metavar='DIR SCORES',
                    help='a synth3 --edge directory, then score files made on it')
    ap.add_argument('--bar', type=Path, default=None, metavar='DIR',
                    help='the synth3 directory of the score files: per obstacle family, safe '
                         'tiles flagged where 2 %% / 0.5 %% of its obstacle tiles pass')
    args = ap.parse_args()
    print('| source | method | AUC | ECE | obstacle >= 0.5 / >= 0.9 | safe flagged | '
          'safe >= 0.9 | '
          + ' | '.join(f'obstacles passed, {k:.0%} of safe kept' for k in args.keep) + ' |')
    print('|---|---|' + '---:|' * (5 + len(args.keep)))
    edge_rows = []
    loaded = []  # (source, its methods' scores, labels, scene indices): read once
    for src in args.sources:
        got = read(src)
        if got is None:
            return 2
        loaded.append((src, *got))
        methods, y, _ = got
        for name, p in methods.items():
            ok = np.isfinite(p)
            p_, y_ = p[ok], y[ok]
            f = family_figures(p_, y_)
            safe, unsafe = p_[y_ == 1], p_[y_ == 0]
            matched = [float(np.mean(unsafe >= np.quantile(safe, 1.0 - k))) for k in args.keep]
            print(f'| {src.name} | {name} | {f["auc"]:.3f} | {f["ece"]:.3f} | '
                  f'{pct(f["unsafe_ge_0.5"])} / {pct(f["unsafe_ge_0.9"])} | '
                  f'{pct(f["safe_lt_0.5"])} | {pct(float(np.mean(safe >= 0.9)))} | '
                  + ' | '.join(pct(m) for m in matched) + ' |')
    edge_dir, edge_files = (args.edge[0], args.edge[1:]) if args.edge else (None, [])
    for src in edge_files:
        got = read(src)
        if got is None:
            return 2
        methods, y, scenes = got
        if scenes is None:
            print(f'operating_points: {src}: not a score file', file=sys.stderr)
            return 2
        edge_rows += [(src.name, name, p, y, scenes) for name, p in methods.items()]
    if edge_rows:
        from landing_zone.tools.sim.shards import SceneDataset
        ds = SceneDataset(edge_dir, 'test')
        plans = {}
        print('\n| source | method | '
              + ' | '.join(f'safe flagged, {a * 100:.0f}-{b * 100:.0f} cm beyond'
                           for a, b in BANDS)
              + ' | ' + ' | '.join(f'reaching {a * 100:.0f}-{b * 100:.0f} cm in: >= 0.5 / >= 0.9'
                                   for a, b in BANDS) + ' |')
        print('|---|---|' + '---:|' * (2 * len(BANDS)))
        for src, name, p, y, scenes in edge_rows:
            for i in scenes:
                if i not in plans:
                    plans[i] = ds.params(i).get('edge')
            if any(plans[i] is None for i in scenes):
                print(f'operating_points: {edge_dir} is not a synth3 --edge dataset',
                      file=sys.stderr)
                return 2
            gap = np.array([plans[i]['gap'] for i in scenes])
            reach = np.array([plans[i]['reach'] for i in scenes])
            cells = []
            for a, b in BANDS:
                k = (y == 1) & (gap >= a) & (gap < b + 1e-9)
                cells.append(f'{pct(float(np.mean(p[k] < 0.5)) if k.any() else None)} '
                             f'of {k.sum()}')
            for a, b in BANDS:
                k = (y == 0) & (reach >= a) & (reach < b + 1e-9)
                cells.append(f'{pct(float(np.mean(p[k] >= 0.5)) if k.any() else None)} / '
                             f'{pct(float(np.mean(p[k] >= 0.9)) if k.any() else None)} '
                             f'of {k.sum()}')
            print(f'| {src} | {name} | ' + ' | '.join(cells) + ' |')
    return bar(args.bar, loaded) if args.bar is not None else 0


def bar(data: Path, loaded: list[tuple[Path, dict[str, np.ndarray], np.ndarray,
                                       list[int] | None]]) -> int:
    """Per score file (as :func:`read` gave it), method and obstacle family (and pooled): the
    safe scenes flagged at the threshold above which 2 % and 0.5 % of the family's obstacle
    scenes lie."""
    from landing_zone.tools.evaluate.lofo import scene_families
    from landing_zone.tools.sim.shards import SceneDataset
    family = np.asarray(scene_families(SceneDataset(data, 'test'))['obstacle'])
    print('\n| source | method | obstacle family | scenes | '
          + ' | '.join(f'safe flagged where {b:.1%} of obstacles pass' for b in BAR) + ' |')
    print('|---|---|---|' + '---:|' * (1 + len(BAR)))
    for src, methods, y, scenes in loaded:
        if scenes is None or max(scenes) >= len(family):
            print(f'operating_points: {src}: not a score file of {data}', file=sys.stderr)
            return 2
        fam = family[np.asarray(scenes)]
        for name, p in methods.items():
            for f in sorted(set(fam)) + ['pooled']:
                k = np.ones(len(fam), bool) if f == 'pooled' else fam == f
                safe, unsafe = p[k & (y == 1)], p[k & (y == 0)]
                cells = [pct(float(np.mean(safe < np.quantile(unsafe, 1.0 - b))))
                         for b in BAR]
                print(f'| {src.name} | {name} | {f} | {k.sum()} | ' + ' | '.join(cells) + ' |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
