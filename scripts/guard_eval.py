"""Does the guard add safety on flights unlike the training set, without costing grass-is-safe?

The shipped network was trained on the simulator's rocks, tires, cinder blocks and a box in
independent grass blades seen by a nodding line scanner. This measures it, alone and with the
guard beside it (:mod:`landing_zone.judging.guard`), on what it never saw:

* **obstacles of shapes outside the library**, built here and only here (the project's
  procedural families live elsewhere): logs, posts, open buckets and crates, slabs, leaning
  boards, balls, piles of blocks, low walls, stumps and lying pipes, each instance with its own
  drawn dimensions (10-50 cm high, at most 70 cm across), standing on the ground the flight's
  own returns show and inserted into the flight as ``landing-zone insert-obstacles`` does
  (rays cut short at their surface), so they stand in whatever vegetation is there;
* **vegetation of other structure** (``simulate-flight --vegetation clumped|tall|bushy|mixed``
  and tall grass denser than any preset), other **scan patterns** (spinning, rosette), other
  tilts, heights and densities; plus the default sites with library obstacles;
* **clear sites** of each vegetation (no obstacle at all): false alarms only.

Every flight is replayed through the same pipeline as the node
(:func:`landing_zone.replay.replay`, map fixed on the site), which keeps the
network's own P(safe) (``p_net``) beside the final one (``p_safe``: the guard and, when the
model has its reference, the OOD signal applied), so all are scored on the same tiles: the
network alone, with the guard (its cap applied to ``p_net``), and with the guard and the OOD
signal (tiles judged safe that look unlike the training data become unknown,
:mod:`landing_zone.judging.ood`). Per condition (tiles pooled over its seeds): per-tile AUC
over the judged tiles, the shares of obstacle tiles at P(safe) >= 0.5 and >= 0.9, false alarms
(share of safe tiles at P(safe) < 0.5), unknown tiles; and for the guard itself, the tiles it
capped and how many of them were safe::

    python scripts/guard_eval.py runs/guard_eval --seeds 3 --json runs/guard_eval.json \
        [--model M.safetensors]

Flights, inserted bags and per-flight results are kept in WORKDIR: a rerun (or a run cut
short) picks up where it stopped. Seeds start at ``--first-seed`` (100: the guard's
thresholds were chosen on seeds below 100, so these flights are fresh).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zlib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

SITE = 12.0  # [m] edge of every site
SEPARATION = 1.45  # [m] between obstacle centres

# name -> (vegetation, scan pattern, library obstacles, test shapes, flight overrides)
CONDITIONS: dict[str, tuple[str, str, int, int, dict[str, Any]]] = {
    'default': ('default', 'line', 3, 9, {}),
    'tall': ('tall', 'line', 0, 12, {}),
    'tall-dense': ('tall', 'line', 0, 12, {'grass_density': 1500.0}),
    'mixed': ('mixed', 'line', 0, 12, {}),
    'clumped': ('clumped', 'line', 0, 12, {}),
    'bushy': ('bushy', 'line', 0, 12, {}),
    'mixed-spinning': ('mixed', 'spinning', 0, 12, {}),
    'clumped-rosette': ('clumped', 'rosette', 0, 12, {}),
    'tall-rosette': ('tall', 'rosette', 0, 12, {}),
    'default-tilt30': ('default', 'line', 0, 12, {'tilt': 30.0}),
    'mixed-high-sparse': ('mixed', 'line', 0, 12, {'height': 18.0, 'density': 1000.0}),
    'clear-tall': ('tall', 'line', 0, 0, {}),
    'clear-tall-dense': ('tall', 'line', 0, 0, {'grass_density': 1500.0}),
    'clear-mixed': ('mixed', 'line', 0, 0, {}),
    'clear-clumped': ('clumped', 'line', 0, 0, {}),
    'clear-bushy': ('bushy', 'line', 0, 0, {}),
}


# --- test shapes (outside the library; this script only) ---------------------------------------

def _model(name: str, mesh: Any, embed: float = 0.0) -> Any:
    from landing_zone.tools.sim.obstacles import ObstacleModel, _normalise
    return ObstacleModel(name, 'box', 'test', _normalise(np.asarray(mesh.vertices, float)),
                         np.asarray(mesh.faces, np.int64), embed)


def _boxes(parts: list[tuple[tuple[float, float, float], tuple[float, float, float]]]) -> Any:
    import trimesh
    meshes = []
    for centre, extents in parts:
        b = trimesh.creation.box(extents=extents)
        b.apply_translation(centre)
        meshes.append(b)
    return trimesh.util.concatenate(meshes)


def _turn(mesh: Any, angle: float, axis: tuple[float, float, float]) -> Any:
    import trimesh
    mesh.apply_transform(trimesh.transformations.rotation_matrix(angle, axis))
    return mesh


def test_shape(kind: str, rng: np.random.Generator) -> Any:
    """One instance of a test shape, its dimensions drawn from ``rng``."""
    import trimesh
    u = rng.uniform
    if kind == 'log':
        r, length = u(0.08, 0.15), u(0.4, 0.7)
        m = _turn(trimesh.creation.cylinder(radius=r, height=length, sections=20),
                  math.pi / 2, (0, 1, 0))
        return _model(f'log r{r:.2f}', m, embed=0.2 * r)
    if kind == 'post':
        r, h = u(0.04, 0.08), u(0.25, 0.5)
        return _model(f'post h{h:.2f}', trimesh.creation.cylinder(radius=r, height=h,
                                                                  sections=16))
    if kind == 'bucket':  # open at the top, a bottom inside
        r, h, w = u(0.12, 0.2), u(0.2, 0.4), 0.012
        tube = trimesh.creation.annulus(r_min=r - w, r_max=r, height=h, sections=32)
        bottom = trimesh.creation.cylinder(radius=r - w, height=w, sections=32)
        bottom.apply_translation((0, 0, -h / 2 + w / 2))
        return _model(f'bucket h{h:.2f}', trimesh.util.concatenate([tube, bottom]))
    if kind == 'crate':  # open at the top, thin walls
        dx, dy, dz, w = u(0.3, 0.6), u(0.25, 0.45), u(0.15, 0.35), 0.015
        return _model(f'crate h{dz:.2f}', _boxes([
            ((0, (dy - w) / 2, dz / 2), (dx, w, dz)), ((0, -(dy - w) / 2, dz / 2), (dx, w, dz)),
            (((dx - w) / 2, 0, dz / 2), (w, dy - 2 * w, dz)),
            ((-(dx - w) / 2, 0, dz / 2), (w, dy - 2 * w, dz)),
            ((0, 0, w / 2), (dx - 2 * w, dy - 2 * w, w))]))
    if kind == 'slab':
        dx, dy, dz = u(0.4, 0.7), u(0.3, 0.6), u(0.15, 0.25)
        return _model(f'slab h{dz:.2f}', trimesh.creation.box(extents=(dx, dy, dz)),
                      embed=0.01)
    if kind == 'board':  # leaning: one edge on the ground
        length, lean = u(0.5, 0.7), math.radians(u(20.0, 45.0))
        m = _turn(trimesh.creation.box(extents=(length, u(0.2, 0.3), 0.03)), lean, (0, 1, 0))
        return _model(f'board {math.degrees(lean):.0f}deg', m)
    if kind == 'ball':
        r = u(0.1, 0.2)
        return _model(f'ball r{r:.2f}', trimesh.creation.icosphere(subdivisions=2, radius=r))
    if kind == 'pile':  # blocks on blocks
        parts = []
        n = int(rng.integers(3, 6))
        for i in range(n):
            s = u(0.1, 0.16)
            z = s / 2 if i < n - 1 else 1.5 * s
            parts.append(((u(-0.12, 0.12), u(-0.12, 0.12), z), (s, s * u(1.0, 1.4), s)))
        return _model(f'pile of {n}', _boxes(parts))
    if kind == 'wall':
        dx, dy, dz = u(0.5, 0.7), u(0.08, 0.15), u(0.15, 0.3)
        return _model(f'wall h{dz:.2f}', trimesh.creation.box(extents=(dx, dy, dz)))
    if kind == 'stump':
        r, h = u(0.12, 0.25), u(0.15, 0.35)
        return _model(f'stump h{h:.2f}', trimesh.creation.cylinder(radius=r, height=h,
                                                                   sections=24))
    if kind == 'pipe':  # lying, hollow
        r, length = u(0.08, 0.15), u(0.4, 0.7)
        m = _turn(trimesh.creation.annulus(r_min=r - 0.01, r_max=r, height=length, sections=24),
                  math.pi / 2, (0, 1, 0))
        return _model(f'pipe r{r:.2f}', m)
    raise ValueError(f'unknown test shape {kind!r}')


SHAPES = ('log', 'post', 'bucket', 'crate', 'slab', 'board', 'ball', 'pile', 'wall', 'stump',
          'pipe')


def place_shapes(points: np.ndarray, count: int, taken: list[np.ndarray],
                 rng: np.random.Generator) -> list[Any]:
    """``count`` test shapes (kinds cycled from a random start) on the flight's own ground."""
    from landing_zone.tools.sim.placement import SINK, ground_height
    from landing_zone.tools.sim.obstacles import Obstacle

    out = []
    start = int(rng.integers(len(SHAPES)))
    half = SITE / 2 - 0.8
    for i in range(count):
        model = test_shape(SHAPES[(start + i) % len(SHAPES)], rng)
        for _ in range(5000):
            c = rng.uniform(-half, half, 2)
            if all(np.hypot(*(c - t)) >= SEPARATION for t in taken):
                break
        else:
            raise RuntimeError(f'no room for test shape {i + 1} of {count}')
        g = ground_height(points, float(c[0]), float(c[1]), 0.6)
        if g is None:
            raise RuntimeError(f'no ground under ({c[0]:.1f}, {c[1]:.1f})')
        out.append(Obstacle(model, float(c[0]), float(c[1]), g - model.embed - SINK,
                            float(rng.uniform(0.0, 2.0 * math.pi))))
        taken.append(c)
    return out


