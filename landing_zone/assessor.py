"""The one pipeline: integrate registered clouds into the map, judge its tiles, find sites.

Both front ends (the ROS node and bag replay) drive this class, so the same clouds give the same
tiles in both. One :class:`Assessor` owns the scrolling density map, the tiler and the network
(loaded once); :meth:`Assessor.integrate` adds a cloud, :meth:`Assessor.assess` judges the tiles:

1. **Placement.** In follow mode (the default) the map's XY window sits on whole tiles around the
   sensor's ground projection and scrolls when the sensor moves more than
   ``map.recenter_distance`` from its centre; vertically it is placed around the ground under
   the sensor (the median height of the cloud's returns) and moves when that drifts past half the
   margin to the nearer window face. In fixed mode (``center=(x, y)``) the XY window never moves
   and the height is placed once, from the first cloud.
2. **Incremental assessment.** Only tiles whose voxels changed since the last pass (the map's
   dirty tiles, widened by the tiles the network's padding reaches into) are re-extracted and
   re-judged; the others keep their results, and tiles that scroll out are forgotten.
3. **Judgement.** A tile the tiler marks valid (observed enough, see
   :class:`~landing_zone.config.TileConfig`) gets P(safe) from the calibrated network (its
   checkpoint's temperature); any other tile is unknown (NaN), never guessed safe. Beside the
   network the guard (:mod:`landing_zone.judging.guard`) caps P(safe) where opaque structure stands
   above the tile's ground, whatever its shape; after it, a tile the network calls safe whose
   features are unlike every training tile's (:mod:`landing_zone.judging.ood`, when the model
   has a reference) becomes unknown, and every tile's confidence is scaled by how near its
   features lie to the training tiles'.
4. **Confidence** in [0, 1] says how much the judgement rests on observation: the product of
   ``min(1, observed_fraction / 0.5)`` (a sensor above the ground sees at most the upper half of
   the tile's cube, the half above the ground voxel) and ``1 - exp(-returns / (100 per m^2 *
   tile area))`` (saturating once the tile holds a few hundred returns per square metre), times
   ``min(1, threshold / distance)`` of the OOD signal where there is one.
5. **Ground planes** (:mod:`landing_zone.judging.ground`): per tile the plane fitted to the
   lower envelope of its ground evidence, its slope, roughness and the free height above it;
   the tile's reported ground height is the plane's at its centre (the tiler's where a tile
   has no plane).
6. **Landing sites** for the vehicle's footprint (:mod:`landing_zone.judging.sites`), within
   the limits on slope, step and clearance; every candidate left out keeps its reasons.

Thread safety: :meth:`integrate` and :meth:`assess` may run on different threads (the node does
this). The map is guarded by a lock held only while rays are integrated or counts are read; the
network runs outside it, so integration never waits for inference. A pass can also be split:
:meth:`begin_assess` copies what it needs at one moment, :meth:`finish_assess` judges it while
integration goes on (replay does this: the same passes as one after the other, overlapped).
"""
from __future__ import annotations

import copy
import math
import os
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from landing_zone.config import AssessorConfig
from landing_zone.errors import InvalidCloudError, ModelError
from landing_zone.judging.sites import (Candidates, GroundGrids, LandingSite,
                                        evaluate_candidates, find_sites)

if TYPE_CHECKING:
    from landing_zone.judging.ood import FeatureReference
    from landing_zone.mapping.density_map import IntegrationStats

__all__ = ['Assessor', 'Assessment', 'default_model_path', 'tile_confidence',
           'MODEL_FILENAME']

# The shipped model's file name inside models/ (in the repository or share/landing_zone/).
MODEL_FILENAME = 'landing_zone.safetensors'
# Observed fraction of a tile's cube that counts as fully observed: from above, only the half
# above the ground voxel can be seen (the rest is occluded by the ground itself).
FULL_OBSERVED_FRACTION = 0.5
# Returns per square metre of tile at which the returns term reaches 1 - 1/e.
RETURNS_PER_M2 = 100.0


def tile_confidence(observed_fraction: np.ndarray, n_returns: np.ndarray,
                    tile_size: float) -> np.ndarray:
    """How much a tile's judgement rests on observation, in [0, 1] (see the module docstring).

    Args:
        observed_fraction: share of the tile's cube observed, in [0, 1].
        n_returns: returns in the tile's column.
        tile_size: tile edge [m].

    Returns:
        float32 array of the broadcast shape.
    """
    obs = np.clip(np.asarray(observed_fraction, np.float64) / FULL_OBSERVED_FRACTION, 0.0, 1.0)
    scale = RETURNS_PER_M2 * tile_size * tile_size
    ret = 1.0 - np.exp(-np.maximum(np.asarray(n_returns, np.float64), 0.0) / scale)
    return (obs * ret).astype(np.float32)


def _median_within(z: np.ndarray, lo: float, hi: float) -> bool:
    """Whether the median of ``z`` (non-empty, finite) lies in ``[lo, hi]``, by counting: it
    does when both middle order statistics do, i.e. when at most ``(n - 1) // 2`` values lie
    below ``lo`` and at most as many above ``hi`` (then the median, their mean, lies between).
    False may also mean "not sure" (a middle value outside): the caller takes the median then.
    Two counts cost a fifth of the partial sort a median takes, on every cloud."""
    n = z.shape[0]
    k = (n - 1) // 2
    return bool(np.count_nonzero(z < lo) <= k and np.count_nonzero(z > hi) <= k)


