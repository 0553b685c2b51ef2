"""The stamp-ordered stream logic both front ends share: clouds + poses in, assessments out.

The node (live topics) and replay (a bag) differ only in where messages come from and where
the outputs go; everything in between is here, so the same input gives the same map:

1. **Poses** (``geometry_msgs/PoseStamped`` or ``nav_msgs/Odometry``: the pose of a frame C,
   the sensor or the odometry's body) go into a :class:`~landing_zone.poses.PoseBuffer`. A
   cloud's sensor origin is C's pose interpolated at the cloud's ``header.stamp`` (position
   linearly, orientation by slerp) composed with ``sensor_offset`` (the LiDAR's pose in C).
   Clouds in the ``body`` or ``sensor`` frame (``cloud_frame``) are registered into the fixed
   frame with that same pose; ``fixed`` clouds are taken as they are.
2. **Clouds** are checked (frame, decodable, x/y/z floats, stamp order) and queued in stamp
   order. The head of the queue is integrated as soon as a pose at or after its stamp exists.
   A cloud newer than the newest pose waits (at most ``max_pending`` clouds, at most
   ``pose_wait`` seconds of stamp time behind the newest cloud); when its wait ends it gets the
   newest pose if that is within ``pose_tolerance`` and is dropped otherwise. A cloud older
   than the oldest pose kept (beyond the tolerance) is dropped at once.
3. **Assessment** is due every ``assessment_period`` seconds of stamp time (on a fixed grid
   from the first integrated cloud's stamp), never on wall time, so a bag replayed slowly or
   fast gives the same sequence of states. The node runs it on its own thread; replay runs it
   right after the cloud that made it due.

Every refusal is counted by reason (:attr:`Stream.dropped_clouds`, :attr:`Stream.dropped_points`)
and never raises to the front end: bad input costs the input, never the map.

Reasons (clouds): ``malformed`` (undecodable message or missing / non-float x, y, z),
``wrong_frame`` (a ``fixed`` cloud not in ``frame_id``, a ``body`` or ``sensor`` cloud in it or a
``body`` cloud not in the odometry's child frame; or the cloud found no pose because the poses
were refused for their frame), ``no_child_frame`` (it found no pose because the odometry does
not say which frame it is the pose of, and the offset or the cloud's frame needs it),
``out_of_order`` (stamp older than a cloud already accepted), ``too_old`` (before the oldest
pose), ``no_pose`` (its wait ended without a pose near enough), ``queue_full`` (more than
``max_pending`` clouds waiting). Reasons (points): the cloud's reason for every point of a
dropped cloud, plus ``nonfinite`` (NaN/Inf rows) and ``degenerate`` (a return at the sensor
origin). Poses: ``bad_pose`` (non-finite or a zero quaternion), ``wrong_frame``,
``no_child_frame`` (an odometry with an empty ``child_frame_id`` where one is needed) and
``second_input`` (a PoseStamped after odometry was taken, or the reverse: the two give the
poses of different frames, so only the first kind that came is used).
"""
from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from landing_zone.config import StreamConfig
from landing_zone.errors import InvalidCloudError, InvalidPoseError

if TYPE_CHECKING:
    from landing_zone.assessor import Assessment, Assessor

__all__ = ['Stream', 'CLOUD_REASONS', 'POINT_REASONS', 'POSE_REASONS']

NS = 1_000_000_000
CLOUD_REASONS = ('malformed', 'wrong_frame', 'no_child_frame', 'out_of_order', 'too_old',
                 'no_pose', 'queue_full')
POINT_REASONS = CLOUD_REASONS + ('nonfinite', 'degenerate')
POSE_REASONS = ('bad_pose', 'wrong_frame', 'no_child_frame', 'second_input')


@dataclass
class _Cloud:
    stamp_ns: int
    xyz: np.ndarray
    arrival: float  # perf_counter() when it entered the stream


@dataclass
class _PassJob:
    job: Any  # the assessor's part
    oldest: float | None  # arrival of the oldest cloud the pass takes in
    t0: float
    stamp_ns: int | None  # the newest cloud it takes in


