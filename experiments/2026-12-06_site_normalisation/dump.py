"""Replay every flight of a set with the shipped pipeline and keep its tile and footprint grids.

    python dump.py SET_DIR OUT_DIR

One ``NAME.npz`` per flight: the judged grid (``p_safe``, ``p_net``, ``guard``, ``ood``),
the labels' truth per tile and per footprint, and the candidates' reasons to leave a footprint
out. What comes after the network can then be tried offline without replaying again.
"""
import json
import sys
from pathlib import Path

import numpy as np


def dump(task):
    from landing_zone.replay import replay
    from landing_zone.io.labels import read_labels, tile_truth
    from landing_zone.tools.evaluate.flights import footprint_truth, labels_task_center

    bag, out = Path(task['bag']), Path(task['out'])
    labels = read_labels(bag.with_name(bag.stem + '.labels.json'))
    center = labels_task_center(labels, None)
    a = replay(bag, None, None, progress=False, center=list(center)).assessment
    truth = tile_truth(a.centers, a.tile_size, labels)
    grid = a.grid
    tg = grid(truth)
    arrays = {'p_safe': grid(a.p_safe), 'p_net': grid(a.p_net), 'truth': tg,
              'ftruth': footprint_truth(tg, a.footprint_radius, a.tile_size),
              'reasons': a.candidates.reasons, 'fp': a.candidates.p_safe,
              'n_returns': grid(a.n_returns.astype(np.float64))}
    for k in ('guard', 'ood'):
        v = getattr(a, k)
        if v is not None:
            arrays[k] = grid(np.asarray(v, np.float64))
    np.savez_compressed(out, **arrays)
    return str(out)


if __name__ == '__main__':
    from landing_zone.tools.engines import run_tasks
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    dst.mkdir(parents=True, exist_ok=True)
    plan = json.loads((src / 'flights.json').read_text())
    tasks = [{'bag': str(src / f"{f['name']}.mcap"), 'out': str(dst / f"{f['name']}.npz")}
             for f in plan['flights'] if not (dst / f"{f['name']}.npz").exists()]
    (dst / 'flights.json').write_text(json.dumps(plan, indent=1))
    for i, r in run_tasks(dump, tasks, workers=2, start_method='spawn'):
        print(r, flush=True)
