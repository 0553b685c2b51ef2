"""Pictures of simulated returns: side and top view, coloured by what each return hit.

Like the paper's Fig. 3: ground brown, grass green, obstacles red. A dataset scene shows its
tile and padded column; a flight shows the site, its unsafe tiles and the obstacles' footprints
(from ``SITE.labels.json`` beside the bag).

matplotlib is used through its object API with the Agg canvas (no global backend state, no
display needed).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError, DatasetError, SimulationError
from landing_zone.io.labels import labels_path_for, read_labels
from landing_zone.tools.sim.mesh import GRASS, GROUND, OBSTACLE

__all__ = ['render', 'render_points', 'render_library', 'render_families', 'CLASS_COLOURS']

CLASS_COLOURS = {GROUND: '#8c6d46', GRASS: '#3f9b3a', OBSTACLE: '#d62728'}
_NAMES = {GROUND: 'ground', GRASS: 'grass', OBSTACLE: 'obstacle'}
_MAX_PLOTTED = 400_000  # points per view; more only blurs the picture and costs seconds


def _figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _scatter(ax: Any, a: np.ndarray, b: np.ndarray, labels: np.ndarray | None, size: float
             ) -> None:
    if labels is None:
        ax.scatter(a, b, s=size, c='0.3', linewidths=0, rasterized=True)
        return
    # Obstacles last: on top of the grass that surrounds them.
    for cls in (GROUND, GRASS, OBSTACLE):
        m = labels == cls
        if np.any(m):
            ax.scatter(a[m], b[m], s=size, c=CLASS_COLOURS[cls], linewidths=0,
                       label=f'{_NAMES[cls]} ({int(m.sum()):,})', rasterized=True)


def render_points(points: np.ndarray, labels: np.ndarray | None, out: str | os.PathLike,
                  title: str = '', boxes: list[tuple[np.ndarray, np.ndarray, str]] = (),
                  polygons: list[tuple[np.ndarray, str]] = (),
                  side_band: tuple[float, float] | None = None,
                  side_window: tuple[float, float] | None = None, seed: int = 0) -> Path:
    """Top view (x-y) and side view (x-z) of returns, coloured by class.

    Args:
        points: (N, 3) returns.
        labels: (N,) class of each return, or None (grey).
        out: PNG path.
        title: figure title.
        boxes: axis-aligned rectangles (lo (2,), hi (2,), colour) drawn in the top view.
        polygons: closed polygons ((K, 2), colour) drawn in the top view.
        side_band: only returns with y in this band appear in the side view (a slice).
        side_window: ... and only those with x in this range (a close-up).
        seed: subsampling of very large clouds.

    Returns:
        The PNG path.
    """
    from matplotlib.patches import Polygon, Rectangle
    points = np.asarray(points, dtype=float)
    if len(points) > _MAX_PLOTTED:
        pick = np.random.default_rng(seed).choice(len(points), _MAX_PLOTTED, replace=False)
        keep = np.sort(pick)
        points = points[keep]
        labels = labels[keep] if labels is not None else None
    size = float(np.clip(2000.0 / max(len(points), 1) ** 0.5, 0.05, 4.0))
    fig = _figure(13.0, 6.5)
    top, side = fig.subplots(1, 2, gridspec_kw={'width_ratios': [1.0, 1.3]})
    _scatter(top, points[:, 0], points[:, 1], labels, size)
    for lo, hi, colour in boxes:
        top.add_patch(Rectangle(lo, *(np.asarray(hi) - lo), fill=False, ec=colour, lw=1.0))
    for poly, colour in polygons:
        top.add_patch(Polygon(poly, closed=True, fill=False, ec=colour, lw=1.2))
    top.set_aspect('equal')
    top.set_xlabel('x [m]')
    top.set_ylabel('y [m]')
    top.set_title('top view')
    sel = np.ones(len(points), bool)
    if side_band is not None:
        sel &= (points[:, 1] >= side_band[0]) & (points[:, 1] < side_band[1])
    if side_window is not None:
        sel &= (points[:, 0] >= side_window[0]) & (points[:, 0] < side_window[1])
    _scatter(side, points[sel, 0], points[sel, 2], labels[sel] if labels is not None else None,
             size * 1.5)
    side.set_xlabel('x [m] (direction of flight)')
    side.set_ylabel('z [m]')
    band = '' if side_band is None else f', {side_band[0]:.2f} <= y < {side_band[1]:.2f} m'
    side.set_title(f'side view{band}')
    if np.any(sel):
        z = points[sel, 2]
        side.set_ylim(z.min() - 0.2, z.max() + 0.4)
        side.set_aspect('equal', adjustable='box')
    if labels is not None:
        side.legend(loc='upper right', markerscale=max(2.0, 6.0 / size ** 0.5), fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out)
    return out


def render_library(out: str | os.PathLike) -> Path:
    """Every obstacle model of the library, shaded, with its name, group and size."""
    from landing_zone.tools.sim.library import library
    lib = list(library().values())
    return _render_models(lib, [f'{m.name} ({m.group})' for m in lib], out, 6, 0.26)


def render_families(out: str | os.PathLike, per_family: int = 4, cols: int = 8,
                    panel: float = 1.7) -> Path:
    """The first ``per_family`` test instances of every obstacle family, ``cols`` to a row,
    ``panel`` inches each."""
    from landing_zone.tools.sim.families import FAMILIES, TEST_BASE, instance
    models, titles = [], []
    for name, fam in FAMILIES.items():
        for k in range(per_family):
            inst = instance(name, TEST_BASE + k)
            models.append(inst.model)
            titles.append(f'{name} ({fam.split}) {inst.pose}' + (
                f', {inst.arrangement}' if inst.arrangement != 'single' else ''))
    return _render_models(models, titles, out, cols, 0.36, panel, dpi=80, fontsize=6)


def _render_models(models: list[Any], titles: list[str], out: str | os.PathLike, cols: int,
                   r: float, panel: float = 2.6, dpi: int = 110, fontsize: int = 8) -> Path:
    """Shaded meshes in a grid, each titled with ``titles`` and its size."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    rows = -(-len(models) // cols)
    fig = _figure(panel * cols, (panel + 0.1) * rows)
    fig.set_dpi(dpi)
    light = np.array([0.4, -0.5, 0.77])
    for k, (m, title) in enumerate(zip(models, titles)):
        ax = fig.add_subplot(rows, cols, k + 1, projection='3d')
        tri = m.vertices[m.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        shade = 0.35 + 0.65 * np.clip(n @ light, 0.0, 1.0)
        base = np.array([0.62, 0.58, 0.52]) if m.kind != 'tire' else np.array([0.3, 0.3, 0.32])
        ax.add_collection3d(Poly3DCollection(tri, facecolors=shade[:, None] * base,
                                             edgecolors='none'))
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_zlim(0.0, 2 * r)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=22, azim=-60)
        ax.set_axis_off()
        dx, dy, dz = m.size
        ax.set_title(f'{title}\n{100 * dx:.0f} x {100 * dy:.0f} x {100 * dz:.0f} cm',
                     fontsize=fontsize)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=dpi)
    return out


