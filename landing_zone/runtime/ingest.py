"""The live receive path: a bounded queue, an integration thread and an assessment thread.

The ``assessor`` node (and anything else that receives clouds as they come) drives a
:class:`LivePipeline`; this module is ROS-free, so it is tested and benchmarked without DDS.

* **Receiving never waits for work.** :meth:`LivePipeline.offer_cloud` and
  :meth:`LivePipeline.offer_pose` only append to a :class:`ReceiveQueue` (microseconds, no
  decoding); the caller (the node's executor thread) is never held by numba or torch.
* **Integration** runs on its own thread: it takes the queue in arrival order, decodes each cloud
  (CDR bytes, as the node takes them, with the rosbags deserializer ``landing-zone replay`` reads
  bags with, or an already built message) and hands it to the
  :class:`~landing_zone.runtime.stream.Stream` that replay drives too, so the same clouds give
  the same map.
* **Assessment** runs on another thread, woken when a pass is due (stamp time, as in replay),
  when integration has caught up and ``eager_interval`` passed since the last pass began (a
  fresher grid when the CPU has room for it), or when the input went quiet; a pass takes in
  everything integrated meanwhile, so passes never queue up.
* **Stale input**: the arrivals of the newest cloud and pose are kept; :func:`stale_level`
  turns their ages into the ``/diagnostics`` level.
* **Overload** (input faster than integration): the queue holds at most ``receive_queue`` clouds
  (a cloud of fewer than 1000 returns counts as its share of one, at least 1/20, so tiny or
  malformed clouds cannot crowd out real ones) and ``receive_queue_mb`` of them; a cloud that
  finds it full pushes out the *oldest* queued
  cloud (newest data wins, latency and memory stay bounded), counted as ``overload``. Nothing
  else changes, so when the input slows down the queue drains and the drops stop by themselves.
* **Every cloud is accounted for**: ``clouds integrated`` plus the ``dropped clouds: REASON``
  counts equals the clouds published, once the queue is empty (docs/INTERFACES.md §1). Besides
  the stream's reasons (malformed, wrong_frame, no_child_frame, out_of_order, too_old, no_pose,
  queue_full) there are three for clouds the stream never saw: ``transport`` (gaps in a
  publisher's sequence numbers: lost between the publisher and this process, e.g. by DDS),
  ``missed_at_start`` (a
  publisher's clouds before the first one that arrived: published before the subscription
  matched, or lost then) and ``overload``.
"""
from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any

import numpy as np

from landing_zone.config import LiveConfig
from landing_zone.errors import LandingZoneError
from landing_zone.runtime.receive import (POINTS_TYPE, ReceiveQueue, SequenceGaps,
                                          _declared_size, _Entry, decode_cloud)
from landing_zone.runtime.stream import CLOUD_REASONS, POINT_REASONS, POSE_REASONS, NS

if TYPE_CHECKING:
    from landing_zone.assessor import Assessment, Assessor
    from landing_zone.runtime.stream import Stream

__all__ = ['LivePipeline', 'LIVE_CLOUD_REASONS', 'warm_up', 'stale_level']

# Reasons for clouds the stream never saw (the stream's own reasons are CLOUD_REASONS).
LIVE_CLOUD_REASONS = ('transport', 'missed_at_start', 'overload')
# How long the threads sleep at most before looking at the clock again [s].
_POLL = 0.05
# An eager pass (before it is due) only while integration works less than this share of the
# time: above it the passes take the CPU integration needs (on a busy 2-core machine, ungated
# eager passes made the queue overflow at 1 M returns/s).
EAGER_MAX_LOAD = 0.5