class Stream:
    """Clouds and poses in stamp order -> the assessor's map -> assessments when due.

    Thread safety: ``add_*`` and :meth:`flush` must come from one thread at a time (the node's
    ingest callback group); :meth:`assess` and :meth:`due` may run on another.

    Args:
        assessor: the pipeline that owns the map.
        config: timing; default :class:`StreamConfig()`.
        clock: seconds for latencies and rates (``time.perf_counter``; tests inject one).

    Attributes:
        clouds: clouds integrated. ``points``: finite returns integrated.
        received_clouds, received_points, poses: what came in.
        dropped_clouds, dropped_points, dropped_poses: counters by reason.
        last_latency: seconds from the arrival of the oldest cloud a pass took in to the end
            of that pass (the node's "cloud to grid" latency), None before the first pass.
    """

    def __init__(self, assessor: Assessor, config: StreamConfig | None = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        from landing_zone.poses import Mount, PoseBuffer

        self.config = config if config is not None else StreamConfig()
        self.config.validate()
        self.assessor = assessor
        self.frame_id = assessor.config.frame_id
        self.cloud_frame = self.config.cloud_frame
        self.mount = Mount(self.config.sensor_offset)
        self.pose_kind: str | None = None  # 'pose' or 'odometry': the first kind accepted
        self.child_frame: str | None = None  # the odometry's child frame, once known
        # (cloud reason, message) while the newest poses are refused for a reason a cloud
        # without a pose should be counted under; None once a pose is accepted
        self._pose_refusal: tuple[str, str] | None = None
        self.clock = clock
        self.poses_buffer = PoseBuffer(max_age_s=self.config.pose_history,
                                       tolerance_s=self.config.pose_tolerance)
        self._pending: collections.deque[_Cloud] = collections.deque()
        self._newest_cloud_ns: int | None = None  # newest stamp accepted into the stream
        self._first_ns: int | None = None  # first integrated stamp: the assessment grid's zero
        self._last_integrated_ns: int | None = None
        self._next_due_ns: int | None = None
        self._lock = threading.Lock()  # the fields below, shared with the assessing thread
        self._unassessed = 0  # clouds integrated since the last pass began
        self._oldest_unassessed: float | None = None
        self._due = False
        self.clouds = 0
        self.points = 0
        self.received_clouds = 0
        self.received_points = 0
        self.poses = 0
        self.dropped_clouds: collections.Counter[str] = collections.Counter()
        self.dropped_points: collections.Counter[str] = collections.Counter()
        self.dropped_poses: collections.Counter[str] = collections.Counter()
        self.assessments = 0
        self.last_latency: float | None = None
        self.latencies: collections.deque[float] = collections.deque(maxlen=100)
        self.assess_seconds: collections.deque[float] = collections.deque(maxlen=100)
        self.assess_seconds_total = 0.0
        self._integrate_times: collections.deque[tuple[float, int]] = \
            collections.deque(maxlen=50)
        # (reason, message) hook; a pose's reason comes as pose_REASON
        self.on_drop: Callable[[str, str], None] | None = None
        # called after each integration with (stamp_ns, xyz, origin): replay keeps a top view
        self.on_integrate: Callable[[int, np.ndarray, np.ndarray], None] | None = None
        self.assessed_stamp_ns: int | None = None  # newest cloud stamp in the last pass

    # -- poses ------------------------------------------------------------------------------

    def add_pose_msg(self, msg: Any) -> None:
        """Add a ``geometry_msgs/PoseStamped`` or a ``nav_msgs/Odometry`` (rclpy or rosbags);
        bad ones are counted."""
        from msg_adapters.pose import read_pose_input

        try:
            frame, child, stamp_ns, position, quaternion = read_pose_input(msg)
        except InvalidPoseError as err:
            self._drop_pose('bad_pose', f'pose dropped: {err}')
            return
        kind = 'pose' if child is None else 'odometry'
        if self.pose_kind is not None and kind != self.pose_kind:
            self._drop_pose('second_input', f'{kind} dropped: the poses come from '
                                            f'{self.pose_kind} already (use one pose input)')
            return
        if frame != self.frame_id:
            message = (f'{kind} dropped: frame_id {frame!r}, expected {self.frame_id!r} (the '
                       'parameter frame_id)')
            self._pose_refusal = ('wrong_frame', 'cloud dropped: its pose was refused: '
                                                 + message)
            self._drop_pose('wrong_frame', message)
            return
        if child is not None and not child and self.config.needs_child_frame:
            needs = [x for x in ('' if self.mount.identity else 'sensor_offset',
                                 '' if self.cloud_frame == 'fixed'
                                 else f'cloud_frame {self.cloud_frame!r}') if x]
            message = (f'odometry dropped: child_frame_id is empty; {" and ".join(needs)} '
                       f'need{"s" if len(needs) == 1 else ""} the frame it is the pose of')
            self._pose_refusal = ('no_child_frame', 'cloud dropped: its pose was refused: '
                                                    + message)
            self._drop_pose('no_child_frame', message)
            return
        self.pose_kind = kind
        if child:
            self.child_frame = child
        self.add_pose(stamp_ns, position, quaternion)

    def add_pose(self, stamp_ns: int, position: Any, quaternion: Any) -> None:
        """Add a pose of the sensor origin in the fixed frame at ``stamp_ns``."""
        try:
            self.poses_buffer.add(stamp_ns, position, quaternion)
        except InvalidPoseError as err:
            self._drop_pose('bad_pose', f'pose dropped: {err}')
            return
        self.poses += 1
        self._pose_refusal = None
        self._drain(final=False)

    def _drop_pose(self, reason: str, message: str) -> None:
        self.dropped_poses[reason] += 1
        if self.on_drop is not None:  # a kind of its own: a pose's drop hides no cloud's
            self.on_drop(f'pose_{reason}', message)

    # -- clouds -----------------------------------------------------------------------------

    def add_cloud_msg(self, msg: Any, arrival: float | None = None) -> None:
        """Add a ``sensor_msgs/PointCloud2`` (rclpy or rosbags); bad ones are counted.

        Args:
            msg: the cloud.
            arrival: when it was received (``clock`` seconds), for the cloud-to-grid latency;
                default now (the node passes the time its subscription took the message).
        """
        from msg_adapters.pointcloud import cloud_to_xyz, declared_points, read_cloud_header

        self.received_clouds += 1
        n_points = declared_points(msg)
        self.received_points += n_points
        try:
            frame, stamp_ns = read_cloud_header(msg)
        except InvalidCloudError as err:
            self._drop_cloud('malformed', n_points, f'cloud dropped: {err}')
            return
        wrong = self._frame_refusal(frame)
        if wrong:
            self._drop_cloud('wrong_frame', n_points, wrong)
            return
        try:
            xyz, nonfinite = cloud_to_xyz(msg)
        except InvalidCloudError as err:
            self._drop_cloud('malformed', n_points, f'cloud dropped: {err}')
            return
        if nonfinite:
            self.dropped_points['nonfinite'] += nonfinite
        self._accept(stamp_ns, xyz, arrival)

    def _frame_refusal(self, frame: str | None) -> str:
        """Why a cloud in ``frame`` cannot be taken under ``cloud_frame`` ('' if it can)."""
        if frame is None:
            return ''
        if self.cloud_frame == 'fixed':
            if frame != self.frame_id:
                return (f'cloud dropped: frame_id {frame!r}, expected {self.frame_id!r} '
                        '(cloud_frame fixed: registered in the parameter frame_id)')
            return ''
        if frame == self.frame_id:
            return (f'cloud dropped: frame_id {frame!r} is the fixed frame, but cloud_frame is '
                    f'{self.cloud_frame!r} (set cloud_frame fixed for registered clouds)')
        if self.cloud_frame == 'body' and self.child_frame and frame != self.child_frame:
            return (f'cloud dropped: frame_id {frame!r}, expected the odometry\'s child frame '
                    f'{self.child_frame!r} (cloud_frame body)')
        return ''

    def reject_cloud(self, reason: str, message: str, n_points: int = 0) -> None:
        """Count a cloud received but refused before it could be read (``reason`` one of
        :data:`CLOUD_REASONS`), as :meth:`add_cloud_msg` counts its own refusals."""
        self.received_clouds += 1
        self.received_points += int(n_points)
        self._drop_cloud(reason, n_points, message)

    def add_cloud(self, stamp_ns: int, xyz: np.ndarray, frame_id: str | None = None) -> None:
        """Add a cloud given as arrays: (N, 3) returns in the fixed frame at ``stamp_ns``."""
        pts = np.asarray(xyz)
        n = int(pts.shape[0]) if pts.ndim >= 1 else 0
        self.received_clouds += 1
        self.received_points += n
        wrong = self._frame_refusal(frame_id)
        if wrong:
            self._drop_cloud('wrong_frame', n, wrong)
            return
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.dtype.kind not in 'fiu':
            self._drop_cloud('malformed', n, f'cloud dropped: points of shape {pts.shape} '
                                             f'dtype {pts.dtype}, expected (N, 3) numbers')
            return
        finite = np.isfinite(pts).all(axis=1)
        if not finite.all():
            self.dropped_points['nonfinite'] += int((~finite).sum())
            pts = pts[finite]
        self._accept(int(stamp_ns), pts)

    def _accept(self, stamp_ns: int, xyz: np.ndarray, arrival: float | None = None) -> None:
        if self._newest_cloud_ns is not None and stamp_ns < self._newest_cloud_ns:
            self._drop_cloud('out_of_order', len(xyz),
                             f'cloud dropped: stamp {stamp_ns / NS:.3f} s is older than a '
                             f'cloud already accepted ({self._newest_cloud_ns / NS:.3f} s)')
            return
        self._newest_cloud_ns = stamp_ns
        if len(self._pending) >= self.config.max_pending:
            old = self._pending.popleft()
            self._drop_cloud('queue_full', len(old.xyz),
                             f'cloud dropped: {self.config.max_pending} clouds already wait '
                             'for a pose')
        self._pending.append(_Cloud(stamp_ns, xyz, self.clock() if arrival is None else arrival))
        self._drain(final=False)

    def _drop_cloud(self, reason: str, n_points: int, message: str) -> None:
        self.dropped_clouds[reason] += 1
        self.dropped_points[reason] += int(n_points)
        if self.on_drop is not None:
            self.on_drop(reason, message)

    def _drain(self, final: bool) -> None:
        """Integrate the waiting clouds whose pose is known, in stamp order."""
        from landing_zone.poses import PoseNotYetError, PoseTooOldError

        wait_ns = int(round(self.config.pose_wait * NS))
        while self._pending:
            cloud = self._pending[0]
            newest_pose = self.poses_buffer.newest_ns
            expired = final or (self._newest_cloud_ns is not None
                                and self._newest_cloud_ns - cloud.stamp_ns > wait_ns)
            if not expired and (newest_pose is None or cloud.stamp_ns > newest_pose):
                return  # its pose may still come
            self._pending.popleft()
            try:
                position, quaternion = self.poses_buffer.lookup(cloud.stamp_ns)
            except PoseTooOldError as err:
                self._drop_cloud('too_old', len(cloud.xyz), f'cloud dropped: {err}')
                continue
            except PoseNotYetError as err:
                if self._pose_refusal is not None:  # the poses came, but were refused
                    self._drop_cloud(self._pose_refusal[0], len(cloud.xyz),
                                     self._pose_refusal[1])
                else:
                    self._drop_cloud('no_pose', len(cloud.xyz), f'cloud dropped: {err}')
                continue
            self._integrate(*self._register(cloud, position, quaternion))

    def _register(self, cloud: _Cloud, position: np.ndarray, quaternion: np.ndarray
                  ) -> tuple[_Cloud, np.ndarray]:
        """The cloud in the fixed frame and the sensor origin, from C's pose at its stamp."""
        from landing_zone.poses import quaternion_to_matrix

        if self.cloud_frame == 'fixed' and self.mount.identity:
            return cloud, position
        R_c = quaternion_to_matrix(quaternion)
        R_s, t_s = self.mount.sensor_pose(R_c, position)
        if self.cloud_frame == 'fixed':
            return cloud, t_s
        R, t = (R_c, position) if self.cloud_frame == 'body' else (R_s, t_s)
        xyz = cloud.xyz
        world = (np.asarray(xyz, np.float64) @ R.T + t).astype(
            xyz.dtype if xyz.dtype.kind == 'f' else np.float64, copy=False)
        return _Cloud(cloud.stamp_ns, world, cloud.arrival), t_s

    def _integrate(self, cloud: _Cloud, origin: np.ndarray) -> None:
        st = self.assessor.integrate(cloud.xyz, origin, stamp=cloud.stamp_ns / NS)
        if st.degenerate:
            self.dropped_points['degenerate'] += st.degenerate
        if st.nonfinite:
            self.dropped_points['nonfinite'] += st.nonfinite
        self.clouds += 1
        self.points += st.returns - st.dropped
        self._integrate_times.append((self.clock(), int(st.returns)))
        if self.on_integrate is not None:
            self.on_integrate(cloud.stamp_ns, cloud.xyz, origin)
        period_ns = int(round(self.config.assessment_period * NS))
        with self._lock:
            self._last_integrated_ns = cloud.stamp_ns
            if self._first_ns is None:
                self._first_ns = cloud.stamp_ns
                self._next_due_ns = cloud.stamp_ns + period_ns
            self._unassessed += 1
            if self._oldest_unassessed is None:
                self._oldest_unassessed = cloud.arrival
            assert self._next_due_ns is not None
            if cloud.stamp_ns >= self._next_due_ns:
                self._due = True
                # the next grid point after this stamp (a long gap skips the missed ones)
                k = (cloud.stamp_ns - self._first_ns) // period_ns + 1
                self._next_due_ns = self._first_ns + k * period_ns

    def flush(self) -> None:
        """End of input (or a long silence): settle every waiting cloud now."""
        self._drain(final=True)

    # -- assessment -------------------------------------------------------------------------

    def due(self) -> bool:
        """Whether an assessment is due (a period of stamp time passed since the last)."""
        with self._lock:
            return self._due

    @property
    def unassessed(self) -> int:
        """Clouds integrated since the last assessment pass began."""
        with self._lock:
            return self._unassessed

    @property
    def stamp_span(self) -> tuple[int | None, int | None]:
        """Stamps [ns] of the first and the newest cloud integrated (None before any)."""
        with self._lock:
            return self._first_ns, self._last_integrated_ns

    @property
    def pending(self) -> int:
        """Clouds waiting for their pose."""
        return len(self._pending)

    def assess(self) -> Assessment:
        """Run one assessment pass now (clears :meth:`due`) and record its latency."""
        return self.finish_assess(self.begin_assess())

    def begin_assess(self) -> _PassJob:
        """Begin a pass now (clears :meth:`due`): the map as it is at this moment goes into it
        (:meth:`Assessor.begin_assess`); :meth:`finish_assess` completes it, on any thread."""
        with self._lock:
            self._due = False
            self.assessed_stamp_ns = self._last_integrated_ns
            oldest = self._oldest_unassessed
            self._oldest_unassessed = None
            self._unassessed = 0
            stamp_ns = self.assessed_stamp_ns
        t0 = self.clock()
        return _PassJob(self.assessor.begin_assess(), oldest, t0, stamp_ns)

    def finish_assess(self, job: _PassJob) -> Assessment:
        """Complete a pass begun by :meth:`begin_assess` and record its time and latency."""
        result = self.assessor.finish_assess(job.job)
        t1 = self.clock()
        self.assessments += 1
        self.assess_seconds.append(t1 - job.t0)
        self.assess_seconds_total += t1 - job.t0
        if job.oldest is not None:
            self.last_latency = t1 - job.oldest
            self.latencies.append(self.last_latency)
        return result

    # -- reporting --------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """Counters for the report and the diagnostics."""
        return {
            'clouds': self.clouds,
            'points': self.points,
            'received_clouds': self.received_clouds,
            'received_points': self.received_points,
            'dropped_clouds': int(sum(self.dropped_clouds.values())),
            'dropped_points': int(sum(self.dropped_points.values())),
            'dropped_clouds_by_reason': dict(sorted(self.dropped_clouds.items())),
            'dropped_points_by_reason': dict(sorted(self.dropped_points.items())),
            'poses': self.poses,
            'dropped_poses_by_reason': dict(sorted(self.dropped_poses.items())),
            'assessments': self.assessments,
        }

    def integration_rate(self) -> tuple[float, float]:
        """Recent clouds/s and returns/s (wall time), from the last 50 integrations."""
        times = list(self._integrate_times)
        if len(times) < 2 or times[-1][0] <= times[0][0]:
            return 0.0, 0.0
        span = times[-1][0] - times[0][0]
        return (len(times) - 1) / span, sum(n for _, n in times[1:]) / span

    def diagnostics(self) -> dict[str, str]:
        """Key/value strings for ``/diagnostics``."""
        clouds_s, points_s = self.integration_rate()
        lat = list(self.latencies)
        secs = list(self.assess_seconds)
        out = {
            'integration rate [clouds/s]': f'{clouds_s:.2f}',
            'integration rate [returns/s]': f'{points_s:.0f}',
            'clouds integrated': str(self.clouds),
            'returns integrated': str(self.points),
            'clouds waiting for a pose': str(self.pending),
            'poses accepted': str(self.poses),
            # the stamp the last grid carries once every cloud is assessed (header.stamp, ns)
            'newest cloud integrated [stamp ns]': str(self.stamp_span[1])
            if self.stamp_span[1] is not None else 'n/a',
            'assessments': str(self.assessments),
            'assessment time, last [s]': f'{secs[-1]:.3f}' if secs else 'n/a',
            'cloud-to-grid latency, last [s]': f'{lat[-1]:.3f}' if lat else 'n/a',
            'cloud-to-grid latency, max of last 100 [s]': f'{max(lat):.3f}' if lat else 'n/a',
            'map memory [MB]': f'{self.assessor.nbytes / 1e6:.1f}',
        }
        for reason in CLOUD_REASONS:
            out[f'dropped clouds: {reason}'] = str(self.dropped_clouds.get(reason, 0))
        for reason in POINT_REASONS:
            out[f'dropped points: {reason}'] = str(self.dropped_points.get(reason, 0))
        for reason in POSE_REASONS:
            out[f'dropped poses: {reason}'] = str(self.dropped_poses.get(reason, 0))
        return out
