"""What the OOD signal (and the guard) do per family: synth3's test split (or, with
``--split train``, a set of families no model trained on) judged as the assessor judges it.

For every test scene: the model's P(safe) and penultimate features from one pass, the k-NN
distance of the features to the model's reference (``NAME.ood.safetensors``), and the rule of
:mod:`landing_zone.judging.ood` (a tile called safe past the threshold becomes unknown). Per
obstacle and vegetation family: the share of scenes made unknown (safe and obstacle scenes
apart), and among the judged ones the shares of obstacle scenes at P(safe) >= 0.5 and >= 0.9 and
of safe scenes flagged, with and without the signal. The test families (never trained on) are
the ones that say whether it helps on what the model never saw.

With ``--guard`` the guard runs first, as in the assessor (:mod:`landing_zone.tools.evaluate.scene_guard`:
on the counts the scene's cube is cut from, above the tile's ground plane): three conditions,
the network alone, with the guard (P(safe) capped where it fires) and with the guard and the
OOD signal, each with the shares above; the JSON gains ``guard`` and ``guard_ood`` beside
``without`` (the network alone) and ``with`` (the OOD signal alone), and per family the shares
of safe and obstacle scenes the guard fired on (``fired_safe``, ``fired_unsafe``).

    python scripts/ood_families.py MODEL DATA_DIR [--reference REF] [--guard [--scores S]] \\
        [--json OUT] [--workers 2] [--split test|train]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def shares(p: np.ndarray, y: np.ndarray, unknown: np.ndarray) -> dict:
    judged = ~unknown
    obst, safe = (y == 0), (y == 1)

    def frac(a: np.ndarray, b: np.ndarray) -> float | None:
        return float(a[b].mean()) if b.any() else None

    return {'n': int(len(y)), 'n_unsafe': int(obst.sum()),
            'unknown_safe': frac(unknown, safe), 'unknown_unsafe': frac(unknown, obst),
            'unsafe_ge_0.5': frac(p >= 0.5, obst & judged),
            'unsafe_ge_0.9': frac(p >= 0.9, obst & judged),
            'safe_lt_0.5': frac(p < 0.5, safe & judged)}


def main() -> None:
    from landing_zone.judging.checkpoint import input_configs, load_model
    from landing_zone.judging.inference import Predictor
    from landing_zone.judging.ood import load_reference, reference_path_for
    from landing_zone.tools.evaluate.lofo import scene_families
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.learn.scenes import ScenePack
    from landing_zone.tools.sim.families import TEST_FAMILIES
    from landing_zone.tools.sim.shards import SceneDataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('model', type=Path)
    ap.add_argument('data', type=Path)
    ap.add_argument('--reference', type=Path, default=None)
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--split', choices=('test', 'train'), default='test',
                    help='the split judged (train: e.g. a set of families no model trained on)')
    ap.add_argument('--guard', action='store_true',
                    help='also the guard, before the OOD signal as in the assessor')
    ap.add_argument('--scores', type=Path, default=None,
                    help='with --guard: every scene\'s P(safe) by the net and by net + guard, '
                         'as evaluate --scores writes them (for scripts/pass_breakdown.py)')
    args = ap.parse_args()
    net, meta = load_model(args.model)
    ref = load_reference(args.reference or reference_path_for(args.model), meta['weights_sha256'])
    ds = SceneDataset(args.data, args.split)
    fams = scene_families(ds)
    pack = ScenePack.from_scenes(ds)
    mcfg, tcfg = input_configs(meta)
    found = None
    if args.guard:  # the guard's findings from the same read of each patch
        from landing_zone.config import GuardConfig
        from landing_zone.tools.evaluate.scene_guard import voxelize_guarded
        t0 = time.perf_counter()
        x, y, found = voxelize_guarded(pack, mcfg, tcfg, GuardConfig(), args.workers)
        print(f'voxelized and guarded {len(pack)} scenes in {time.perf_counter() - t0:.1f} s',
              file=sys.stderr)
    else:
        x, y = voxelize(pack, mcfg, tcfg, args.workers)
    with Predictor(net) as predict:
        p, feats = predict.with_features(x)
    ratio = ref.ratio(feats)
    y = y.numpy().astype(np.int64)
    unknown = (p >= 0.5) & (ratio > 1.0)
    none = np.zeros_like(unknown)
    conditions = {'without': (p, none), 'with': (p, unknown)}
    fired = None
    if found is not None:
        from landing_zone.config import GuardConfig
        from landing_zone.judging.guard import guard_p_safe
        fired = found.fired
        pg = guard_p_safe(p, found, GuardConfig()).astype(np.float64)
        conditions['guard'] = (pg, none)
        conditions['guard_ood'] = (pg, (pg >= 0.5) & (ratio > 1.0))
        if args.scores is not None:
            from types import SimpleNamespace

            from landing_zone.tools.evaluate.roc import scores_json
            rows = [SimpleNamespace(name='net', scores=p),
                    SimpleNamespace(name='net + guard', scores=pg)]
            doc = scores_json(rows, pack.scene_ids.numpy(), y, str(ds.meta.get('dataset')),
                              args.split)
            args.scores.write_text(json.dumps(doc) + '\n', encoding='utf-8')

    def figures(sel: np.ndarray) -> dict:
        fig = {k: shares(q[sel], y[sel], u[sel]) for k, (q, u) in conditions.items()}
        if fired is not None:
            fig['fired_safe'] = float(fired[sel & (y == 1)].mean())
            fig['fired_unsafe'] = float(fired[sel & (y == 0)].mean())
        return fig

    out: dict = {'model': str(args.model), 'threshold': float(ref.threshold), 'axes': {}}
    for axis in ('obstacle', 'vegetation', 'terrain'):
        out['axes'][axis] = {}
        for fam in sorted(set(fams[axis])):
            out['axes'][axis][fam] = {**figures(fams[axis] == fam),
                                      'test_family': bool(axis == 'obstacle'
                                                          and fam in TEST_FAMILIES)}
    out['all'] = figures(np.ones(len(y), bool))

    def pct(v: float | None) -> str:
        return '-' if v is None else f'{100 * v:.1f}%'

    rows = [(f'{a}:{f}' + (' (test family)' if v['test_family'] else ''), v)
            for a, d in out['axes'].items() for f, v in d.items()] + [('all', out['all'])]
    if args.guard:
        print('| family | guard fired (safe / obstacle) | unknown (safe / obstacle), guard + '
              'OOD | obstacle P>=0.5 net / + guard / + OOD | P>=0.9 net / + guard / + OOD | '
              'safe flagged net / + guard / + OOD |')
        print('|---|---:|---:|---:|---:|---:|')
        for name, v in rows:
            c = [v[k] for k in ('without', 'guard', 'guard_ood')]
            print(f'| {name} | {pct(v["fired_safe"])} / {pct(v["fired_unsafe"])} | '
                  f'{pct(c[2]["unknown_safe"])} / {pct(c[2]["unknown_unsafe"])} | '
                  + ' | '.join(' / '.join(pct(x[key]) for x in c)
                               for key in ('unsafe_ge_0.5', 'unsafe_ge_0.9', 'safe_lt_0.5'))
                  + ' |')
    else:
        print('| family | unknown (safe / obstacle) | obstacle P>=0.5 without -> with | P>=0.9 '
              'without -> with | safe flagged without -> with |')
        print('|---|---:|---:|---:|---:|')
        for name, v in rows:
            w, o = v['without'], v['with']
            print(f'| {name} | {pct(o["unknown_safe"])} / {pct(o["unknown_unsafe"])} | '
                  f'{pct(w["unsafe_ge_0.5"])} -> {pct(o["unsafe_ge_0.5"])} | '
                  f'{pct(w["unsafe_ge_0.9"])} -> {pct(o["unsafe_ge_0.9"])} | '
                  f'{pct(w["safe_lt_0.5"])} -> {pct(o["safe_lt_0.5"])} |')
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1) + '\n', encoding='utf-8')


if __name__ == '__main__':
    main()