def _verdict(label: int, obstacle: dict[str, Any] | None) -> str:
    """A scene's label as its title says it (a safe synth3 edge scene has an obstacle beside
    the tile)."""
    if label == 0:
        return 'unsafe' + (f", {obstacle['model']}" if obstacle else '')
    return 'safe' + (f", {obstacle['model']} beyond the tile's edge" if obstacle else '')


def _render_scene(root: Path, out: Path, index: int, split: str) -> Path:
    from landing_zone.tools.sim.shards import SceneDataset
    ds = SceneDataset(root, split)
    if not -len(ds) <= index < len(ds):
        raise DatasetError(f'scene {index} out of range: {root} ({split}) holds {len(ds)}')
    scene = ds[index]
    p = scene.params
    boxes = [(np.array([-0.5, -0.5]), np.array([0.5, 0.5]), 'k'),
             (np.array([-0.8, -0.8]), np.array([0.8, 0.8]), '0.6')]
    polygons = []
    if p.get('obstacle'):
        from landing_zone.tools.sim.library import get_model
        from landing_zone.tools.sim.obstacles import Obstacle
        ob = p['obstacle']
        placed = Obstacle(get_model(ob['model']), ob['x'], ob['y'], ob['z'], ob['yaw'])
        polygons.append((placed.footprint(), CLASS_COLOURS[OBSTACLE]))
    if p.get('dataset') == 'hybrid':  # cut from a recorded flight
        where = f"tile ({p['tile'][0]:g}, {p['tile'][1]:g}) of {p.get('flight')}" + (
            f", {p.get('altered', 0)} returns moved onto the obstacle" if p.get('obstacle')
            else '')
    elif p.get('dataset') == 'synth3':  # drawn from the families
        sen = p['sensor']
        where = (f"{p['vegetation']['family']} vegetation, {p['terrain']['family']} ground, "
                 f"{sen['family']} scanner {sen['height']:g} m up"
                 + ('' if p.get('obstacle') else f" (pair's family {p['family']})"))
    else:
        where = (f"{p.get('grass_density'):g} blades/m^2, {p.get('grass_height'):g} m, sensor "
                 f"at x {p.get('sensor_offset'):g} m, {p.get('sensor_height'):g} m up")
    title = (f"{p.get('dataset')} scene {p.get('index')} ({p.get('split')}): "
             f"{_verdict(scene.label, p.get('obstacle'))}; "
             f"{where}, {len(scene.points):,} returns")
    # The column and a little around it: far returns of rays that passed above the tile are
    # kept in the data but would shrink the tile to a dot.
    near = np.all(np.abs(scene.points[:, :2]) < 1.5, axis=1)
    return render_points(scene.points[near], scene.hit_class[near], out, title, boxes,
                         polygons, side_band=(-0.5, 0.5))


