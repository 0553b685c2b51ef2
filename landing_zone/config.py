"""Configuration of the landing_zone pipeline: one dataclass per stage, SI units.

The ROS node declares the same fields as dotted parameters (``map.voxel_size``,
``tiles.tile_size``, ...) and copies them onto :class:`AssessorConfig` mechanically
(:func:`AssessorConfig.from_flat` / :meth:`AssessorConfig.to_flat`), so the names in
``config/assessor.yaml``, the node and the Python API are the same.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from landing_zone.errors import ConfigError

__all__ = [
    'MapConfig',
    'TileConfig',
    'ModelConfig',
    'SiteConfig',
    'GuardConfig',
    'AssessorConfig',
]


@dataclass
class MapConfig:
    """The scrolling volumetric density map."""

    voxel_size: float = 0.05  # edge of a cubic voxel [m]; the paper's 5 cm
    size_xy: float = 20.0  # extent of the map in x and in y [m]
    size_z: float = 4.0  # vertical extent of the map [m]
    # Where the map sits vertically relative to its centre: the window spans
    # [center_z - z_below, center_z - z_below + size_z]. The vehicle is usually far above the
    # ground, so in follow mode the map is centred on the ground below, not on the sensor.
    z_below: float = 2.0  # [m]
    # Follow mode re-centres when the sensor's ground point is this far from the centre [m].
    recenter_distance: float = 2.0

    def validate(self) -> None:
        _positive('map.voxel_size', self.voxel_size)
        _positive('map.size_xy', self.size_xy)
        _positive('map.size_z', self.size_z)
        if not 0.0 <= self.z_below <= self.size_z:
            raise ConfigError(f'map.z_below must lie in [0, map.size_z], got {self.z_below}')
        _nonnegative('map.recenter_distance', self.recenter_distance)
        if self.size_xy / self.voxel_size > 4096 or self.size_z / self.voxel_size > 1024:
            raise ConfigError('map too large for its voxel size (at most 4096 x 4096 x 1024 '
                              f'voxels), got {self.size_xy} m / {self.voxel_size} m')

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxels along x, y, z."""
        n_xy = int(round(self.size_xy / self.voxel_size))
        return (n_xy, n_xy, int(round(self.size_z / self.voxel_size)))


@dataclass
class TileConfig:
    """How the map's XY plane is cut into tiles and each tile into a network input."""

    tile_size: float = 1.0  # edge of a square tile [m]; the paper's 1 m
    # Voxels of context added on every side of the tile's cube: 20 + 2*6 = 32 at 5 cm.
    padding: int = 6
    # Robust ground: this quantile of the heights of occupied voxels in the tile column.
    ground_quantile: float = 0.05
    # A voxel counts as occupied for the ground estimate when its density is at least this.
    occupied_density: float = 0.6
    # A tile is judged only if at least this fraction of its 1 m^3 cube was observed
    # (crossed or hit by at least one ray) ...
    min_observed_fraction: float = 0.25
    # ... and at least this many returns fell into its column.
    min_returns: int = 20

    def validate(self) -> None:
        _positive('tiles.tile_size', self.tile_size)
        if self.padding < 0:
            raise ConfigError(f'tiles.padding must be >= 0, got {self.padding}')
        if not 0.0 <= self.ground_quantile < 1.0:
            raise ConfigError(f'tiles.ground_quantile must lie in [0, 1), got '
                              f'{self.ground_quantile}')
        if not 0.5 <= self.occupied_density < 1.0:
            raise ConfigError(f'tiles.occupied_density must lie in [0.5, 1), got '
                              f'{self.occupied_density}')
        if not 0.0 <= self.min_observed_fraction <= 1.0:
            raise ConfigError(f'tiles.min_observed_fraction must lie in [0, 1], got '
                              f'{self.min_observed_fraction}')
        if self.min_returns < 0:
            raise ConfigError(f'tiles.min_returns must be >= 0, got {self.min_returns}')


@dataclass
class ModelConfig:
    """The safety CNN."""

    path: str = ''  # weights file (.safetensors); empty = the model shipped in models/
    device: str = 'cpu'  # 'cpu', 'cuda' or 'cuda:N'
    batch_size: int = 256  # tiles per forward pass

    def validate(self) -> None:
        if not (self.device == 'cpu' or self.device.startswith('cuda')):
            raise ConfigError(f"model.device must be 'cpu' or 'cuda[:N]', got {self.device!r}")
        if self.batch_size < 1:
            raise ConfigError(f'model.batch_size must be >= 1, got {self.batch_size}')


@dataclass
class SiteConfig:
    """Landing-site candidates for the vehicle's footprint."""

    footprint_radius: float = 1.5  # radius of the vehicle's circular footprint [m]
    top_k: int = 5  # candidates reported, best first
    min_p_safe: float = 0.5  # candidates below this P(all tiles under the footprint safe) drop

    def validate(self) -> None:
        _positive('landing_sites.footprint_radius', self.footprint_radius)
        if self.top_k < 0:
            raise ConfigError(f'landing_sites.top_k must be >= 0, got {self.top_k}')
        if not 0.0 <= self.min_p_safe <= 1.0:
            raise ConfigError(f'landing_sites.min_p_safe must lie in [0, 1], got '
                              f'{self.min_p_safe}')