class LivePipeline:
    """A :class:`~landing_zone.runtime.stream.Stream` fed from a bounded queue, on two threads.

    Args:
        stream: the stream (and through it the assessor) the clouds go into.
        config: the queue's bounds and the idle time.
        publish: called on the assessment thread with each :class:`Assessment`.
        clock: seconds (``time.perf_counter``, as the stream's).
        on_error: called with (reason, message) for refusals the stream does not see itself
            (the node logs them, rate-limited).

    Thread safety: ``offer_*`` may be called from any one thread (the node's executor);
    :meth:`diagnostics` from any thread.
    """

    def __init__(self, stream: Stream, config: LiveConfig | None = None,
                 publish: Callable[[Assessment], None] | None = None,
                 clock: Callable[[], float] = time.perf_counter,
                 on_error: Callable[[str, str], None] | None = None) -> None:
        self.config = config if config is not None else LiveConfig()
        self.config.validate()
        self.stream = stream
        self.publish = publish
        self.clock = clock
        self.on_error = on_error
        # every key exists from the start, so reading the counters from another thread never
        # meets a dict that grows under it
        for reason in CLOUD_REASONS:
            stream.dropped_clouds[reason] += 0
        for reason in POINT_REASONS:
            stream.dropped_points[reason] += 0
        for reason in POSE_REASONS:
            stream.dropped_poses[reason] += 0
        self.queue = ReceiveQueue(self.config.receive_queue,
                                  int(self.config.receive_queue_mb * 1e6))
        self.gaps = SequenceGaps()
        self.received = 0  # clouds offered
        self._last_input = self.started = clock()
        self._last_pass = -float('inf')  # when the last assessment pass began
        # (end, seconds) of the integration thread's work items of about the last second
        self._work: collections.deque[tuple[float, float]] = collections.deque(maxlen=10_000)
        # arrivals of the newest cloud and pose (None: none yet), for the stale-input alarm
        self.last_cloud: float | None = None
        self.last_pose: float | None = None
        self._stop = threading.Event()
        self._assess_wake = threading.Event()
        self._draining = False  # drain() asks for a pass now, idle or not
        self._busy = threading.Lock()  # held while an item is processed (drain() waits on it)
        self._threads: list[threading.Thread] = []
        # the latest unexpected failures of the threads (bounded: a bug hit by every cloud)
        self.errors: collections.deque[BaseException] = collections.deque(maxlen=20)
        self.assess_hooks: list[Callable[[], None]] = []  # run on the assessment thread

    # -- receiving (the executor thread) -----------------------------------------------------

    def offer_cloud(self, payload: Any, publisher: Hashable = None,
                    seq: int | None = None) -> None:
        """Take one cloud as it came (CDR bytes or a message); never blocks on work."""
        now = self.clock()
        self.received += 1
        lost, missed = self.gaps.observe(publisher, seq)
        if (lost or missed) and self.on_error is not None:
            if lost:
                self.on_error('transport', f'{lost} cloud(s) lost before the node could take '
                                           'them (a gap in the publisher\'s sequence numbers)')
            if missed:
                self.on_error('missed_at_start', f'{missed} cloud(s) of a publisher came '
                                                 'before its first one that arrived')
        nbytes, points = _declared_size(payload)
        pushed = self.queue.put('cloud', payload, now, nbytes, points)
        self._last_input = self.last_cloud = now
        if pushed and self.on_error is not None:
            self.on_error('overload', f'{pushed} queued cloud(s) dropped: integration is '
                                      f'behind ({self.config.receive_queue} clouds queued); '
                                      'the newest are kept')

    def offer_pose(self, msg: Any) -> None:
        """Take one pose message; never blocks on work."""
        now = self.clock()
        self.queue.put('pose', msg, now)
        self._last_input = self.last_pose = now

    # -- the threads -------------------------------------------------------------------------

    def start(self) -> None:
        """Start the integration and assessment threads."""
        for name, target in (('lz-integrate', self._ingest_loop),
                             ('lz-assess', self._assess_loop)):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self, drain: bool = True, timeout: float = 30.0) -> None:
        """Stop the threads; with ``drain``, integrate what is queued and assess it first."""
        if drain and self._threads:
            self.drain(timeout)
        self._stop.set()
        self.queue.wake()
        self._assess_wake.set()
        for t in self._threads:
            t.join(timeout)
        self._threads = []

    def drain(self, timeout: float = 30.0) -> bool:
        """Wait until every queued item is integrated, waiting clouds settled and the last
        ones assessed (as after ``idle_flush`` of silence, but now). True if it got there."""
        deadline = time.monotonic() + timeout
        while len(self.queue) and time.monotonic() < deadline:
            time.sleep(0.01)
        with self._busy:
            self.stream.flush()
        self._draining = True
        try:
            while self.stream.unassessed and time.monotonic() < deadline:
                self._assess_wake.set()
                time.sleep(0.01)
        finally:
            self._draining = False
        return not len(self.queue) and not self.stream.unassessed

    def _ingest_loop(self) -> None:
        stream = self.stream
        while not self._stop.is_set():
            entry = self.queue.get(_POLL)
            if entry is None:
                if self.clock() - self._last_input > self.config.idle_flush:
                    with self._busy:
                        if stream.pending:
                            stream.flush()
                    if stream.unassessed:
                        self._assess_wake.set()
                continue
            t_work = self.clock()
            try:
                with self._busy:
                    if entry.kind == 'cloud':
                        self._ingest_cloud(entry)
                    else:
                        stream.add_pose_msg(entry.payload)
            except LandingZoneError as err:  # the stream counts bad input; a backstop
                if self.on_error is not None:
                    self.on_error('error', f'dropped: {err}')
            except Exception as err:  # a bug: keep the node alive, make it visible
                self.errors.append(err)
                if self.on_error is not None:
                    self.on_error('bug', f'integration failed: {type(err).__name__}: {err}')
            now = self.clock()
            self._work.append((now, now - t_work))
            while self._work[0][0] < now - 1.0:
                self._work.popleft()
            if stream.due() or self._eager():
                self._assess_wake.set()

    def _eager(self) -> bool:
        """Whether a pass may start before it is due: integration has caught up (nothing
        queued), clouds wait to be assessed, and since the last pass began ``eager_interval``
        passed and twice that pass's duration (assessing takes at most half the time, so
        integration, which goes first, keeps its share when passes are slow)."""
        gap = self.config.eager_interval
        if gap <= 0 or self.queue.clouds or not self.stream.unassessed:
            return False
        if self.integration_load() > EAGER_MAX_LOAD:
            return False
        secs = self.stream.assess_seconds
        last = secs[-1] if secs else 0.0
        return self.clock() - self._last_pass >= max(gap, 2.0 * last)

    def integration_load(self) -> float:
        """The share of the last second the integration thread spent working (0..1); any
        thread (a copy is read: only the integration thread changes the record)."""
        since = self.clock() - 1.0
        return min(sum(w for t, w in tuple(self._work) if t >= since), 1.0)

    def _ingest_cloud(self, entry: _Entry) -> None:
        try:
            msg = decode_cloud(entry.payload)
        except LandingZoneError as err:
            self.stream.reject_cloud('malformed', f'cloud dropped: {err}')
            return
        self.stream.add_cloud_msg(msg, arrival=entry.arrival)

    def _assess_loop(self) -> None:
        stream = self.stream
        while not self._stop.is_set():
            self._assess_wake.wait(_POLL)
            self._assess_wake.clear()
            if self._stop.is_set():
                break
            idle = self.clock() - self._last_input > self.config.idle_flush
            if stream.due() or self._eager() or (stream.unassessed and (idle or self._draining)):
                self._last_pass = self.clock()
                try:
                    result = stream.assess()
                    if self.publish is not None:
                        self.publish(result)
                except Exception as err:  # a bug: keep the node alive, make it visible
                    self.errors.append(err)
                    if self.on_error is not None:
                        self.on_error('bug', f'assessment failed: {type(err).__name__}: {err}')
            for hook in self.assess_hooks:
                try:
                    hook()
                except Exception as err:
                    self.errors.append(err)
                    if self.on_error is not None:
                        self.on_error('bug', f'{type(err).__name__}: {err}')

    # -- reporting ---------------------------------------------------------------------------

    def input_ages(self) -> dict[str, float | None]:
        """Seconds since the newest cloud and the newest pose arrived (None: none yet)."""
        now = self.clock()
        return {'cloud': None if self.last_cloud is None else now - self.last_cloud,
                'pose': None if self.last_pose is None else now - self.last_pose}

    def dropped_clouds(self) -> dict[str, int]:
        """Every cloud drop count by reason: the stream's and the receive path's."""
        out = {r: int(self.stream.dropped_clouds.get(r, 0)) for r in CLOUD_REASONS}
        out['transport'] = self.gaps.transport
        out['missed_at_start'] = self.gaps.missed_at_start
        out['overload'] = self.queue.dropped_clouds
        return out

    def diagnostics(self) -> dict[str, str]:
        """Key/value strings for ``/diagnostics``: the stream's and the receive path's."""
        out = self.stream.diagnostics()
        for kind, age in self.input_ages().items():
            out[f'newest {kind} age [s]'] = 'n/a' if age is None else f'{age:.2f}'
        drops = self.dropped_clouds()
        for reason in LIVE_CLOUD_REASONS:
            out[f'dropped clouds: {reason}'] = str(drops[reason])
        out['dropped points: overload'] = str(self.queue.dropped_points)
        out['dropped poses: overload'] = str(self.queue.dropped_poses)
        out['clouds received'] = str(self.received)
        out['clouds queued'] = str(self.queue.clouds)
        out['clouds queued, peak'] = str(self.queue.peak_clouds)
        out['publishers seen'] = str(self.gaps.publishers)
        return out


