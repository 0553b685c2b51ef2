"""A vegetation family held out of training, judged without trusting any model's calibration.

``landing-zone evaluate --by-family`` reports the safe tiles a held-out vegetation family gets
flagged at P(safe) < 0.5; that share moves with each model's temperature, which a probe trained
from scratch fits on its own validation split. This reads ``evaluate --scores`` files of models
named ``..._FAMILY_sSEED`` (trained with ``--hold-out vegetation:FAMILY``) and reports, for
each, on synth3's test split:

* **flagged at matched alarms**: the share of FAMILY's safe tiles below the threshold that
  flags 5 % of the other vegetation's safe tiles, and the obstacle tiles passed at it;
* **AUC** of FAMILY's safe tiles against every obstacle tile (how far the net ranks the unseen
  vegetation above obstacles);
* the shares at 0.5 as ``evaluate`` counts them;

and with ``--by-obstacle``, each model's AUC per obstacle family and per vegetation family
(each over its scenes, as ``evaluate --by-family`` computes it)::

    python scripts/vegetation_holdout.py data/synth3_test SCORES.json [SCORES.json ...]
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from landing_zone.tools.evaluate.lofo import scene_families
from landing_zone.tools.sim.shards import SceneDataset

MATCHED = 0.05  # share of the other vegetation's safe tiles flagged at the matched threshold


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data', type=Path, help='the synth3 dataset the scores were made on')
    ap.add_argument('scores', type=Path, nargs='+', help='evaluate --scores files')
    ap.add_argument('--by-obstacle', action='store_true',
                    help='also each model\'s AUC per obstacle and vegetation family')
    args = ap.parse_args()
    families = scene_families(SceneDataset(args.data, 'test'))
    obstacle, vegetation = (np.asarray(families[a]) for a in ('obstacle', 'vegetation'))
    for path in args.scores:
        doc = json.loads(path.read_text())
        index = np.asarray(doc['scenes'])
        y = np.asarray(doc['labels'])
        veg, obs_fam = vegetation[index], obstacle[index]
        for name, scores in doc['methods'].items():
            found = re.search(r'_([a-z_]+?)_s\d+\)?$', name)
            if found is None or found.group(1) not in set(veg):
                print(f'{name}: no held-out vegetation family in its name, skipped')
                continue
            fam, s = found.group(1), np.asarray(scores, float)
            held, other, obs = (y == 1) & (veg == fam), (y == 1) & (veg != fam), y == 0
            t = np.quantile(s[other], MATCHED)
            auc = roc_auc_score(np.r_[np.ones(held.sum()), np.zeros(obs.sum())],
                                np.r_[s[held], s[obs]])
            print(f'{name}: {fam} held out; at matched alarms flagged '
                  f'{np.mean(s[held] < t):.1%}, obstacles passed {np.mean(s[obs] >= t):.1%}; '
                  f'AUC {fam} safe vs obstacles {auc:.3f}; at 0.5 flagged '
                  f'{np.mean(s[held] < 0.5):.1%}, obstacles passed {np.mean(s[obs] >= 0.5):.1%}')
            if args.by_obstacle:
                for axis, of in (('obstacle', obs_fam), ('vegetation', veg)):
                    print(f'  AUC by {axis}: ' + ', '.join(
                        f'{f} {roc_auc_score(y[of == f], s[of == f]):.3f}'
                        for f in sorted(set(of))))
    return 0


if __name__ == '__main__':
    sys.exit(main())
