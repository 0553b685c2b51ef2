"""Probe: does the net judge better when it also reads how often each voxel was observed?

The network reads one number per 5 cm voxel, ``x = (hits - passes) / (hits + passes + 2)``
(:mod:`landing_zone.judging.tiles`): a voxel hit once and never passed reads as one hit ten
times and passed five times would, nearly. The map keeps both counts; this asks whether the
rest of what they say is worth a second input channel, before any of the product is changed.
The second channel is ``(hits + passes) / (hits + passes + 2)``, how well the voxel was
observed (0 unobserved, 1/3 one ray, 0.83 ten rays): with the first it gives back both counts.
It is cut by the tiler's own kernel from the counts ``(hits + passes, 0)`` on the same ground
plane as the first channel (:func:`landing_zone.judging.patches.cut_patch`), so both channels
lie on one grid, voxel for voxel; scenes without a fitted plane (where the kernel would pick
the ground from occupancy, which differs between the two cuts) are counted, and left out.

The second channel is standardised by its mean and spread over the training cache (read
raw, in [0, 0.87] with a mean far from 0, it left SGD at this rate training worse: loss 0.34-0.38
against 0.23-0.24 after ten epochs, test AUC 0.914-0.919 against 0.945).

Arm C reads the hits alone beside the first channel, ``hits / (hits + 2)`` (0 where nothing
was hit, 1/3 one hit, 0.83 ten), recovered from the two cut channels (they give back both
counts), raw: sparse and nonnegative as a hit map is.

The arms are trained from scratch by the same loop on the same cached augmented copies (the
voxel cache's yaw, height shift and context cuts, :class:`~landing_zone.tools.learn.samples.
AugmentedVolumes`), the shipped spec with its first convolution reading one channel (A) or
two (B, C), the shipped optimiser (SGD lr 0.01, momentum 0.9, L2 5e-4, batch 20, dropout 0.5) with
a cosine rate, and judged on synth3's test split: per-scene scores to ``OUT/scores_ARM_sSEED.
json`` in ``evaluate --scores`` form (``scripts/pass_breakdown.py --matched`` reads them)::

    python scripts/channel_probe.py OUT [--data DIR ...] [--scenes 5000] [--copies 2]
        [--epochs 10] [--seeds 0 1] [--arms A B C]

Measured (2026-12-05; docs/EXPERIMENTS.md, "What the net reads of the map"): test AUC A 0.945
in both seeds, B 0.904-0.927, C 0.945: neither count is worth a channel.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from sklearn.metrics import roc_auc_score
from torch import nn
from torch.nn import functional as F

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.net import ConvBlock, SafetyNet, SafetyNetConfig
from landing_zone.judging.patches import cut_patch, patch_counts, patch_ground
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.learn.samples import AugmentedVolumes, collect, cut_context
from landing_zone.tools.learn.scenes import ScenePack, open_source
from landing_zone.tools.sim.shards import SceneDataset


ARMS = {'A': [0], 'B': [0, 1], 'C': [0, 2]}  # arm -> channels read: density, observed, hits


def with_hits(x: torch.Tensor) -> torch.Tensor:
    """(K, 2, ...) cut channels -> (K, 3, ...): the hits channel ``h / (h + 2)`` appended,
    from ``x0 = (h - p) / (n + 2)`` and ``x1 = n / (n + 2)``, ``n = h + p``."""
    s = x[:, 1].float()
    n = 2 * s / (1 - s)
    h = torch.clamp(torch.round((n + x[:, 0].float() * (n + 2)) / 2), min=0)
    return torch.cat([x, (h / (h + 2)).unsqueeze(1).to(x.dtype)], 1)


class TwoChannels(AugmentedVolumes):
    """:class:`AugmentedVolumes` whose sample also carries the observation channel, and
    whether its ground plane was fitted (both channels on one grid)."""

    def __getitem__(self, key: Any) -> tuple[torch.Tensor, ...]:
        epoch, scene, copy = (0, int(key), 0) if isinstance(key, (int, np.integer)) else key
        yaw, dz, cuts = self.draw(epoch, scene, copy)
        pts, org = self.pack.scene(scene)
        if cuts:
            pts, org = cut_context(pts, org, cuts)
        h, p, lo = patch_counts(pts, org, self.map_cfg, self.tile_cfg, yaw, dz)
        ground = patch_ground((h, p, lo), self.map_cfg, self.tile_cfg)
        x = cut_patch((h, p, lo), self.map_cfg, self.tile_cfg, ground, dz).inputs[0]
        seen = cut_patch((h + p, np.zeros_like(p), lo), self.map_cfg, self.tile_cfg, ground,
                         dz).inputs[0]
        # x is 0 where unobserved; so is (h + p) / (h + p + 2): the cuts agree on the box
        fitted = bool(np.isfinite(ground.plane_z[0]))
        return (torch.from_numpy(x), torch.tensor(float(self.pack.labels[scene])),
                torch.from_numpy(seen), torch.tensor(fitted))


def cache(pack: ScenePack, copies: int, seed: int, augment: bool, workers: int
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(K, 2, S, S, S) float16 inputs, (K,) labels, (K,) plane fitted; copy c of scene s is
    row s * copies + c."""
    mcfg, tcfg = MapConfig(), TileConfig()
    ds = TwoChannels(pack, mcfg, tcfg, seed, augment=augment, edge_drop=0.3 if augment else 0.0)
    keys = [(-1, s, c) for s in range(len(pack)) for c in range(copies)]
    side = tile_voxels(mcfg.voxel_size, tcfg) + 2 * tcfg.padding
    x, y, (seen, fitted) = collect(ds, keys, side, workers, dtype=torch.float16)
    return torch.cat([x, seen.to(torch.float16)], 1), y, fitted


