"""Ground: a height field of fractal Perlin (gradient) noise, meshed on a regular grid.

The noise is written here with numpy rather than taken from a package: the usual Perlin
packages (``noise``, ``perlin-noise``) evaluate one point per Python call and are not among the
dependencies of the dataset machine, while a vectorised gradient noise is thirty lines and
evaluates a whole grid at once.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import GROUND, Mesh

__all__ = ['TerrainConfig', 'PerlinNoise', 'Terrain', 'SlopedTerrain']

# The largest magnitude 2D gradient noise with unit gradients can take is sqrt(2)/2: dividing by
# it maps the noise into [-1, 1], so heights stay within +-amplitude.
_NOISE_BOUND = math.sqrt(0.5)


@dataclass(frozen=True)
class TerrainConfig:
    """Shape of the ground."""

    amplitude: float = 0.05  # heights lie within +-amplitude of the nominal ground [m]
    wavelength: float = 2.0  # feature size of the coarsest octave [m]
    octaves: int = 2  # each further octave halves the wavelength and the weight
    spacing: float = 0.1  # grid step of the ground mesh [m]

    def validate(self) -> None:
        for name in ('amplitude', 'wavelength', 'spacing'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise SimulationError(f'terrain {name} must be a non-negative number, '
                                      f'got {value!r}')
        if self.wavelength <= 0 or self.spacing <= 0:
            raise SimulationError(f'terrain wavelength and spacing must be positive, got '
                                  f'{self.wavelength} and {self.spacing}')
        if not 1 <= self.octaves <= 8:
            raise SimulationError(f'terrain octaves must lie in [1, 8], got {self.octaves}')

    def to_dict(self) -> dict:
        return asdict(self)


class PerlinNoise:
    """Fractal 2D gradient noise (Perlin 2002 fade curve), values in [-1, 1].

    Args:
        rng: source of the gradient table, the permutation and the per-octave offsets.
        wavelength: feature size of the first octave [m].
        octaves: number of octaves summed with weights 1, 1/2, 1/4, ...
    """

    def __init__(self, rng: np.random.Generator, wavelength: float, octaves: int) -> None:
        perm = rng.permutation(256)
        self._perm = np.concatenate([perm, perm]).astype(np.int64)
        angles = rng.uniform(0.0, 2.0 * np.pi, 256)
        self._grad = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        # Lattice points have noise 0: random offsets keep the origin off the lattice.
        self._offsets = rng.uniform(0.0, 256.0, (octaves, 2))
        self.wavelength = float(wavelength)
        self.octaves = int(octaves)

    def _octave(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = x - x0
        fy = y - y0
        ix = x0.astype(np.int64) & 255
        iy = y0.astype(np.int64) & 255
        perm, grad = self._perm, self._grad

        def corner(dx: int, dy: int) -> np.ndarray:
            g = grad[perm[perm[ix + dx] + ((iy + dy) & 255)] & 255]
            return g[..., 0] * (fx - dx) + g[..., 1] * (fy - dy)

        u = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0)
        v = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0)
        bottom = corner(0, 0) + u * (corner(1, 0) - corner(0, 0))
        top = corner(0, 1) + u * (corner(1, 1) - corner(0, 1))
        return (bottom + v * (top - bottom)) / _NOISE_BOUND

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        total = np.zeros(np.broadcast(x, y).shape)
        weight_sum = 0.0
        for k in range(self.octaves):
            scale = 2.0 ** k / self.wavelength
            weight = 0.5 ** k
            total += weight * self._octave(x * scale + self._offsets[k, 0],
                                           y * scale + self._offsets[k, 1])
            weight_sum += weight
        return np.clip(total / weight_sum, -1.0, 1.0)


class Terrain:
    """Ground heights on a regular grid over ``[lo, hi]``, two triangles per cell.

    :meth:`height` interpolates exactly on the mesh's triangles, so whatever is placed on the
    ground (blade bases, obstacles) sits on the surface the rays hit.

    Args:
        config: shape of the ground.
        rng: randomness of the noise.
        lo: (x, y) lower corner of the covered region [m].
        hi: (x, y) upper corner [m].
    """

    def __init__(self, config: TerrainConfig, rng: np.random.Generator,
                 lo: tuple[float, float], hi: tuple[float, float]) -> None:
        config.validate()
        self.config = config
        s = config.spacing
        self.lo = np.floor(np.asarray(lo, dtype=float) / s) * s
        nx, ny = (np.ceil((np.asarray(hi, dtype=float) - self.lo) / s).astype(int) + 1)
        self.shape = (int(ny), int(nx))  # cells along y, x
        noise = PerlinNoise(rng, config.wavelength, config.octaves)
        xs = self.lo[0] + s * np.arange(nx + 1)
        ys = self.lo[1] + s * np.arange(ny + 1)
        self.heights = config.amplitude * noise(xs[None, :], ys[:, None])  # (ny+1, nx+1)

    @property
    def hi(self) -> np.ndarray:
        return self.lo + self.config.spacing * np.array([self.shape[1], self.shape[0]])

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.heights.min()), float(self.heights.max())

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground height at (x, y), on the mesh's triangles; clamped to the covered region."""
        s = self.config.spacing
        ny, nx = self.shape
        gx = np.clip((np.asarray(x, dtype=float) - self.lo[0]) / s, 0.0, nx)
        gy = np.clip((np.asarray(y, dtype=float) - self.lo[1]) / s, 0.0, ny)
        j = np.minimum(np.floor(gx).astype(np.int64), nx - 1)
        i = np.minimum(np.floor(gy).astype(np.int64), ny - 1)
        fx = gx - j
        fy = gy - i
        h = self.heights
        z00, z01 = h[i, j], h[i, j + 1]
        z10, z11 = h[i + 1, j], h[i + 1, j + 1]
        # Cells are split along their (0,0)-(1,1) diagonal, as in mesh().
        lower = z00 + fx * (z01 - z00) + fy * (z11 - z01)
        upper = z00 + fy * (z10 - z00) + fx * (z11 - z10)
        return np.where(fx >= fy, lower, upper)

    def add_bank(self, slope: float, x0: float) -> None:
        """Raise the ground from ``x = x0`` on, rising towards +x at ``slope`` [deg].

        ``x0`` is moved onto the nearest grid line, so the crease lies on the mesh's edges
        and :meth:`height` stays exact.
        """
        if not (math.isfinite(slope) and 0 <= slope <= 45 and math.isfinite(x0)):
            raise SimulationError(f'bank slope must lie in [0, 45] degrees and its start be '
                                  f'finite, got {slope!r} and {x0!r}')
        s = self.config.spacing
        x0 = round(x0 / s) * s
        xs = self.lo[0] + s * np.arange(self.shape[1] + 1)
        self.heights = self.heights + math.tan(math.radians(slope)) * np.maximum(xs - x0,
                                                                                 0.0)[None, :]

    def mesh(self) -> Mesh:
        """The ground as triangles labelled GROUND."""
        s = self.config.spacing
        ny, nx = self.shape
        xs = self.lo[0] + s * np.arange(nx + 1)
        ys = self.lo[1] + s * np.arange(ny + 1)
        gx, gy = np.meshgrid(xs, ys)
        vertices = np.stack([gx, gy, self.heights], axis=-1).reshape(-1, 3)
        idx = np.arange((ny + 1) * (nx + 1), dtype=np.uint32).reshape(ny + 1, nx + 1)
        v00 = idx[:-1, :-1].ravel()
        v01 = idx[:-1, 1:].ravel()
        v10 = idx[1:, :-1].ravel()
        v11 = idx[1:, 1:].ravel()
        faces = np.concatenate([np.stack([v00, v01, v11], axis=1),
                                np.stack([v00, v11, v10], axis=1)])
        return Mesh.from_arrays(vertices, faces, GROUND)