# --- one flight --------------------------------------------------------------------------------

def run_flight(work: Path, name: str, seed: int, keep_map: bool = False,
               model: Path | None = None, align: bool = True) -> dict[str, Any]:
    """Simulate, insert, replay one flight of a condition (cached in ``work``) with ``model``
    (None: the shipped one, and its OOD reference beside it), its cubes aligned to the ground
    planes or, ``align`` False, cut level; with ``keep_map`` the final
    density map goes to ``NAME_SEED.npz`` beside its labels (for ``scripts/ood_eval.py``)."""
    from landing_zone.tools.sim.insert import insert_obstacles
    from landing_zone.tools.sim.recorded import read_flight
    from landing_zone.replay import replay
    from landing_zone.tools.sim.flight import flight_config, simulate_flight

    result = work / f'{name}_{seed}.json'
    if result.exists():
        return json.loads(result.read_text())
    veg, scan, n_lib, n_shapes, extra = CONDITIONS[name]
    extra = dict(extra)
    density = extra.pop('density', None)
    t0 = time.perf_counter()
    cfg = flight_config(veg, scan, density=density, size=SITE, obstacles=n_lib, seed=seed,
                        **extra)
    bag = work / f'{name}_{seed}.mcap'
    simulate_flight(cfg, bag, overwrite=True)
    labels = bag.with_suffix('.labels.json')
    if n_shapes:
        doc = json.loads(labels.read_text())
        taken = [np.array([o['x'], o['y']]) for o in doc['obstacles']]
        # shapes of their own per condition and seed (the ground and the flight noise of one
        # seed are the same whatever the vegetation)
        rng = np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(name.encode())]))
        shapes = place_shapes(read_flight(bag).points, n_shapes, taken, rng)
        inserted = work / f'{name}_{seed}_h.mcap'
        insert_obstacles(bag, inserted, obstacles=shapes, seed=seed, overwrite=True)
        bag.unlink()
        bag, labels = inserted, inserted.with_suffix('.labels.json')
    from landing_zone.config import AssessorConfig, GuardConfig

    config = AssessorConfig()
    config.tiles = replace(config.tiles, align_to_ground=align)
    res = replay(bag, center=(0.0, 0.0), progress=False, model=model, config=config)
    a = res.assessment
    cap = GuardConfig().max_p_safe
    ood = a.ood if a.ood is not None else np.full(len(a), np.nan)
    doc = json.loads(labels.read_text())
    truth = {(round(t['x'], 3), round(t['y'], 3)): bool(t['safe']) for t in doc['tiles']}
    kinds, centres = _obstacle_tiles(doc['obstacles'])
    tiles = []
    for k, (x, y) in enumerate(a.centers.tolist()):
        key = (round(x, 3), round(y, 3))
        if key not in truth:
            continue
        p_guard = min(float(a.p_net[k]), cap) if a.guard[k] else float(a.p_net[k])
        tiles.append({'x': key[0], 'y': key[1], 'safe': truth[key], 'p_net': _num(a.p_net[k]),
                      'p_guard': _num(p_guard),
                      'p_safe': _num(a.p_safe[k]), 'ood': _num(ood[k]),
                      'guard': bool(a.guard[k]),
                      'guard_hits': int(a.guard_hits[k]), 'kinds': kinds.get(key, []),
                      'centre': key in centres})
    doc = {'condition': name, 'seed': seed, 'tile_size': float(doc['tile_size']), 'tiles': tiles,
           'ood_reference': res.ood_reference,
           'obstacles': [o.get('model', o['kind'])
                         for o in json.loads(labels.read_text())['obstacles']],
           'assess_seconds': res.timings['assess'], 'seconds': time.perf_counter() - t0}
    result.write_text(json.dumps(doc))
    if keep_map:
        _save_map(bag, a, work / f'{name}_{seed}.npz')
        (work / f'{name}_{seed}.labels.json').write_text(labels.read_text())
    bag.unlink()  # the figures are kept; the bags are big
    return doc