def default_model_path() -> Path:
    """The shipped model: ``models/landing_zone.safetensors`` in the first place it exists.

    Looked up in the package's share directory (colcon install, via ament_index when present),
    ``<prefix>/share/landing_zone/models`` (pip install), then the source tree's ``models/``.

    Raises:
        ModelError: no shipped model is installed.
    """
    candidates: list[Path] = []
    try:  # ament_index is ROS tooling but not rclpy; absent on a plain pip install
        from ament_index_python.packages import (PackageNotFoundError,
                                                 get_package_share_directory)
        try:
            candidates.append(Path(get_package_share_directory('landing_zone')) / 'models')
        except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH unset
            pass
    except ImportError:
        pass
    candidates.append(Path(sys.prefix) / 'share' / 'landing_zone' / 'models')
    candidates.append(Path(__file__).resolve().parent.parent / 'models')
    for directory in candidates:
        path = directory / MODEL_FILENAME
        if path.is_file():
            return path
    raise ModelError(f'no shipped model found ({MODEL_FILENAME} in '
                     f'{", ".join(str(c) for c in candidates)}); pass a model file '
                     '(--model / model.path)')


@dataclass
class Assessment:
    """The tiles of the map's window and the landing sites, at one moment.

    The tiles are the map's XY window cut on the global tile lattice, listed x-major (tile
    ``(origin[0] + i, origin[1] + j)`` is entry ``i * shape[1] + j``), so every per-tile array
    reshapes to the grid with :meth:`grid`.

    Attributes:
        frame_id: fixed frame of the coordinates.
        tile_size: tile edge [m].
        origin: global tile index (kx, ky) of grid cell (0, 0).
        shape: tiles of the grid along x and y.
        index: (T, 2) int64 global tile indices.
        centers: (T, 2) float64 tile centres [m].
        ground_z: (T,) float64 estimated ground height [m] (the ground plane's at the tile
            centre, else the tiler's); NaN where none was found.
        p_safe: (T,) float32 P(safe); NaN where the tile is not observed enough to judge.
        confidence: (T,) float32 in [0, 1].
        observed_fraction: (T,) float32 observed share of each tile's cube.
        n_returns: (T,) int64 returns in each tile's column.
        sites: landing-site candidates, best first.
        footprint_radius: radius of the vehicle footprint the sites were found for [m].
        stamp: time [s] of the newest cloud integrated before this assessment, if given.
        reassessed: tiles re-extracted in this pass (the others kept their results).
        seconds: wall time of this pass [s].
        p_net: (T,) float32 the network's own P(safe), before the guard; None: not kept.
        guard: (T,) bool the guard capped the tile's P(safe) (:mod:`landing_zone.judging.guard`).
        guard_hits: (T,) int64 returns on the largest solid cluster reaching into the tile.
        guard_height: (T,) float32 top of that cluster above the ground [m]; NaN: none.
        slope_deg: (T,) float32 slope of the tile's ground plane [deg]; NaN: no plane.
        roughness: (T,) float32 RMS residual of its ground about the plane [m]; NaN: no plane.
        clearance: (T,) float32 free height above its ground within the map [m]; NaN: no plane.
        grad: (T, 2) float64 the ground plane's gradient (dz/dx, dz/dy); NaN: no plane.
        candidates: every tile-centred footprint with its figures and its reasons to be left
            out (:class:`~landing_zone.judging.sites.Candidates`).
        ood: (T,) float32 the tile's feature distance over the OOD threshold (past 1: unlike
            the training data, :mod:`landing_zone.judging.ood`); NaN where not judged or
            without a reference.
    """

    frame_id: str
    tile_size: float
    origin: tuple[int, int]
    shape: tuple[int, int]
    index: np.ndarray
    centers: np.ndarray
    ground_z: np.ndarray
    p_safe: np.ndarray
    confidence: np.ndarray
    observed_fraction: np.ndarray
    n_returns: np.ndarray
    sites: list[LandingSite] = field(default_factory=list)
    footprint_radius: float = 0.0
    stamp: float | None = None
    reassessed: int = 0
    seconds: float = 0.0
    p_net: np.ndarray | None = None
    guard: np.ndarray | None = None
    guard_hits: np.ndarray | None = None
    guard_height: np.ndarray | None = None
    slope_deg: np.ndarray | None = None
    roughness: np.ndarray | None = None
    clearance: np.ndarray | None = None
    grad: np.ndarray | None = None
    candidates: Candidates | None = None
    ood: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.index.shape[0])

    @property
    def known(self) -> np.ndarray:
        """(T,) bool, tiles that were judged (p_safe is a number)."""
        out: np.ndarray = np.isfinite(self.p_safe)
        return out

    def grid(self, values: np.ndarray) -> np.ndarray:
        """A per-tile array as the (X, Y) grid (cell (i, j) is tile ``origin + (i, j)``)."""
        return np.asarray(values).reshape(self.shape)

    def lookup(self, x: float, y: float) -> int | None:
        """Entry of the tile containing world point (x, y), or None outside the grid."""
        i = math.floor(x / self.tile_size) - self.origin[0]
        j = math.floor(y / self.tile_size) - self.origin[1]
        if 0 <= i < self.shape[0] and 0 <= j < self.shape[1]:
            return i * self.shape[1] + j
        return None

    def reasons(self) -> list[str | None]:
        """Per tile, why its P(safe) is lower than the network's (None: it is the network's)."""
        from landing_zone.judging.guard import REASON_SOLID
        from landing_zone.judging.ood import REASON_OOD

        if self.guard is None or self.guard_hits is None or self.guard_height is None:
            return [None] * len(self)
        n = len(self)
        ood = self.ood if self.ood is not None else np.full(n, np.nan, np.float32)
        p_net = self.p_net if self.p_net is not None else self.p_safe
        out: list[str | None] = []
        for g, hits, h, p, q, r in zip(self.guard.tolist(), self.guard_hits.tolist(),
                                       self.guard_height.tolist(), self.p_safe.tolist(),
                                       p_net.tolist(), ood.tolist()):
            if g:
                out.append(f'{REASON_SOLID}: {hits} returns up to {h:.2f} m')
            elif math.isnan(p) and not math.isnan(q):
                # judged by the network, made unknown after it: only the OOD signal does that
                out.append(f'{REASON_OOD}: feature distance {r:.2f} x the threshold')
            else:
                out.append(None)
        return out

    def to_report(self, stats: dict[str, Any] | None = None) -> dict[str, Any]:
        """The REPORT.json document (docs/INTERFACES.md §3).

        Beyond the contract's keys, ``reasons`` lists the tiles whose P(safe) is lower than the
        network's (``x``, ``y``, ``reason``, ``p_net``: the network's own P(safe)), tiles carry
        ``roughness`` and ``clearance`` beside ``slope_deg``, sites their ``step``,
        ``clearance`` and ground ``normal``, and ``rejected_sites`` lists every candidate
        footprint left out with its ``reasons`` (but those whose one reason is ``unknown``).
        The reasons cover the guard's caps and the tiles the OOD signal made unknown
        (``p_safe`` null).

        Args:
            stats: the front end's counters (clouds, points, dropped_points, seconds, ...).
        """
        tiles = []
        nan = np.full(len(self), np.nan)
        slope = (self.slope_deg if self.slope_deg is not None else nan).tolist()
        rough = (self.roughness if self.roughness is not None else nan).tolist()
        clear = (self.clearance if self.clearance is not None else nan).tolist()
        for (x, y), gz, p, c, sl, ro, cl in zip(self.centers.tolist(), self.ground_z.tolist(),
                                                self.p_safe.tolist(),
                                                self.confidence.tolist(), slope, rough, clear):
            tiles.append({'x': x, 'y': y,
                          'ground_z': None if math.isnan(gz) else round(gz, 4),
                          'p_safe': None if math.isnan(p) else round(p, 6),
                          'confidence': round(c, 6),
                          'slope_deg': None if math.isnan(sl) else round(sl, 3),
                          'roughness': None if math.isnan(ro) else round(ro, 4),
                          'clearance': None if math.isnan(cl) else round(cl, 3)})
        # why a tile's P(safe) is below the network's goes beside the tiles, one entry per
        # such tile
        lowered = [{'x': x, 'y': y, 'reason': why,
                    'p_net': None if self.p_net is None else round(float(self.p_net[k]), 6)}
                   for k, ((x, y), why) in enumerate(zip(self.centers.tolist(), self.reasons()))
                   if why is not None]
        rejected = (self.candidates.rejected(include_unknown_only=False)
                    if self.candidates is not None else [])
        return {'frame_id': self.frame_id, 'tile_size': self.tile_size, 'tiles': tiles,
                'landing_sites': [s.to_dict() for s in self.sites],
                'stats': dict(stats or {}), 'reasons': lowered, 'rejected_sites': rejected}


