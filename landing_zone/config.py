"""Configuration of landing_zone: one dataclass per stage, SI units, and every parameter fact.

Each field that is a parameter of the ``assessor`` node carries its facts as field metadata
(:class:`Param`: description, unit, range, read-only), here and nowhere else. From them come
the checks of :meth:`validate`, the node's ``ParameterDescriptor``\\ s (:data:`PARAMETERS`) and
the text of ``config/assessor.yaml`` (:func:`params_yaml`; a test holds the file to it).

The node declares the pipeline's fields as dotted parameters (``map.voxel_size``,
``tiles.tile_size``, ...) and copies them onto :class:`AssessorConfig` mechanically
(:func:`AssessorConfig.from_flat` / :meth:`AssessorConfig.to_flat`), so the names in
``config/assessor.yaml``, the node and the Python API are the same. :class:`StreamConfig` (the
stream node and replay share) and :class:`NodeConfig` (the node's own) are flat.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from landing_zone.errors import ConfigError

__all__ = [
    'Param',
    'MapConfig',
    'TileConfig',
    'ModelConfig',
    'SiteConfig',
    'GuardConfig',
    'OODConfig',
    'AssessorConfig',
    'StreamConfig',
    'NodeConfig',
    'LiveConfig',
    'QOS_RELIABILITY',
    'PARAMETERS',
    'live_config',
    'default_parameters',
    'configs_from_flat',
    'params_yaml',
]

SECTIONS = ('map', 'tiles', 'model', 'landing_sites', 'guard', 'ood')


@dataclass(frozen=True)
class Param:
    """The facts of one parameter.

    Attributes:
        description: what it does, one phrase (the descriptor's text, the YAML comment).
        unit: SI unit, '' for none.
        range: (lo, hi) of allowed values, both included unless ``open_lo`` / ``open_hi``;
            None: no range (strings, arrays).
        open_lo: ``lo`` itself is not allowed.
        open_hi: ``hi`` itself is not allowed.
        read_only: fixed once the node runs (it sizes the map, the tiles or the network).
        name: the parameter's name when it is not the field's own (``region_center``).
    """

    description: str
    unit: str = ''
    range: tuple[float, float] | None = None
    open_lo: bool = False
    open_hi: bool = False
    read_only: bool = False
    name: str = ''

    @property
    def text(self) -> str:
        """Description with unit and read-only mark, as the node and the YAML show it."""
        unit = f' [{self.unit}]' if self.unit else ''
        return f'{self.description}{unit}' + (' (read-only)' if self.read_only else '')

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`ConfigError` naming ``name`` if ``value`` is outside the range."""
        if self.range is None:
            return
        lo, hi = self.range
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f'{name} must be a number, got {value!r}') from None
        ok = math.isfinite(v) and (v > lo if self.open_lo else v >= lo) and (
            v < hi if self.open_hi else v <= hi)
        if not ok:
            if lo == 0 and self.open_lo and math.isinf(hi):
                raise ConfigError(f'{name} must be a positive number, got {value!r}')
            left, right = '(' if self.open_lo else '[', ')' if self.open_hi else ']'
            raise ConfigError(f'{name} must lie in {left}{lo:g}, {hi:g}{right}, got {value!r}')


def param(default: Any, description: str, unit: str = '',
          range: tuple[float, float] | None = None, *, open_lo: bool = False,
          open_hi: bool = False, read_only: bool = False, name: str = '') -> Any:
    """A dataclass field with its :class:`Param` facts as metadata."""
    return field(default=default, metadata={'param': Param(
        description, unit, range, open_lo, open_hi, read_only, name)})


