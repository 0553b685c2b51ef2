"""Forbs: herbaceous broadleaf plants (docks, clover, plantain, nettles, young ferns), each a
few stems with flat leaves along them or a rosette of leaves lying near the ground.

A shrub (:func:`landing_zone.sim.grass.bush_mesh`) is a canopy: leaves filling half an
ellipsoid over twigs. A forb is built from its stems out: every stem leans a little, its
leaves sit at heights drawn along it (towards its top or its base), each a diamond on the stem
pointing out at its own tilt (drooping to near upright), and a rosette's leaves radiate from
the plant's foot almost flat. Nothing here is woody; the stems are as thin as grass (2-6 mm),
so a landing skid pushes them aside like grass: the :mod:`landing_zone.sim.vegetation` family
built of them (``forb``) is safe ground.

Meshes are built as whole arrays (no per-leaf Python loop): a site holds tens of thousands
of leaves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from landing_zone.sim.grass import ScaleField, blade_strips, points_in_polygon
from landing_zone.sim.mesh import GRASS, Mesh
from landing_zone.sim.terrain import Terrain

__all__ = ['ForbForm', 'forb_mesh', 'forb_top']

_SINK = 0.005  # [m] stems start this far below the ground (no gap under them)
_ROSETTE_LIFT = 0.01  # [m] a rosette's leaves start this far above the ground
_ROSETTE_SCALE = (1.0, 1.8)  # a rosette leaf is this many times a stem leaf's length
_LOWEST_LEAF = 0.15  # leaves sit on the stem's upper 85 %
_LONGEST = 1.2  # a stem leaf is 0.6-1.2 times the form's leaf size


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

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> 'ForbForm':
        return cls(**{k: d[k] for k in cls.__dataclass_fields__})


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
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    n = rng.poisson(form.plants * float(np.prod(hi - lo)))
    xy = lo + (hi - lo) * rng.random((n, 2))
    keep = points_in_polygon(xy, polygon)
    for x, y, r in keep_out:
        keep &= np.hypot(xy[:, 0] - x, xy[:, 1] - y) > r
    if density_scale is not None:
        keep &= rng.random(n) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
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
