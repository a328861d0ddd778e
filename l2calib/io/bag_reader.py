"""Streaming access to ROS1 and ROS2 bags through rosbags, with errors that name the file.

One :class:`Bag` is one recording: a ROS1 ``.bag`` file, a ROS2 bag directory (with
``metadata.yaml``), or a bare ROS2 storage file (``.db3`` or ``.mcap``). Messages are streamed
(:meth:`Bag.messages`), never loaded all at once. Livox ``CustomMsg`` types are registered for
ROS2 bags that carry no message definitions; ROS1 bags always embed theirs.

Example:
    >>> with Bag("run.bag") as bag:  # doctest: +SKIP
    ...     info = bag.require_topic("/imu", {IMU_TYPE}, "data.imu.topic")
    ...     for m in bag.messages(["/imu"]):
    ...         msg = bag.deserialize(m)
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from l2calib.errors import DataError, FormatError
from l2calib.io.rosmsgs import LIVOX_PACKAGES, register_livox_types

POINTCLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"
LIVOX_CUSTOM_TYPES = frozenset(f"{p}/msg/CustomMsg" for p in LIVOX_PACKAGES)
LIDAR_TYPES = frozenset({POINTCLOUD2_TYPE}) | LIVOX_CUSTOM_TYPES
IMU_TYPE = "sensor_msgs/msg/Imu"
NAVSAT_TYPE = "sensor_msgs/msg/NavSatFix"

_ROS2_SUFFIXES = (".db3", ".mcap")
# Everything rosbags (or the storage libraries below it) may raise on a damaged file.
_READ_ERRORS = (
    OSError,
    EOFError,
    ValueError,
    KeyError,
    IndexError,
    struct.error,
    sqlite3.Error,
    AssertionError,
    RuntimeError,
)


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes:
        name: Topic name.
        msgtype: Message type in rosbags' normalised form (``sensor_msgs/msg/Imu``).
        count: Number of messages.
    """

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagMessage:
    """One raw (serialised) message.

    Attributes:
        topic: Topic name.
        msgtype: Normalised message type.
        record_ns: Time the recorder received it (bag time, ns).
        raw: Serialised bytes (ROS1 or CDR).
    """

    topic: str
    msgtype: str
    record_ns: int
    raw: bytes


def _fix_for(path: Path) -> str:
    if path.suffix == ".bag":
        return (
            "the file looks truncated or damaged: run `rosbag reindex` on a copy "
            "(ROS1), or re-record it"
        )
    return (
        "the bag looks truncated or damaged: run `ros2 bag reindex` on the directory "
        "(ROS2), or re-record it"
    )


