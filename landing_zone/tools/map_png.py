"""The safety map as a picture (``demo``'s and ``replay --png``'s map.png).

Two panels side by side, on the same axes in the map's frame:

- **P(safe) per tile**, opaque, in exactly the colour bar's colours (one colormap, one norm);
  tiles not judged are drawn grey. Over them: the tiles whose centred footprint was left out
  for slope, step or clearance (hatched, one pattern each), the true obstacles' footprints
  (from SITE.labels.json, outlined) and the landing sites (footprint circles numbered best
  first).
- **Top view of the returns**: the highest return in each 10 cm cell, coloured by height, so
  the bank, the grass and the obstacles can be seen beside their tiles; the obstacles' outlines
  are drawn there too.

One legend below the panels names every mark drawn. matplotlib is offline tooling: the node
never draws.
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from landing_zone.errors import BagError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from landing_zone.assessor import Assessment

__all__ = ['draw_map', 'render_png', 'P_SAFE_CMAP', 'UNKNOWN_COLOR', 'TOP_VIEW_CELL']

P_SAFE_CMAP = 'RdYlGn'  # red 0 -> yellow 0.5 -> green 1
UNKNOWN_COLOR = '#9e9e9e'  # a tile not judged: a grey no P(safe) colour comes near
TOP_VIEW_CELL = 0.1  # pixel of the top view [m]
# How a candidate left out for a limit is marked: hatch, colour and legend text per reason.
REASON_HATCH = {'slope': ('///', 'black', 'too steep'),
                'step': ('xxx', '#3a0ca3', 'too high a step'),
                'clearance': ('...', '#00b4d8', 'too little clearance')}
OBSTACLE_COLOR = 'black'
SITE_COLOR = '#1f3bff'


def draw_map(assessment: Assessment, top_view: np.ndarray | None = None,
             labels: str | os.PathLike[str] | dict[str, Any] | None = None,
             title: str | None = None) -> Figure:
    """The figure of the module docstring (not saved; the caller closes it).

    Args:
        assessment: the tiles and sites to draw.
        top_view: (N, 3) returns for the top-view panel; None or empty: no such panel.
        labels: SITE.labels.json (path or document): outline the true obstacles.
        title: the figure's title; default one counting the judged tiles.
    """
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    ts = assessment.tile_size
    x0, y0 = assessment.origin[0] * ts, assessment.origin[1] * ts
    nx, ny = assessment.shape
    extent = (x0, x0 + nx * ts, y0, y0 + ny * ts)
    heights = (_height_image(np.asarray(top_view, np.float64).reshape(-1, 3), extent,
                             TOP_VIEW_CELL) if top_view is not None else None)
    panels = 2 if heights is not None else 1
    fig = Figure(figsize=(6.4 * panels, 6.6), dpi=110, layout='constrained')
    axes = fig.subplots(1, panels, squeeze=False)[0]
    ax = axes[0]

    # P(safe), opaque: the image and the colour bar share one colormap and one norm
    cmap = _p_safe_cmap()
    norm = Normalize(vmin=0.0, vmax=1.0)
    p = assessment.grid(assessment.p_safe)
    img = ax.imshow(np.ma.masked_invalid(p).T, origin='lower', extent=extent, cmap=cmap,
                    norm=norm, interpolation='nearest')
    fig.colorbar(img, ax=ax, label='P(safe) of the tile', shrink=0.85, pad=0.02)
    handles = []
    unknown = int((~np.isfinite(p)).sum())
    if unknown:
        handles.append(_patch(facecolor=UNKNOWN_COLOR, edgecolor='none',
                              label=f'tile not judged ({unknown})'))
    handles += _draw_reasons(ax, assessment)
    outlines = _obstacles(labels)
    for a in axes:
        for ob in outlines:
            a.add_patch(_polygon(ob))
    if outlines:
        handles.append(_patch(facecolor='none', edgecolor=OBSTACLE_COLOR, linewidth=1.5,
                              path_effects=_halo(),
                              label=f'obstacle footprint, ground truth ({len(outlines)})'))
    handles += _draw_sites(ax, assessment)
    judged = int(np.isfinite(assessment.p_safe).sum())
    ax.set_title(f'P(safe) per {ts:g} m tile', fontsize=10)

    if heights is not None:
        h = axes[1]
        finite = np.isfinite(heights)
        lo, hi = np.percentile(heights[finite], [1, 99]) if finite.any() else (0.0, 1.0)
        top = h.imshow(np.ma.masked_invalid(heights).T, origin='lower', extent=extent,
                       cmap='viridis', vmin=lo, vmax=max(hi, lo + 1e-3),
                       interpolation='nearest')
        fig.colorbar(top, ax=h, label=f'height of the highest return [m] '
                                      f'({assessment.frame_id} z)', shrink=0.85, pad=0.02)
        h.set_title(f'Top view: highest return per {100 * TOP_VIEW_CELL:.0f} cm cell '
                    '(white: no return)', fontsize=10)
    for a in axes:
        a.set_xlim(extent[0], extent[1])
        a.set_ylim(extent[2], extent[3])
        a.set_aspect('equal')
        a.set_xlabel(f'x [m] ({assessment.frame_id})')
        a.set_ylabel('y [m]')
    fig.suptitle(title or f'Safety map: {judged} of {len(assessment)} tiles judged, '
                          f'{len(assessment.sites)} landing site(s)')
    if handles:
        fig.legend(handles=handles, loc='outside lower center', ncol=min(3, len(handles)),
                   fontsize=8, frameon=False)
    return fig


def render_png(assessment: Assessment, top_view: np.ndarray | None,
               path: str | os.PathLike[str],
               labels: str | os.PathLike[str] | dict[str, Any] | None = None,
               title: str | None = None) -> None:
    """Draw :func:`draw_map` into the PNG file ``path``.

    Raises:
        BagError: the file cannot be written.
    """
    fig = draw_map(assessment, top_view, labels, title)
    try:
        fig.savefig(path)
    except OSError as err:
        raise BagError(f'cannot write {path}: {err.strerror}') from err


def _p_safe_cmap() -> Any:
    from matplotlib import colormaps

    return colormaps[P_SAFE_CMAP].with_extremes(bad=UNKNOWN_COLOR)


def _patch(**kw: Any) -> Any:
    from matplotlib.patches import Patch

    return Patch(**kw)


def _polygon(corners: np.ndarray) -> Any:
    from matplotlib.patches import Polygon

    return Polygon(corners, closed=True, fill=False, edgecolor=OBSTACLE_COLOR, linewidth=1.5,
                   path_effects=_halo())


def _halo() -> list[Any]:
    """A white rim under a black outline, so it reads on dark and light tiles alike."""
    from matplotlib import patheffects

    return [patheffects.withStroke(linewidth=3.5, foreground='white')]


def _obstacles(labels: str | os.PathLike[str] | dict[str, Any] | None) -> list[np.ndarray]:
    if labels is None:
        return []
    from landing_zone.io.labels import obstacle_footprints, read_labels

    return obstacle_footprints(labels if isinstance(labels, dict) else read_labels(labels))


def _draw_reasons(ax: Any, assessment: Assessment) -> list[Any]:
    """Hatch the tiles whose centred footprint is left out for slope, step or clearance;
    return the legend's handles (one per reason drawn)."""
    from matplotlib.patches import Rectangle

    from landing_zone.judging.sites import REASONS

    cand = assessment.candidates
    if cand is None:
        return []
    ts = assessment.tile_size
    handles = []
    for why, (hatch, color, text) in REASON_HATCH.items():
        bit = 1 << REASONS.index(why)
        cells = np.argwhere(cand.reasons & bit)
        for i, j in cells:
            x, y = cand.center(int(i), int(j))
            ax.add_patch(Rectangle((x - ts / 2, y - ts / 2), ts, ts, fill=False, hatch=hatch,
                                   edgecolor=color, linewidth=0))
        if len(cells):
            handles.append(_patch(facecolor='white', edgecolor=color, hatch=hatch,
                                  label=f'landing footprint centred here: {text} '
                                        f'({len(cells)})'))
    return handles


