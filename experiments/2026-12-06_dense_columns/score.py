"""Score saved candidate grids (``dense.py``'s OUT.grids.npz) on a directory of held-out dumps
(or links to some of them), beside the shipped judgement.

    python score.py TEST_DIR GRIDS.npz [GRIDS.npz ...]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / '2026-12-06_site_normalisation'))
from analyse import as_judged, figures, show  # noqa: E402

test = sorted(Path(sys.argv[1]).glob('*.npz'))
flights = [dict(np.load(p), name=p.stem) for p in test]
print(f'{len(flights)} flights')
show('shipped', figures(flights, lambda f: f['p_safe'].astype(np.float64)))
for g in sys.argv[2:]:
    grids = np.load(g)
    show(Path(g).name, figures(flights, lambda f: as_judged(f, grids[f['name']])))
