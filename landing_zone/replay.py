"""Bag front end: run the node's pipeline offline on a recorded bag (``landing-zone replay``).

The bag's clouds and poses go, in log-time order, through the same
:class:`~landing_zone.runtime.stream.Stream` and :class:`~landing_zone.assessor.Assessor` the
node uses. Each assessment is written
into the output bag at the stamp of the newest cloud it includes (the moment the node would
have published it) on the node's topics (``/assessor/safety_grid``, ``/assessor/safety_cloud``,
``/assessor/landing_sites``, ``/assessor/markers``, ``/diagnostics``); the final state goes to
REPORT.json (docs/INTERFACES.md §3). The result keeps a subsample of the returns (``top_view``)
for pictures of the map, which the offline tools draw.

A survey file (LAS / LAZ, :mod:`landing_zone.io.survey`) replays the same way: its returns and
sensor trajectory become the same cloud and pose messages, in a local metric frame whose
origin the report states (``survey``).

Everything is deterministic except the wall-time figures (``stats.seconds`` and the rates and
latencies in ``/diagnostics``).
"""
from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from landing_zone.errors import BagError, ConfigError

if TYPE_CHECKING:
    from landing_zone.assessor import Assessment, Assessor
    from landing_zone.config import AssessorConfig, StreamConfig
    from landing_zone.io.bags import BagMessage
    from landing_zone.io.survey import Survey
    from landing_zone.runtime.stream import Stream

__all__ = ['ReplayResult', 'replay', 'output_topics', 'NODE_NAME', 'require_inputs',
           'POSE_TYPES']

NODE_NAME = 'assessor'
# Returns kept for the PNG's top view: every TOP_VIEW_STRIDE-th return, at most TOP_VIEW_MAX.
TOP_VIEW_STRIDE = 4
TOP_VIEW_MAX = 400_000


def output_topics(node: str = NODE_NAME) -> dict[str, str]:
    """Output topic -> message type, as the node named ``node`` publishes them."""
    from msg_adapters.grid import DIAGNOSTICS_TYPE, OUTPUT_TYPES

    out = {f'/{node}/{name}': msgtype for name, msgtype in OUTPUT_TYPES.items()}
    out['/diagnostics'] = DIAGNOSTICS_TYPE
    return out


@dataclass
class ReplayResult:
    """What a replay produced.

    Attributes:
        assessment: the final state of the tiles.
        stats: the report's counters (clouds, points, dropped_points, seconds, ...).
        bag_seconds: stamp-time span of the clouds integrated [s].
        seconds: wall time of the whole replay, set-up and report included [s].
        assessments: assessment passes written to the output bag.
        top_view: (N, 3) float32 subsample of the returns (for the PNG).
        timings: wall seconds by stage: ``setup`` (model, map, warm-up), ``read`` (bag reading and
            deserializing), ``ingest`` (decoding and integrating clouds, poses), ``assess``
            (tiles and network, on a thread of its own, overlapped with the rest),
            ``assess_wait`` (what of it the loop waited for), ``write`` (building and writing
            the output messages), ``loop`` (read + ingest + assess_wait + write), ``report``
            (JSON and PNG); ``cpu``: CPU seconds of the whole process during the loop, every
            thread (the work, whatever else shares the machine).
        ood_reference: the OOD reference file judged with (None: the signal was off).
    """

    assessment: Assessment
    stats: dict[str, Any]
    bag_seconds: float
    seconds: float
    assessments: int
    top_view: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    timings: dict[str, float] = field(default_factory=dict)
    survey: dict[str, Any] | None = None
    ood_reference: str | None = None

    @property
    def realtime_factor(self) -> float:
        """Bag time replayed per second of processing (the loop: reading, integrating,
        assessing, writing; set-up and the report excluded), inf for an empty bag."""
        loop = self.timings.get('loop', self.seconds)
        return self.bag_seconds / loop if loop > 0 else math.inf


