"""`landing-zone bench assess`: tiles + CNN for a full 20 m x 20 m map, and training costs.

The map is the integrate benchmark's scene (rolling ground with grass, sensor 8 m up and 10 m
back) integrated into the default 400 x 400 x 80 map, which holds 400 tiles of 1 m. Measured:

- extraction of all 400 tiles (:func:`extract_tiles`: the map's counts, ground, inputs, cut
  level), and the assessor's own cut, which the full-map and strip figures count: the counts
  read once, the cubes aligned to the tiles' ground planes (``tiles.align_to_ground``) and
  pooled for the net, only the valid tiles' built;
- the guard beside the network (:func:`~landing_zone.judging.guard.guard_tiles`) on the same
  counts, as the assessor runs it; the full-map and strip figures include it;
- the ground planes (:func:`~landing_zone.judging.ground.fit_ground`: slope, roughness,
  clearance) on the same counts and the landing-site candidates with their limits and reasons
  (:func:`~landing_zone.judging.sites.evaluate_candidates` and ``find_sites`` on the whole
  grid, as every pass runs them); the full-map and strip figures include both;
- the OOD signal (:mod:`landing_zone.judging.ood`) of the shipped model: its features from the
  same forward pass (:meth:`~landing_zone.judging.inference.Predictor.with_features`) and their
  k-NN distances to its reference (``models/landing_zone.ood.safetensors``; without one, a
  random reference of :data:`SYNTHETIC_REFERENCE` rows, timing only); the full-map and strip
  figures of the shipped model include it;
- the network on the 400 inputs in fp32 (default layout and channels-last) and, where the CPU
  has native bf16 (AVX-512 BF16 / AMX) or on CUDA, bf16 channels-last; for a net that opens
  with a pool (the shipped one), also on the inputs the tiler pooled (as the assessor cuts
  and feeds them): ms per tile in a batch and seconds per map (extraction + network);
- re-assessing only the tiles a new batch of returns touched (the map's dirty tiles, widened by
  one tile since inputs reach into the neighbours' padding);
- the nets of ensembles of 1, 3 and 5 copies of the shipped net on the map's and the strip's
  tiles (what each member costs, :mod:`landing_zone.judging.ensemble`);
- for reference, a training step (forward + backward + SGD, batch 20) and the data pipeline
  (re-voxelizing one 26k-return patch, one process).

Two nets are timed: the shipped model (:data:`~landing_zone.judging.net.DEFAULT_SPEC`) and the
paper's :data:`~landing_zone.judging.net.PAPER_SPEC`, each loaded from ``models/`` where the file
is there, otherwise an untrained net of that architecture, which costs exactly the same (timing
only: its outputs mean nothing); with ``bench assess --model M``, also each candidate model file
M, as the shipped one (map and strip, with the OOD reference beside it, else a random one of its
size): whether a candidate fits the budget. Figures are medians of repeats (best in brackets):
the cores are shared.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from landing_zone.config import GuardConfig, MapConfig, SiteConfig, TileConfig
from landing_zone.mapping.density_map import DensityMap
from landing_zone.judging.checkpoint import load_model
from landing_zone.judging.ensemble import SafetyEnsemble
from landing_zone.judging.ground import fit_ground
from landing_zone.judging.guard import guard_tiles
from landing_zone.judging.sites import GroundGrids, evaluate_candidates, find_sites
from landing_zone.judging.inference import Predictor, bf16_supported
from landing_zone.judging.net import DEFAULT_SPEC, PAPER_SPEC, SafetyNet, SafetyNetConfig
from landing_zone.judging.ood import FeatureReference, unit_rows
from landing_zone.judging.patches import PatchVoxelizer
from landing_zone.judging.tiles import (CountBuffers, extract_tiles, tile_voxels,
                                        tiles_from_counts, widen_tiles)

from landing_zone.tools.bench.integrate import SENSOR, make_batches

# the inference budget on the 2-core machine, with everything the judgement needs
TARGET_MAP_S = 0.5
TARGET_STRIP_S = 0.15
AIM_MAP_S = 0.25
TARGET_MS_PER_TILE = 5.0
SYNTHETIC_REFERENCE = 4096  # rows of the timing-only reference when none is shipped
POOLED = ', pooled by the tiler'  # the mode's suffix where the tiler pools the inputs


def _times(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    fn()  # warm-up: compilation, inference copies, first touch
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def _model(spec: str) -> tuple[SafetyNet, str, Path | None]:
    """The net of ``spec`` from ``models/``, its label and the file it came from; an untrained
    one (file None) where there is no such file."""
    from landing_zone.assessor import default_model_path
    try:
        shipped = default_model_path()
        path = shipped if spec == DEFAULT_SPEC else shipped.parent / f'paper_{spec}.safetensors'
        net, _ = load_model(path)
        if net.spec == spec:
            return (net, f'{net.spec} ({"shipped model" if path == shipped else path.name})',
                    path)
    except Exception:  # no such model file (or unreadable): time an untrained one
        pass
    torch.manual_seed(0)
    return SafetyNet(SafetyNetConfig(spec)).eval(), f'{spec} (untrained: timing only)', None


def _candidate(path: str) -> tuple[SafetyNet, str]:
    """A model file given on the command line (``bench assess --model``), loaded as any model
    is (a bad file exits with one clear line)."""
    net, _ = load_model(path)
    return net, f'{net.spec} ({Path(path).name})'


def _reference(net: SafetyNet, model: Path | None) -> tuple[FeatureReference, str]:
    """The OOD reference the model file ``model`` judges with (NAME.ood.safetensors beside
    it), or a random one of its size where there is none."""
    from landing_zone.judging.checkpoint import weights_sha256
    from landing_zone.judging.ood import load_reference, reference_path_for

    if model is not None:
        try:
            path = reference_path_for(model)
            return load_reference(path, weights_sha256(net), net.head.in_features), path.name
        except Exception:  # no reference beside it (or not this model's): time a random one
            pass
    rng = np.random.default_rng(0)
    feats = unit_rows(rng.normal(size=(SYNTHETIC_REFERENCE, net.head.in_features)))
    return (FeatureReference(feats, 10, 1.0, 99.5, ''),
            f'random, {SYNTHETIC_REFERENCE} rows (timing only)')


def _network_rows(net: SafetyNet, inputs: np.ndarray, pooled: np.ndarray, repeats: int,
                  device: str) -> list[tuple[str, float, float]]:
    """Seconds of the net on the tiles' inputs per mode; for a net that opens with a pool, also
    on ``pooled`` (the inputs the tiler pooled, as the assessor feeds it)."""
    rows = []
    variants = [('fp32', False, False), ('fp32', True, False)]
    if device == 'cuda' or bf16_supported():
        variants.append(('bf16', True, False))
    if net.input_pool > 1:
        variants += [(prec, cl, True) for prec, cl, _ in variants if cl]
    for precision, cl, pool in variants:
        x = pooled if pool else inputs
        with Predictor(net) as predictor:  # one inference copy per mode, as the assessor keeps
            med, best = _times(lambda: predictor(x, 256, precision, channels_last=cl,
                                                 pooled=pool), repeats)
        rows.append((f'{precision} {"channels-last" if cl else "default layout"}'
                     f'{POOLED if pool else ""}', med, best))
    return rows


def _train_step_ms(spec: str, precision: str, repeats: int = 3) -> tuple[float, float]:
    torch.manual_seed(0)
    net = SafetyNet(SafetyNetConfig(spec)).to(memory_format=torch.channels_last_3d).train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    x = (torch.rand(20, 1, 32, 32, 32) * 2 - 1).contiguous(memory_format=torch.channels_last_3d)
    y = (torch.rand(20) > 0.5).float()

    def step() -> None:
        with torch.autocast('cpu', dtype=torch.bfloat16, enabled=precision == 'bf16'):
            _, loss = net(x, y)
        opt.zero_grad()
        loss.backward()
        opt.step()

    med, best = _times(step, repeats)
    return med / 20 * 1e3, best / 20 * 1e3


def _ensemble_rows(net: SafetyNet | SafetyEnsemble, pooled: np.ndarray, strip_tiles: int,
                   repeats: int) -> dict[str, dict[str, float]]:
    """Seconds of the nets alone (with their features, fp32 channels-last, pooled inputs) for
    ensembles of 1, 3 and 5 copies of the shipped net's first member: the cost of members
    (:mod:`landing_zone.judging.ensemble`), on the map's tiles and on a strip's."""
    import copy

    first = net.members[0] if isinstance(net, SafetyEnsemble) else net
    out = {}
    print(f'\nensembles of {first.spec} (members in turn, fp32 channels-last, pooled inputs, '
          'with features; the nets alone):')
    for k in (1, 3, 5):
        model = first if k == 1 else SafetyEnsemble([copy.deepcopy(first)
                                                     for _ in range(k)]).eval()
        with Predictor(model) as predictor:
            full, _ = _times(lambda: predictor.with_features(pooled, 256, 'fp32',
                                                             pooled=True), repeats)
            part, _ = _times(lambda: predictor.with_features(pooled[:strip_tiles], 256,
                                                             'fp32', pooled=True), repeats)
        out[str(k)] = {'map_s': full, 'strip_s': part}
        print(f'  {k} member{"s" if k > 1 else " "}: {full:.3f} s per {len(pooled)} tiles, '
              f'{part:.3f} s per {strip_tiles}')
    return out


class _Scene:
    """The benchmark's map (the integrate scene) and the stages the assessor runs on it, each
    one call on the counts, as the assessor makes it."""

    def __init__(self, batches: int, seed: int) -> None:
        self.dmap = DensityMap(MapConfig())
        for pts in make_batches(batches, seed):
            self.dmap.integrate(pts, SENSOR)
        self.tcfg = TileConfig()
        self.tv = tile_voxels(self.dmap.voxel_size, self.tcfg)
        self.gcfg = GuardConfig()
        self.scfg = SiteConfig()
        self.buffers = CountBuffers()
        self.batch = extract_tiles(self.dmap, self.tcfg, buffers=self.buffers)
        index = self.batch.index
        self.nxy = tuple(int(v) for v in index.max(axis=0) - index.min(axis=0) + 1)
        self.origin = tuple(int(v) for v in index.min(axis=0))

    def counts(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # the assessor hands the guard and the ground fit the counts it read for the tiler;
        # read them here too
        dmap, tv, pad = self.dmap, self.tv, self.tcfg.padding
        lo = np.concatenate([index.min(axis=0) * tv - pad, dmap.lo[2:]])
        hi = np.concatenate([(index.max(axis=0) + 1) * tv + pad, dmap.hi[2:]])
        lo = np.clip(lo, dmap.lo, dmap.hi)
        hi = np.clip(hi, lo, dmap.hi)
        h, p = dmap.counts(lo, hi - lo)
        return h, p, lo

    def ground(self, index: np.ndarray, read: Any = None) -> Any:
        # the assessor fits on the counts it read for the tiler: ``read`` given, no read here
        h, p, lo = self.counts(index) if read is None else read
        return fit_ground(h, p, lo, self.dmap.voxel_size, index, self.tv,
                          self.tcfg.occupied_density)

    def guard(self, b: Any, g: Any, read: Any) -> None:
        # as the assessor runs it: on the counts it read for the tiler, above the ground planes
        guard_tiles(read, self.dmap.voxel_size, b, g, self.tv, self.gcfg)

    def sites(self, g: Any) -> None:
        # every pass chooses the sites afresh over the whole grid
        nxy = self.nxy
        grid = GroundGrids(g.plane_z.reshape(nxy), g.grad.reshape(nxy + (2,)),
                           g.clearance.reshape(nxy), g.overhead.reshape(nxy))
        p = np.full(nxy, 0.9)
        cand = evaluate_candidates(p, p, self.origin, self.scfg, self.tcfg.tile_size, grid)
        find_sites(p, p, self.origin, self.scfg, self.tcfg.tile_size, ground=grid,
                   candidates=cand)

    def cut(self, index: np.ndarray, read: Any, g: Any, pool: int) -> Any:
        # the assessor's cut: on the counts it read, the cubes aligned to the tiles' ground
        # planes (tiles.align_to_ground), only the valid tiles' built, pooled for the net
        return tiles_from_counts(*read, self.dmap.voxel_size, self.tcfg, index,
                                 g if self.tcfg.align_to_ground else None,
                                 invalid_inputs=False, pool=pool)


@dataclass
class _Stages:
    """Seconds of the stages beside the network on the whole map, and what they made."""

    cut: float  # the assessor's cut, pooled for the shipped net
    cut_unpooled: float
    ground: float
    guard: float
    sites: float
    grd: Any  # the ground planes of every tile
    pooled: np.ndarray  # the inputs the tiler pooled


def run(batches: int = 30, seed: int = 0, models: tuple[str, ...] = ()) -> dict:
    """Measure and print the assessment benchmark; return its figures. ``models``: candidate
    model files, each timed as the shipped one is (map and strip, with its OOD reference)."""
    candidates = [_candidate(m) for m in models]  # a bad file fails before any timing
    batches = max(int(batches), 2)
    repeats = 3
    device = 'cuda' if torch.cuda.is_available() else 'cpu'
    results: dict = {'torch_threads': torch.get_num_threads(), 'bf16_native': bf16_supported(),
                     'device': device}
    sc = _Scene(batches, seed)
    print(f'map: 20 x 20 x 4 m at 5 cm, {batches} batches of 10,000 returns (the integrate '
          f'scene); torch threads {torch.get_num_threads()}, native bf16: {bf16_supported()}')
    # extracting every tile, as extract_tiles does it
    _extraction(sc, results, repeats)
    # the stages beside the network: the assessor's cut, ground planes, guard, sites
    st = _stages(sc, results, repeats)
    # the nets, each with its OOD signal where it flies with one
    entries: list[tuple[str, SafetyNet, str, bool, Path | None]] = []
    for spec in (DEFAULT_SPEC, PAPER_SPEC):
        net, label, path = _model(spec)
        entries.append((spec, net, label, spec == DEFAULT_SPEC, path))
    entries += [(label, net, label, True, Path(m)) for (net, label), m in zip(candidates, models)]
    nets, refs = _networks(sc, st, entries, results, repeats, device)
    # steady state: a sensor sweeps a strip; only the tiles its rays touched are re-assessed
    wide = _strip(sc, st, nets, refs, results, repeats, seed)
    # ensembles of the shipped architecture: what each member adds to a map and to a strip
    results['ensemble_s'] = _ensemble_rows(nets[DEFAULT_SPEC], st.pooled, len(wide), repeats)
    # training and data, for reference
    _training(results, seed)
    return results


def _extraction(sc: _Scene, results: dict, repeats: int) -> None:
    dmap, tcfg, buffers = sc.dmap, sc.tcfg, sc.buffers
    ext_med, ext_best = _times(lambda: extract_tiles(dmap, tcfg, buffers=buffers), repeats)
    cnt_med, _ = _times(dmap.counts, repeats)
    # what the assessor cuts for a net that opens with a 2^3 pool (the shipped one)
    extp_med, extp_best = _times(lambda: extract_tiles(dmap, tcfg, buffers=buffers, pool=2),
                                 repeats)
    n, valid = len(sc.batch), int(sc.batch.valid.sum())
    results.update(tiles=n, valid_tiles=valid, extract_s=ext_med,
                   extract_pooled_s=extp_med, extract_counts_s=cnt_med)
    print(f'extract {n} tiles ({valid} valid): {ext_med * 1e3:.1f} ms '
          f'({ext_best * 1e3:.1f}); of which reading the counts {cnt_med * 1e3:.1f} ms; '
          f'pooled 2^3 as the shipped net reads them: {extp_med * 1e3:.1f} ms '
          f'({extp_best * 1e3:.1f})')


def _stages(sc: _Scene, results: dict, repeats: int) -> _Stages:
    index, n, tcfg, nxy = sc.batch.index, len(sc.batch), sc.tcfg, sc.nxy
    grd = sc.ground(index)
    read = sc.counts(index)
    ground_med, ground_best = _times(lambda: sc.ground(index, read), repeats)
    # what the assessor cuts for the shipped net (its inputs below): counts read, then the cut
    cut_med, cut_best = _times(lambda: sc.cut(index, sc.counts(index), grd, 2), repeats)
    cut1_med, _ = _times(lambda: sc.cut(index, sc.counts(index), grd, 1), repeats)
    pooled = sc.cut(index, read, grd, 2).inputs
    results.update(extract_assessor_s=cut_med, extract_assessor_unpooled_s=cut1_med)
    aligned = 'aligned to the ground planes, ' if tcfg.align_to_ground else ''
    print(f'the assessor\'s cut ({aligned}valid tiles only, counts read included): pooled '
          f'{cut_med * 1e3:.1f} ms '
          f'({cut_best * 1e3:.1f}), unpooled {cut1_med * 1e3:.1f} ms')
    guard_med, guard_best = _times(lambda: sc.guard(sc.batch, grd, read), repeats)
    sites_med, sites_best = _times(lambda: sc.sites(grd), repeats)
    results.update(ground_s=ground_med, guard_s=guard_med, sites_s=sites_med)
    print(f'ground planes of the {n} tiles (slope, roughness, clearance; on the counts the '
          f'tiler read): {ground_med * 1e3:.1f} ms ({ground_best * 1e3:.1f})')
    print(f'guard on the {n} tiles (on the counts the tiler read): '
          f'{guard_med * 1e3:.1f} ms ({guard_best * 1e3:.1f})')
    print(f'landing-site candidates, limits and reasons over the {nxy[0]} x {nxy[1]} grid: '
          f'{sites_med * 1e3:.1f} ms ({sites_best * 1e3:.1f})')
    return _Stages(cut_med, cut1_med, ground_med, guard_med, sites_med, grd, pooled)


def _networks(sc: _Scene, st: _Stages, entries: list[tuple[str, SafetyNet, str, bool,
                                                           Path | None]],
              results: dict, repeats: int, device: str
              ) -> tuple[dict[str, SafetyNet], dict[str, FeatureReference]]:
    """Each net on the map's tiles per mode; the full map's seconds with its best mode. Entries:
    (key, net, label, whether it flies with an OOD signal, the file whose reference that is;
    None: a random one of its size). The shipped net and the candidates judge with their OOD
    signal, the paper's net without one."""
    batch, n, pooled = sc.batch, len(sc.batch), st.pooled
    nets: dict[str, SafetyNet] = {}
    refs: dict[str, FeatureReference] = {}
    oods: dict[str, dict] = {}
    for spec, net, label, with_ood, model_file in entries:
        if device == 'cuda':
            net = net.to('cuda')
        nets[spec] = net
        rows = _network_rows(net, batch.inputs, pooled, repeats, device)
        best_row = min(rows, key=lambda r: r[1])
        net_s, judged = best_row[1], best_row[0]
        pool = judged.endswith(POOLED)
        x = pooled if pool else batch.inputs
        if with_ood:  # what flies (or would): the network with its OOD signal
            ref, ref_label = _reference(net, model_file)
            refs[spec] = ref
            prec, cl = judged.split()[0], 'channels-last' in judged
            with Predictor(net) as predictor:
                feats = predictor.with_features(x, 256, prec, channels_last=cl,
                                                pooled=pool)[1]
                net_s, _ = _times(lambda: ref.ratio(predictor.with_features(
                    x, 256, prec, channels_last=cl, pooled=pool)[1]), repeats)
            dist_s, dist_best = _times(lambda: ref.ratio(feats), repeats)
            judged += ' + OOD'
            oods[spec] = {'reference': ref_label, 'rows': int(len(ref.features)),
                          'distance_s': dist_s, 'network_with_ood_s': net_s}
        full = (st.cut if pool else st.cut_unpooled) + st.ground + st.guard + st.sites + net_s
        results[spec] = {
            'label': label, 'mmac_per_tile': net.flops() / 1e6,
            'network_s': {name: med for name, med, _ in rows},
            'ms_per_tile': {name: med / n * 1e3 for name, med, _ in rows},
            'best': best_row[0], 'map_s': full}
        print(f'\n{label}, {net.flops() / 1e6:.0f} MMAC per tile, on {device}:')
        print(f'  {"mode":<28} {"s / 400 tiles":>14} {"(best)":>8} {"ms / tile":>10}')
        for name, med, best in rows:
            print(f'  {name:<28} {med:>14.3f} {best:>8.3f} {med / n * 1e3:>10.2f}')
        if spec in refs:
            print(f'  OOD reference {oods[spec]["reference"]}: distances of the {n} tiles '
                  f'{dist_s * 1e3:.1f} ms ({dist_best * 1e3:.1f}); network with features and '
                  f'distances {net_s:.3f} s')
        verdict = ('met' if full <= TARGET_MAP_S else 'NOT met')
        print(f'  full map (extraction + ground + guard + sites + {judged}): {full:.2f} s; '
              f'target <= {TARGET_MAP_S} s {verdict}; aim {AIM_MAP_S} s; ms per tile '
              f'{best_row[1] / n * 1e3:.2f} (target <= {TARGET_MS_PER_TILE:.0f})')
    results['ood'] = oods[DEFAULT_SPEC]
    for spec in oods:
        if spec != DEFAULT_SPEC:
            results[spec]['ood'] = oods[spec]
    return nets, refs


