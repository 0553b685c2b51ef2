"""The map PNG: P(safe) in the colour bar's colours, the top view apart, a legend for each mark."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from matplotlib.colors import to_hex, to_rgba
from matplotlib.image import imread
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from landing_zone.errors import BagError
from landing_zone.judging.sites import CLEARANCE, SLOPE, STEP
from landing_zone.tools.map_png import (UNKNOWN_COLOR, _height_image, draw_map, render_png)
from test_grid import hand_made


def pixel(fig, image, ax, x, y):
    """RGBA of the saved image's pixel under data point (x, y) of ``ax``."""
    px, py = ax.transData.transform((x, y))
    return image[int(image.shape[0] - py), int(px)]


def top_view(a, rng):
    """Returns over the tiles' extent, heights rising with x."""
    ts = a.tile_size
    lo = np.array(a.origin) * ts
    xy = lo + rng.uniform(0, 1, (4000, 2)) * np.array(a.shape) * ts
    return np.column_stack([xy, 0.1 * xy[:, 0]])


def test_tile_pixels_have_the_colour_bars_colours(tmp_path):
    # no sites and no candidates: nothing drawn over the tiles
    a = replace(hand_made(), sites=[], candidates=None)
    fig = draw_map(a, top_view(a, np.random.default_rng(0)))
    fig.savefig(tmp_path / 'map.png')
    image = imread(tmp_path / 'map.png')
    assert image.shape[:2] == (round(fig.get_figheight() * fig.dpi),
                               round(fig.get_figwidth() * fig.dpi))
    ax = fig.axes[0]
    bar = ax.images[0].colorbar
    assert bar is not None and bar.ax in fig.axes
    seen = 0
    for (x, y), p in zip(a.centers, a.p_safe):
        got = pixel(fig, image, ax, x, y)
        if np.isnan(p):
            assert to_hex(got) == to_hex(UNKNOWN_COLOR)
            continue
        # opaque, in the colour bar's colormap and norm
        want = bar.cmap(bar.norm(float(p)))
        np.testing.assert_allclose(got, want, atol=1 / 255)
        # and the colour bar's own pixel at that P(safe), where it lies inside the bar
        if 0.02 < p < 0.98:
            in_bar = pixel(fig, image, bar.ax, 0.5, float(p))
            np.testing.assert_allclose(got, in_bar, atol=2 / 255)
            seen += 1
        assert got[3] == 1.0
    assert seen == 1  # the tile of 0.5
    # tiles of 0.994 and 1.0: both in the bar's greens, distinct from 0.006's red
    assert not np.allclose(pixel(fig, image, ax, 0.5, 5.5), pixel(fig, image, ax, 1.5, 5.5))


def marked():
    """hand_made with a footprint left out for each limit, sites with a radius, an obstacle."""
    a = hand_made()
    reasons = np.zeros_like(a.candidates.reasons)
    reasons[0, 0], reasons[1, 0], reasons[2, 0] = SLOPE, STEP | SLOPE, CLEARANCE
    a = replace(a, candidates=replace(a.candidates, reasons=reasons), footprint_radius=0.5)
    labels = {'frame_id': 'map', 'tile_size': 1.0, 'tiles': [],
              'obstacles': [{'kind': 'rock', 'x': 1.2, 'y': 5.3, 'z': 0.1, 'yaw': 0.3,
                             'size': [0.4, 0.3, 0.2]}]}
    return a, labels


def legend_styles(fig):
    """(edge colour, hatch) of each legend entry, and the entries' texts."""
    (legend,) = fig.legends
    styles = set()
    for h in legend.legend_handles:
        if isinstance(h, Line2D):
            styles.add((to_hex(h.get_markeredgecolor()), None))
        else:
            assert isinstance(h, Patch)
            styles.add((to_hex(h.get_edgecolor()), h.get_hatch()))
    return styles, [t.get_text() for t in legend.get_texts()]


def test_the_legend_names_every_mark_drawn(tmp_path):
    a, labels = marked()
    fig = draw_map(a, top_view(a, np.random.default_rng(1)), labels=labels)
    ax = fig.axes[0]
    styles, texts = legend_styles(fig)
    drawn = {(to_hex(p.get_edgecolor()), p.get_hatch()) for p in ax.patches}
    assert len(drawn) == 5  # three hatches, the obstacle outline, the site circles
    assert drawn <= styles
    joined = ' | '.join(texts)
    for words in ('not judged (1)', 'too steep (2)', 'too high a step (1)',
                  'too little clearance (1)', 'obstacle footprint, ground truth (1)',
                  'landing site', 'numbered best first (2)'):
        assert words in joined, words
    # the unknown tile's legend colour is the colour it is drawn in
    (unknown,) = [h for h, t in zip(fig.legends[0].legend_handles, texts) if 'not judged' in t]
    assert to_hex(unknown.get_facecolor()) == to_hex(UNKNOWN_COLOR)
    assert to_rgba(ax.images[0].cmap.get_bad()) == to_rgba(UNKNOWN_COLOR)
    # the numbered circles: one number per site at its centre
    assert [t.get_text() for t in ax.texts] == ['1', '2']
    # the title says what is drawn, not what is not
    title = fig.get_suptitle()
    assert 'hatched' not in title and '5 of 6 tiles judged' in title
    # the obstacle is outlined on the top view too
    assert len(fig.axes[1].patches) == 1
    render_png(a, None, tmp_path / 'm.png', labels=labels)
    assert (tmp_path / 'm.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_only_what_is_drawn_is_in_the_legend():
    a = replace(hand_made(), sites=[], candidates=None,
                p_safe=np.nan_to_num(hand_made().p_safe, nan=0.5))
    fig = draw_map(a, None)
    assert fig.legends == [] and len(fig.axes) == 2  # the map and its colour bar, no top view
    a, _ = marked()
    fig = draw_map(a)
    _, texts = legend_styles(fig)
    assert not any('obstacle' in t for t in texts)


def test_the_top_view_is_the_highest_return_per_cell():
    pts = np.array([[0.05, 0.05, 1.0], [0.06, 0.02, 3.0], [0.15, 0.05, -2.0],
                    [5.0, 5.0, 9.0], [0.05, 0.05, np.nan]])
    img = _height_image(pts, (0.0, 0.3, 0.0, 0.2), cell=0.1)
    assert img.shape == (3, 2)
    assert img[0, 0] == 3.0 and img[1, 0] == -2.0
    assert np.isnan(img[2, 0]) and np.isnan(img[0, 1])
    assert _height_image(np.zeros((0, 3)), (0.0, 1.0, 0.0, 1.0), 0.1) is None


def test_an_unwritable_path_is_a_bag_error(tmp_path):
    with pytest.raises(BagError, match='cannot write'):
        render_png(hand_made(), None, tmp_path / 'missing' / 'map.png')