class _Outputs:
    """Writes each assessment's messages into the output bag."""

    def __init__(self, writer: Any) -> None:
        from msg_adapters import MessageTypes

        self.writer = writer
        self.types = MessageTypes.rosbags(writer.types) if writer is not None else None
        self.seconds = 0.0  # spent building and writing messages
        self.topics = output_topics()
        if writer is not None:
            for topic, msgtype in self.topics.items():
                writer.add_topic(topic, msgtype)

    def messages(self, assessment: Assessment, diagnostics: dict[str, str], stamp_ns: int
                 ) -> list[tuple[str, Any]]:
        """(topic, message) of one assessment, in the order they are written."""
        from msg_adapters import MessageTypes, grid

        t = self.types if self.types is not None else MessageTypes.rosbags()
        base = f'/{NODE_NAME}'
        return [(f'{base}/safety_grid', grid.safety_grid(assessment, stamp_ns, t)),
                (f'{base}/safety_cloud', grid.safety_cloud(assessment, stamp_ns, t)),
                (f'{base}/landing_sites', grid.landing_site_poses(assessment, stamp_ns, t)),
                (f'{base}/landing_sites_cloud', grid.landing_sites_cloud(assessment, stamp_ns, t)),
                (f'{base}/markers', grid.markers(assessment, stamp_ns, types=t)),
                ('/diagnostics', grid.diagnostics(diagnostics, stamp_ns, types=t))]

    def write(self, assessment: Assessment, diagnostics: dict[str, str], stamp_ns: int) -> None:
        if self.writer is None:
            return
        t0 = time.perf_counter()
        for topic, msg in self.messages(assessment, diagnostics, stamp_ns):
            self.writer.write(topic, stamp_ns, msg)
        self.seconds += time.perf_counter() - t0


def replay(bag: str | os.PathLike[str], out: str | os.PathLike[str] | None = None,
           report: str | os.PathLike[str] | None = None, *,
           points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
           model: str | os.PathLike[str] | None = None,
           center: Sequence[float] | None = None,
           config: AssessorConfig | None = None, stream_config: StreamConfig | None = None,
           progress: bool = True,
           overlap: bool = True, trajectory: str | os.PathLike[str] | None = None,
           log: Callable[[str], None] | None = None, warm: bool = True,
           cloud_frame: str | None = None,
           sensor_offset: Sequence[float] | None = None) -> ReplayResult:
    """Assess a recorded flight as the node would, writing its outputs.

    Args:
        bag: ROS 2 bag (directory, .mcap or .db3) or ROS 1 .bag with the clouds and poses.
        out: output bag (.mcap file, or a directory) for the node's topics; None: not written.
        report: REPORT.json path; None: not written.
        points_topic: topic of the clouds (sensor_msgs/PointCloud2).
        pose_topic: topic of the poses: geometry_msgs/PoseStamped or nav_msgs/Odometry (the
            type is read from the bag), the pose of a frame C (docs/INTERFACES.md §1).
        model: model file; default the config's, else the shipped model.
        center: (x, y) of a fixed region of interest; default: follow the sensor.
        config: the pipeline's configuration; default AssessorConfig().
        stream_config: the stream's timing; default StreamConfig().
        progress: show a tqdm progress bar (on a terminal).
        overlap: judge each pass on a worker thread while the next clouds are integrated
            (the same passes and outputs; False runs them in turn, for comparison).
        trajectory: for a LAS / LAZ ``bag``: the sensor trajectory (CSV ``t,x,y,z`` or SBET);
            None derives it from GPS time and scan angle. ``center`` is then in the file's
            CRS and units.
        log: called with each line worth telling the user (a survey's assumptions).
        warm: run :func:`~landing_zone.runtime.ingest.warm_up` in the set-up, as the node
            does (False: the first clouds and pass pay for loading the kernels, in the loop).
        cloud_frame: where the returns are: 'fixed', 'body' (in C) or 'sensor' (in the
            LiDAR's frame); default the stream config's (fixed).
        sensor_offset: (x, y, z, roll, pitch, yaw) of the LiDAR in C [m, rad]; default the
            stream config's (zeros).

    Returns:
        A :class:`ReplayResult`.

    Raises:
        BagError: the bag is missing, unreadable, corrupt, or lacks the topics.
        ModelError: the model is missing or invalid.
        ConfigError: a bad configuration or center.
    """
    # all imported before the clock starts, so that no timing counts the importing
    from tqdm import tqdm  # noqa: F401 (for _messages)

    from landing_zone.assessor import Assessor
    from landing_zone.runtime.ingest import warm_up
    from landing_zone.io.bags import BagWriter, read_messages  # noqa: F401 (for _messages)
    from landing_zone.io.survey import is_survey, read_survey
    from landing_zone.runtime.stream import Stream

    t_start = time.perf_counter()
    bag = Path(bag)
    # the input: a survey file read whole, or a bag checked for the topics
    survey = None
    if is_survey(bag):
        survey = read_survey(bag, trajectory, log=log)
    else:
        require_inputs(bag, points_topic, pose_topic)
    # the stream's frames and the region's centre, checked (a survey's made local)
    stream_config = _with_frames(stream_config, cloud_frame, sensor_offset)
    center = _local_center(center, survey)
    # the node's pipeline, every TOP_VIEW_STRIDE-th return kept for the top view
    assessor = Assessor(config, center=center, model=model)
    stream = Stream(assessor, stream_config)
    kept = _keep_returns(stream)
    # the set-up and the loop: the messages through the stream, each pass written out
    writer = BagWriter(out, overwrite=True) if out is not None else None
    times = _run(bag, survey, writer, assessor, stream, points_topic=points_topic,
                 pose_topic=pose_topic, progress=progress, overlap=overlap,
                 warm_up=warm_up if warm else None, t_start=t_start)
    # the result: the final state, the counters, the timings and the top view
    res = _result(assessor, stream, times, kept, survey, t_start)
    # the report, and the wall time of the whole replay
    _report(res, report, assessor, t_start)
    return res