def workdir_tiles(work: Path, key: str = 'p_safe') -> tuple[np.ndarray, np.ndarray]:
    """P(safe) ``key`` (``p_net``, ``p_guard`` or ``p_safe``) and ground truth (1 safe) of
    every judged tile of the flights kept in ``work`` (``NAME_SEED.json`` per flight, as
    :func:`run_flight` writes them), pooled; the reader of this script's results for
    ``flight_reliability.py`` and ``operating_points.py``."""
    p, y = [], []
    results = sorted(f for f in work.glob('*_[0-9]*.json') if not f.name.endswith('.labels.json'))
    if not results:
        raise ValueError(f'no flight results (NAME_SEED.json) in {work}')
    for f in results:
        for t in json.loads(f.read_text())['tiles']:
            if t[key] is not None:
                p.append(float(t[key]))
                y.append(1.0 if t['safe'] else 0.0)
    return np.asarray(p), np.asarray(y)


def _obstacle_tiles(obstacles: list[dict[str, Any]]
                    ) -> tuple[dict[tuple[float, float], list[str]], set[tuple[float, float]]]:
    """Per tile the kinds of the obstacles over it (a test shape's kind is the first word of
    its name), and the tiles holding an obstacle's centre."""
    from landing_zone.tools.sim.flight import polygon_overlaps_square

    kinds: dict[tuple[float, float], list[str]] = {}
    centres = set()
    for o in obstacles:
        kind = str(o.get('model', o['kind'])).split()[0].split('_')[0]
        c, s = math.cos(o['yaw']), math.sin(o['yaw'])
        dx, dy = o['size'][0] / 2, o['size'][1] / 2
        # the footprint's bounding box turned by the yaw: a superset of the footprint, used
        # only to find the tiles to test against the labels' unsafe ones
        box = np.array([[o['x'] + c * u - s * v, o['y'] + s * u + c * v]
                        for u, v in ((-dx, -dy), (dx, -dy), (dx, dy), (-dx, dy))])
        for kx in range(math.floor(box[:, 0].min()), math.ceil(box[:, 0].max())):
            for ky in range(math.floor(box[:, 1].min()), math.ceil(box[:, 1].max())):
                if polygon_overlaps_square(box, np.array([kx, ky]), np.array([kx + 1, ky + 1])):
                    kinds.setdefault((kx + 0.5, ky + 0.5), []).append(kind)
        centres.add((math.floor(o['x']) + 0.5, math.floor(o['y']) + 0.5))
    return kinds, centres


