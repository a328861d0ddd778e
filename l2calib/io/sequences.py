"""Bags to :class:`~l2calib.data.Sequence` objects: one pass per bag, scans streamed on demand.

:func:`open_sequences` reads each bag once: the IMU topic into memory (converted to SI), and for
the LiDAR topic only an index (per-scan stamp, record time, point count). :class:`BagScans`
re-reads just the messages of a requested window when a :class:`~l2calib.data.Segment` is cut,
so memory stays bounded by the window, not the bag.

Each bag is one sequence (named after the file or directory); split recordings are separate
sequences. Warnings (unconfirmed units, gaps, repaired stamps) go to the ``l2calib`` logger and
to ``sequence.meta["warnings"]``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from l2calib.data import NS_PER_S, LidarScan, Sequence
from l2calib.errors import DataError
from l2calib.io.bag_reader import IMU_TYPE, LIDAR_TYPES, Bag, BagMessage
from l2calib.io.imu_reader import ImuTopicReader, detect_units, to_imu_samples
from l2calib.io.lidar_conventions import TimeConvention
from l2calib.io.lidar_scans import LidarTopicReader, decode_lidar, to_scan
from l2calib.io.stamps import MAX_BRIDGED_EMPTY_SCANS, lidar_gaps, stamp_stats
from l2calib.recipe import DataConfig

log = logging.getLogger("l2calib.io")
log.addHandler(logging.NullHandler())  # the CLI prints meta["warnings"] itself
IMU_GAP_FACTOR, IMU_MIN_GAP_S = 5.0, 0.02
LIDAR_GAP_FACTOR = 1.8


@dataclass(frozen=True, eq=False)
class BagScans:
    """A :class:`~l2calib.data.ScanSource` that streams one LiDAR topic of a bag.

    Attributes:
        path: The bag.
        topic: LiDAR topic.
        convention: Per-point time convention used to stamp the points.
        min_range_m, max_range_m: Range limits applied to every point.
        index: ``stamp_ns``, ``end_ns``, ``record_ns``, ``header_ns``, ``n_points``,
            ``empty_before`` arrays of the scans that kept points, sorted by stamp.
    """

    path: str
    topic: str
    convention: TimeConvention
    min_range_m: float
    max_range_m: float
    index: dict[str, np.ndarray]

    @property
    def stamps_ns(self) -> np.ndarray:
        """``[S]`` int64 scan stamps (earliest kept point), increasing."""
        return self.index["stamp_ns"]

    @property
    def empty_before(self) -> np.ndarray | None:
        """``[S]`` empty messages (dropped on reading) right before each kept scan."""
        return self.index.get("empty_before")

    def load(self, start_ns: int, end_ns: int) -> list[LidarScan]:
        """Scans whose stamp lies in ``[start_ns, end_ns]``, read from the bag, in time order."""
        st = self.stamps_ns
        sel = (st >= start_ns) & (st <= end_ns)
        if not sel.any():
            return []
        rec = self.index["record_ns"][sel]
        out = []
        with Bag(self.path) as bag:
            for message in bag.messages([self.topic], int(rec.min()), int(rec.max()) + 1):
                cloud = decode_lidar(bag, message, self.convention.field)
                scan, _ = to_scan(cloud, self.convention, self.min_range_m, self.max_range_m)
                if scan is not None and start_ns <= scan.stamp_ns <= end_ns:
                    out.append(scan)
        out.sort(key=lambda s: s.stamp_ns)
        return out


def resolve_topic(
    bag: Bag, topic: str, msgtypes: frozenset[str] | set[str], setting: str, auto: bool
) -> str:
    """The configured topic, or with ``auto`` the bag's only topic of that type if it is missing.

    Raises:
        DataError: missing topic / wrong type / several candidates (names them all).
    """
    if auto and topic not in bag.topics:
        found = bag.topics_of(msgtypes)
        if len(found) == 1:
            return found[0].name
        if len(found) > 1:
            raise DataError(
                f"{bag.path}: several candidate topics for {setting}: "
                f"{', '.join(t.name for t in found)}",
                fix=f"choose one with {setting} (or --{setting.split('.')[-2]}-topic)",
            )
    return bag.require_topic(topic, msgtypes, setting).name


def _track(messages, total: int, label: str, enabled: bool):
    if not enabled:
        yield from messages
        return
    from rich.progress import Progress

    with Progress(transient=True) as progress:
        task = progress.add_task(label, total=total)
        for i, m in enumerate(messages):
            yield m
            if i % 200 == 0:
                progress.update(task, completed=i)


def open_sequence(
    path: str | Path,
    data: DataConfig | None = None,
    *,
    name: str | None = None,
    auto_topics: bool = False,
    progress: bool = False,
) -> Sequence:
    """Opens one bag as a :class:`~l2calib.data.Sequence` (one streaming pass).

    Args:
        path: ROS1 ``.bag``, ROS2 bag directory, or ``.db3``/``.mcap`` file.
        data: Topics, units and time conventions (recipe ``data`` section; default: detect).
        name: Sequence name (default: the file or directory stem).
        auto_topics: If a configured topic is missing, use the bag's only topic of that type.
        progress: Show a rich progress bar.

    Raises:
        DataError: missing/wrong topics, undetectable conventions, unusable IMU or LiDAR data,
            or LiDAR and IMU time ranges that do not overlap.
        FormatError: truncated or corrupt bag.
    """
    data = data or DataConfig()
    path = Path(path)
    warnings: list[str] = []
    with Bag(path) as bag:
        lidar_topic = resolve_topic(
            bag, data.lidar.topic, LIDAR_TYPES, "data.lidar.topic", auto_topics
        )
        imu_topic = resolve_topic(bag, data.imu.topic, {IMU_TYPE}, "data.imu.topic", auto_topics)
        lidar = LidarTopicReader(bag, lidar_topic, data.lidar, strict=True)
        imu = ImuTopicReader(bag, imu_topic)
        total = bag.topics[lidar_topic].count + bag.topics[imu_topic].count
        message: BagMessage
        for message in _track(
            bag.messages([lidar_topic, imu_topic]), total, f"reading {path.name}", progress
        ):
            (lidar if message.topic == lidar_topic else imu).feed(message)
        lidar.finish()
        raw_imu = imu.finish()
    where_imu, where_lidar = f"{path}: {imu_topic}", f"{path}: {lidar_topic}"
    units = detect_units(raw_imu, data.imu)
    if not units.accel_confirmed:
        raise DataError(
            f"{where_imu}: accelerometer unit unclear: {units.accel_evidence}",
            fix="set data.imu.accel_unit (m/s^2 or g); check the IMU driver",
        )
    if not units.gyro_confirmed:
        warnings.append(
            f"{where_imu}: gyro unit assumed {units.gyro_unit} ({units.gyro_evidence})"
            "; set data.imu.gyro_unit to confirm"
        )
    imu_samples, repaired = to_imu_samples(raw_imu, units, where_imu)
    if repaired["reordered"] or repaired["duplicates"] or repaired["non_finite"]:
        warnings.append(f"{where_imu}: repaired stamps/values {repaired}")
    index = lidar.scan_index()
    if index["stamp_ns"].size == 0:
        raise DataError(
            f"{where_lidar}: no scan has valid points (all NaN, zero, or outside "
            f"[{data.lidar.min_range_m}, {data.lidar.max_range_m}] m)",
            fix="check the LiDAR topic and data.lidar.min_range_m/max_range_m",
        )
    empty = len(lidar.stats) - index["stamp_ns"].size
    if empty:
        warnings.append(
            f"{where_lidar}: {empty} empty scan(s) skipped (no valid point: all NaN, zero or "
            f"out of range); up to {MAX_BRIDGED_EMPTY_SCANS} in a row are bridged, longer runs "
            "are gaps the selection avoids"
        )
    lo = max(int(imu_samples.stamps_ns[0]), int(index["stamp_ns"][0]))
    hi = min(int(imu_samples.stamps_ns[-1]), int(index["end_ns"][-1]))
    if hi <= lo:
        raise DataError(
            f"{path}: LiDAR ({lidar_topic}) and IMU ({imu_topic}) time ranges do not overlap: "
            f"LiDAR {_span(index['stamp_ns'][0], index['end_ns'][-1])}, "
            f"IMU {_span(imu_samples.stamps_ns[0], imu_samples.stamps_ns[-1])}",
            fix="both sensors must be stamped on the same clock; check the drivers' time "
            "sources (PTP/GPS vs system time) or record both in the same bag",
        )
    imu_st = stamp_stats(imu_samples.stamps_ns, None, IMU_GAP_FACTOR, IMU_MIN_GAP_S)
    if imu_st.gaps_ns:
        a, b = max(imu_st.gaps_ns, key=lambda g: g[1] - g[0])
        warnings.append(
            f"{path}: IMU has {len(imu_st.gaps_ns)} gap(s) longer than "
            f"{imu_st.gap_threshold_s:.3f} s (longest {imu_st.max_gap_s:.3f} s, at "
            f"{(a - lo) / NS_PER_S:.3f} s, stamp {a / NS_PER_S:.3f} s, on {imu_topic})"
        )
    lidar_gaps_ns = lidar_gaps(index["stamp_ns"], index["empty_before"], LIDAR_GAP_FACTOR)
    if lidar_gaps_ns:
        longest = max((b - a) / NS_PER_S for a, b in lidar_gaps_ns)
        warnings.append(
            f"{where_lidar}: LiDAR has {len(lidar_gaps_ns)} gap(s) longer than "
            f"{LIDAR_GAP_FACTOR:g} scan intervals (longest {longest:.3f} s)"
        )
    for w in warnings:
        log.warning(w)
    meta = {
        "source": "bag",
        "path": str(path),
        "lidar_topic": lidar_topic,
        "imu_topic": imu_topic,
        "time_convention": lidar.convention.as_dict(),
        "imu_units": units.as_dict(),
        "imu_gaps_ns": [list(g) for g in imu_st.gaps_ns],
        "lidar_gaps_ns": [list(g) for g in lidar_gaps_ns],
        "empty_scans": int(empty),
        "warnings": warnings,
    }
    scans = BagScans(
        str(path),
        lidar_topic,
        lidar.convention,
        data.lidar.min_range_m,
        data.lidar.max_range_m,
        index,
    )
    return Sequence(name or _stem(path), imu_samples, scans, meta)


def _span(a: int, b: int) -> str:
    return f"[{a / NS_PER_S:.3f}, {b / NS_PER_S:.3f}] s"


def _stem(path: Path) -> str:
    return path.name if path.is_dir() else path.stem


def open_sequences(
    paths: Seq[str | Path],
    data: DataConfig | None = None,
    *,
    auto_topics: bool = False,
    progress: bool = False,
) -> list[Sequence]:
    """Opens several bags, one :class:`~l2calib.data.Sequence` each (names made unique).

    See :func:`open_sequence` for arguments and errors.
    """
    if not paths:
        raise DataError("no bag given", fix="pass one or more bag paths")
    names: dict[str, int] = {}
    out = []
    for p in paths:
        stem = _stem(Path(p))
        names[stem] = names.get(stem, 0) + 1
        name = stem if names[stem] == 1 else f"{stem}-{names[stem]}"
        out.append(open_sequence(p, data, name=name, auto_topics=auto_topics, progress=progress))
    return out