def _local_center(center: Sequence[float] | None, survey: Survey | None
                  ) -> Sequence[float] | None:
    """``center`` checked; for a survey, moved from the file's CRS and units into its local
    metric frame (where its clouds and poses are).

    Raises:
        ConfigError: ``center`` is not two finite numbers.
    """
    if center is not None and (len(center) != 2 or not all(math.isfinite(c) for c in center)):
        raise ConfigError(f'center must be two finite numbers, got {center!r}')
    if survey is not None and center is not None:
        # the file's CRS and units -> the local metric frame
        center = tuple(float(v) for v in (np.asarray(center, np.float64) - survey.origin[:2])
                       * survey.metres_per_unit)
    return center


def _keep_returns(stream: Stream) -> list[np.ndarray]:
    """A list the stream fills, as it integrates each cloud, with every TOP_VIEW_STRIDE-th of
    its returns (float32), for the result's top view."""
    kept: list[np.ndarray] = []

    def keep(_: int, xyz: np.ndarray, __: np.ndarray) -> None:
        kept.append(np.asarray(xyz[::TOP_VIEW_STRIDE], np.float32))

    stream.on_integrate = keep
    return kept


@dataclass
class _Times:
    """What the set-up and the loop of a replay took (seconds) and how many passes ran."""

    setup: float  # from the start to the loop: checks, model, map, warm-up
    loop: float  # wall time of the loop over the messages, the last pass included
    cpu: float  # CPU time of the whole process during the loop
    ingest: float  # decoding and integrating clouds and poses
    waited: float  # what the loop waited for passes to finish
    write: float  # building and writing the output messages
    passes: int  # assessment passes written


def _run(bag: Path, survey: Survey | None, writer: Any, assessor: Assessor, stream: Stream, *,
         points_topic: str, pose_topic: str, progress: bool, overlap: bool,
         warm_up: Callable[..., Any] | None, t_start: float) -> _Times:
    """The set-up's end and the loop: the messages through the stream in log-time order, a
    pass begun whenever one is due and its outputs written into ``writer`` (None: none).

    The warm-up (None: none) belongs to the set-up, as on the node. A last pass takes in what
    no pass has (or the whole bag, had none been due). The output bag is closed when all went
    well, aborted with the pending pass on any error; the assessor is closed either way, its
    results still readable.
    """
    if writer is not None:
        writer.open()
    passes = _Passes(stream, overlap)
    try:
        outputs = _Outputs(writer)
        if warm_up is not None:
            # as the node does before it listens: loading and compiling the kernels, torch's
            # first pass and the first messages built fall in the set-up, not in the loop
            warm_up(assessor, build=lambda a: outputs.messages(a, {}, 0))
        t_loop = time.perf_counter()
        cpu_loop = time.process_time()
        setup = t_loop - t_start
        messages = _messages(bag, survey, assessor, points_topic, pose_topic, progress)
        t_ingest, last_ns = _feed(messages, stream, passes, outputs, pose_topic)
        t0 = time.perf_counter()
        stream.flush()
        t_ingest += time.perf_counter() - t0
        if stream.unassessed or passes.count == 0:
            passes.begin(outputs, fallback_ns=last_ns)
        passes.end(outputs)
        if writer is not None:
            writer.close()
    except BaseException:
        passes.abort()
        if writer is not None:
            writer.abort()
        raise
    finally:
        assessor.close()  # its threads; the results stay readable
    return _Times(setup=setup, loop=time.perf_counter() - t_loop,
                  cpu=time.process_time() - cpu_loop, ingest=t_ingest, waited=passes.waited,
                  write=outputs.seconds, passes=passes.count)