@dataclass
class GuardConfig:
    """The guard beside the network: opaque structure above the ground (landing_zone.guard)."""

    enabled: bool = True  # cap P(safe) where the guard fires
    min_height: float = 0.12  # solid voxels count from this far above the tile's ground [m]
    max_height: float = 1.5  # ... up to this height [m]
    min_hits: int = 2  # a solid voxel holds at least this many returns ...
    min_hit_ratio: float = 0.4  # ... and at least this share of the rays reaching it ended there
    # ... and it casts a shadow: of the rays ending in it or crossing the least crossed voxel
    # beneath or beside it, at most this share crossed (behind a solid no ray gets; under grass
    # most go on)
    max_pass_behind: float = 0.1
    min_cluster_hits: int = 20  # the guard fires on a connected cluster with this many returns
    margin: float = 0.2  # clusters are traced this far beyond the tile's edges [m]
    max_p_safe: float = 0.05  # P(safe) of a tile where the guard fires is at most this

    def validate(self) -> None:
        _nonnegative('guard.min_height', self.min_height)
        if not self.max_height > self.min_height:
            raise ConfigError(f'guard.max_height ({self.max_height}) must exceed '
                              f'guard.min_height ({self.min_height})')
        if self.min_hits < 1:
            raise ConfigError(f'guard.min_hits must be >= 1, got {self.min_hits}')
        if not 0.0 < self.min_hit_ratio <= 1.0:
            raise ConfigError(f'guard.min_hit_ratio must lie in (0, 1], got '
                              f'{self.min_hit_ratio}')
        if not 0.0 <= self.max_pass_behind <= 1.0:
            raise ConfigError(f'guard.max_pass_behind must lie in [0, 1], got '
                              f'{self.max_pass_behind}')
        if self.min_cluster_hits < 1:
            raise ConfigError(f'guard.min_cluster_hits must be >= 1, got '
                              f'{self.min_cluster_hits}')
        _nonnegative('guard.margin', self.margin)
        if not 0.0 <= self.max_p_safe <= 1.0:
            raise ConfigError(f'guard.max_p_safe must lie in [0, 1], got {self.max_p_safe}')


@dataclass
class AssessorConfig:
    """The whole pipeline; the defaults are those of the node (docs/INTERFACES.md §1)."""

    frame_id: str = 'map'  # fixed frame of clouds, poses and outputs
    # None: the map follows the sensor (scrolling). (x, y): a fixed region of interest.
    center: tuple[float, float] | None = None
    map: MapConfig = field(default_factory=MapConfig)
    tiles: TileConfig = field(default_factory=TileConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    landing_sites: SiteConfig = field(default_factory=SiteConfig)
    guard: GuardConfig = field(default_factory=GuardConfig)

    def validate(self) -> None:
        if not self.frame_id:
            raise ConfigError('frame_id must not be empty')
        if self.center is not None:
            if len(self.center) != 2 or not all(math.isfinite(float(c)) for c in self.center):
                raise ConfigError(f'center must be two finite numbers, got {self.center!r}')
        self.map.validate()
        self.tiles.validate()
        self.model.validate()
        self.landing_sites.validate()
        self.guard.validate()
        ratio = self.map.size_xy / self.tiles.tile_size
        if ratio < 1 or abs(ratio - round(ratio)) > 1e-6:
            raise ConfigError(f'map.size_xy ({self.map.size_xy}) must be a whole multiple of '
                              f'tiles.tile_size ({self.tiles.tile_size})')
        vox = self.tiles.tile_size / self.map.voxel_size
        if abs(vox - round(vox)) > 1e-6:
            raise ConfigError(f'tiles.tile_size ({self.tiles.tile_size}) must be a whole '
                              f'multiple of map.voxel_size ({self.map.voxel_size})')

    def to_flat(self) -> dict[str, Any]:
        """Dotted names -> values, as the node's parameters and the YAML file spell them."""
        flat: dict[str, Any] = {'frame_id': self.frame_id}
        for section in _SECTIONS:
            for f in dataclasses.fields(getattr(self, section)):
                flat[f'{section}.{f.name}'] = getattr(getattr(self, section), f.name)
        return flat

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> 'AssessorConfig':
        """Build from dotted names (unknown names are an error, missing ones default)."""
        cfg = cls()
        for key, value in flat.items():
            if key == 'frame_id':
                cfg.frame_id = str(value)
                continue
            if key == 'center':
                cfg.center = None if value is None else (float(value[0]), float(value[1]))
                continue
            section, _, name = key.partition('.')
            sub = getattr(cfg, section, None) if section in _SECTIONS else None
            if sub is None or name not in {f.name for f in dataclasses.fields(sub)}:
                raise ConfigError(f'unknown configuration key {key!r}')
            current = getattr(sub, name)
            setattr(sub, name, type(current)(value))
        cfg.validate()
        return cfg


# The sections of AssessorConfig, as the dotted names' prefixes.
_SECTIONS = ('map', 'tiles', 'model', 'landing_sites', 'guard')


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f'{name} must be a positive number, got {value!r}')


def _nonnegative(name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise ConfigError(f'{name} must be a non-negative number, got {value!r}')
