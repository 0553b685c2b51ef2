"""A/B probe of training levers on the base net: more scenes, and a dense auxiliary loss.

Trains the shipped architecture from scratch with the shipped optimiser (SGD lr 0.01, momentum
0.9, L2 5e-4, batch 20, dropout 0.5) on cached augmented copies of the training scenes (the
voxel cache ``train --cache-voxels`` makes, cubes aligned as the robot cuts them), once per
auxiliary weight given, and judges synth3's test split (and, if there, ``data/assembly_test``):
the per-scene scores go to ``OUT/scores_WEIGHT.json`` in ``evaluate --scores`` form, so
``scripts/pass_breakdown.py`` and friends read them.

**The dense auxiliary loss** (weight > 0): beside P(safe), a convolution over each column of
the last convolution's features (64 channels x 4 heights; the shipped spec's 4^3 map), one
logit per cell, is trained to say which of the tile's 4 x 4 cells hold at least two obstacle
returns (the simulator labels every return by what
it hit; the cells turn with the sample's yaw and lose the returns its context cut drops). It is a
probe, not part of ``train``: measured, it did not lift the net (models/MODEL_CARD.md, "What still
passes, and three levers measured").

    python scripts/lever_probe.py OUT WEIGHT [WEIGHT ...] [--data DIR ...] [--epochs 5]
        [--copies 2] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from sklearn.metrics import roc_auc_score
from torch import nn
from torch.nn import functional as F

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.tools.learn.samples import AugmentedVolumes, cut_context, voxelize
from landing_zone.tools.learn.scenes import ScenePack, open_source
from landing_zone.tools.sim.mesh import OBSTACLE
from landing_zone.tools.sim.shards import SceneDataset

GRID = 4  # auxiliary cells per side of the tile: 25 cm


def obstacle_cells(source, pack: ScenePack, copies: int, seed: int, map_cfg: MapConfig,
                   tile_cfg: TileConfig) -> torch.Tensor:
    """(S * copies, GRID, GRID) float32: which cells of the tile hold >= 2 obstacle returns in
    each cached copy, in the voxel cache's row order (copy ``c`` of scene ``s`` is sample
    ``(-1, s, c)``: the same yaw and context cuts)."""
    ds = AugmentedVolumes(pack, map_cfg, tile_cfg, seed, augment=True, z_shift=0.3, yaw=True,
                          edge_drop=0.3)
    out = np.zeros((len(pack) * copies, GRID, GRID), np.float32)
    half = tile_cfg.tile_size / 2
    for s in range(len(pack)):
        scene = source[int(pack.scene_ids[s])]
        if scene.label == 1 or scene.hit_class is None:
            continue
        ob = np.asarray(scene.points, np.float64)[np.asarray(scene.hit_class) == OBSTACLE]
        for c in range(copies):
            yaw, _, cuts = ds.draw(-1, s, c)
            q = cut_context(ob, np.zeros(3), cuts)[0] if cuts else ob
            # the voxelizer's rotation (landing_zone.judging.patches.patch_counts)
            cs, sn = math.cos(yaw), math.sin(yaw)
            x, y = cs * q[:, 0] - sn * q[:, 1], sn * q[:, 0] + cs * q[:, 1]
            inside = (np.abs(x) < half) & (np.abs(y) < half)
            i = np.clip(((x[inside] + half) / tile_cfg.tile_size * GRID).astype(int), 0,
                        GRID - 1)
            j = np.clip(((y[inside] + half) / tile_cfg.tile_size * GRID).astype(int), 0,
                        GRID - 1)
            counts = np.zeros((GRID, GRID))
            np.add.at(counts, (i, j), 1)
            out[s * copies + c] = counts >= 2
    return torch.from_numpy(out)


def train_one(inputs: torch.Tensor, labels: torch.Tensor, cells: torch.Tensor, weight: float,
              epochs: int, seed: int) -> SafetyNet:
    """The shipped net trained from scratch on the cache, with the auxiliary loss at
    ``weight`` (0: none)."""
    torch.manual_seed(seed)
    net = SafetyNet(SafetyNetConfig())
    # the shipped spec's last convolution gives 64 x 4 x 4 x 4 features: one logit per
    # column of them (64 channels x 4 heights), a 25 cm cell of the tile each
    aux = nn.Conv3d(64, 1, (1, 1, GRID))
    opt = torch.optim.SGD(list(net.parameters()) + list(aux.parameters()), lr=0.01,
                          momentum=0.9, weight_decay=5e-4)
    rng = np.random.default_rng(seed)
    t0 = time.time()
    for epoch in range(epochs):
        net.train()
        order = rng.permutation(len(inputs))
        total = 0.0
        for b in range(0, len(order), 20):
            rows = torch.from_numpy(order[b:b + 20])
            x = inputs[rows].float().contiguous(memory_format=torch.channels_last_3d)
            feats = net.features(x)  # what SafetyNet.embed computes in training mode
            assert feats.shape[1:] == (64, GRID, GRID, GRID), feats.shape
            logits = net.head(net.dense(feats.reshape(len(x), -1))).squeeze(1)
            loss = F.binary_cross_entropy_with_logits(logits, labels[rows])
            if weight > 0:
                cell_logits = aux(feats).reshape(len(x), GRID, GRID)
                loss = loss + weight * F.binary_cross_entropy_with_logits(cell_logits,
                                                                          cells[rows])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(x)
        print(f'weight {weight}: epoch {epoch + 1} loss {total / len(order):.4f} '
              f'{time.time() - t0:.0f} s', flush=True)
    return net.eval()


def judged(net: SafetyNet, inputs: torch.Tensor) -> np.ndarray:
    with torch.no_grad():
        logits = torch.cat([net(inputs[i:i + 512].float())[0]
                            for i in range(0, len(inputs), 512)])
    return torch.sigmoid(logits).numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('out', type=Path)
    ap.add_argument('weights', type=float, nargs='+', help='auxiliary loss weights (0: none)')
    ap.add_argument('--data', nargs='+', default=['data/synth3_some', 'data/synth3_more',
                                                  'data/synth3_b'])
    ap.add_argument('--test', default='data/synth3_test')
    ap.add_argument('--epochs', type=int, default=5)
    ap.add_argument('--copies', type=int, default=2)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--workers', type=int, default=2)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    mcfg, tcfg = MapConfig(), TileConfig()
    torch.set_num_threads(2)
    source, _ = open_source(args.data)
    pack = ScenePack.from_scenes(source)
    inputs, labels = voxelize(pack, mcfg, tcfg, args.workers, seed=args.seed, augment=True,
                              copies=args.copies, dtype=torch.float16, edge_drop=0.3)
    cells = obstacle_cells(source, pack, args.copies, args.seed, mcfg, tcfg)
    print(f'{len(pack)} scenes, {len(inputs)} cached cubes', flush=True)
    tests = {}
    for name in (args.test, 'data/assembly_test'):
        if Path(name).exists():
            tpack = ScenePack.from_scenes(SceneDataset(name, 'test'))
            tests[name] = voxelize(tpack, mcfg, tcfg, args.workers, dtype=torch.float16)
    for weight in args.weights:
        net = train_one(inputs, labels, cells, weight, args.epochs, args.seed)
        for name, (tx, ty) in tests.items():
            p = judged(net, tx)
            print(f'weight {weight}: {name} AUC {roc_auc_score(ty.numpy(), p):.4f}', flush=True)
            if name == args.test:
                (args.out / f'scores_{weight}.json').write_text(json.dumps({
                    'dataset': 'synth3', 'split': 'test', 'scenes': list(range(len(ty))),
                    'labels': [int(v) for v in ty],
                    'methods': {f'aux {weight}': [float(v) for v in p]}}))


if __name__ == '__main__':
    main()