def _messages(bag: Path, survey: Survey | None, assessor: Assessor, points_topic: str,
              pose_topic: str, progress: bool) -> Iterable[BagMessage]:
    """The clouds and poses of the bag or the survey in log-time order, behind a progress bar
    (on a terminal, if ``progress``)."""
    from tqdm import tqdm

    from landing_zone.io.bags import read_messages

    source = (survey.messages(points_topic, pose_topic, assessor.config.frame_id)
              if survey is not None else read_messages(bag, [points_topic, pose_topic]))
    bar: Iterable[BagMessage] = tqdm(source, unit=' msg', desc=f'replay {bag.name}',
                                     disable=None if progress else True, mininterval=0.5,
                                     leave=False)
    return bar


def _feed(messages: Iterable[BagMessage], stream: Stream, passes: _Passes, outputs: _Outputs,
          pose_topic: str) -> tuple[float, int]:
    """Give each message to the stream (a pose, else a cloud), beginning a pass whenever one
    is due.

    Returns:
        (seconds spent ingesting, log time of the last message [ns], 0 without any).
    """
    last_ns = 0
    t_ingest = 0.0
    for m in messages:
        last_ns = m.stamp_ns
        t0 = time.perf_counter()
        if m.topic == pose_topic:
            stream.add_pose_msg(m.msg)
        else:
            stream.add_cloud_msg(m.msg)
        t_ingest += time.perf_counter() - t0
        if stream.due():
            passes.begin(outputs)
    return t_ingest, last_ns


def _result(assessor: Assessor, stream: Stream, times: _Times, kept: list[np.ndarray],
            survey: Survey | None, t_start: float) -> ReplayResult:
    """The replay's result, its ``seconds`` and report timing still to be set."""
    result = assessor.last
    assert result is not None
    first_ns, last_cloud_ns = stream.stamp_span
    stats = stream.stats()
    stats['seconds'] = round(time.perf_counter() - t_start, 3)
    bag_seconds = (last_cloud_ns - first_ns) / 1e9 if first_ns is not None else 0.0
    stats['bag_seconds'] = round(bag_seconds, 3)
    assess_s = stream.assess_seconds_total
    timings = {'setup': times.setup,
               'read': max(times.loop - times.ingest - times.waited - times.write, 0.0),
               'ingest': times.ingest, 'assess': assess_s, 'assess_wait': times.waited,
               'write': times.write, 'loop': times.loop, 'cpu': times.cpu}
    top = np.concatenate(kept) if kept else np.zeros((0, 3), np.float32)
    if len(top) > TOP_VIEW_MAX:
        top = top[::int(math.ceil(len(top) / TOP_VIEW_MAX))]
    return ReplayResult(assessment=result, stats=stats, bag_seconds=bag_seconds,
                        seconds=0.0, assessments=times.passes, top_view=top, timings=timings,
                        survey=survey.describe() if survey is not None else None,
                        ood_reference=str(assessor.ood_path) if assessor.ood_path else None)


def _report(res: ReplayResult, report: str | os.PathLike[str] | None, assessor: Assessor,
            t_start: float) -> None:
    """Write the report to ``report`` (None: none); set the time that took and that of the
    whole replay (begun at ``t_start``, time.perf_counter()) in ``res``."""
    t_report = time.perf_counter()
    if report is not None:
        _write_report(Path(report), res, assessor)
    res.timings['report'] = time.perf_counter() - t_report
    res.seconds = time.perf_counter() - t_start