def _check_fields(obj: Any, prefix: str) -> None:
    for f in dataclasses.fields(obj):
        p = f.metadata.get('param')
        if p is not None:  # named as the node names it (snapshot.period, not snapshot_period)
            p.check(p.name or prefix + f.name, getattr(obj, f.name))


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
    # 0.8 on the least tile probability lists what 0.5 on the independence product did on 64
    # fresh flights (61 and 60 % of the clear footprints, none over an obstacle; judging.sites)
    min_p_safe: float = param(
        0.8, 'Candidates below this P(all tiles under the footprint safe) are left out', '',
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


@dataclass
class StreamConfig:
    """The stream's timing (:mod:`landing_zone.runtime.stream`), shared by node and replay."""

    assessment_period: float = param(1.0, 'Stamp time between assessments', 's', (0.0, 60.0),
                                     open_lo=True)
    pose_tolerance: float = param(0.05, "How far a cloud may lie outside the poses' span", 's',
                                  (0.0, 10.0))
    pose_wait: float = param(0.5, 'How long (stamp time) a cloud may wait for its pose', 's',
                             (0.0, 10.0))
    max_pending: int = param(20, 'Clouds that may wait for their pose at once', '', (1, 1000))
    pose_history: float = param(30.0, 'Span of poses kept for interpolation', 's',
                                (0.0, 3600.0), open_lo=True, read_only=True)

    def validate(self) -> None:
        _check_fields(self, '')


@dataclass
class LiveConfig:
    """The live receive path's bounds (:mod:`landing_zone.runtime.ingest`), node only."""

    # clouds that may wait for the integration thread: 1 s at 20 Hz, room for the clouds that
    # come while an assessment pass has the CPU (10 overflowed now and then at 0.3 M returns/s
    # on a busy 2-core machine)
    # (a cloud of fewer than 1000 returns counts as its share of one, at least 1/20: a flood
    # of tiny or malformed clouds cannot push the real ones out; runtime.ingest)
    receive_queue: int = param(
        20, 'Clouds that may wait for integration, small ones by their share of 1000 returns; '
        'more push out the oldest (overload)', '', (1, 10000), read_only=True)
    receive_queue_mb: float = param(64.0, '... and at most this many MB of them', 'MB',
                                    (1.0, 100000.0), read_only=True)
    idle_flush: float = param(
        1.0, 'After this long without input, waiting clouds are settled and the last ones '
        'assessed', 's', (0.05, 60.0))

    def validate(self) -> None:
        if isinstance(self.receive_queue, bool) or not isinstance(self.receive_queue, int):
            raise ConfigError(f'receive_queue must be a positive integer, got '
                              f'{self.receive_queue!r}')
        _check_fields(self, '')


# The subscriptions' reliability choices (rclpy's ReliabilityPolicy names them in the node).
QOS_RELIABILITY = ('best_effort', 'reliable')


@dataclass
class NodeConfig:
    """The ``assessor`` node's own settings (the front end's, not the pipeline's)."""

    # 50: room for the clouds that arrive while the executor thread waits for the GIL (5 lost
    # about 1 in 200 at 120 Hz on the live branch's measurements)
    qos_depth: int = param(50, 'History depth of the points and pose subscriptions', '',
                           (1, 1000), read_only=True)
    qos_reliability: str = param(
        'best_effort', 'Reliability of the subscriptions: best_effort (any publisher) or '
        'reliable', read_only=True)
    diagnostics_period: float = param(1.0, 'Time between /diagnostics messages', 's',
                                      (0.1, 60.0), read_only=True)
    warn_period: float = param(5.0, 'Least time between two warnings of one kind', 's',
                               (0.0, 3600.0))
    snapshot_path: str = param(
        '', 'Map snapshot: saved periodically, loaded at start if it matches; empty: none',
        read_only=True,
        name='snapshot.path')
    snapshot_period: float = param(10.0, 'Time between two snapshots (wall time)', 's',
                                   (1.0, 86400.0), name='snapshot.period')

    def validate(self) -> None:
        if self.qos_reliability not in QOS_RELIABILITY:
            raise ConfigError(f'qos_reliability must be one of {", ".join(QOS_RELIABILITY)}, '
                              f'got {self.qos_reliability!r}')
        _check_fields(self, '')

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> NodeConfig:
        """The node's settings among dotted parameters (by their parameter names); others are
        ignored, missing ones keep their defaults.

        Raises:
            ConfigError: a value out of range or not one of the choices.
        """
        cfg: NodeConfig = _from_names(cls, flat)
        return cfg


def _from_names(cls: Any, flat: dict[str, Any]) -> Any:
    """An instance of a flat config class from the parameters named as its fields' facts say
    (``snapshot.path`` for ``snapshot_path``), validated."""
    kwargs = {}
    for f in dataclasses.fields(cls):
        p = f.metadata.get('param')
        name = (p.name if p is not None and p.name else f.name)
        if name in flat:
            kwargs[f.name] = flat[name]
    obj = cls(**kwargs)
    obj.validate()
    return obj


def live_config(flat: dict[str, Any]) -> LiveConfig:
    """The receive path's settings among dotted parameters (others are ignored).

    Raises:
        ConfigError: a value out of range.
    """
    cfg: LiveConfig = _from_names(LiveConfig, flat)
    return cfg


def _parameter_table() -> dict[str, tuple[Any, Param]]:
    """Every node parameter by name: (default, facts), in the order of the YAML file."""
    out: dict[str, tuple[Any, Param]] = {}

    def add(obj: Any, prefix: str) -> None:
        for f in dataclasses.fields(obj):
            p = f.metadata.get('param')
            if p is not None:
                out[p.name or prefix + f.name] = (getattr(obj, f.name), p)

    top = AssessorConfig()
    add(top, '')
    for section in SECTIONS:
        add(getattr(top, section), section + '.')
    add(StreamConfig(), '')
    add(NodeConfig(), '')
    add(LiveConfig(), '')
    return out


# name -> (default, Param) of every parameter of the node; region_center's default None = unset.
PARAMETERS: dict[str, tuple[Any, Param]] = _parameter_table()


def default_parameters() -> dict[str, Any]:
    """Every parameter with a default, by name (the pipeline's, the stream's, the node's)."""
    return {name: default for name, (default, _) in PARAMETERS.items() if default is not None}


def configs_from_flat(flat: dict[str, Any]) -> tuple[AssessorConfig, StreamConfig,
                                                     dict[str, Any]]:
    """Split dotted parameters into the pipeline's config, the stream's and the rest.

    ``region_center`` (empty or two numbers) becomes ``AssessorConfig.center``; names of
    :class:`StreamConfig` fields go to the stream config; names :meth:`AssessorConfig.to_flat`
    knows go to the pipeline; anything else (front-end settings such as ``qos_depth``) is
    returned as it is.

    Raises:
        ConfigError: a value of the wrong type or out of range.
    """
    known = set(AssessorConfig().to_flat())
    stream_fields = {f.name: f for f in dataclasses.fields(StreamConfig)}
    core: dict[str, Any] = {}
    stream = StreamConfig()
    rest: dict[str, Any] = {}
    for name, value in flat.items():
        if name in known:
            core[name] = value
        elif name in stream_fields:
            current = getattr(stream, name)
            try:
                setattr(stream, name, type(current)(value))
            except (TypeError, ValueError) as err:
                raise ConfigError(f'{name} must be a {type(current).__name__}, got '
                                  f'{value!r}') from err
        elif name == 'region_center':
            center = list(value or [])
            if len(center) not in (0, 2):
                raise ConfigError(f'region_center must be empty or two numbers, got {value!r}')
            core['center'] = [float(c) for c in center] if center else None
        else:
            rest[name] = value
    try:
        cfg = AssessorConfig.from_flat(core)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError):
            raise
        raise ConfigError(f'bad parameter value: {err}') from err
    stream.validate()
    return cfg, stream, rest


