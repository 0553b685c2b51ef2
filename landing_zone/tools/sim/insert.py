"""Virtual obstacles in recorded flights: the rays that would have hit them are cut short.

A recorded flight holds real (or simulated) grass, ground and sensor noise; what it lacks are
obstacles where we want them. :func:`insert_obstacles` (``landing-zone insert-obstacles``) puts
obstacles of the simulator's library into a bag: every return whose ray, from the sensor origin
to the return, meets an obstacle's surface first is moved to that surface (plus the sensor's
range noise, along the ray); every other return is left exactly as it was. Rays that passed by
stay as they were, and the obstacle's shadow appears by itself: the returns that would have
lain behind it now lie on it.

The pieces, one module each:

* :mod:`landing_zone.tools.sim.alteration`: the array core (:func:`alter_returns`), points and
  origins in, the altered points and the mask of altered returns out;
* :mod:`landing_zone.tools.sim.placement`: where an obstacle stands (:func:`ground_height`,
  :func:`place_obstacles`), from the bag's own returns around the spot;
* :mod:`landing_zone.tools.sim.recorded`: the flight's returns with their sensor origins
  (:func:`read_flight`) and the rewriting of a cloud's bytes (:func:`alter_cloud`);
* :mod:`landing_zone.io.labels`: the ground truth files;
* this module, :func:`insert_obstacles`: the bag tool. The sensor origin of a cloud is the pose
  topic interpolated at the cloud's ``header.stamp``, with the stream's own message decoding
  (:func:`~msg_adapters.pose.read_pose_msg`,
  :func:`~msg_adapters.pointcloud.read_cloud_header`) and interpolation
  (:class:`~landing_zone.poses.PoseBuffer`, same tolerance), as the node does.
  The output bag is the input copied message by message as CDR bytes
  (:class:`~landing_zone.io.bags.RawBag`); in a cloud with altered returns only the ``x``, ``y``,
  ``z`` bytes of those returns change (in the cloud's own layout, precision and byte order), and
  its ``label`` field, when it has an integer one (simulated flights: 0 ground, 1 grass,
  2 obstacle), is set to 2 (obstacle) for them. Every other byte of every message, every topic,
  type and log time stays the same.

Obstacles stand on the estimated ground, sunk by ``SINK`` (and by the model's own embedding, as
the simulator places them), so no ray slips under them; they keep ``MIN_SEPARATION`` between
centres (also from obstacles the labels file lists). The ground truth goes to
``OUT.labels.json`` (docs/INTERFACES.md section 3): the input's labels (``BAG.labels.json``
beside the bag, or ``labels``) or, without them, every tile holding at least ``MIN_TILE_RETURNS``
returns as safe; then every tile an inserted footprint overlaps is unsafe, and the inserted
obstacles join the list with ``"inserted": true``.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError, ConfigError, InvalidCloudError, InvalidPoseError, \
    SimulationError
from landing_zone.io.bags import BagWriter, RawBag
from landing_zone.io.labels import labels_path_for, read_labels, write_labels
from landing_zone.tools.sim.alteration import RANGE_SIGMA, ObstacleScene
from landing_zone.tools.sim.families import parse_families
from landing_zone.tools.sim.flight_site import tile_labels
from landing_zone.tools.sim.library import models
from landing_zone.tools.sim.obstacles import Obstacle
from landing_zone.tools.sim.placement import DEFAULT_KINDS, SINK, place_obstacles
from landing_zone.tools.sim.recorded import alter_cloud, read_flight
from msg_adapters.pointcloud import read_cloud_header

__all__ = ['insert_obstacles', 'InsertResult', 'update_labels', 'MIN_TILE_RETURNS']

MIN_TILE_RETURNS = 20  # without a labels file, tiles holding this many returns are the site


@dataclass
class InsertResult:
    """What :func:`insert_obstacles` wrote and measured."""

    bag: Path
    labels: Path
    obstacles: list[Obstacle]
    clouds: int  # clouds read
    altered_clouds: int  # clouds with at least one altered return
    skipped_clouds: int  # clouds left as they were: no pose at their stamp, other frame
    returns: int  # finite returns of the clouds read
    altered: int  # returns moved onto an obstacle
    messages: int  # messages copied (all topics)
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out['bag'], out['labels'] = str(self.bag), str(self.labels)
        out['obstacles'] = [o.to_json() for o in self.obstacles]
        out['seconds'] = round(self.seconds, 3)
        out['timings'] = {k: round(v, 3) for k, v in self.timings.items()}
        return out


def _tile_key(x: float, y: float, ts: float) -> tuple[int, int]:
    return int(math.floor(x / ts)), int(math.floor(y / ts))


def update_labels(labels: dict[str, Any] | None, obstacles: Sequence[Obstacle],
                  points: np.ndarray, frame_id: str, extra: dict[str, Any] | None = None
                  ) -> dict[str, Any]:
    """The ground truth after the insertion (docs/INTERFACES.md §3).

    Args:
        labels: the flight's labels, or None: every tile holding ``MIN_TILE_RETURNS`` returns
            is safe.
        obstacles: the inserted obstacles.
        points: (N, 3) the flight's returns (for the tiles without labels).
        frame_id: of the flight.
        extra: stored under ``"insertion"`` (how the obstacles were made).

    Returns:
        A new document; ``labels`` is not changed.
    """

    if labels is not None:
        doc = copy.deepcopy(labels)
    else:
        doc = {'frame_id': frame_id, 'tile_size': 1.0, 'tiles': [], 'obstacles': []}
        p = np.asarray(points, np.float64).reshape(-1, 3)
        if len(p):
            k = np.floor(p[:, :2]).astype(np.int64)
            keys, n = np.unique(k, axis=0, return_counts=True)
            keys = keys[n >= MIN_TILE_RETURNS]
            order = np.lexsort((keys[:, 0], keys[:, 1]))  # y rows, x within (as the simulator)
            doc['tiles'] = [{'x': float(kx) + 0.5, 'y': float(ky) + 0.5, 'safe': True}
                            for kx, ky in keys[order]]
    ts = float(doc.get('tile_size', 1.0))
    index = {_tile_key(t['x'], t['y'], ts): t for t in doc['tiles']}
    for ob in obstacles:
        fp = ob.footprint()
        for t in tile_labels([ob], fp.min(axis=0), fp.max(axis=0), ts):
            if t['safe']:
                continue
            key = _tile_key(t['x'], t['y'], ts)
            if key in index:
                index[key]['safe'] = False
            else:
                index[key] = t
                doc['tiles'].append(t)
    doc.setdefault('obstacles', [])
    doc['obstacles'] = list(doc['obstacles']) + [dict(o.to_json(), inserted=True)
                                                 for o in obstacles]
    if extra is not None:
        doc['insertion'] = extra
    return doc


def insert_obstacles(bag: str | os.PathLike[str], out: str | os.PathLike[str], *,
                     count: int = 6, seed: int = 0, kinds: Sequence[str] = DEFAULT_KINDS,
                     families: Sequence[str] = (),
                     group: str = 'test', region: Sequence[float] | None = None,
                     labels: str | os.PathLike[str] | None = None,
                     obstacles: Sequence[Obstacle] | None = None,
                     points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
                     frame_id: str = 'map', range_sigma: float = RANGE_SIGMA,
                     overwrite: bool = False, threads: int = 0) -> InsertResult:
    """Insert obstacles into a recorded flight; write OUT.mcap and OUT.labels.json.

    Args:
        bag: ROS 2 bag (.mcap, .db3 or directory) or ROS 1 .bag with clouds and poses.
        out: the output bag, a ``.mcap`` file; the labels go beside it.
        count: obstacles to insert.
        seed: of the placement and the range noise.
        kinds: obstacle kinds, cycled through.
        families: obstacle families, cycled through after the kinds (random instances).
        group: ``train`` or ``test`` obstacle models (as the datasets split them).
        region: ``(x0, y0, x1, y1)`` where obstacles may stand.
        labels: SITE.labels.json of the flight (default ``BAG.labels.json`` beside the bag if
            it exists): the ground truth to extend and, without ``region``, where obstacles may
            stand (its safe tiles).
        obstacles: insert these instead of placing ``count`` at random.
        points_topic: topic of the registered clouds (sensor_msgs/PointCloud2).
        pose_topic: topic of the sensor poses (geometry_msgs/PoseStamped).
        frame_id: the fixed frame of clouds and poses (others are copied unaltered).
        range_sigma: range noise of the moved returns [m].
        overwrite: replace existing outputs.
        threads: Embree threads (0: one per core).

    Returns:
        An :class:`InsertResult`.

    Raises:
        BagError: the bag is unreadable, lacks the topics, poses or clouds; the output exists.
        ConfigError: bad region, labels or noise.
        SimulationError: unknown kinds or group, a count that does not fit.
    """
    # the outputs and options, checked before any reading
    t_start = time.perf_counter()
    bag, out = Path(bag), Path(out)
    labels_out = _check_outputs(bag, out, overwrite)
    if not (isinstance(range_sigma, (int, float)) and math.isfinite(range_sigma)
            and range_sigma >= 0):
        raise ConfigError(f'range noise must be a non-negative number, got {range_sigma!r}')
    if group not in ('train', 'test'):
        raise SimulationError(f"obstacle group must be 'train' or 'test', got {group!r}")
    models(tuple(kinds), group)  # unknown kinds fail here, before any reading
    families = parse_families(tuple(families))
    labels_in = Path(labels) if labels is not None else labels_path_for(bag)
    if labels is not None and not labels_in.exists():
        raise ConfigError(f'labels file not found: {labels_in}')
    doc = read_labels(labels_in) if labels_in.exists() else None

    # the flight
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    flight = read_flight(bag, points_topic, pose_topic, frame_id)
    poses, points = flight.poses, flight.points
    timings['read'] = time.perf_counter() - t0

    # the obstacles and the labels with them
    t0 = time.perf_counter()
    seeds = np.random.SeedSequence([int(seed), 0x1E5E47]).spawn(2)
    if obstacles is None:
        placed = place_obstacles(points, count, np.random.default_rng(seeds[0]), kinds=kinds,
                                 group=group, region=region, labels=doc, families=families)
    else:
        placed = list(obstacles)
    scene = ObstacleScene(placed, threads=threads)
    extra = {'source': bag.name, 'seed': int(seed), 'group': group, 'kinds': list(kinds),
             **({'families': list(families)} if families else {}),
             'count': len(placed), 'range_sigma': range_sigma,
             'region': list(map(float, region)) if region is not None else None,
             'sink': SINK}
    new_labels = update_labels(doc, placed, points, frame_id, extra)
    timings['place'] = time.perf_counter() - t0

    # every message copied, the clouds with the obstacles in them
    t0 = time.perf_counter()
    counts = _copy_altered(bag, out, overwrite, scene, poses, np.random.default_rng(seeds[1]),
                           points_topic, frame_id, range_sigma)
    try:
        write_labels(labels_out, new_labels)
    except OSError as err:
        out.unlink(missing_ok=True)  # a bag without its labels is no result
        raise BagError(f'cannot write {labels_out}: {err.strerror}') from err
    timings['write'] = time.perf_counter() - t0
    timings['alter'] = counts.pop('cast_s')
    return InsertResult(out, labels_out, placed, counts['clouds'], counts['altered_clouds'],
                        counts['skipped'], counts['returns'], counts['altered'],
                        counts['messages'], time.perf_counter() - t_start, timings)


def _check_outputs(bag: Path, out: Path, overwrite: bool) -> Path:
    """The output's labels path, the output checked: a .mcap that is not the input, written
    only where it may be."""
    if out.suffix != '.mcap':
        raise BagError(f'the output must be a .mcap file, got {out}')
    labels_out = labels_path_for(out)
    if out.resolve() == bag.resolve():
        raise BagError(f'the output {out} would overwrite the input bag')
    if not overwrite:
        for path in (out, labels_out):
            if path.exists():
                raise BagError(f'{path} exists already (use --overwrite)')
    if not out.parent.is_dir():
        raise BagError(f'cannot write {out}: {out.parent} is not a directory')
    return labels_out


def _copy_altered(bag: Path, out: Path, overwrite: bool, scene: ObstacleScene, poses: Any,
                  noise: np.random.Generator, points_topic: str, frame_id: str,
                  range_sigma: float) -> dict[str, Any]:
    """Copy every message of ``bag`` to ``out``, the clouds of ``points_topic`` in
    ``frame_id`` with the obstacles of ``scene`` in them; returns the counts (and the seconds
    of casting, ``cast_s``)."""
    clouds = altered_clouds = skipped = returns = altered = messages = 0
    cast_s = 0.0
    writer = BagWriter(out, overwrite=overwrite)
    writer.open()
    try:
        with RawBag(bag) as src:
            for topic, msgtype in src.topics.items():
                writer.add_topic(topic, msgtype, types=src.types_of(topic))
            for m in src.messages():
                data = m.data
                if m.topic == points_topic:
                    clouds += 1
                    msg = src.deserialize(m)
                    try:
                        frame, stamp = read_cloud_header(msg)
                        origin = poses.lookup(stamp)[0] if frame == frame_id else None
                    except (InvalidCloudError, InvalidPoseError):
                        origin = None
                    if origin is None:
                        skipped += 1
                    else:
                        t1 = time.perf_counter()
                        try:
                            new, n, k = alter_cloud(data, msg, origin, scene, noise,
                                                    range_sigma)
                        except InvalidCloudError:
                            new, n, k = None, 0, 0
                            skipped += 1
                        cast_s += time.perf_counter() - t1
                        returns += n
                        if new is not None:
                            data = new
                            altered_clouds += 1
                            altered += k
                writer.write_raw(m.topic, m.stamp_ns, data)
                messages += 1
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return {'clouds': clouds, 'altered_clouds': altered_clouds, 'skipped': skipped,
            'returns': returns, 'altered': altered, 'messages': messages, 'cast_s': cast_s}