def _write_report(path: Path, res: ReplayResult, assessor: Assessor) -> None:
    """Write REPORT.json: the final state and counters, the model, the OOD reference (null:
    the signal was off), the configuration and, for a survey, its description."""
    doc = res.assessment.to_report(res.stats)
    doc['model'] = str(assessor.model_path) if assessor.model_path else None
    # without a reference the OOD signal is off: say so (null)
    doc['ood_reference'] = res.ood_reference
    doc['config'] = {k: (list(v) if isinstance(v, tuple) else v)
                     for k, v in assessor.config.to_flat().items()}
    doc['config']['region_center'] = list(assessor.config.center or [])
    if res.survey is not None:
        doc['survey'] = res.survey
    _write_json(path, doc)


POSE_TYPES = ('geometry_msgs/msg/PoseStamped', 'nav_msgs/msg/Odometry')


def require_inputs(bag: str | os.PathLike[str], points_topic: str, pose_topic: str) -> None:
    """Raise BagError unless the bag has a PointCloud2 topic ``points_topic`` and a
    PoseStamped or Odometry topic ``pose_topic`` (one line)."""
    from landing_zone.io.bags import bag_topics

    topics, points = bag_topics(bag), ('sensor_msgs/msg/PointCloud2',)
    for topic, want in ((points_topic, points), (pose_topic, POSE_TYPES)):
        have = sorted(topics) or ['no topics']
        if topics.get(topic) not in want:
            raise BagError(f'{bag}: topic {topic} carries {topics[topic] or "an unknown type"}, '
                           f'expected {" or ".join(want)}' if topic in topics else
                           f'{bag} lacks topic {topic} (it has {", ".join(have)}); choose with '
                           '--points-topic / --pose-topic')


def _with_frames(stream_config: StreamConfig | None, cloud_frame: str | None,
                 sensor_offset: Sequence[float] | None) -> StreamConfig | None:
    """The stream config with ``cloud_frame`` and ``sensor_offset`` set where given."""
    from dataclasses import replace

    from landing_zone.config import StreamConfig as _StreamConfig
    out = replace(stream_config if stream_config is not None else _StreamConfig(),
                  **{k: v for k, v in (('cloud_frame', cloud_frame),
                                       ('sensor_offset', sensor_offset)) if v is not None})
    out.validate()
    return out


class _Passes:
    """Assessment passes overlapped with integration, with the results of one after another.

    A pass begins (:meth:`Stream.begin_assess`: the map copied at that moment) right after the
    cloud that made it due, as it would without overlap, and is judged on a worker thread while
    the next clouds are integrated; the next pass begins only when this one has finished, and
    the outputs are written in order. So the passes and what is written are those of running
    each pass in turn; only the wall time differs.
    """

    def __init__(self, stream: Stream, overlap: bool = True) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.stream = stream
        self.overlap = overlap
        self.count = 0
        self.waited = 0.0  # seconds the reading thread waited for a pass to finish
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='replay-assess')
        self._pending: tuple[Any, int, dict[str, str]] | None = None

    def begin(self, outputs: _Outputs, fallback_ns: int = 0) -> None:
        self._collect(outputs)
        job = self.stream.begin_assess()
        # what /diagnostics says is what was true when the pass began
        diagnostics = self.stream.diagnostics()
        stamp = job.stamp_ns if job.stamp_ns is not None else fallback_ns
        self._pending = (self._pool.submit(self.stream.finish_assess, job), stamp, diagnostics)
        self.count += 1
        if not self.overlap:
            self._collect(outputs)

    def _collect(self, outputs: _Outputs) -> None:
        if self._pending is None:
            return
        future, stamp, diagnostics = self._pending
        self._pending = None
        t0 = time.perf_counter()
        result = future.result()
        self.waited += time.perf_counter() - t0
        outputs.write(result, diagnostics, stamp)

    def end(self, outputs: _Outputs) -> None:
        self._collect(outputs)
        self._pool.shutdown()

    def abort(self) -> None:
        if self._pending is not None:
            self._pending[0].cancel()
            try:
                self._pending[0].result()
            except BaseException:  # the error that aborts the replay is raised already
                pass
        self._pool.shutdown()


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + '.tmp')
    try:
        tmp.write_text(json.dumps(doc, indent=1, allow_nan=False) + '\n', encoding='utf-8')
        os.replace(tmp, path)
    except OSError as err:
        raise BagError(f'cannot write report {path}: {err.strerror}') from err