def stale_level(ages: dict[str, float | None], stale_after: float, stale_error: float
                ) -> tuple[str, str]:
    """The ``/diagnostics`` level the input's ages call for, and why.

    WARN when no cloud (or no pose) has arrived for ``stale_after`` seconds, ERROR past
    ``stale_error``: a planner must never act on a grid that silently stopped updating. Before
    the first of a kind it is WARN (the node waits for its input); OK when both are fresh.

    Args:
        ages: :meth:`LivePipeline.input_ages`.
        stale_after, stale_error: the thresholds [s].

    Returns:
        ``(level, message)``, level 'OK', 'WARN' or 'ERROR'; message '' when OK.
    """
    level, parts = 'OK', []
    for kind in ('cloud', 'pose'):
        age = ages.get(kind)
        if age is None:
            parts.append(f'no {kind} received yet')
            level = 'WARN' if level == 'OK' else level
        elif age > stale_error:
            parts.append(f'no {kind} for {age:.1f} s (stale_error {stale_error:g} s)')
            level = 'ERROR'
        elif age > stale_after:
            parts.append(f'no {kind} for {age:.1f} s (stale_after {stale_after:g} s)')
            level = 'WARN' if level == 'OK' else level
    return level, ', '.join(parts)


def warm_up(assessor: Assessor, build: Callable[[Assessment], Any] | None = None) -> float:
    """Compile and run every kernel the live path uses, once, before any real cloud comes.

    numba compiles (or loads from its cache) each kernel on first use, torch builds its
    convolution primitives on the first pass, and rosbags generates its deserializers on first
    use: seconds that would otherwise fall on the first clouds. A synthetic cloud (serialized
    and decoded as a received one is, with enough rays for the parallel walk, a voxel hit often
    enough to need a high byte, and a second pose far enough to scroll the map) goes through a
    scratch stream and a scratch map of the same voxel and tile settings, then one pass runs
    with the real network; ``build`` (the node's message builders) gets its result. The real map
    is not touched.

    Returns:
        The seconds it took.
    """
    import copy

    from landing_zone.assessor import Assessor as _Assessor
    from landing_zone.runtime.stream import Stream
    from landing_zone.judging.inference import predict
    from msg_adapters import MessageTypes, jazzy_typestore, make_header
    from msg_adapters.pointcloud import make_cloud, points_to_structured

    t0 = time.perf_counter()
    cfg = copy.deepcopy(assessor.config)
    ts = cfg.tiles.tile_size
    cfg.map.size_xy = 4 * ts
    cfg.map.recenter_distance = min(cfg.map.recenter_distance, ts)
    cfg.center = None
    scratch = _Assessor(cfg, model=assessor.model)
    try:
        stream = Stream(scratch)
        types = MessageTypes.rosbags()
        store = jazzy_typestore()
        rng = np.random.default_rng(0)
        half = 2 * ts
        for k, (x0, stamp) in enumerate(((0.0, 1), (3.0 * ts, 3))):
            xy = rng.uniform(-half, half, (4096, 2)) + (x0, 0.0)
            z = rng.uniform(0.0, 0.1, 4096)
            pts = np.column_stack([xy, z]).astype(np.float32)
            if k == 0:
                pts[:300] = (0.01, 0.01, 0.02)  # one voxel hit past 255: the high-byte paths
            for s in (stamp - 1, stamp + 1):
                pose = types.build(
                    'geometry_msgs/msg/PoseStamped', header=make_header(s * NS // 10, cfg.frame_id,
                                                                        types),
                    pose=types.build('geometry_msgs/msg/Pose',
                                     position=types.build('geometry_msgs/msg/Point', x=x0, y=0.0,
                                                          z=8.0),
                                     orientation=types.build('geometry_msgs/msg/Quaternion',
                                                             x=0.0, y=0.0, z=0.0, w=1.0)))
                stream.add_pose_msg(pose)
            cloud = make_cloud(points_to_structured(pts),
                               make_header(stamp * NS // 10, cfg.frame_id, types), types)
            raw = bytes(store.serialize_cdr(cloud, POINTS_TYPE))
            stream.add_cloud_msg(decode_cloud(raw))
        stream.flush()
        result = stream.assess()
    finally:
        scratch.close()  # its map's threads and its predictor
    side = int(assessor.model.config.input_size)
    predict(assessor.model, np.zeros((2, 1, side, side, side), np.float32),
            batch_size=assessor.config.model.batch_size)
    if build is not None:
        build(result)
    return time.perf_counter() - t0