def _save_map(bag: Path, a: Any, out: Path) -> None:
    """The flight's final map (every return integrated, the map fixed on the site)."""
    from landing_zone.assessor import Assessor
    from landing_zone.tools.sim.recorded import read_flight

    fl = read_flight(bag)
    ok = np.isfinite(fl.origins).all(axis=1)
    first = int(np.flatnonzero(ok)[0])
    m = Assessor(center=(0.0, 0.0))
    m.integrate(fl.points[fl.cloud == first], fl.origins[first])  # places the map's height
    rest = (fl.cloud != first) & ok[fl.cloud]
    m.map.integrate(fl.points[rest], fl.ray_origins()[rest])
    hits, passes = m.map.counts()
    np.savez_compressed(out, hits=hits, passes=passes, lo=m.map.lo, index=a.index,
                        ground_z=a.ground_z, p_safe=a.p_net, voxel_size=m.map.voxel_size)


def _num(v: float) -> float | None:
    return None if math.isnan(float(v)) else float(v)


# --- scoring -----------------------------------------------------------------------------------

def scores(tiles: list[dict[str, Any]], key: str) -> dict[str, Any]:
    """AUC, obstacle tiles passed, false alarms and unknown tiles of P(safe) ``key``."""
    from sklearn.metrics import roc_auc_score

    judged = [t for t in tiles if t[key] is not None]
    y = np.array([t['safe'] for t in judged], bool)
    p = np.array([t[key] for t in judged], float)
    out: dict[str, Any] = {'tiles': len(tiles), 'unknown': len(tiles) - len(judged),
                           'safe': int(y.sum()), 'obstacle': int((~y).sum())}
    out['auc'] = float(roc_auc_score(y, p)) if y.any() and (~y).any() else None
    out['obstacle_ge_0.5'] = float((p[~y] >= 0.5).mean()) if (~y).any() else None
    out['obstacle_ge_0.9'] = float((p[~y] >= 0.9).mean()) if (~y).any() else None
    out['false_alarms'] = float((p[y] < 0.5).mean()) if y.any() else None
    return out