class _TileState:
    """Per-tile results on the map's tile window, shifted when the window scrolls."""

    def __init__(self, origin: np.ndarray, shape: tuple[int, int]) -> None:
        self.origin = np.asarray(origin, np.int64).copy()
        self.shape = shape
        self.p_safe = np.full(shape, np.nan, np.float32)
        self.confidence = np.zeros(shape, np.float32)
        self.ground_z = np.full(shape, np.nan, np.float64)
        self.observed_fraction = np.zeros(shape, np.float32)
        self.n_returns = np.zeros(shape, np.int64)
        self.p_net = np.full(shape, np.nan, np.float32)
        self.guard = np.zeros(shape, bool)
        self.guard_hits = np.zeros(shape, np.int64)
        self.guard_height = np.full(shape, np.nan, np.float32)
        self.grad_x = np.full(shape, np.nan, np.float64)
        self.grad_y = np.full(shape, np.nan, np.float64)
        self.roughness = np.full(shape, np.nan, np.float32)
        self.clearance = np.full(shape, np.nan, np.float32)
        self.overhead = np.full(shape, np.nan, np.float32)
        self.ood = np.full(shape, np.nan, np.float32)

    _FIELDS = ('p_safe', 'confidence', 'ground_z', 'observed_fraction', 'n_returns', 'p_net',
               'guard', 'guard_hits', 'guard_height', 'grad_x', 'grad_y', 'roughness',
               'clearance', 'overhead', 'ood')

    def move(self, origin: np.ndarray) -> None:
        """Re-anchor at ``origin``: keep the tiles still inside, forget those that left."""
        origin = np.asarray(origin, np.int64)
        d = origin - self.origin
        if not d.any():
            return
        fresh = _TileState(origin, self.shape)
        sx, sy = self.shape
        # overlap in old cell coordinates: [d, d + shape) ∩ [0, shape)
        a = np.maximum(d, 0)
        b = np.minimum(d + np.array([sx, sy]), [sx, sy])
        if np.all(b > a):
            for name in self._FIELDS:
                getattr(fresh, name)[a[0] - d[0]:b[0] - d[0], a[1] - d[1]:b[1] - d[1]] = \
                    getattr(self, name)[a[0]:b[0], a[1]:b[1]]
        self.__dict__.update(fresh.__dict__)

    def cells(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell coordinates of global tile indices and which of them lie in the window."""
        rel = np.asarray(index, np.int64) - self.origin
        inside = np.all((rel >= 0) & (rel < self.shape), axis=1)
        return rel[:, 0], rel[:, 1], inside


@dataclass
class _Pass:
    """What :meth:`Assessor.begin_assess` took from the map for one pass."""

    todo: np.ndarray  # (K, 2) global indices of the tiles to judge
    counts: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # hits, passes, box lo
    stamp: float | None
    t0: float


class Assessor:
    """Integrate clouds, judge tiles, find landing sites (docs/INTERFACES.md §4).

    Examples:
        >>> a = Assessor()                          # follow mode, the shipped model
        >>> a = Assessor(center=(10.0, -4.0))       # a fixed region of interest
        >>> a.integrate(points_xyz, sensor_origin)  # (N, 3) and (3,), fixed frame [m]
        >>> result = a.assess()                     # per-tile p_safe, confidence, sites

    Attributes:
        config: the resolved configuration (``center`` set in fixed mode).
        map: the :class:`~landing_zone.mapping.density_map.DensityMap`.
        model: the network; ``model_path`` the file it came from (None if passed in).
        model_metadata: the checkpoint's metadata.
        ood: the model's OOD reference (:class:`~landing_zone.judging.ood.FeatureReference`),
            None without one (``ood.enabled`` false, or no file); ``ood_path`` its file.
        stats: the integration counters summed over every cloud.
        clouds: clouds integrated.
    """

    def __init__(self, config: AssessorConfig | None = None, *,
                 center: Sequence[float] | None = None, model: Any = None) -> None:
        """Build the map and load the network.

        Args:
            config: the pipeline's configuration; default :class:`AssessorConfig()`.
            center: (x, y) of a fixed region of interest; overrides ``config.center``. None
                (and no ``config.center``): the map follows the sensor.
            model: a loaded :class:`~landing_zone.judging.net.SafetyNet` or
                :class:`~landing_zone.judging.ensemble.SafetyEnsemble`, or a path to a
                checkpoint; default ``config.model.path``, or the shipped model when that is empty.

        Raises:
            ConfigError: an invalid configuration.
            ModelError: the model is missing, corrupt, or expects other inputs than the tiler
                makes; or the OOD reference named is missing, bad or of another model.
        """
        from landing_zone.mapping.density_map import DensityMap, IntegrationStats
        from landing_zone.judging.tiles import tile_voxels

        # a private copy: the caller may go on editing theirs
        cfg = copy.deepcopy(config) if config is not None else AssessorConfig()
        if center is not None:
            c = tuple(float(v) for v in np.asarray(center, np.float64).reshape(-1))
            cfg.center = c  # type: ignore[assignment]
        cfg.validate()
        self.config = cfg
        self.tile_vox = tile_voxels(cfg.map.voxel_size, cfg.tiles)
        self.tile_size = float(cfg.tiles.tile_size)
        self._n_tiles = (int(round(cfg.map.shape[0] / self.tile_vox)),
                         int(round(cfg.map.shape[1] / self.tile_vox)))
        # how many tiles the padding of a tile's input reaches into on each side
        self._reach = int(math.ceil(cfg.tiles.padding / self.tile_vox))
        self.model, self.model_metadata, self.model_path = self._load_model(model)
        from landing_zone.judging.inference import Predictor
        # owns the inference copy and torch's thread count until close()
        self._predictor = Predictor(self.model)
        side = self.tile_vox + 2 * cfg.tiles.padding
        if int(self.model.config.input_size) != side:
            raise ModelError(
                f'model {self.model_path or "(given)"} reads {self.model.config.input_size}^3 '
                f'volumes but tiles.tile_size / map.voxel_size + 2 * tiles.padding gives '
                f'{side}^3')
        self._check_voxel_size()
        self.ood, self.ood_path = self._load_ood()
        self._map_lock = threading.Lock()  # the map and the tile window's placement
        self._state_lock = threading.Lock()  # the tile results
        self._assess_lock = threading.Lock()  # one assessment pass at a time
        self._invalidated = False  # every tile to be judged again at the next pass
        from landing_zone.judging.tiles import CountBuffers
        self._count_buffers = CountBuffers()  # what each pass copies the counts into
        self.map: DensityMap = DensityMap(cfg.map, tile_vox=self.tile_vox)
        self.stats: IntegrationStats = IntegrationStats()
        self.clouds = 0
        self._placed_z = False
        self._stamp: float | None = None
        start = (0.0, 0.0) if cfg.center is None else cfg.center
        self._place(start[0], start[1], 0.0)
        self._state = _TileState(self._tile_origin(), self._n_tiles)
        self._last: Assessment | None = None

    # -- set-up -----------------------------------------------------------------------------

    def _load_model(self, model: Any) -> tuple[Any, dict[str, Any], Path | None]:
        from landing_zone.judging.checkpoint import load_model
        from landing_zone.judging.ensemble import SafetyEnsemble
        from landing_zone.judging.net import SafetyNet

        if isinstance(model, (SafetyNet, SafetyEnsemble)):
            return model.eval(), {}, None
        if model is not None and not isinstance(model, (str, os.PathLike)):
            raise ModelError(f'model must be a SafetyNet, a SafetyEnsemble or a path, got '
                             f'{type(model).__name__}')
        path = Path(model) if model is not None else (
            Path(self.config.model.path) if self.config.model.path else default_model_path())
        net, meta = load_model(path, device=self.config.model.device)
        return net, meta, path

    def _load_ood(self) -> tuple[FeatureReference | None, Path | None]:
        """The OOD reference: ``ood.path``, else the one beside the model file, if there."""
        from landing_zone.judging.checkpoint import weights_sha256
        from landing_zone.judging.ood import load_reference, reference_path_for

        cfg = self.config.ood
        if not cfg.enabled:
            return None, None
        if cfg.path:
            path = Path(cfg.path)
        elif self.model_path is not None and reference_path_for(self.model_path).is_file():
            path = reference_path_for(self.model_path)
        else:
            return None, None  # this model has no reference: judged without the signal
        # bound to the weights as loaded (a net passed in memory has no metadata to ask)
        sha = self.model_metadata.get('weights_sha256') or weights_sha256(self.model)
        return load_reference(path, sha, dim=self.model.head.in_features), path

    def _check_voxel_size(self) -> None:
        meta = self.model_metadata
        trained = None
        for holder in (meta, meta.get('map'), meta.get('inputs')):
            if isinstance(holder, dict) and isinstance(holder.get('voxel_size'), (int, float)):
                trained = float(holder['voxel_size'])
                break
        if trained is not None and abs(trained - self.config.map.voxel_size) > 1e-9:
            raise ModelError(f'model {self.model_path} was trained on {trained} m voxels but '
                             f'map.voxel_size is {self.config.map.voxel_size} m')

    # -- placement --------------------------------------------------------------------------

    @property
    def follow(self) -> bool:
        """Whether the map follows the sensor (no fixed centre)."""
        return self.config.center is None

    def _tile_origin(self) -> np.ndarray:
        return self.map.lo[:2] // self.tile_vox

    def _place(self, x: float, y: float, ground_z: float) -> None:
        """Put the window's XY on whole tiles around (x, y) and its z around ``ground_z``."""
        nt = np.array(self._n_tiles, np.int64)
        k = np.array([round(x / self.tile_size), round(y / self.tile_size)], np.int64)
        lo_xy = (k - nt // 2) * self.tile_vox
        vs = self.config.map.voxel_size
        lo_z = math.floor(ground_z / vs) - int(round(self.config.map.z_below / vs))
        self.map.set_lo(np.array([lo_xy[0], lo_xy[1], lo_z], np.int64))

    @property
    def center(self) -> np.ndarray:
        """(3,) world position [m] of the window's XY centre and its ground level."""
        lo_m, hi_m = self.map.bounds
        return np.array([(lo_m[0] + hi_m[0]) / 2, (lo_m[1] + hi_m[1]) / 2,
                         lo_m[2] + self.config.map.z_below])

    def _maybe_recenter(self, points: np.ndarray, origin: np.ndarray) -> None:
        z = points[:, 2]
        z = z[np.isfinite(z)]
        mc = self.config.map
        c = self.center
        z_margin = min(mc.z_below, mc.size_z - mc.z_below)
        tol = max(z_margin / 2, mc.voxel_size)
        # the ground under the sensor: the median height of the returns (most hit the ground);
        # a cloud without finite returns says nothing about it
        ground = None
        if z.size and self._placed_z and _median_within(z, c[2] - tol, c[2] + tol):
            ground = float(c[2])  # stands in for the median: it moves nothing
        elif z.size:
            ground = float(np.median(z))
        z_moved = ground is not None and (not self._placed_z or abs(ground - c[2]) > tol)
        if self.follow:
            xy_moved = math.hypot(origin[0] - c[0], origin[1] - c[1]) > mc.recenter_distance
            if xy_moved or z_moved:
                self._place(float(origin[0]), float(origin[1]),
                            ground if z_moved and ground is not None else float(c[2]))
        elif z_moved and not self._placed_z and ground is not None:
            assert self.config.center is not None  # fixed mode
            self._place(self.config.center[0], self.config.center[1], ground)
        self._placed_z = self._placed_z or ground is not None
        # the tiles' results follow the window at the next pass (begin_assess), not here: a
        # pass that runs meanwhile keeps the window it began with

    # -- the pipeline -----------------------------------------------------------------------

    def integrate(self, points: np.ndarray, origin: ArrayLike,
                  stamp: float | None = None) -> IntegrationStats:
        """Add one registered cloud to the map (moving the map first in follow mode).

        Args:
            points: (N, 3) returns in the fixed frame [m]; NaN/Inf rows are dropped and
                counted in the returned stats, never raised.
            origin: (3,) the sensor origin of the cloud (its pose at the cloud's stamp) [m].
            stamp: the cloud's time [s]; recorded as the assessment's stamp.

        Returns:
            What happened to the returns.

        Raises:
            InvalidCloudError: ``points`` is not an (N, 3) numeric array or ``origin`` is not
                three finite numbers.
        """
        pts = np.asarray(points)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in 'fiu':
            raise InvalidCloudError(f'points must be a numeric (N, 3) array, got shape '
                                    f'{pts.shape} dtype {pts.dtype}')
        org = np.asarray(origin, np.float64).reshape(-1)
        if org.shape != (3,) or not np.all(np.isfinite(org)):
            raise InvalidCloudError(f'sensor origin must be three finite numbers, got {origin!r}')
        with self._map_lock:
            self._maybe_recenter(pts, org)
            st = self.map.integrate(pts, org)
            self.stats = self.stats + st
            self.clouds += 1
            if stamp is not None:
                self._stamp = float(stamp)
        return st

    def _dirty_tiles(self) -> np.ndarray:
        """Tiles to re-extract: changed ones and the neighbours whose padding reaches them."""
        dirty = self.map.pop_dirty()
        origin = self._tile_origin()
        shape = np.array(self._n_tiles)
        grid = np.zeros(self._n_tiles, bool)
        rel = dirty - origin
        keep = np.all((rel >= 0) & (rel < shape), axis=1)
        grid[rel[keep, 0], rel[keep, 1]] = True
        if self._reach and grid.any():
            from scipy.ndimage import binary_dilation
            grid = binary_dilation(grid, np.ones((2 * self._reach + 1,) * 2, bool))
        out: np.ndarray = np.argwhere(grid).astype(np.int64) + origin
        return out

    def _read_counts(self, tiles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copy of the counts the tiles' inputs read: their bounding box, padding included,
        clipped to the window (as :func:`landing_zone.judging.tiles.extract_tiles` reads them, but
        only the copy is made under the map's lock)."""
        pad = self.config.tiles.padding
        lo = np.asarray(self.map.lo, np.int64)
        hi = np.asarray(self.map.hi, np.int64)
        # from the lowest level any ray reached: the levels below hold nothing, and every
        # reader (tiler, ground planes, guard) takes a box's outside for unobserved
        floor = np.array([self.map.floor_z], np.int64)
        box_lo = np.concatenate([tiles.min(axis=0) * self.tile_vox - pad, floor])
        box_hi = np.concatenate([(tiles.max(axis=0) + 1) * self.tile_vox + pad, hi[2:]])
        box_lo = np.clip(box_lo, lo, hi)
        box_hi = np.clip(box_hi, box_lo, hi)
        sx, sy, sz = (int(v) for v in box_hi - box_lo)
        # into the same memory every pass (passes come one at a time: the last one's copy is
        # no longer read), so a pass does not pay the page faults of 100 MB of fresh memory
        hits, passes = self.map.counts(box_lo, box_hi - box_lo,
                                       out=self._count_buffers.get((sx, sy, sz)))
        return hits, passes, box_lo

    def assess(self) -> Assessment:
        """Judge the tiles whose voxels changed since the last pass; return all tiles' state.

        Returns:
            An :class:`Assessment` of every tile of the current window.
        """
        return self.finish_assess(self.begin_assess())

    def begin_assess(self) -> _Pass:
        """The part of a pass that sees the map at one moment, under the map's lock: the
        tiles that changed, a copy of their counts, the window. Quick (a copy); integration
        may go on while :meth:`finish_assess` judges the copy, on this thread or another.

        One pass at a time: this waits until the previous pass has finished, and the pass it
        begins holds the assessor until :meth:`finish_assess` is called with it.
        """
        self._assess_lock.acquire()
        try:
            t0 = time.perf_counter()
            with self._map_lock:
                if self._invalidated:
                    self._invalidated = False
                    self.map.mark_tile_size(self.tile_vox)
                todo = self._dirty_tiles()
                counts = self._read_counts(todo) if len(todo) else None
                stamp = self._stamp
                origin = self._tile_origin()
            with self._state_lock:
                # tiles that left the window are forgotten; those that entered since the last
                # pass are among the changed ones (scrolling marks them), judged afresh now
                self._state.move(origin)
        except BaseException:
            self._assess_lock.release()
            raise
        return _Pass(todo, counts, stamp, t0)

    def finish_assess(self, job: _Pass) -> Assessment:
        """Judge what :meth:`begin_assess` copied (the tiler's kernel and the network, outside
        the map's lock), store the results and return every tile's state."""
        from landing_zone.judging.ground import fit_ground
        from landing_zone.judging.guard import guard_p_safe, guard_tiles
        from landing_zone.judging.tiles import tiles_from_counts

        try:
            todo, counts = job.todo, job.counts
            # the ground planes first: the cubes may be aligned to them (tiles.align_to_ground)
            ground = fit_ground(*counts, self.config.map.voxel_size, todo, self.tile_vox,
                                self.config.tiles.occupied_density,
                                self.config.landing_sites.clutter_height) \
                if counts is not None else None
            # the cubes of tiles that cannot be valid are not built: no network reads them;
            # those that are come max-pooled by the net's opening pool (the tiler writes an
            # eighth of the cube, the network skips that pass over it; the same numbers)
            pool = self.model.input_pool
            if self.model.config.input_size % pool:
                pool = 1
            batch = tiles_from_counts(*counts, self.config.map.voxel_size, self.config.tiles,
                                      todo, ground, invalid_inputs=False, pool=pool) \
                if counts is not None else None
            p_net = np.full(len(todo), np.nan, np.float32)
            ood = np.full(len(todo), np.nan, np.float32)
            if batch is not None and batch.valid.any():
                # the network runs outside the map's lock: integration goes on meanwhile
                # the tiler writes 2 * density - 1: finite by construction, no check
                x, bs = batch.inputs[batch.valid], self.config.model.batch_size
                if self.ood is not None:
                    # the features come from the same forward pass as P(safe)
                    p_net[batch.valid], feats = self._predictor.with_features(
                        x, batch_size=bs, check_finite=False, pooled=pool > 1)
                    ood[batch.valid] = self.ood.ratio(feats)
                else:
                    p_net[batch.valid] = self._predictor(x, batch_size=bs, check_finite=False,
                                                         pooled=pool > 1)
            p, guard = p_net, None
            if batch is not None and counts is not None and ground is not None \
                    and self.config.guard.enabled:
                # the guard reads the same counts: opaque structure above the ground caps
                # P(safe)
                guard = guard_tiles(counts, self.config.map.voxel_size, batch, ground,
                                    self.tile_vox, self.config.guard)
                p = guard_p_safe(p_net, guard, self.config.guard)
            # after the guard: a "safe" the network gives a tile unlike its training data is
            # not trusted (NaN ratios, tiles not judged or no reference, compare False)
            p = np.where((ood > 1.0) & (p >= 0.5), np.float32(np.nan), p).astype(np.float32)
            with self._state_lock:
                st = self._state
                if batch is not None:
                    i, j, inside = st.cells(batch.index)
                    i, j = i[inside], j[inside]
                    st.p_safe[i, j] = p[inside]
                    st.p_net[i, j] = p_net[inside]
                    if guard is not None:
                        st.guard[i, j] = guard.fired[inside]
                        st.guard_hits[i, j] = guard.hits[inside]
                        st.guard_height[i, j] = guard.height[inside]
                    else:
                        st.guard[i, j], st.guard_hits[i, j], st.guard_height[i, j] = \
                            False, 0, np.nan
                    st.ground_z[i, j] = batch.ground_z[inside]
                    if ground is not None:
                        # the plane's height at the centre, where the tile has a plane
                        has = np.isfinite(ground.plane_z)
                        st.ground_z[i, j] = np.where(has, ground.plane_z,
                                                     batch.ground_z)[inside]
                        st.grad_x[i, j] = ground.grad[inside, 0]
                        st.grad_y[i, j] = ground.grad[inside, 1]
                        st.roughness[i, j] = ground.roughness[inside]
                        st.clearance[i, j] = ground.clearance[inside]
                        st.overhead[i, j] = ground.overhead[inside]
                    st.observed_fraction[i, j] = batch.observed_fraction[inside]
                    st.n_returns[i, j] = batch.n_returns[inside]
                    # past the OOD threshold the judgement rests on extrapolation
                    near = 1.0 / np.maximum(np.nan_to_num(ood[inside], nan=1.0), 1.0)
                    st.confidence[i, j] = tile_confidence(
                        batch.observed_fraction[inside], batch.n_returns[inside],
                        self.tile_size) * near.astype(np.float32)
                    st.ood[i, j] = ood[inside]
                result = self._snapshot(st, job.stamp)
            result.reassessed = int(len(todo))
            result.seconds = time.perf_counter() - job.t0
            self._last = result
            return result
        finally:
            self._assess_lock.release()

    def _snapshot(self, st: _TileState, stamp: float | None) -> Assessment:
        sx, sy = st.shape
        gx, gy = np.meshgrid(np.arange(sx), np.arange(sy), indexing='ij')
        index = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.int64) + st.origin
        from landing_zone.judging.ground import slope_deg

        origin = (int(st.origin[0]), int(st.origin[1]))
        grad = np.stack([st.grad_x, st.grad_y], axis=-1)
        has_plane = np.isfinite(st.grad_x)
        ground = GroundGrids(plane_z=np.where(has_plane, st.ground_z, np.nan), grad=grad,
                             clearance=st.clearance, overhead=st.overhead)
        cand = evaluate_candidates(st.p_safe, st.confidence, origin, self.config.landing_sites,
                                   self.tile_size, ground)
        sites = find_sites(st.p_safe, st.confidence, origin, self.config.landing_sites,
                           self.tile_size, ground_z=st.ground_z, ground=ground,
                           candidates=cand)
        return Assessment(
            frame_id=self.config.frame_id, tile_size=self.tile_size,
            origin=(int(st.origin[0]), int(st.origin[1])), shape=(int(sx), int(sy)),
            index=index, centers=(index + 0.5) * self.tile_size,
            ground_z=st.ground_z.ravel().copy(), p_safe=st.p_safe.ravel().copy(),
            confidence=st.confidence.ravel().copy(),
            observed_fraction=st.observed_fraction.ravel().copy(),
            n_returns=st.n_returns.ravel().copy(), sites=sites,
            footprint_radius=float(self.config.landing_sites.footprint_radius), stamp=stamp,
            p_net=st.p_net.ravel().copy(), guard=st.guard.ravel().copy(),
            guard_hits=st.guard_hits.ravel().copy(), guard_height=st.guard_height.ravel().copy(),
            slope_deg=slope_deg(grad).ravel(), roughness=st.roughness.ravel().copy(),
            clearance=st.clearance.ravel().copy(), grad=grad.reshape(-1, 2).copy(),
            candidates=cand, ood=st.ood.ravel().copy())

    def export_state(self) -> dict[str, np.ndarray]:
        """Copies of the map's counts and the tiles' results, taken under the locks at one
        moment (between two clouds), for :mod:`landing_zone.runtime.snapshot`."""
        with self._assess_lock, self._map_lock, self._state_lock:
            out = {f'map.{k}': v for k, v in self.map.export_state().items()}
            self._state.move(self._tile_origin())
            st = self._state
            out['tiles.origin'] = st.origin.copy()
            for name in _TileState._FIELDS:
                out[f'tiles.{name}'] = getattr(st, name).copy()
            out['placed_z'] = np.array([self._placed_z], np.uint8)
            out['stamp'] = np.array([np.nan if self._stamp is None else self._stamp])
        return out

    def import_state(self, state: dict[str, np.ndarray], tiles: bool = True) -> None:
        """Restore :meth:`export_state`'s arrays into this assessor (same configuration).

        Args:
            state: the arrays.
            tiles: restore the tiles' results too; False (another model judged them) marks
                every tile for the next pass instead.

        Raises:
            ConfigError: the arrays do not fit this assessor's map or tiles.
        """
        from landing_zone.errors import ConfigError

        with self._map_lock, self._state_lock:
            self.map.import_state({k[4:]: v for k, v in state.items() if k.startswith('map.')})
            fresh = _TileState(self._tile_origin(), self._n_tiles)
            if tiles:
                origin = state.get('tiles.origin')
                if not isinstance(origin, np.ndarray) or origin.shape != (2,) or \
                        not np.array_equal(origin, fresh.origin):
                    raise ConfigError('tile state origin does not match the map window')
                for name in _TileState._FIELDS:
                    a = state.get(f'tiles.{name}')
                    want = getattr(fresh, name)
                    if not isinstance(a, np.ndarray) or a.shape != want.shape or \
                            a.dtype != want.dtype:
                        raise ConfigError(f'tile state {name!r} does not fit {want.shape} '
                                          f'{want.dtype}')
                    setattr(fresh, name, a.copy())
            else:
                self.map.mark_tile_size(self.tile_vox)
            self._state = fresh
            placed = state.get('placed_z')
            self._placed_z = bool(placed[0]) if isinstance(placed, np.ndarray) and \
                placed.size else True
            stamp = state.get('stamp')
            self._stamp = float(stamp[0]) if isinstance(stamp, np.ndarray) and stamp.size \
                and np.isfinite(stamp[0]) else None

    def invalidate(self) -> None:
        """Judge every tile again at the next pass (after a change of the tiles' settings).

        Only a flag: the next pass marks the tiles, so the caller (the node's executor thread)
        never waits for the map's lock while a cloud is integrated."""
        self._invalidated = True

    @property
    def last_stamp(self) -> float | None:
        """Stamp [s] of the newest cloud integrated (None before any)."""
        return self._stamp

    def close(self) -> None:
        """Release what the assessor holds beyond memory: the map's worker threads and the
        predictor's hold on torch's thread count. The assessor is not used after this."""
        self.map.close()
        self._predictor.close()

    def __enter__(self) -> Assessor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def last(self) -> Assessment | None:
        """The most recent assessment, if any."""
        return self._last

    @property
    def nbytes(self) -> int:
        """Memory of the map's counts [bytes]."""
        return int(self.map.nbytes)

    def __repr__(self) -> str:
        mode = 'follow' if self.follow else f'fixed at {self.config.center}'
        return (f'Assessor({mode}, model={self.model.config.spec}, map={self.map!r}, '
                f'clouds={self.clouds})')
