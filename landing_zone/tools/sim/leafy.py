"""Leafy plants: forbs and crowns, the leaf-bearing vegetation of the ``forb`` and ``canopy``
priors (:mod:`landing_zone.tools.sim.vegetation`).

A **forb** is a herbaceous broadleaf plant (docks, clover, plantain, nettles, young ferns): a few
stems with flat leaves along them, or a rosette of leaves lying near the ground. It is built
from its stems out: every stem leans a little, its leaves sit at heights drawn along it
(towards its top or its base), each a diamond on the stem pointing out at its own tilt
(drooping to near upright), and a rosette's leaves radiate from the plant's foot almost flat.

A **crown** is leaves filling a volume: one to five overlapping half-ellipsoid lobes (a dome, a
flat cushion, a lumpy cluster, a crown lifted on bare stems), leaves in random orientation at
a drawn leaf-area density, over a few thin twigs from the foot. The shrubs of
:func:`landing_zone.tools.sim.grass.bush_mesh` are one such shape (a single dome of triangles); a
crown's shapes, sizes, leaves and porosity are drawn over far wider ranges.

Nothing here is woody: stems and twigs are 2-8 mm thick, so a landing skid pushes them aside
like grass, and the families built of them are safe ground. Meshes are built as whole arrays
(no per-leaf Python loop): a site holds tens of thousands of leaves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from landing_zone.tools.sim.grass import ScaleField, blade_strips, scatter
from landing_zone.tools.sim.mesh import GRASS, Mesh
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['ForbForm', 'forb_mesh', 'forb_top', 'CrownForm', 'crown_mesh', 'crown_top']

_SINK = 0.005  # [m] stems start this far below the ground (no gap under them)
_ROSETTE_LIFT = 0.01  # [m] a rosette's leaves start this far above the ground
_ROSETTE_SCALE = (1.0, 1.8)  # a rosette leaf is this many times a stem leaf's length
_LOWEST_LEAF = 0.15  # leaves sit on the stem's upper 85 %
_LONGEST = 1.2  # a stem leaf is 0.6-1.2 times the form's leaf size
_MOST_LEAVES = 3000  # per crown lobe (a lobe a metre across thins out instead of costing more)


@dataclass(frozen=True)
class ForbForm:
    """One kind of plant in a patch (a patch holds one or two kinds)."""
    plants: float  # plants per m^2
    height: float  # mean stem height [m]
    height_cv: float  # standard deviation of a plant's height / the mean
    spread: float  # radius over which a plant's stems stand around its centre [m]
    stems: int  # stems per plant
    leaves: int  # leaves per stem
    leaf_size: float  # length of a stem leaf [m]
    leaf_tilt: float  # mean angle of a leaf above the horizontal [deg] (negative: drooping)
    leaf_bias: float  # a leaf sits at u ** leaf_bias of the stem (u uniform): < 1 towards the top
    rosette: float  # share of a plant's leaves that lie in a rosette at its foot
    stem_lean: float  # standard deviation of a stem's lean from the vertical [deg]
    stem_width: float  # [m]


def forb_top(form: ForbForm, limit: float) -> float:
    """The highest a plant of ``form`` reaches above the ground [m], at most ``limit``: the
    tallest stem (+3 sigma) with an upright leaf at its tip."""
    return min(form.height * (1.0 + 3.0 * form.height_cv) + _LONGEST * form.leaf_size, limit)


def forb_mesh(form: ForbForm, terrain: Terrain, rng: np.random.Generator, polygon: np.ndarray,
              limit: float, keep_out: list[tuple[float, float, float]] = (),
              density_scale: ScaleField | None = None,
              height_scale: ScaleField | None = None) -> Mesh:
    """The stems and leaves of a patch's plants of one ``form`` (a GRASS mesh).

    Args:
        form: the kind of plant.
        terrain: the ground.
        rng: randomness of placement and shapes.
        polygon: (K, 2) convex region whose plants are built (centres inside it).
        limit: no part reaches higher than this above the ground at its plant's foot [m].
        keep_out: (x, y, radius) discs no plant's centre falls in (an obstacle).
        density_scale, height_scale: optional fields that thin the plants and scale their
            height (a flight site's patches and clearings).
    """
    xy, keep = scatter(form.plants, polygon, rng)
    for x, y, r in keep_out:
        keep &= np.hypot(xy[:, 0] - x, xy[:, 1] - y) > r
    if density_scale is not None:
        keep &= rng.random(len(xy)) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
    xy = xy[keep]
    n = len(xy)
    if n == 0:
        return Mesh.empty()
    height = form.height * np.maximum(1.0 + form.height_cv * np.clip(
        rng.standard_normal(n), -3.0, 3.0), 0.3)
    if height_scale is not None:
        height = height * height_scale(xy[:, 0], xy[:, 1])
    # Room for an upright leaf at the top of the tallest stem.
    height = np.minimum(height, limit - _LONGEST * form.leaf_size)
    ground = terrain.height(xy[:, 0], xy[:, 1])

    # Stems: around the plant's centre, each leaning its own way.
    s = form.stems
    owner = np.repeat(np.arange(n), s)
    ang = rng.uniform(0.0, 2.0 * math.pi, n * s)
    rad = form.spread * np.sqrt(rng.random(n * s))
    base_xy = xy[owner] + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    base = np.column_stack([base_xy, terrain.height(base_xy[:, 0], base_xy[:, 1]) - _SINK])
    stem_h = height[owner] * rng.uniform(0.7, 1.0, n * s)
    lean = np.radians(np.minimum(np.abs(form.stem_lean * rng.standard_normal(n * s)), 60.0))
    azimuth = rng.uniform(0.0, 2.0 * math.pi, n * s)
    stems = blade_strips(base, stem_h, lean, azimuth, form.stem_width, segments=3, bend=1.5)
    # The stem's straight chord from base to tip: where its leaves attach (the strip bends
    # away from it by at most a few centimetres at these leans).
    tip = base + np.column_stack([np.tan(lean) * stem_h * np.cos(azimuth),
                                  np.tan(lean) * stem_h * np.sin(azimuth), stem_h])

    # Stem leaves: L per stem, minus the rosette's share, which moves to the plant's foot.
    per_stem = form.leaves
    k = np.repeat(np.arange(n * s), per_stem)
    on_rosette = rng.random(len(k)) < form.rosette
    t = _LOWEST_LEAF + (1.0 - _LOWEST_LEAF) * rng.random(len(k)) ** form.leaf_bias
    attach = base[k] + t[:, None] * (tip[k] - base[k])
    length = form.leaf_size * rng.uniform(0.6, _LONGEST, len(k))
    tilt = np.clip(form.leaf_tilt + 20.0 * rng.standard_normal(len(k)), -60.0, 85.0)
    rosette_foot = np.column_stack([xy[owner[k]], ground[owner[k]] + _ROSETTE_LIFT])
    attach = np.where(on_rosette[:, None], rosette_foot, attach)
    length = np.where(on_rosette, length * rng.uniform(*_ROSETTE_SCALE, len(k)), length)
    tilt = np.where(on_rosette, rng.uniform(-5.0, 25.0, len(k)), tilt)
    leaves = _diamonds(attach, length, np.radians(tilt),
                       rng.uniform(0.0, 2.0 * math.pi, len(k)), rng.uniform(0.3, 0.6, len(k)))
    return Mesh.concat([stems, leaves])


@dataclass(frozen=True)
class CrownForm:
    """The leafy crowns of a patch."""
    crowns: float  # crowns per m^2
    height: tuple[float, float]  # range of a crown's top above the ground [m]
    width: tuple[float, float]  # range of a crown's width [m]
    lobes: int  # most half-ellipsoid lobes a crown is made of (1 .. lobes each)
    lift: float  # share of the crown's height below its leaves (bare stems)
    leaf_density: float  # leaf area per crown volume [m^2 / m^3]
    leaf_size: float  # length of a leaf [m]
    twigs: int  # twigs per crown from its foot into the lower leaves
    twig_width: float  # [m]


def crown_top(form: CrownForm) -> float:
    """The highest a crown of ``form`` reaches above the ground at its foot [m] (leaves
    included)."""
    return form.height[1] + 0.5 * form.leaf_size


def crown_mesh(form: CrownForm, terrain: Terrain, rng: np.random.Generator,
               polygon: np.ndarray, keep_out: list[tuple[float, float, float]] = (),
               density_scale: ScaleField | None = None,
               height_scale: ScaleField | None = None, count: int | None = None) -> Mesh:
    """The leaves and twigs of a patch's crowns (a GRASS mesh).

    Crowns stand where a Poisson process puts their centres inside ``polygon`` (or ``count``
    of them, placed uniformly: ``polygon`` is then a rectangle), clear of the ``keep_out``
    discs by half their width; ``density_scale`` thins them and ``height_scale`` scales their
    height (never above ``form.height[1]``), as :func:`forb_mesh` does.
    """
    xy, keep = scatter(form.crowns, polygon, rng, count)
    n = len(xy)
    width = np.exp(rng.uniform(math.log(form.width[0]), math.log(form.width[1]), n))
    top = rng.uniform(form.height[0], form.height[1], n)
    for x, y, r in keep_out:
        keep &= np.hypot(xy[:, 0] - x, xy[:, 1] - y) > r + 0.5 * width
    if density_scale is not None:
        keep &= rng.random(n) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
    xy, width, top = xy[keep], width[keep], top[keep]
    n = len(xy)
    if n == 0:
        return Mesh.empty()
    if height_scale is not None:
        top = np.minimum(top * height_scale(xy[:, 0], xy[:, 1]), form.height[1])
    ground = terrain.height(xy[:, 0], xy[:, 1])
    base = form.lift * top  # the leaves' lowest height above the ground

    # Lobes: half-ellipsoids standing on the crown's leaf base, spread over its width.
    count = rng.integers(1, form.lobes + 1, n)
    owner = np.repeat(np.arange(n), count)
    m = len(owner)
    r_xy = 0.5 * width[owner] * np.where(count[owner] > 1, rng.uniform(0.45, 0.8, m), 1.0)
    off_r = (0.5 * width[owner] - r_xy) * np.sqrt(rng.random(m))
    off_a = rng.uniform(0.0, 2.0 * math.pi, m)
    centre = np.column_stack([xy[owner, 0] + off_r * np.cos(off_a),
                              xy[owner, 1] + off_r * np.sin(off_a),
                              ground[owner] + base[owner]])
    stretch = rng.uniform(0.7, 1.0, m)  # the lobe's two horizontal semi-axes differ
    # The first lobe of a crown reaches its top, the others 60-100 % of the way.
    first = np.r_[True, owner[1:] != owner[:-1]]
    rise = np.where(first, 1.0, rng.uniform(0.6, 1.0, m))
    axes = np.column_stack([r_xy, r_xy * stretch,
                            np.maximum(rise * (top[owner] - base[owner]), 0.02)])
    turn = rng.uniform(0.0, 2.0 * math.pi, m)
    volume = 2.0 / 3.0 * math.pi * axes.prod(axis=1)
    leaves = np.maximum(np.round(form.leaf_density * volume
                                 / (0.5 * 0.45 * form.leaf_size ** 2)), 1).astype(int)
    leaves = np.minimum(leaves, _MOST_LEAVES)
    k = np.repeat(np.arange(m), leaves)
    u = rng.standard_normal((len(k), 3))  # uniform in the unit half-ball (z >= 0)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u[:, 2] = np.abs(u[:, 2])
    u *= rng.random(len(k))[:, None] ** (1.0 / 3.0)
    local = u * axes[k]
    c, s = np.cos(turn[k]), np.sin(turn[k])
    at = centre[k] + np.column_stack([c * local[:, 0] - s * local[:, 1],
                                      s * local[:, 0] + c * local[:, 1], local[:, 2]])
    # A leaf centred within half its length of the crown's top stays under it.
    length = form.leaf_size * rng.uniform(0.6, 1.0, len(k))
    ceiling = ground[owner[k]] + top[owner[k]] - 0.5 * length
    at[:, 2] = np.minimum(at[:, 2], ceiling)
    azimuth = rng.uniform(0.0, 2.0 * math.pi, len(k))
    tilt = np.arcsin(rng.uniform(-1.0, 1.0, len(k)))  # leaf axes uniform on the sphere
    start = at - (0.5 * length)[:, None] * np.column_stack(
        [np.cos(tilt) * np.cos(azimuth), np.cos(tilt) * np.sin(azimuth), np.sin(tilt)])
    leaf_mesh = _diamonds(start, length, tilt, azimuth, rng.uniform(0.3, 0.9, len(k)))

    # Twigs: from the foot to points of the lower leaves.
    t = np.repeat(np.arange(n), form.twigs)
    if len(t) == 0:
        return leaf_mesh
    ang = rng.uniform(0.0, 2.0 * math.pi, len(t))
    rad = 0.4 * width[t] * np.sqrt(rng.random(len(t)))
    tip = np.column_stack([xy[t, 0] + rad * np.cos(ang), xy[t, 1] + rad * np.sin(ang),
                           ground[t] + base[t] + (top[t] - base[t]) * rng.uniform(0.1, 0.6,
                                                                                  len(t))])
    foot = np.column_stack([xy[t], ground[t] - _SINK])
    d = tip - foot
    twigs = blade_strips(foot, d[:, 2], np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2]),
                         np.arctan2(d[:, 1], d[:, 0]), form.twig_width, segments=2, bend=1.0)
    return Mesh.concat([leaf_mesh, twigs])


def _diamonds(attach: np.ndarray, length: np.ndarray, tilt: np.ndarray, azimuth: np.ndarray,
              aspect: np.ndarray) -> Mesh:
    """Flat leaves: diamonds from ``attach`` out along ``azimuth`` at ``tilt`` above the
    horizontal, ``aspect`` times as wide as long, each two triangles."""
    ca, sa = np.cos(azimuth), np.sin(azimuth)
    along = np.column_stack([np.cos(tilt) * ca, np.cos(tilt) * sa, np.sin(tilt)])
    across = np.column_stack([-sa, ca, np.zeros(len(ca))])
    half = (0.5 * length)[:, None]
    mid = attach + half * along
    width = (0.5 * aspect * length)[:, None]
    v = np.stack([attach, mid + width * across, attach + 2.0 * half * along,
                  mid - width * across], axis=1)  # (n, 4, 3)
    quad = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    faces = (np.arange(len(v))[:, None, None] * 4 + quad[None]).reshape(-1, 3)
    return Mesh.from_arrays(v.reshape(-1, 3), faces, GRASS)