def _render_flight(bag: Path, out: Path) -> Path:
    from landing_zone.io.bags import read_messages
    from msg_adapters.pointcloud import cloud_to_structured
    parts, labels = [], []
    has_labels = True
    for m in read_messages(bag, topics=['/lidar/points']):
        arr = cloud_to_structured(m.msg)
        parts.append(np.stack([arr['x'], arr['y'], arr['z']], axis=1).astype(np.float32))
        if has_labels and 'label' in arr.dtype.names:
            labels.append(arr['label'].astype(np.uint8))
        else:
            has_labels = False
    if not parts:
        raise BagError(f'{bag} holds no /lidar/points clouds')
    points = np.concatenate(parts)
    cls = np.concatenate(labels) if has_labels else None
    boxes, polygons = [], []
    truth = labels_path_for(bag)
    title = f'{bag.name}: {len(points):,} returns'
    band = window = None
    if truth.exists():
        info = read_labels(truth)
        ts = float(info.get('tile_size', 1.0))
        for t in info['tiles']:
            if not t['safe']:
                c = np.array([t['x'], t['y']])
                boxes.append((c - ts / 2, c + ts / 2, '#ff7f0e'))
        from landing_zone.tools.sim.library import get_model
        from landing_zone.tools.sim.obstacles import Obstacle
        for ob in info['obstacles']:
            placed = Obstacle(get_model(ob['model']), ob['x'], ob['y'], ob['z'], ob['yaw'])
            polygons.append((placed.footprint(), 'k'))
        if 'site' in info:
            lo, hi = np.array(info['site']['lo']), np.array(info['site']['hi'])
            boxes.append((lo, hi, '0.2'))
        title += f", {len(info['obstacles'])} obstacles, {len(boxes) - 1} unsafe tiles (orange)"
        if info['obstacles']:
            ob = info['obstacles'][0]
            band = (ob['y'] - 0.5, ob['y'] + 0.5)
            window = (ob['x'] - 4.0, ob['x'] + 4.0)
    return render_points(points, cls, out, title, boxes, polygons, side_band=band,
                         side_window=window)


def render(source: str | os.PathLike, out: str | os.PathLike, index: int = 0,
           split: str = 'all') -> Path:
    """Render a dataset scene (``source`` a dataset directory), a flight (a ``.mcap`` bag) or
    the obstacle library (``source`` the word ``library``) or the obstacle families (the word
    ``families``: six test instances of each).

    Raises:
        SimulationError: ``source`` is neither.
        DatasetError, BagError: it cannot be read.
    """
    source, out = Path(source), Path(out)
    if out.suffix.lower() != '.png':
        raise SimulationError(f'render writes a .png file, got {out}')
    if str(source) == 'library' and not source.exists():
        return render_library(out)
    if str(source) == 'families' and not source.exists():
        return render_families(out)
    if source.is_dir() and (source / 'meta.json').exists():
        return _render_scene(source, out, index, split)
    if source.suffix == '.mcap' and source.exists():
        return _render_flight(source, out)
    raise SimulationError(f'{source} is neither a dataset directory nor a .mcap flight bag')