def _draw_sites(ax: Any, assessment: Assessment) -> list[Any]:
    """Footprint circles of the landing sites, numbered best first; the legend's handle."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    if not assessment.sites:
        return []
    for rank, site in enumerate(assessment.sites, start=1):
        ax.add_patch(Circle((site.x, site.y), assessment.footprint_radius, fill=False,
                            edgecolor=SITE_COLOR, linewidth=2.4 if rank == 1 else 1.4))
        ax.annotate(str(rank), (site.x, site.y), color=SITE_COLOR, ha='center', va='center',
                    fontsize=9, weight='bold',
                    bbox={'boxstyle': 'circle,pad=0.15', 'facecolor': 'white',
                          'edgecolor': 'none', 'alpha': 0.85})
    return [Line2D([], [], linestyle='none', marker='o', markersize=11, markerfacecolor='none',
                   markeredgecolor=SITE_COLOR, markeredgewidth=1.8,
                   label=f'landing site: footprint r = {assessment.footprint_radius:g} m, '
                         f'numbered best first ({len(assessment.sites)})')]


def _height_image(points: np.ndarray, extent: tuple[float, float, float, float],
                  cell: float) -> np.ndarray | None:
    """Highest return per ``cell``-sized pixel of the extent (NaN where none), x-major."""
    if len(points) == 0:
        return None
    nx = max(1, int(round((extent[1] - extent[0]) / cell)))
    ny = max(1, int(round((extent[3] - extent[2]) / cell)))
    i = np.floor((points[:, 0] - extent[0]) / cell).astype(np.int64)
    j = np.floor((points[:, 1] - extent[2]) / cell).astype(np.int64)
    ok = (i >= 0) & (i < nx) & (j >= 0) & (j < ny) & np.isfinite(points[:, 2])
    if not ok.any():
        return None
    img = np.full(nx * ny, -np.inf)
    np.maximum.at(img, i[ok] * ny + j[ok], points[ok, 2])
    img[np.isinf(img)] = np.nan
    return img.reshape(nx, ny)
