"""Read any ROS bag in stamp order and write ROS 2 bags, with rosbags (no ROS installation).

Reading (:func:`read_messages`, :func:`bag_topics`) accepts

* a ROS 2 bag directory (``metadata.yaml`` plus ``.mcap`` or ``.db3`` files), read by
  ``rosbags.highlevel.AnyReader``;
* a ``.db3`` file inside such a directory (the directory is read);
* a ``.mcap`` file, by itself (what :class:`BagWriter` writes for a ``*.mcap`` path, the file
  inside a ``ros2 bag record -s mcap`` directory, Foxglove recordings, ...), which AnyReader
  opens too, deserializing with the schemas embedded in the file (an unindexed file must hold
  its messages in log-time order, as a recorder writes them);
* a ROS 1 ``.bag`` file, whose types AnyReader maps to their ROS 2 names
  (``sensor_msgs/msg/PointCloud2``, headers with ``builtin_interfaces/msg/Time`` stamps).

Messages come out in the bag's log-time order, deserialized into rosbags dataclasses whose field
names are rclpy's, so ``msg_adapters`` decodes them like live messages. :class:`RawBag` reads
the same bags without deserializing: every message's CDR bytes (a ROS 1 message converted to
CDR) and the type definitions to write them again, so a tool can copy a bag message for message,
byte for byte, with :meth:`BagWriter.write_raw`.

Writing (:class:`BagWriter`) produces a ROS 2 bag with MCAP storage, version 9. A path ending in
``.mcap`` becomes that one self-describing file (schemas, channels and the rosbag2 metadata
record live inside it; ``ros2 bag play SITE.mcap`` and :func:`read_messages` read it); any other
path becomes a rosbag2 directory with ``metadata.yaml``, in MCAP or SQLite3 storage.

rosbags is imported inside the functions, so importing this module costs little.
Every failure is a :class:`~landing_zone.errors.BagError` with a one-line message.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from landing_zone.errors import BagError
from msg_adapters import jazzy_typestore

if TYPE_CHECKING:
    from types import TracebackType

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

__all__ = [
    'BagMessage',
    'RawMessage',
    'RawBag',
    'read_messages',
    'bag_topics',
    'require_topics',
    'BagWriter',
]


class BagMessage(NamedTuple):
    """One message of a bag."""

    topic: str
    stamp_ns: int  # the bag's log (receive) time; the header stamp may differ
    msgtype: str  # ROS 2 type name, 'sensor_msgs/msg/PointCloud2'
    msg: Any  # rosbags dataclass with rclpy's field names


class RawMessage(NamedTuple):
    """One message of a bag as it is stored, CDR-serialized (ROS 1 messages converted)."""

    topic: str
    stamp_ns: int  # the bag's log (receive) time
    msgtype: str  # ROS 2 type name
    data: bytes | memoryview  # CDR with its 4-byte encapsulation header


def _describe(err: BaseException) -> str:
    """One line naming a foreign exception."""
    text = ' '.join(str(err).split()) or type(err).__name__
    return text if len(text) <= 200 else text[:197] + '...'


def _target(path: Path) -> Path:
    """The path AnyReader opens for a bag path (a ``.db3`` file: its bag directory)."""
    if not path.exists():
        raise BagError(f'bag not found: {path}')
    if path.is_dir():
        if not (path / 'metadata.yaml').exists():
            raise BagError(f'{path} is a directory without metadata.yaml, not a ROS 2 bag')
        return path
    if path.suffix == '.bag':
        return path
    if path.suffix == '.mcap':
        return path
    if path.suffix == '.db3' and (path.parent / 'metadata.yaml').exists():
        return path.parent
    if path.suffix == '.db3':
        raise BagError(f'{path} is a .db3 file without the metadata.yaml of its bag directory; '
                       'pass the bag directory')
    raise BagError(f'{path} is not a bag (expected a ROS 2 bag directory, a .mcap, .db3 or a '
                   'ROS 1 .bag file)')


def _check_topics(path: Path, available: dict[str, str],
                  topics: Iterable[str] | None) -> set[str] | None:
    """The requested topics as a set, after checking that the bag has every one."""
    if topics is None:
        return None
    wanted = {topics} if isinstance(topics, str) else set(topics)
    missing = sorted(wanted - set(available))
    if missing:
        raise BagError(f'{path} lacks topic(s) {", ".join(missing)} (it has '
                       f'{", ".join(sorted(available)) or "no topics"})')
    return wanted


def bag_topics(path: str | os.PathLike[str]) -> dict[str, str]:
    """The topics of a bag and their message types.

    Args:
        path: Bag directory, ``.mcap`` / ``.db3`` file or ROS 1 ``.bag`` file.

    Returns:
        ``{topic: msgtype}`` with ROS 2 type names.

    Raises:
        BagError: The bag is missing, not a bag, or unreadable.
    """
    path = Path(path)
    target = _target(path)
    from rosbags.highlevel import AnyReader
    try:
        with AnyReader([target], default_typestore=jazzy_typestore()) as reader:
            return {topic: info.msgtype or '' for topic, info in reader.topics.items()}
    except BagError:
        raise
    except Exception as err:  # any rosbags/sqlite/yaml failure means the same: unreadable bag
        raise BagError(f'cannot read bag {path}: {_describe(err)}') from err


def require_topics(bag: str | os.PathLike[str], points_topic: str, pose_topic: str) -> None:
    """Raise BagError unless the bag has both topics with the right types (one line).

    The types are ``sensor_msgs/msg/PointCloud2`` and ``geometry_msgs/msg/PoseStamped``, the
    inputs of the node (docs/INTERFACES.md §1).
    """
    topics = bag_topics(bag)
    for topic, want in ((points_topic, 'sensor_msgs/msg/PointCloud2'),
                        (pose_topic, 'geometry_msgs/msg/PoseStamped')):
        if topic not in topics:
            raise BagError(f'{bag} lacks topic {topic} (it has '
                           f'{", ".join(sorted(topics)) or "no topics"}); choose with '
                           '--points-topic / --pose-topic')
        if topics[topic] != want:
            raise BagError(f'{bag}: topic {topic} carries {topics[topic] or "an unknown type"}, '
                           f'expected {want}')


def read_messages(path: str | os.PathLike[str],
                  topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Iterate over the messages of a bag in log-time order.

    Args:
        path: Bag directory, ``.mcap`` / ``.db3`` file or ROS 1 ``.bag`` file.
        topics: Only these topics (every one must be in the bag); ``None`` for all.

    Yields:
        :class:`BagMessage` per message, deserialized.

    Raises:
        BagError: The bag is missing, not a bag, corrupt (also when found mid-way), or lacks a
            requested topic. Raised on the first ``next()``, as the function is a generator.
    """
    path = Path(path)
    yield from _read_any(path, _target(path), topics)