def next_to_obstacle(doc: dict[str, Any]) -> list[bool | None]:
    """Per tile of a flight's result: whether one of its 8 neighbours holds an obstacle (None
    for results written before the tiles carried their centres)."""
    if 'tile_size' not in doc:
        return [None] * len(doc['tiles'])
    ts = doc['tile_size']

    def index(t: dict[str, Any]) -> tuple[int, int]:  # tile centres lie on half tiles
        return math.floor(t['x'] / ts), math.floor(t['y'] / ts)

    blocked = {index(t) for t in doc['tiles'] if not t['safe']}
    out: list[bool | None] = []
    for t in doc['tiles']:
        i, j = index(t)
        out.append(any((i + di, j + dj) in blocked for di in (-1, 0, 1) for dj in (-1, 0, 1)
                       if di or dj))
    return out


def false_alarms_by_neighbour(docs: list[dict[str, Any]], key: str = 'p_safe'
                              ) -> dict[str, Any] | None:
    """The safe tiles judged (P(safe) ``key`` known) and those flagged (< 0.5), next to an
    obstacle tile and elsewhere: synth3's training scenes never show a safe tile with an
    obstacle beside it, so this is where a flight's false alarms may come from."""
    near: dict[bool, list[int]] = {True: [0, 0], False: [0, 0]}
    for d in docs:
        for t, nb in zip(d['tiles'], next_to_obstacle(d)):
            if nb is None:
                return None
            if t['safe'] and t[key] is not None:
                near[nb][0] += 1
                near[nb][1] += t[key] < 0.5
    return {'next_to_obstacle': {'safe': near[True][0], 'flagged': near[True][1]},
            'elsewhere': {'safe': near[False][0], 'flagged': near[False][1]}}


