"""The one pipeline: integrate registered clouds into the map, judge its tiles, find sites.

Both front ends (the ROS node and bag replay) drive this class, so the same clouds give the same
tiles in both. One :class:`Assessor` owns the scrolling density map, the tiler and the network
(loaded once); :meth:`Assessor.integrate` adds a cloud, :meth:`Assessor.assess` judges the tiles:

1. **Placement** (:mod:`landing_zone.mapping.window`). In follow mode (the default) the map's
   window sits on whole tiles around the sensor and scrolls with it, its height around the
   ground under the sensor; in fixed mode (``center=(x, y)``) the XY window never moves.
2. **Incremental assessment.** Only tiles whose voxels changed since the last pass (the map's
   dirty tiles, widened by the tiles the network's padding reaches into) are re-extracted and
   re-judged; the others keep their results, and tiles that scroll out are forgotten.
3. **Judgement** (:mod:`landing_zone.judging.judgement`). A tile the tiler marks valid
   (observed enough, see :class:`~landing_zone.config.TileConfig`) gets P(safe) from the
   calibrated network (its checkpoint's temperature); any other tile is unknown (NaN), never
   guessed safe. Beside the network the guard (:mod:`landing_zone.judging.guard`) caps P(safe)
   where opaque structure stands above the tile's ground, whatever its shape; after it, a tile
   the network calls safe whose features are unlike every training tile's
   (:mod:`landing_zone.judging.ood`, when the model has a reference) becomes unknown, and every
   tile's confidence is scaled by how near its features lie to the training tiles'. A tile
   with fewer than ``tiles.min_returns`` returns from rays at least
   ``tiles.min_ray_depression_deg`` below the horizontal is unknown too: seen only at grazing
   angles (a ground vehicle's view), unlike every tile the network learnt from.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from landing_zone.config import AssessorConfig
from landing_zone.errors import InvalidCloudError, ModelError
from landing_zone.judging.assessment import Assessment
from landing_zone.judging.judgement import Judgement, judge_tiles
from landing_zone.judging.loading import load_net, load_ood
from landing_zone.judging.ground import slope_deg
from landing_zone.judging.sites import GroundGrids, evaluate_candidates, find_sites
from landing_zone.judging.tile_state import TileCounts, TileState
from landing_zone.judging.tiles import CountBuffers, tile_voxels
from landing_zone.mapping.density_map import DensityMap
from landing_zone.mapping.rays import IntegrationStats
from landing_zone.mapping.window import Window

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
class _Pass:
    """What :meth:`Assessor.begin_assess` took from the map for one pass."""

    todo: np.ndarray  # (K, 2) global indices of the tiles to judge
    counts: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # hits, passes, box lo
    stamp: float | None
    t0: float
    steep: np.ndarray | None = None  # (K,) returns from steep rays; None: rule off


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
        path = None if model is not None and not isinstance(model, (str, os.PathLike)) else (
            Path(model) if model is not None else
            Path(cfg.model.path) if cfg.model.path else default_model_path())
        self.model, self.model_metadata, self.model_path = load_net(model, path, cfg,
                                                                    self.tile_vox)
        self.ood, self.ood_path = load_ood(cfg, self.model, self.model_metadata,
                                           self.model_path)
        # torch: when a model is loaded
        from landing_zone.judging.inference import Predictor, prior_shift
        # owns the inference copy and torch's thread count until close(); P(safe) at the
        # prior stated (model.obstacle_prior), from the one the model was calibrated at
        calibrated_at = float(self.model_metadata.get('calibration_prior', 0.5))
        self._predictor = Predictor(self.model, logit_shift=prior_shift(
            cfg.model.obstacle_prior, calibrated_at))
        self._map_lock = threading.Lock()  # the map and the tile window's placement
        self._state_lock = threading.Lock()  # the tile results
        self._assess_lock = threading.Lock()  # one assessment pass at a time
        self._invalidated = False  # every tile to be judged again at the next pass
        self._count_buffers = CountBuffers()  # what each pass copies the counts into
        self.map: DensityMap = DensityMap(cfg.map, tile_vox=self.tile_vox)
        self.stats: IntegrationStats = IntegrationStats()
        self.clouds = 0
        self._stamp: float | None = None
        self._window = Window(self.map, cfg.map, self.tile_vox, self.tile_size, self._n_tiles,
                              cfg.center)
        self._state = TileState(self._window.tile_origin(), self._n_tiles)
        # per tile, the returns from steep rays (tiles.min_ray_depression_deg)
        self._steep = TileCounts(self._window.tile_origin(), self._n_tiles, self.tile_size)
        self._last: Assessment | None = None

    # -- placement --------------------------------------------------------------------------

    @property
    def follow(self) -> bool:
        """Whether the map follows the sensor (no fixed centre)."""
        return self._window.follow

    @property
    def center(self) -> np.ndarray:
        """(3,) world position [m] of the window's XY centre and its ground level."""
        return self._window.center

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
            # the tiles' results follow the window at the next pass (begin_assess), not here:
            # a pass that runs meanwhile keeps the window it began with
            self._window.follow_cloud(pts, org)
            st = self.map.integrate(pts, org)
            self._count_steep(pts, org)
            self.stats = self.stats + st
            self.clouds += 1
            if stamp is not None:
                self._stamp = float(stamp)
        return st

    def _count_steep(self, pts: np.ndarray, org: np.ndarray) -> None:
        """Count into their tiles the returns whose ray from ``org`` drops at least
        ``tiles.min_ray_depression_deg`` below the horizontal (the map's lock held)."""
        deg = self.config.tiles.min_ray_depression_deg
        if deg <= 0:
            return
        self._steep.move(self._window.tile_origin())
        self._steep.add_steep(pts, org, deg)

    def _read_counts(self, tiles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copy of the counts the tiles' inputs read (as
        :func:`landing_zone.judging.tiles.extract_tiles` reads them, but only the copy is made
        under the map's lock)."""
        box_lo, size = self._window.box_around(tiles, self.config.tiles.padding)
        # into the same memory every pass (passes come one at a time: the last one's copy is
        # no longer read), so a pass does not pay the page faults of 100 MB of fresh memory
        shape = (int(size[0]), int(size[1]), int(size[2]))
        hits, passes = self.map.counts(box_lo, size, out=self._count_buffers.get(shape))
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
                todo = self._window.dirty_tiles(self._reach)
                counts = self._read_counts(todo) if len(todo) else None
                stamp = self._stamp
                origin = self._window.tile_origin()
                steep = None
                if self.config.tiles.min_ray_depression_deg > 0:
                    self._steep.move(origin)
                    steep = self._steep.take(todo)
            with self._state_lock:
                # tiles that left the window are forgotten; those that entered since the last
                # pass are among the changed ones (scrolling marks them), judged afresh now
                self._state.move(origin)
        except BaseException:
            self._assess_lock.release()
            raise
        return _Pass(todo, counts, stamp, t0, steep)

    def finish_assess(self, job: _Pass) -> Assessment:
        """Judge what :meth:`begin_assess` copied (the tiler's kernel and the network, outside
        the map's lock), store the results and return every tile's state."""
        try:
            # judge the copied counts: ground planes, cubes, network, guard, OOD
            found = judge_tiles(job.counts, job.todo, self.config, self.tile_vox,
                                self._predictor, self.ood, job.steep)
            # how much each judgement rests on observation, and on familiar features
            confidence = self._confidence(found)
            with self._state_lock:
                # into the window's tiles; the others keep what they had
                self._state.store(found, confidence)
                # every tile of the window, and the landing sites over them
                result = self._snapshot(self._state, job.stamp)
            result.reassessed = int(len(job.todo))
            result.seconds = time.perf_counter() - job.t0
            self._last = result
            return result
        finally:
            self._assess_lock.release()

    def _confidence(self, found: Judgement) -> np.ndarray:
        """(K,) confidence of the judged tiles: :func:`tile_confidence`, scaled down past the
        OOD threshold (there the judgement rests on extrapolation)."""
        batch = found.batch
        if batch is None:
            return np.zeros(0, np.float32)
        near = 1.0 / np.maximum(np.nan_to_num(found.ood, nan=1.0), 1.0)
        out: np.ndarray = tile_confidence(batch.observed_fraction, batch.n_returns,
                                          self.tile_size) * near.astype(np.float32)
        return out

    def _snapshot(self, st: TileState, stamp: float | None) -> Assessment:
        sx, sy = st.shape
        gx, gy = np.meshgrid(np.arange(sx), np.arange(sy), indexing='ij')
        index = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.int64) + st.origin
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
            candidates=cand, ood=st.ood.ravel().copy(), grazing=st.grazing.ravel().copy())

    def export_state(self) -> dict[str, np.ndarray]:
        """Copies of the map's counts and the tiles' results, taken under the locks at one
        moment (between two clouds), for :mod:`landing_zone.runtime.snapshot`."""
        with self._assess_lock, self._map_lock, self._state_lock:
            out = {f'map.{k}': v for k, v in self.map.export_state().items()}
            self._state.move(self._window.tile_origin())
            out.update(self._state.export())
            self._steep.move(self._window.tile_origin())
            out['steep.returns'] = self._steep.counts.copy()
            out['steep.deg'] = np.array([self.config.tiles.min_ray_depression_deg])
            out['placed_z'] = np.array([self._window.placed_z], np.uint8)
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
        with self._map_lock, self._state_lock:
            self.map.import_state({k[4:]: v for k, v in state.items() if k.startswith('map.')})
            fresh = TileState(self._window.tile_origin(), self._n_tiles)
            if tiles:
                fresh.restore(state)
            else:
                self.map.mark_tile_size(self.tile_vox)
            self._state = fresh
            self._steep = self._restore_steep(state)
            placed = state.get('placed_z')
            self._window.placed_z = bool(placed[0]) if isinstance(placed, np.ndarray) and \
                placed.size else True
            stamp = state.get('stamp')
            self._stamp = float(stamp[0]) if isinstance(stamp, np.ndarray) and stamp.size \
                and np.isfinite(stamp[0]) else None

    def _restore_steep(self, state: dict[str, np.ndarray]) -> TileCounts:
        """The steep returns of :meth:`export_state`'s arrays on the window as imported. A
        snapshot without them (or counted at another angle) does not say: each tile's return
        count stands in, so a restart does not make the map unknown."""
        out = TileCounts(self._window.tile_origin(), self._n_tiles, self.tile_size)
        counts, deg = state.get('steep.returns'), state.get('steep.deg')
        if not (isinstance(deg, np.ndarray) and deg.size and
                deg[0] == self.config.tiles.min_ray_depression_deg):
            counts = state.get('tiles.n_returns')
        if isinstance(counts, np.ndarray) and counts.shape == out.shape and \
                counts.dtype.kind in 'iu':
            out.counts = counts.astype(np.int64)
        return out

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