def _read_any(path: Path, target: Path, topics: Iterable[str] | None) -> Iterator[BagMessage]:
    """Messages of a bag AnyReader can open (ROS 2 directory, ROS 1 file)."""
    from rosbags.highlevel import AnyReader
    try:
        reader = AnyReader([target], default_typestore=jazzy_typestore())
        reader.open()
    except Exception as err:  # rosbags raises its own, sqlite3, yaml and OS errors here
        raise BagError(f'cannot open bag {path}: {_describe(err)}') from err
    try:
        available = {topic: info.msgtype or '' for topic, info in reader.topics.items()}
        wanted = _check_topics(path, available, topics)
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        stream = reader.messages(connections=connections) if connections else iter(())
        while True:
            try:
                connection, stamp, raw = next(stream)
                msg = reader.deserialize(raw, connection.msgtype)
            except StopIteration:
                return
            except Exception as err:  # a corrupt record deep in the bag: any error of the libs
                raise BagError(f'corrupt bag {path}: {_describe(err)}') from err
            yield BagMessage(connection.topic, int(stamp), connection.msgtype, msg)
    finally:
        reader.close()


class RawBag:
    """A bag read message by message as CDR bytes, with the definitions of its types.

    Reads what :func:`read_messages` reads. A ROS 2 bag's messages come as stored; a ROS 1
    bag's are converted to CDR (with the bag's own type definitions, ROS 1 header ``seq``
    included). :meth:`types_of` gives the typestore holding each topic's type as the bag defines
    it, for :meth:`BagWriter.add_topic`, so a copy keeps every topic and type.

    Example::

        with RawBag('in.mcap') as src, BagWriter('out.mcap') as dst:
            for topic, msgtype in src.topics.items():
                dst.add_topic(topic, msgtype, types=src.types_of(topic))
            for m in src.messages():
                dst.write_raw(m.topic, m.stamp_ns, m.data)

    Args:
        path: Bag directory, ``.mcap`` / ``.db3`` file or ROS 1 ``.bag`` file.

    Raises:
        BagError: On entering: the bag is missing, not a bag or unreadable.
    """

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self.topics: dict[str, str] = {}
        self._target = _target(self.path)
        self._any: Any = None
        self._types: dict[str, tuple[Typestore, str]] = {}

    def __enter__(self) -> RawBag:
        from rosbags.highlevel import AnyReader
        try:
            self._any = AnyReader([self._target], default_typestore=jazzy_typestore())
            self._any.open()
        except Exception as err:  # rosbags raises its own, sqlite3, yaml and OS errors
            self._any = None
            raise BagError(f'cannot open bag {self.path}: {_describe(err)}') from err
        for connection in self._any.connections:
            self._types.setdefault(connection.topic, (self._any.typestore, connection.msgtype))
        self.topics = {topic: msgtype for topic, (_, msgtype) in self._types.items()}
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        if self._any is not None:
            self._any.close()
            self._any = None

    def types_of(self, topic: str) -> Typestore:
        """The typestore that defines ``topic``'s type as this bag does."""
        return self._types[topic][0]

    def deserialize(self, message: RawMessage) -> Any:
        """The rosbags dataclass of a message.

        Raises:
            BagError: The bytes do not hold a message of its type.
        """
        store = self._types[message.topic][0]
        try:
            return store.deserialize_cdr(message.data, message.msgtype)
        except Exception as err:  # rosbags' SerdeError, struct errors, index errors
            raise BagError(f'corrupt bag {self.path}: {_describe(err)}') from err

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """The messages in log-time order.

        Args:
            topics: Only these topics (every one must be in the bag); ``None`` for all.

        Raises:
            BagError: A requested topic is absent, or the bag is corrupt (also mid-way).
        """
        wanted = _check_topics(self.path, self.topics, topics)
        reader = self._any
        if reader is None:
            raise BagError(f'bag {self.path} is not open')
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not connections:
            return
        stream = reader.messages(connections=connections)
        while True:
            try:
                connection, stamp, raw = next(stream)
                if reader.is2:
                    data = raw
                else:  # (rosbags' ros1_to_cdr fails on headers of a store built from a bag)
                    store = reader.typestore
                    data = store.serialize_cdr(store.deserialize_ros1(raw, connection.msgtype),
                                               connection.msgtype)
            except StopIteration:
                return
            except Exception as err:  # a corrupt record deep in the bag: any error of the libs
                raise BagError(f'corrupt bag {self.path}: {_describe(err)}') from err
            yield RawMessage(connection.topic, int(stamp), connection.msgtype, data)