def summarise(docs: list[dict[str, Any]]) -> dict[str, Any]:
    tiles = [t for d in docs for t in d['tiles']]
    fired = [t for t in tiles if t['guard']]
    return {'flights': len(docs), 'cnn': scores(tiles, 'p_net'),
            'false_alarms_by_neighbour': false_alarms_by_neighbour(docs),
            'cnn_guard': scores(tiles, 'p_guard'), 'cnn_guard_ood': scores(tiles, 'p_safe'),
            'guard_fired': len(fired), 'guard_fired_safe': sum(t['safe'] for t in fired),
            'guard_added_alarms': sum(t['safe'] and t['p_net'] is not None
                                      and t['p_net'] >= 0.5 for t in fired),
            'guard_caught': sum(not t['safe'] and t['p_net'] is not None
                                and t['p_net'] >= 0.5 for t in fired)}


def _pct(v: float | None) -> str:
    return 'n/a' if v is None else f'{100 * v:.1f}%'


def _auc(v: float | None) -> str:
    return 'n/a' if v is None else f'{v:.3f}'


def table(summary: dict[str, dict[str, Any]]) -> str:
    rows = ['| condition | flights | tiles (obstacle) | AUC CNN / +guard | obstacle >= 0.5 '
            'CNN / +guard | obstacle >= 0.9 CNN / +guard | false alarms CNN / +guard | '
            'guard fired (safe) |',
            '|---|---:|---:|---:|---:|---:|---:|---:|']
    for name, s in summary.items():
        c, g = s['cnn'], s['cnn_guard']
        rows.append(
            f'| {name} | {s["flights"]} | {c["tiles"] - c["unknown"]} ({c["obstacle"]}) | '
            f'{_auc(c["auc"])} / {_auc(g["auc"])} | '
            f'{_pct(c["obstacle_ge_0.5"])} / {_pct(g["obstacle_ge_0.5"])} | '
            f'{_pct(c["obstacle_ge_0.9"])} / {_pct(g["obstacle_ge_0.9"])} | '
            f'{_pct(c["false_alarms"])} / {_pct(g["false_alarms"])} | '
            f'{s["guard_fired"]} ({s["guard_fired_safe"]}) |')
    return '\n'.join(rows)