def two_channel_net(channels: int, seed: int) -> SafetyNet:
    """The shipped spec (opening pool, then a 5^3 convolution) with that convolution reading
    ``channels`` channels, initialised as the net initialises its own (Glorot, zero bias)."""
    torch.manual_seed(seed)
    net = SafetyNet(SafetyNetConfig())
    first = net.features[1]
    assert isinstance(first, ConvBlock), net.spec
    if channels != 1:
        conv = first.conv
        net.features[1] = ConvBlock(channels, conv.out_channels, conv.kernel_size[0],
                                    net.config.dropout)
        nn.init.xavier_uniform_(net.features[1].conv.weight)
        nn.init.zeros_(net.features[1].conv.bias)
    return net


def logits(net: SafetyNet, x: torch.Tensor) -> torch.Tensor:
    """The net's logit on (B, C, S, S, S) inputs (its own forward asserts one channel)."""
    feats = net.features(x)
    out: torch.Tensor = net.head(net.dense(feats.reshape(len(x), -1))).squeeze(1)
    return out


def train(x: torch.Tensor, y: torch.Tensor, channels: list[int], epochs: int, seed: int
          ) -> SafetyNet:
    net = two_channel_net(len(channels), seed)
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    steps = epochs * math.ceil(len(x) / 20)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    rng = np.random.default_rng(seed)
    t0 = time.time()
    for epoch in range(epochs):
        net.train()
        order = rng.permutation(len(x))
        total = 0.0
        for b in range(0, len(order), 20):
            rows = torch.from_numpy(order[b:b + 20])
            xb = x[rows][:, channels].float().contiguous(memory_format=torch.channels_last_3d)
            loss = F.binary_cross_entropy_with_logits(logits(net, xb), y[rows])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(rows)
        print(f'channels {channels}, seed {seed}: epoch {epoch + 1} loss '
              f'{total / len(order):.4f} {time.time() - t0:.0f} s', flush=True)
    return net.eval()


def judged(net: SafetyNet, x: torch.Tensor, channels: list[int]) -> np.ndarray:
    with torch.no_grad():
        z = torch.cat([logits(net, x[i:i + 256][:, channels].float())
                       for i in range(0, len(x), 256)])
    return torch.sigmoid(z).numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('out', type=Path)
    ap.add_argument('--data', nargs='+', default=['data/synth3_b'])
    ap.add_argument('--test', default='data/synth3_test')
    ap.add_argument('--scenes', type=int, default=5000, help='the first this many scenes')
    ap.add_argument('--copies', type=int, default=2)
    ap.add_argument('--epochs', type=int, default=10)
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1])
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--arms', nargs='+', choices=tuple(ARMS), default=list(ARMS))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(2)
    source, _ = open_source(args.data)
    pack = ScenePack.from_scenes(source, range(min(args.scenes, len(source))))
    t0 = time.time()
    x, y, fitted = cache(pack, args.copies, 0, True, args.workers)
    tpack = ScenePack.from_scenes(SceneDataset(args.test, 'test'))
    tx, ty, tfit = cache(tpack, 1, 0, False, args.workers)
    print(f'{len(pack)} scenes, {len(x)} cached cubes ({int((~fitted).sum())} without a ground '
          f'plane, left out); test {len(tx)} ({int((~tfit).sum())} without one, scored all); '
          f'{time.time() - t0:.0f} s', flush=True)
    x, y = x[fitted], y[fitted]
    x, tx = with_hits(x), with_hits(tx)
    mean, std = float(x[:, 1].float().mean()), float(x[:, 1].float().std())
    x[:, 1] = ((x[:, 1].float() - mean) / std).to(x.dtype)
    tx[:, 1] = ((tx[:, 1].float() - mean) / std).to(tx.dtype)
    print(f'observation channel: mean {mean:.3f}, spread {std:.3f} (standardised)', flush=True)
    for seed in args.seeds:
        for arm in args.arms:
            channels = ARMS[arm]
            net = train(x, y, channels, args.epochs, seed)
            p = judged(net, tx, channels)
            print(f'arm {arm} (channels {channels}), seed {seed}: test AUC '
                  f'{roc_auc_score(ty.numpy(), p):.4f}', flush=True)
            (args.out / f'scores_{arm}_s{seed}.json').write_text(json.dumps({
                'dataset': 'synth3', 'split': 'test', 'scenes': list(range(len(ty))),
                'labels': [int(v) for v in ty],
                'methods': {f'{arm} s{seed}': [float(v) for v in p]}}))


if __name__ == '__main__':
    main()