class BagWriter:
    """Write a ROS 2 bag (MCAP storage by default) from rosbags typestore messages.

    A path ending in ``.mcap`` (with ``storage='mcap'``) gives that single file: rosbags writes
    the bag directory in a temporary folder beside it and the ``.mcap`` file is moved into place
    on a clean close (its embedded rosbag2 metadata makes it self-describing). Any other path
    gives a rosbag2 directory there. An exception inside the ``with`` block leaves nothing
    behind.

    Example::

        with BagWriter('site.mcap') as bag:
            bag.add_topic('/lidar/points', 'sensor_msgs/msg/PointCloud2')
            bag.write('/lidar/points', stamp_ns, cloud)

    Args:
        path: Output path; must not exist unless ``overwrite``.
        storage: ``'mcap'`` or ``'sqlite3'``.
        overwrite: Replace an existing file or bag directory at ``path``.
        types: Typestore whose definitions are written (default:
            :func:`msg_adapters.jazzy_typestore`).
    """

    def __init__(self, path: str | os.PathLike[str], storage: str = 'mcap', *,
                 overwrite: bool = False, types: Typestore | None = None):
        self.path = Path(path)
        if storage not in ('mcap', 'sqlite3'):
            raise BagError(f"bag storage must be 'mcap' or 'sqlite3', got {storage!r}")
        self.single_file = self.path.suffix == '.mcap'
        if self.single_file and storage != 'mcap':
            raise BagError(f'{self.path}: a .mcap path needs storage mcap, not {storage}')
        self.storage = storage
        self.overwrite = overwrite
        self.types = types if types is not None else jazzy_typestore()
        self._writer: Any = None
        self._tmpdir: Path | None = None
        self._connections: dict[str, Connection] = {}

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:
        """Start writing (the context manager calls this)."""
        from rosbags.rosbag2 import StoragePlugin, Writer
        if self._writer is not None:
            raise BagError(f'bag {self.path} is already open')
        if self.path.exists() or self.path.is_symlink():
            if not self.overwrite:
                raise BagError(f'{self.path} exists already (not overwriting)')
        if not self.path.parent.is_dir():
            raise BagError(f'cannot write bag {self.path}: {self.path.parent} is not a directory')
        plugin = StoragePlugin.MCAP if self.storage == 'mcap' else StoragePlugin.SQLITE3
        target = self.path
        try:
            if self.single_file:
                # rosbags names the storage file after its directory: <stem>/<stem>.mcap, so the
                # file's embedded metadata already names the final file.
                self._tmpdir = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.',
                                                     dir=self.path.parent))
                target = self._tmpdir / self.path.stem
            elif self.overwrite and self.path.exists():
                self._tmpdir = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.',
                                                     dir=self.path.parent))
                target = self._tmpdir / self.path.name
            self._writer = Writer(target, version=9, storage_plugin=plugin)
            self._writer.open()
        except Exception as err:
            self._cleanup()
            raise BagError(f'cannot write bag {self.path}: {_describe(err)}') from err

    def add_topic(self, topic: str, msgtype: str, *, types: Typestore | None = None) -> None:
        """Declare a topic and its ROS 2 message type (``'sensor_msgs/msg/PointCloud2'``).

        Args:
            topic: Topic name.
            msgtype: ROS 2 type name.
            types: Typestore whose definition of ``msgtype`` is written for this topic (a bag
                being copied: :meth:`RawBag.types_of`); default the writer's.

        Raises:
            BagError: The bag is not open, the topic exists, or the type is unknown.
        """
        if self._writer is None:
            raise BagError(f'bag {self.path} is not open')
        if topic in self._connections:
            raise BagError(f'topic {topic} was added twice to {self.path}')
        store = types if types is not None else self.types
        if msgtype not in store.types:
            raise BagError(f'message type {msgtype} is unknown to the typestore')
        try:
            self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                                   typestore=store)
        except Exception as err:
            raise BagError(f'cannot add topic {topic} to {self.path}: {_describe(err)}') from err

    def write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialize a message (rosbags dataclass) to CDR and write it at a log time.

        Raises:
            BagError: Unknown topic, a message of another type, or unserializable content.
        """
        connection = self._connections.get(topic)
        if connection is None or self._writer is None:
            raise BagError(f'topic {topic} was not added to {self.path}')
        msgtype = getattr(msg, '__msgtype__', None)
        if msgtype is not None and msgtype != connection.msgtype:
            raise BagError(f'topic {topic} carries {connection.msgtype}, got a {msgtype}')
        try:
            data = self.types.serialize_cdr(msg, connection.msgtype)
            self._writer.write(connection, int(stamp_ns), data)
        except Exception as err:  # rosbags' SerdeError, struct errors on out-of-range values
            raise BagError(f'cannot write a {connection.msgtype} to {topic}: '
                           f'{_describe(err)}') from err

    def write_raw(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        """Write a message already serialized to CDR (as :class:`RawBag` yields them).

        Raises:
            BagError: Unknown topic or a failed write.
        """
        connection = self._connections.get(topic)
        if connection is None or self._writer is None:
            raise BagError(f'topic {topic} was not added to {self.path}')
        try:
            self._writer.write(connection, int(stamp_ns), data)
        except Exception as err:
            raise BagError(f'cannot write to {topic} of {self.path}: {_describe(err)}') from err

    def close(self) -> None:
        """Finish the bag and move it into place."""
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        try:
            writer.close()
            if self._tmpdir is not None:
                produced = Path(writer.path)
                source = produced / f'{produced.name}.mcap' if self.single_file else produced
                if self.path.is_dir() and not self.path.is_symlink():
                    shutil.rmtree(self.path)
                os.replace(source, self.path)
        except Exception as err:
            raise BagError(f'cannot finish bag {self.path}: {_describe(err)}') from err
        finally:
            self._cleanup()

    def abort(self) -> None:
        """Stop writing and remove what was written."""
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()
            except Exception:  # already failing: removing the output is what matters
                pass
            if self._tmpdir is None:
                shutil.rmtree(writer.path, ignore_errors=True)
        self._cleanup()

    def _cleanup(self) -> None:
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None