_YAML_HEAD = '''\
# Parameters of the `assessor` node (landing_zone), with their defaults.
#
#   ros2 run landing_zone assessor --ros-args --params-file config/assessor.yaml
#   landing-zone replay SITE.mcap --out OUT.mcap --report REPORT.json --params config/assessor.yaml
#
# Nested sections are the dotted parameter names (map.voxel_size, ...), the same names as the
# fields of landing_zone.config.AssessorConfig. Write floats with a decimal point (20.0, not 20):
# ROS 2 parameters are typed. Parameters marked (read-only) size the map, the tiles or the
# network and cannot change while the node runs.
#
# Generated from the field metadata in landing_zone/config.py (landing_zone.config.params_yaml);
# test/test_config.py fails when the two differ.
assessor:
  ros__parameters:
'''


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return value if value else "''"
    return repr(value)


def params_yaml() -> str:
    """The text of ``config/assessor.yaml``: every parameter, its default and its facts."""
    lines = [_YAML_HEAD.rstrip('\n')]

    def emit(indent: str, key: str, value: Any, p: Param, commented: bool = False) -> None:
        entry = f'{indent}{"# " if commented else ""}{key}: {value}'
        inline = f'{entry:<{len(indent) + 29}}  # {p.text}'
        if not commented and len(inline) <= 99:
            lines.append(inline)
        else:
            lines.append(f'{indent}# {p.text}')
            lines.append(entry)

    top = AssessorConfig()
    for f in dataclasses.fields(top):
        p = f.metadata.get('param')
        if p is None:
            continue
        if p.name == 'region_center':
            emit('    ', p.name, '[10.0, -4.0]', p, commented=True)
        else:
            emit('    ', f.name, _yaml_value(getattr(top, f.name)), p)
    for section in SECTIONS:
        lines.append('')
        lines.append(f'    {section}:')
        sub = getattr(top, section)
        for f in dataclasses.fields(sub):
            emit('      ', f.name, _yaml_value(getattr(sub, f.name)), f.metadata['param'])
    nested: dict[str, list[tuple[str, Any, Param]]] = {}
    for title, obj in (('The stream (landing_zone.config.StreamConfig), shared with replay.',
                        StreamConfig()),
                       ('The node only (landing_zone.config.NodeConfig).', NodeConfig()),
                       ('The live receive path, node only (landing_zone.config.LiveConfig).',
                        LiveConfig())):
        lines.append('')
        lines.append(f'    # {title}')
        for f in dataclasses.fields(obj):
            p = f.metadata['param']
            if '.' in p.name:  # a dotted name is a nested section in the YAML
                head, key = p.name.split('.', 1)
                nested.setdefault(head, []).append((key, getattr(obj, f.name), p))
                continue
            emit('    ', f.name, _yaml_value(getattr(obj, f.name)), p)
    for head, entries in nested.items():
        lines.append('')
        lines.append(f'    {head}:')
        for key, value, p in entries:
            emit('      ', key, _yaml_value(value), p)
    return '\n'.join(lines) + '\n'
