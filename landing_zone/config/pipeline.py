"""The pipeline's stages, one dataclass each, and :class:`AssessorConfig` that holds them."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from landing_zone.config.facts import _check_fields, param
from landing_zone.errors import ConfigError

__all__ = ['SECTIONS', 'MapConfig', 'TileConfig', 'ModelConfig', 'SiteConfig', 'GuardConfig',
           'OODConfig', 'AssessorConfig']

SECTIONS = ('map', 'tiles', 'model', 'landing_sites', 'guard', 'ood')


@dataclass
class MapConfig:
    """The scrolling volumetric density map."""

    # the paper's 5 cm
    voxel_size: float = param(0.05, 'Edge of a cubic voxel; must match the model', 'm',
                              (0.0, 1.0), open_lo=True, read_only=True)
    size_xy: float = param(20.0, 'Extent of the scrolling map in x and y', 'm', (0.0, 400.0),
                           open_lo=True, read_only=True)
    size_z: float = param(4.0, 'Vertical extent of the map', 'm', (0.0, 100.0), open_lo=True,
                          read_only=True)
    # Where the map sits vertically relative to its centre: the window spans
    # [center_z - z_below, center_z - z_below + size_z]. The vehicle is usually far above the
    # ground, so in follow mode the map is centred on the ground below, not on the sensor.
    z_below: float = param(2.0, 'How far the map reaches below the ground under the sensor', 'm',
                           (0.0, 100.0), read_only=True)
    recenter_distance: float = param(
        2.0, 'Follow mode scrolls when the sensor is this far from the centre', 'm',
        (0.0, 200.0))

    def validate(self) -> None:
        _check_fields(self, 'map.')
        if not self.z_below <= self.size_z:
            raise ConfigError(f'map.z_below must lie in [0, map.size_z], got {self.z_below}')
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

    # the paper's 1 m
    tile_size: float = param(1.0, 'Edge of a square tile, a whole number of voxels', 'm',
                             (0.0, 10.0), open_lo=True, read_only=True)
    # 20 + 2*6 = 32 voxels at 5 cm
    padding: int = param(6, "Voxels of context around a tile's cube; must match the model",
                         '', (0, 64), read_only=True)
    # One value per voxel column keeps grass from outvoting the columns that show the ground.
    ground_quantile: float = param(
        0.05, "Quantile of the column minima taken as the tile's ground", '', (0.0, 1.0),
        open_hi=True)
    occupied_density: float = param(
        0.6, 'Density from which a voxel counts as occupied (ground estimate)', '', (0.5, 1.0),
        open_hi=True)
    # (crossed or hit by at least one ray)
    min_observed_fraction: float = param(
        0.25, 'Tiles with less of their cube observed are unknown', '', (0.0, 1.0))
    min_returns: int = param(20, 'Tiles with fewer returns in their column are unknown', '',
                             (0, 1_000_000))
    # A ground vehicle's sensor sees the ground 6 to 20 degrees down, a helicopter's at least
    # 25 (experiments/2026-12-06_real-scan): the network was trained on the helicopter's view
    # and judges the grazing one wildly. Read-only: the counts are taken as clouds arrive.
    min_ray_depression_deg: float = param(
        20.0, 'Tiles with fewer than min_returns returns from rays at least this steep below '
        'the horizontal are unknown (a grazing view); 0 turns it off', 'deg', (0.0, 90.0),
        open_hi=True, read_only=True)
    # The shipped model was trained on cubes cut level (of level and sloped synth3 ground), yet
    # judges a 10-degree site as it judges the same site flat only with the cubes aligned (per-
    # tile AUC 0.999 tilted and flat, no obstacle tile passed; cut level 0.975 and 4 of 30:
    # experiments/2026-12-01_sloped_ground). Training, evaluate, calibrate and fit-ood cut their
    # cubes as this says too (judging.patches.scene_to_input), so models are trained and judged
    # on the cubes the assessor cuts.
    align_to_ground: bool = param(
        True, "Align each tile's cube to its ground plane (columns sheared along the slope, so "
        'a slope reads as level ground); off cuts it level')

    def validate(self) -> None:
        _check_fields(self, 'tiles.')


@dataclass
class ModelConfig:
    """The safety CNN."""

    path: str = param('', 'Model file (.safetensors); empty: the shipped model', read_only=True)
    device: str = param('cpu', 'Inference device: cpu, cuda or cuda:N', read_only=True)
    batch_size: int = param(256, 'Tiles per forward pass', '', (1, 65536))
    # The model is calibrated at the share its metadata states (an even one: the training
    # scenes'); stating the site's own share moves every logit by the change in prior log odds
    # (docs/ROS_NODE.md, "What a planner reads"). A lower share raises P(safe) everywhere:
    # raise landing_sites.min_p_safe with it to keep the same decisions.
    obstacle_prior: float = param(
        0.5, 'Share of tiles expected to hold an obstacle, at which P(safe) is calibrated', '',
        (0.0, 1.0), open_lo=True, open_hi=True, read_only=True)

    def validate(self) -> None:
        _check_fields(self, 'model.')
        if not (self.device == 'cpu' or self.device.startswith('cuda')):
            raise ConfigError(f"model.device must be 'cpu' or 'cuda[:N]', got {self.device!r}")


@dataclass
class SiteConfig:
    """Landing-site candidates for the vehicle's footprint."""

    footprint_radius: float = param(1.5, "Radius of the vehicle's circular footprint", 'm',
                                    (0.0, 50.0), open_lo=True)
    top_k: int = param(5, 'Landing-site candidates published, best first', '', (0, 100))
    # 0.9, the level planners are told to act at (docs/LANDING_SITES.md, "A site's P(safe)"):
    # fewer sites over an obstacle than at 0.8, for fewer clear ones; a planner that wants more
    # sites lowers it knowingly
    min_p_safe: float = param(
        0.9, 'Candidates below this P(all tiles under the footprint safe) are left out', '',
        (0.0, 1.0))
    # Skids: 5-10 degrees is the usual limit of a helicopter's landing gear.
    max_slope_deg: float = param(
        8.0, 'Candidates whose ground under the footprint is steeper are left out', 'deg',
        (0.0, 90.0))
    max_step: float = param(
        0.15, 'Candidates with a larger step between the ground planes of two neighbouring '
        'tiles under the footprint are left out', 'm', (0.0, 10.0))
    min_clearance: float = param(
        1.5, 'Candidates with less free height above the ground over the footprint (within '
        'the map) are left out', 'm', (0.0, 100.0))
    clutter_height: float = param(
        0.5, 'Clearance is measured above this height over the ground (below it, grass and '
        'obstacles are judged by the network)', 'm', (0.0, 10.0))

    def validate(self) -> None:
        _check_fields(self, 'landing_sites.')