def _strip(sc: _Scene, st: _Stages, nets: dict[str, SafetyNet],
           refs: dict[str, FeatureReference], results: dict, repeats: int, seed: int
           ) -> np.ndarray:
    """Re-assessing the tiles a strip of returns touched, with their neighbours; returns them."""
    dmap = sc.dmap
    dmap.pop_dirty()
    pts = make_batches(1, seed + 1000, batch=70_000)[0]
    strip = pts[(pts[:, 0] >= 2.0) & (pts[:, 0] < 5.0)]
    dmap.integrate(strip, SENSOR)
    dirty = dmap.pop_dirty()
    # inputs reach one tile into the neighbours (padding), so their inputs changed too
    wide = widen_tiles(dirty)
    known = {tuple(k) for k in sc.batch.index.tolist()}
    wide = np.array([k for k in wide.tolist() if tuple(k) in known], np.int64).reshape(-1, 2)
    results['dirty'] = {'returns': int(len(strip)), 'dirty_tiles': int(len(dirty)),
                        'tiles': int(len(wide))}
    print(f'\nre-assess after {len(strip):,} returns on a 3 m strip (x in [2, 5) m): '
          f'{len(dirty)} dirty tiles, {len(wide)} with their neighbours:')
    for spec, net in nets.items():
        mode = results[spec]['best']
        prec, cl, pool = mode.split()[0], 'channels-last' in mode, mode.endswith(POOLED)

        predictor = Predictor(net)
        ref = refs.get(spec)

        def update(predictor: Predictor = predictor, prec: str = prec, cl: bool = cl,
                   ref: FeatureReference | None = ref, pool: bool = pool) -> None:
            sub_read = sc.counts(wide)
            g = sc.ground(wide, sub_read)
            sub = sc.cut(wide, sub_read, g, 2 if pool else 1)
            sc.guard(sub, g, sub_read)
            if ref is None:
                predictor(sub.inputs, 256, prec, channels_last=cl, pooled=pool)
            else:  # as the assessor runs it: the features from the same pass
                ref.ratio(predictor.with_features(sub.inputs, 256, prec, channels_last=cl,
                                                  pooled=pool)[1])
            sc.sites(st.grd)  # the grid's candidates are chosen afresh

        med, best = _times(update, repeats)
        predictor.close()
        results['dirty'][spec] = med
        verdict = 'met' if med <= TARGET_STRIP_S else 'NOT met'
        print(f'  {spec}{" + OOD" if ref is not None else ""}: {med:.3f} s ({best:.3f}) against '
              f'{results[spec]["map_s"]:.3f} s for the whole map; target <= {TARGET_STRIP_S} s '
              f'{verdict}')
    return wide


def _training(results: dict, seed: int) -> None:
    print('\ntraining step, batch 20, forward + backward + SGD, channels-last:')
    results['train_ms_per_sample'] = {}
    for spec in (DEFAULT_SPEC, PAPER_SPEC):
        for prec in (['fp32', 'bf16'] if bf16_supported() else ['fp32']):
            med, best = _train_step_ms(spec, prec)
            results['train_ms_per_sample'][f'{spec} {prec}'] = med
            print(f'  {spec} {prec}: {med:.1f} ms per sample ({best:.1f})')
    if not bf16_supported():
        print('  bf16 skipped: no native bf16 on this CPU (it would fall back to slow kernels)')
    pts = make_batches(1, seed + 2000, batch=26_000, half=2.5)[0]
    voxelizer = PatchVoxelizer()
    med, best = _times(lambda: voxelizer(pts, SENSOR, yaw=0.4, z_shift=0.1), 5)
    results['pipeline_samples_per_s'] = 1.0 / med
    print(f'data pipeline (re-voxelize a 26k-return patch, one process): {1 / med:.0f} '
          f'samples/s ({1 / best:.0f})')
