"""What the OOD signal does per family: synth3's test split judged as the assessor judges it.

For every test scene: the model's P(safe) and penultimate features from one pass, the k-NN
distance of the features to the model's reference (``NAME.ood.safetensors``), and the rule of
:mod:`landing_zone.judging.ood` (a tile called safe past the threshold becomes unknown). Per
obstacle and vegetation family: the share of scenes made unknown (safe and obstacle scenes
apart), and among the judged ones the shares of obstacle scenes at P(safe) >= 0.5 and >= 0.9 and
of safe scenes flagged, with and without the signal. The test families (never trained on) are
the ones that say whether it helps on what the model never saw.

    python scripts/ood_families.py MODEL DATA_DIR [--reference REF] [--json OUT] [--workers 2]
"""
from __future__ import annotations

import argparse
import json
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
    from landing_zone.learn.lofo import scene_families
    from landing_zone.learn.samples import voxelize
    from landing_zone.learn.scenes import ScenePack
    from landing_zone.sim.families import TEST_FAMILIES
    from landing_zone.sim.shards import SceneDataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('model', type=Path)
    ap.add_argument('data', type=Path)
    ap.add_argument('--reference', type=Path, default=None)
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--workers', type=int, default=2)
    args = ap.parse_args()
    net, meta = load_model(args.model)
    ref = load_reference(args.reference or reference_path_for(args.model), meta['weights_sha256'])
    ds = SceneDataset(args.data, 'test')
    fams = scene_families(ds)
    pack = ScenePack.from_scenes(ds)
    mcfg, tcfg = input_configs(meta)
    x, y = voxelize(pack, mcfg, tcfg, args.workers)
    with Predictor(net) as predict:
        p, feats = predict.with_features(x)
    ratio = ref.ratio(feats)
    y = y.numpy().astype(np.int64)
    unknown = (p >= 0.5) & (ratio > 1.0)
    none = np.zeros_like(unknown)
    out: dict = {'model': str(args.model), 'threshold': float(ref.threshold), 'axes': {}}
    for axis in ('obstacle', 'vegetation'):
        out['axes'][axis] = {}
        for fam in sorted(set(fams[axis])):
            sel = fams[axis] == fam
            out['axes'][axis][fam] = {'without': shares(p[sel], y[sel], none[sel]),
                                      'with': shares(p[sel], y[sel], unknown[sel]),
                                      'test_family': bool(axis == 'obstacle'
                                                          and fam in TEST_FAMILIES)}
    out['all'] = {'without': shares(p, y, none), 'with': shares(p, y, unknown)}

    def pct(v: float | None) -> str:
        return '-' if v is None else f'{100 * v:.1f}%'

    print('| family | unknown (safe / obstacle) | obstacle P>=0.5 without -> with | P>=0.9 '
          'without -> with | safe flagged without -> with |')
    print('|---|---:|---:|---:|---:|')
    rows = [(f'{a}:{f}' + (' (test family)' if v['test_family'] else ''), v)
            for a, d in out['axes'].items() for f, v in d.items()] + [('all', out['all'])]
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