@dataclass
class GuardConfig:
    """The guard beside the network: opaque structure above the ground (judging.guard)."""

    enabled: bool = param(True, 'Cap P(safe) where opaque structure stands above the ground')
    min_height: float = param(0.12, "Solid voxels count from this far above the tile's ground",
                              'm', (0.0, 2.0))
    # anything taller than max_height stands in the band below it too
    max_height: float = param(1.0, '... up to this height above it', 'm', (0.0, 4.0),
                              open_lo=True)
    min_hits: int = param(2, 'A solid voxel holds at least this many returns', '', (1, 1000))
    min_hit_ratio: float = param(
        0.4, 'A solid voxel ended at least this share of the rays that reached it', '',
        (0.0, 1.0), open_lo=True)
    # Behind a solid no ray gets; under grass most go on.
    max_pass_behind: float = param(
        0.1, "Shadow: share of a solid voxel's rays crossing the emptiest voxel next to it, "
        'at most', '', (0.0, 1.0))
    min_cluster_hits: int = param(20, 'The guard fires on a connected cluster of solid voxels '
                                  'with at least this many returns', '', (1, 100000))
    margin: float = param(0.2, "Clusters are traced this far beyond the tile's edges", 'm',
                          (0.0, 2.0))
    # One voxel: a solid voxel touching the tile's edge may hold an obstacle reaching into the
    # tile by less than a voxel, which the map cannot resolve (on 112 fresh flights it caught
    # 12 of the 81 obstacle tiles passed at 0.5 and flagged 4 of 14,281 safe tiles; two
    # voxels 18 and 63: experiments/2026-12-04_guard_reach)
    reach: float = param(0.05, 'A cluster counts for a tile when it comes this close to the '
                         "tile's edge (at most margin)", 'm', (0.0, 2.0))
    max_p_safe: float = param(0.05, 'P(safe) of a tile where the guard fires is at most this',
                              '', (0.0, 1.0))

    def validate(self) -> None:
        _check_fields(self, 'guard.')
        if not self.max_height > self.min_height:
            raise ConfigError(f'guard.max_height ({self.max_height}) must exceed '
                              f'guard.min_height ({self.min_height})')
        if self.reach > self.margin:
            raise ConfigError(f'guard.reach ({self.reach}) must not exceed guard.margin '
                              f'({self.margin}): clusters are traced only that far')


@dataclass
class OODConfig:
    """The out-of-distribution signal after the guard (judging.ood)."""

    # Its threshold and k live in the reference file, fitted with the model's data
    # (landing-zone fit-ood): they belong to the model, not to the deployment.
    enabled: bool = param(True, 'Tiles judged safe but unlike the training data become unknown',
                          read_only=True)
    path: str = param('', 'OOD reference file; empty: NAME.ood.safetensors beside the model',
                      read_only=True)

    def validate(self) -> None:
        _check_fields(self, 'ood.')
        if self.path and not self.path.endswith('.safetensors'):
            raise ConfigError(f'ood.path must be a .safetensors file, got {self.path!r}')


@dataclass
class AssessorConfig:
    """The whole pipeline; the defaults are those of the node (docs/INTERFACES.md §1)."""

    frame_id: str = param('map', 'Fixed frame of the clouds, poses and outputs', read_only=True)
    # None: the map follows the sensor (scrolling). (x, y): a fixed region of interest.
    center: tuple[float, float] | None = param(
        None, 'X Y of a fixed region of interest; unset: the map follows the sensor', 'm',
        read_only=True, name='region_center')
    map: MapConfig = field(default_factory=MapConfig)
    tiles: TileConfig = field(default_factory=TileConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    landing_sites: SiteConfig = field(default_factory=SiteConfig)
    guard: GuardConfig = field(default_factory=GuardConfig)
    ood: OODConfig = field(default_factory=OODConfig)

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
        self.ood.validate()
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
        for section in SECTIONS:
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
            sub = getattr(cfg, section, None) if section in SECTIONS else None
            if sub is None or name not in {f.name for f in dataclasses.fields(sub)}:
                raise ConfigError(f'unknown configuration key {key!r}')
            current = getattr(sub, name)
            setattr(sub, name, type(current)(value))
        cfg.validate()
        return cfg
