"""Replay every flight of a set with the shipped pipeline and keep its tile and footprint grids.

    python dump.py SET_DIR OUT_DIR

One ``NAME.npz`` per flight: the judged grid (``p_safe``, ``p_net``, ``guard``, ``ood``),
the labels' truth per tile and per footprint, and the candidates' reasons to leave a footprint
out. What comes after the network can then be tried offline without replaying again.

Also the network's input of every tile as the last pass judged it (``cubes``: int8, 127 x the
max-pooled 16^3 cube the net's first layer reads; ``cube_index``: global tile indices;
``cube_truth``): tiles of maps as the robot builds them, for training on.
"""
import json
import sys
from pathlib import Path

import numpy as np


def dump(task):
    from landing_zone.replay import replay
    from landing_zone.io.labels import read_labels, tile_truth
    from landing_zone.tools.evaluate.flights import labels_task_center
    from landing_zone.tools.evaluate.footprints import footprint_truth

    from landing_zone.judging import judgement

    bag, out = Path(task['bag']), Path(task['out'])
    labels = read_labels(bag.with_name(bag.stem + '.labels.json'))
    center = labels_task_center(labels, None)
    seen = {}
    original = judgement._predict

    def capture(batch, pool, *args):
        for k in np.flatnonzero(batch.valid):
            seen[tuple(batch.index[k])] = batch.inputs[k, 0]
        return original(batch, pool, *args)
    judgement._predict = capture
    try:
        a = replay(bag, None, None, progress=False, center=list(center)).assessment
    finally:
        judgement._predict = original
    keys = sorted(seen)
    cube_index = np.array(keys, np.int64).reshape(-1, 2)
    cubes = np.stack([seen[k] for k in keys]) if keys else np.zeros((0, 16, 16, 16))
    cube_truth = tile_truth((cube_index + 0.5) * a.tile_size, a.tile_size, labels)
    truth = tile_truth(a.centers, a.tile_size, labels)
    grid = a.grid
    tg = grid(truth)
    arrays = {'p_safe': grid(a.p_safe), 'p_net': grid(a.p_net), 'truth': tg,
              'ftruth': footprint_truth(tg, a.footprint_radius, a.tile_size),
              'reasons': a.candidates.reasons, 'fp': a.candidates.p_safe,
              'n_returns': grid(a.n_returns.astype(np.float64)),
              'cubes': np.round(cubes * 127).astype(np.int8), 'cube_index': cube_index,
              'cube_truth': cube_truth, 'origin': np.array(a.origin)}
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