def default_typestore(ros2: bool) -> Any:
    """A typestore with the standard messages and Livox ``CustomMsg`` registered."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    return register_livox_types(store)


class Bag:
    """A recording opened for streaming (use as a context manager).

    Args:
        path: ROS1 ``.bag`` file, ROS2 bag directory, or ROS2 ``.db3``/``.mcap`` file.

    Raises:
        DataError: if the path does not exist or is not a bag.
        FormatError: if the bag is truncated, unindexed or otherwise unreadable.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise DataError(f"{self.path}: no such bag", fix="check the path")
        if self.path.is_dir():
            if not (self.path / "metadata.yaml").is_file():
                raise DataError(
                    f"{self.path}: a directory without metadata.yaml is not a ROS2 bag",
                    fix="pass the ROS2 bag directory (with metadata.yaml) or its .db3/.mcap file",
                )
        elif self.path.suffix not in (".bag", *_ROS2_SUFFIXES):
            raise DataError(
                f"{self.path}: unknown bag format {self.path.suffix!r}",
                fix="pass a ROS1 .bag file, a ROS2 bag directory, or a .db3/.mcap file",
            )
        self.is_ros2 = self.path.suffix != ".bag"
        self._reader: Any = None

    # ------------------------------------------------------------------ open / close
    def __enter__(self) -> Bag:
        from rosbags.highlevel import AnyReader

        try:
            reader = AnyReader([self.path], default_typestore=default_typestore(self.is_ros2))
            reader.open()
        except Exception as exc:  # rosbags raises several unrelated types
            raise self._format_error("cannot open", exc) from None
        self._reader = reader
        return self

    def __exit__(self, *exc: object) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            finally:
                self._reader = None

    def _format_error(self, what: str, exc: BaseException) -> FormatError:
        text = " ".join(str(a) for a in getattr(exc, "args", ()) if a) or type(exc).__name__
        return FormatError(f"{self.path}: {what} bag ({text})", fix=_fix_for(self.path))

    @property
    def reader(self) -> Any:
        """The open rosbags ``AnyReader``."""
        if self._reader is None:
            raise RuntimeError("Bag is not open; use it as a context manager")
        return self._reader

    # ------------------------------------------------------------------ metadata
    @property
    def topics(self) -> dict[str, TopicInfo]:
        """All topics with their normalised message types and counts."""
        out = {}
        for name, info in self.reader.topics.items():
            out[name] = TopicInfo(name, info.msgtype or "(mixed types)", int(info.msgcount))
        return out

    @property
    def start_ns(self) -> int:
        """Record time of the first message (ns)."""
        return int(self.reader.start_time)

    @property
    def end_ns(self) -> int:
        """Record time just after the last message (ns)."""
        return int(self.reader.end_time)

    def topics_of(self, msgtypes: Iterable[str]) -> list[TopicInfo]:
        """Topics whose type is one of ``msgtypes``, sorted by name."""
        wanted = set(msgtypes)
        return sorted(
            (t for t in self.topics.values() if t.msgtype in wanted), key=lambda t: t.name
        )

    def require_topic(self, topic: str, msgtypes: Iterable[str], setting: str) -> TopicInfo:
        """Checks that ``topic`` exists, has one of ``msgtypes`` and holds messages.

        Args:
            topic: Topic name.
            msgtypes: Accepted normalised types.
            setting: Recipe field that names this topic (quoted in the fix).

        Raises:
            DataError: naming the bag, the topic, and the topics that would fit.
        """
        msgtypes = set(msgtypes)
        kinds = " or ".join(sorted(msgtypes))
        candidates = [t.name for t in self.topics_of(msgtypes)]
        hint = (
            f"set {setting} to one of: {', '.join(candidates)}"
            if candidates
            else f"this bag has no {kinds} topic; record one"
        )
        info = self.topics.get(topic)
        if info is None:
            raise DataError(
                f"{self.path}: topic {topic!r} not found (looking for {kinds})", fix=hint
            )
        if info.msgtype not in msgtypes:
            raise DataError(
                f"{self.path}: topic {topic!r} has type {info.msgtype}, expected {kinds}",
                fix=hint,
            )
        if info.count == 0:
            raise DataError(f"{self.path}: topic {topic!r} has no messages", fix=hint)
        return info

    # ------------------------------------------------------------------ messages
    def messages(
        self, topics: Iterable[str], start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[BagMessage]:
        """Streams raw messages of ``topics`` in record-time order.

        Args:
            topics: Topic names (unknown names are ignored; check with :meth:`require_topic`).
            start_ns: Only messages recorded at or after this time (ns).
            stop_ns: Only messages recorded before this time (ns).

        Raises:
            FormatError: if the bag turns out to be damaged while reading.
        """
        wanted = set(topics)
        conns = [c for c in self.reader.connections if c.topic in wanted]
        if not conns:
            return
        it = self.reader.messages(connections=conns, start=start_ns, stop=stop_ns)
        while True:
            try:
                conn, record_ns, raw = next(it)
            except StopIteration:
                return
            except _READ_ERRORS as exc:
                raise self._format_error("damaged", exc) from None
            except Exception as exc:  # rosbags' own ReaderError types
                if type(exc).__module__.startswith("rosbags"):
                    raise self._format_error("damaged", exc) from None
                raise
            yield BagMessage(conn.topic, conn.msgtype, int(record_ns), bytes(raw))

    def deserialize(self, message: BagMessage) -> Any:
        """Deserialises one message with the bag's type definitions.

        Raises:
            FormatError: naming the topic if the bytes do not match the type.
        """
        try:
            return self.reader.deserialize(message.raw, message.msgtype)
        except Exception as exc:
            raise FormatError(
                f"{self.path}: message on {message.topic!r} at record time "
                f"{message.record_ns} ns does not decode as {message.msgtype} ({exc})",
                fix=_fix_for(self.path),
            ) from None


def header_stamp_ns(msg: Any) -> int:
    """``header.stamp`` of a deserialised message in ns."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