class SlopedTerrain(Terrain):
    """:class:`Terrain` on an inclined plane through the origin: the noise heights plus
    ``tan(slope) * ((x, y) . (cos azimuth, sin azimuth))`` (the ground rises towards
    ``azimuth``). The plane is linear on every grid triangle, so :meth:`height` stays exact.

    Args:
        config, rng, lo, hi: as for :class:`Terrain` (the noise is drawn the same way).
        slope: inclination of the plane [deg], 0 to 45.
        azimuth: direction of steepest ascent [rad].
    """

    def __init__(self, config: TerrainConfig, rng: np.random.Generator,
                 lo: tuple[float, float], hi: tuple[float, float], slope: float = 0.0,
                 azimuth: float = 0.0) -> None:
        if not (isinstance(slope, (int, float)) and math.isfinite(slope) and 0 <= slope <= 45):
            raise SimulationError(f'terrain slope must lie in [0, 45] degrees, got {slope!r}')
        if not (isinstance(azimuth, (int, float)) and math.isfinite(azimuth)):
            raise SimulationError(f'terrain slope azimuth must be a finite angle, got '
                                  f'{azimuth!r}')
        super().__init__(config, rng, lo, hi)
        self.slope = float(slope)
        self.azimuth = float(azimuth)
        s = config.spacing
        ny, nx = self.shape
        xs = self.lo[0] + s * np.arange(nx + 1)
        ys = self.lo[1] + s * np.arange(ny + 1)
        g = math.tan(math.radians(slope))
        self.heights = self.heights + g * (math.cos(azimuth) * xs[None, :]
                                           + math.sin(azimuth) * ys[:, None])