def by_kind(docs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per obstacle kind, over the obstacle tiles it is on: how often the guard fires, and
    the shares passed at P(safe) >= 0.5 by the network alone and with the guard; the same on
    the tiles holding the obstacles' centres (where most of an obstacle stands)."""
    out: dict[str, dict[str, Any]] = {}
    tiles = [t for d in docs for t in d['tiles'] if not t['safe'] and t['p_net'] is not None]
    for kind in sorted({k for t in tiles for k in t['kinds']}):
        row: dict[str, Any] = {}
        for part, sel in (('all', lambda t: True), ('centre', lambda t: t['centre'])):
            ts = [t for t in tiles if kind in t['kinds'] and sel(t)]
            row[part] = {'tiles': len(ts),
                         'guard_fired': float(np.mean([t['guard'] for t in ts])) if ts else None,
                         'cnn_ge_0.5': float(np.mean([t['p_net'] >= 0.5 for t in ts]))
                         if ts else None,
                         'cnn_guard_ge_0.5': float(np.mean([t['p_guard'] >= 0.5 for t in ts]))
                         if ts else None}
        out[kind] = row
    return out


def ood_table(summary: dict[str, dict[str, Any]]) -> str:
    rows = ['| condition | unknown CNN + guard / + OOD | AUC | obstacle >= 0.5 | obstacle >= 0.9 '
            '| false alarms |', '|---|---:|---:|---:|---:|---:|']
    for name, s in summary.items():
        g, o = s['cnn_guard'], s['cnn_guard_ood']
        rows.append(f'| {name} | {_pct(g["unknown"] / g["tiles"])} / '
                    f'{_pct(o["unknown"] / o["tiles"])} | {_auc(o["auc"])} | '
                    f'{_pct(o["obstacle_ge_0.5"])} | {_pct(o["obstacle_ge_0.9"])} | '
                    f'{_pct(o["false_alarms"])} |')
    return '\n'.join(rows)


def kind_table(kinds: dict[str, dict[str, Any]]) -> str:
    rows = ['| obstacle kind | tiles (centre tiles) | guard fires: all / centre | passed at '
            '>= 0.5, CNN: all / centre | CNN + guard: all / centre |',
            '|---|---:|---:|---:|---:|']
    for kind, r in kinds.items():
        a, c = r['all'], r['centre']
        rows.append(f'| {kind} | {a["tiles"]} ({c["tiles"]}) | {_pct(a["guard_fired"])} / '
                    f'{_pct(c["guard_fired"])} | {_pct(a["cnn_ge_0.5"])} / '
                    f'{_pct(c["cnn_ge_0.5"])} | {_pct(a["cnn_guard_ge_0.5"])} / '
                    f'{_pct(c["cnn_guard_ge_0.5"])} |')
    return '\n'.join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('workdir', type=Path)
    ap.add_argument('--seeds', type=int, default=3, help='flights per condition')
    ap.add_argument('--first-seed', type=int, default=100)
    ap.add_argument('--conditions', default=','.join(CONDITIONS),
                    help='comma separated, from: ' + ', '.join(CONDITIONS))
    ap.add_argument('--json', type=Path, default=None, help='write the figures here')
    ap.add_argument('--model', type=Path, default=None,
                    help='model file (default: the shipped one); its NAME.ood.safetensors '
                         'beside it is its OOD reference. Use a WORKDIR per model: results '
                         'there are reused')
    ap.add_argument('--level', action='store_true',
                    help='cut the cubes level (tiles.align_to_ground off; default: aligned to '
                         'the ground plane, the shipped default). Use a WORKDIR per setting')
    ap.add_argument('--keep-maps', action='store_true',
                    help='also keep each flight\'s final density map (NAME_SEED.npz)')
    args = ap.parse_args()
    names = [c.strip() for c in args.conditions.split(',') if c.strip()]
    unknown = [c for c in names if c not in CONDITIONS]
    if unknown:
        print(f'guard_eval: unknown condition {unknown[0]!r}', file=sys.stderr)
        return 2
    args.workdir.mkdir(parents=True, exist_ok=True)
    summary: dict[str, dict[str, Any]] = {}
    for name in names:
        docs = []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            docs.append(run_flight(args.workdir, name, seed, args.keep_maps, args.model,
                                   align=not args.level))
            print(f'{name} seed {seed}: {docs[-1]["seconds"]:.0f} s', file=sys.stderr)
        summary[name] = summarise(docs)
    obstacle = [n for n in names if CONDITIONS[n][3] or CONDITIONS[n][2]]
    if obstacle:
        docs = [json.loads((args.workdir / f'{n}_{s}.json').read_text()) for n in obstacle
                for s in range(args.first_seed, args.first_seed + args.seeds)]
        summary['all with obstacles'] = summarise(docs)
        summary['all with obstacles']['by_kind'] = by_kind(docs)
    print(table(summary))
    print()
    print(ood_table(summary))
    if obstacle:
        print()
        print(kind_table(summary['all with obstacles']['by_kind']))
        nb = summary['all with obstacles']['false_alarms_by_neighbour']
        if nb is not None:
            print()
            print('false alarms (net + guard + OOD) on safe tiles: ' + '; '.join(
                f'{where.replace("_", " ")} {v["flagged"]} of {v["safe"]} '
                f'({_pct(v["flagged"] / v["safe"] if v["safe"] else None)})'
                for where, v in nb.items()))
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
