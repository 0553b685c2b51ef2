"""Hand-built input volumes with known answers, for the baselines' tests and timings.

A height field seen from straight above: the voxels its surface passes through are occupied,
those above it observed free, those below it unobserved (the ground hides them), in the
network's encoding ``2 * density - 1``. Vertical faces (a box's sides) come out occupied because
each column is filled over the whole height range the surface takes inside its cell.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from landing_zone.tools.evaluate.baselines.volumes import VolumeGeometry

__all__ = ['heightfield_volume', 'boxes_and_flats']

# Densities of a voxel hit by 4 of 5 rays (occupied) and passed by 3 rays without a hit (free).
_OCCUPIED = 2 * (4 + 1) / (5 + 2) - 1
_FREE = 2 * (0 + 1) / (3 + 2) - 1


def heightfield_volume(height: Callable[[np.ndarray, np.ndarray], np.ndarray], side: int = 32,
                       geometry: VolumeGeometry | None = None, samples: int = 5) -> np.ndarray:
    """One volume (side, side, side) of the surface z = height(x, y) [m], cube centred on 0.

    Args:
        height: vectorised height function of x, y [m].
        side: voxels per side of the cube.
        geometry: voxel size of the cube.
        samples: height samples per cell side (corners included) that bound the surface's
            vertical extent in each column.
    """
    g = geometry if geometry is not None else VolumeGeometry()
    vs = g.voxel_size
    lo = -side / 2 * vs
    edges = lo + np.arange(side + 1) * vs
    # Sample each cell on a (samples x samples) grid including its corners: (side, side, s, s)
    frac = np.linspace(0.0, 1.0, samples)
    xs = edges[:-1, None] + frac[None, :] * vs  # (side, s)
    hx = height(xs[:, None, :, None], xs[None, :, None, :])
    hx = np.broadcast_to(hx, (side, side, samples, samples))
    zlo = hx.min(axis=(2, 3))[..., None]
    zhi = hx.max(axis=(2, 3))[..., None]
    zk = edges[:-1][None, None, :]
    vol = np.zeros((side, side, side), np.float32)
    vol[zk > zhi] = _FREE
    vol[(zk <= zhi) & (zk + vs > zlo)] = _OCCUPIED
    return vol


def boxes_and_flats(n: int, seed: int, side: int = 32,
                    geometry: VolumeGeometry | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A trivially separable set: ``n`` volumes (n, 1, S, S, S), half ground with a box on it
    (label 0, unsafe), half bare ground (label 1), both gently tilted and offset at random.
    """
    g = geometry if geometry is not None else VolumeGeometry()
    rng = np.random.default_rng(seed)
    half_tile = g.tile_size / 2
    vols = np.zeros((n, 1, side, side, side), np.float32)
    labels = np.arange(n) % 2
    for t in range(n):
        sx, sy = rng.uniform(-0.15, 0.15, 2)
        z0 = rng.uniform(-0.02, 0.02)
        if labels[t]:
            def h(x, y, sx=sx, sy=sy, z0=z0):
                return z0 + sx * x + sy * y
        else:
            w = rng.uniform(0.2, 0.4, 2)
            c = rng.uniform(-half_tile + w / 2, half_tile - w / 2)
            top = rng.uniform(0.2, 0.5)

            def h(x, y, sx=sx, sy=sy, z0=z0, w=w, c=c, top=top):
                inside = (np.abs(x - c[0]) < w[0] / 2) & (np.abs(y - c[1]) < w[1] / 2)
                return z0 + sx * x + sy * y + np.where(inside, top, 0.0)
        vols[t, 0] = heightfield_volume(h, side, g)
    return vols, labels
