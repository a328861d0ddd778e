"""LiDAR messages to :class:`~l2calib.data.LidarScan`: decoding, filtering and a streaming index.

A point is kept if its coordinates are finite and not all zero (organised clouds mark missing
returns with NaN or zeros), its time is finite, and its range lies in
``[min_range_m, max_range_m]``; dropped points lose their times with them. A scan's stamp is the
time of its earliest kept point, its ``offset_s`` the kept points' times after it.

:class:`LidarTopicReader` is fed one message at a time (so a bag is read in one pass): it buffers
the first few messages to detect the time convention, then keeps only per-scan numbers (stamps,
counts, time ranges) — never the points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from l2calib.data import NS_PER_S, LidarScan
from l2calib.errors import DataError
from l2calib.io.bag_reader import LIVOX_CUSTOM_TYPES, Bag, BagMessage, header_stamp_ns
from l2calib.io.lidar_conventions import (
    TimeConvention,
    detect_convention,
    pick_time_field,
    point_times_ns,
    squared_range,
    valid_mask,
)
from l2calib.io.pointcloud import (
    RawCloud,
    parse_livox_custom,
    raw_from_livox_custom,
    raw_from_pointcloud2,
)
from l2calib.recipe import LidarInput

PROBE_MESSAGES = 10  # scans with points used to detect the time convention
MAX_PROBE_MESSAGES = 200  # give up detecting after this many (mostly empty) scans


def decode_lidar(bag: Bag, message: BagMessage, time_field: str | None) -> RawCloud:
    """Decodes one LiDAR message (PointCloud2 or Livox CustomMsg) into a :class:`RawCloud`."""
    where = f"{bag.path}: {message.topic}"
    if message.msgtype in LIVOX_CUSTOM_TYPES:
        return raw_from_livox_custom(
            message.raw, bag.is_ros2, lambda raw: bag.deserialize(message), header_stamp_ns
        )
    msg = bag.deserialize(message)
    return raw_from_pointcloud2(msg, header_stamp_ns(msg), time_field, where)


@dataclass(frozen=True)
class CloudStats:
    """Numbers about one message (what ``inspect`` reports and the scan index keeps).

    Attributes:
        stamp_ns: Earliest kept point (ns), or -1 if nothing was kept.
        end_ns: Latest kept point (ns), or -1.
        n_total: Points in the message.
        n_nan: Points with non-finite coordinates or time.
        n_zero: Points at (0, 0, 0) (missing returns of organised clouds).
        n_range: Valid points outside the range limits.
        n_kept: Points in the scan.
        rel_min_s: Earliest valid point minus the header stamp (s); NaN if none.
        rel_max_s: Latest valid point minus the header stamp (s); NaN if none.
    """

    stamp_ns: int
    end_ns: int
    n_total: int
    n_nan: int
    n_zero: int
    n_range: int
    n_kept: int
    rel_min_s: float
    rel_max_s: float


def to_scan(
    cloud: RawCloud,
    conv: TimeConvention,
    min_range_m: float,
    max_range_m: float,
    stats_only: bool = False,
) -> tuple[LidarScan | None, CloudStats]:
    """Filters a message's points and stamps them (``None`` if no point survives).

    Args:
        cloud: The decoded message.
        conv: Its time convention.
        min_range_m: Points closer than this are dropped (m).
        max_range_m: Points farther than this are dropped (m).
        stats_only: Skip building the scan (indexing needs only the numbers).

    Returns:
        The scan (points float32 in the LiDAR frame, ``offset_s`` float64) and its stats.
    """
    t = point_times_ns(cloud, conv)
    xyz = cloud.xyz
    r2 = squared_range(xyz)
    finite = np.isfinite(r2)
    valid = valid_mask(cloud, r2)
    n_nan = int(np.count_nonzero(~finite))
    if cloud.time_raw is not None and cloud.time_raw.dtype.kind == "f":
        n_nan += int(np.count_nonzero(finite & ~np.isfinite(cloud.time_raw)))
    n_zero = int(np.count_nonzero(r2 == 0))
    with np.errstate(invalid="ignore"):
        keep = valid & (r2 >= min_range_m**2) & (r2 <= max_range_m**2)
    n_kept = int(np.count_nonzero(keep))
    if valid.any():
        rel = t[valid] - cloud.header_ns
        rel_min, rel_max = rel.min() / NS_PER_S, rel.max() / NS_PER_S
    else:
        rel_min = rel_max = float("nan")
    stats = dict(
        n_total=len(cloud),
        n_nan=n_nan,
        n_zero=n_zero,
        n_range=int(np.count_nonzero(valid)) - n_kept,
        n_kept=n_kept,
        rel_min_s=float(rel_min),
        rel_max_s=float(rel_max),
    )
    if n_kept == 0:
        return None, CloudStats(-1, -1, **stats)
    tk = t[keep]
    stamp = int(tk.min())
    if stats_only:
        return None, CloudStats(stamp, int(tk.max()), **stats)
    scan = LidarScan(
        stamp_ns=stamp,
        points_lidar=xyz[keep],
        offset_s=(tk - stamp).astype(np.float64) / NS_PER_S,
        intensity=None if cloud.intensity is None else cloud.intensity[keep],
        ring=None if cloud.ring is None else cloud.ring[keep],
    )
    return scan, CloudStats(stamp, int(tk.max()), **stats)


@dataclass
class LidarTopicReader:
    """Streams one LiDAR topic: detects its time convention, then indexes every scan.

    Args:
        bag: The open bag.
        topic: LiDAR topic.
        cfg: Recipe LiDAR input (overrides and range limits).
        strict: Raise detection errors (``True``) or record them in :attr:`errors`.

    Attributes:
        convention: The time convention once known.
        header_ns, record_ns: ``[S]`` header and record stamps of every message.
        stats: Per-message :class:`CloudStats` (only after the convention is known).
        errors: Detection/decoding problems (``strict=False`` only).
    """

    bag: Bag
    topic: str
    cfg: LidarInput
    strict: bool = True
    convention: TimeConvention | None = None
    header_ns: list[int] = field(default_factory=list)
    record_ns: list[int] = field(default_factory=list)
    stats: list[CloudStats] = field(default_factory=list)
    errors: list[DataError] = field(default_factory=list)
    _time_field: str | None = None
    _buffer: list[RawCloud | CloudStats] = field(default_factory=list)
    _n_probe: int = 0
    _failed: bool = False

    def _fail(self, exc: DataError) -> None:
        if self.strict:
            raise exc
        self.errors.append(exc)
        self._failed = True
        self._buffer.clear()

    def feed(self, message: BagMessage) -> None:
        """Adds one message of this topic."""
        self.record_ns.append(message.record_ns)
        if self._failed:  # keep the stamps for statistics, skip the points
            self.header_ns.append(self._header_only(message))
            return
        try:
            if not self.record_ns[:-1]:  # first message: choose the time field
                if message.msgtype in LIVOX_CUSTOM_TYPES:
                    self._time_field = "offset_time"
                else:
                    msg = self.bag.deserialize(message)
                    fields = tuple(f.name for f in msg.fields)
                    self._time_field = pick_time_field(
                        fields, self.cfg, f"{self.bag.path}: {self.topic}"
                    )
            cloud = decode_lidar(self.bag, message, self._time_field)
        except DataError as exc:
            self._fail(exc)
            self.header_ns.append(self._header_only(message))
            return
        self.header_ns.append(cloud.header_ns)
        if self.convention is not None:
            self._index(cloud)
            return
        if valid_mask(cloud).any():
            self._buffer.append(cloud)
            self._n_probe += 1
        else:  # keep only its numbers: detection needs points, the index needs its place
            self._buffer.append(
                to_scan(
                    cloud,
                    TimeConvention(None),
                    self.cfg.min_range_m,
                    self.cfg.max_range_m,
                    stats_only=True,
                )[1]
            )
        if self._n_probe >= PROBE_MESSAGES or len(self._buffer) >= MAX_PROBE_MESSAGES:
            self._detect()

    def _header_only(self, message: BagMessage) -> int:
        if message.msgtype in LIVOX_CUSTOM_TYPES:
            parsed = parse_livox_custom(message.raw, self.bag.is_ros2)
            if parsed is not None:
                return parsed[0]
        return header_stamp_ns(self.bag.deserialize(message))

    def _detect(self) -> None:
        where = f"{self.bag.path}: {self.topic}"
        usable = [c for c in self._buffer if isinstance(c, RawCloud)]
        try:
            if not usable:
                raise DataError(
                    f"{where}: none of the first {len(self._buffer)} scans has a "
                    "valid point (all NaN or zero)",
                    fix="check the LiDAR topic (blocked or broken sensor?)",
                )
            self.convention = detect_convention(usable, self.cfg, where)
        except DataError as exc:
            self._fail(exc)
            return
        buffered, self._buffer = self._buffer, []
        for item in buffered:
            if isinstance(item, CloudStats):
                self.stats.append(item)
            else:
                self._index(item)

    def _index(self, cloud: RawCloud) -> None:
        _, stats = to_scan(
            cloud, self.convention, self.cfg.min_range_m, self.cfg.max_range_m, stats_only=True
        )
        self.stats.append(stats)

    def finish(self) -> None:
        """Call after the last message (detects on fewer messages if the topic is short)."""
        if self.convention is None and self._buffer and not self._failed:
            self._detect()

    def scan_index(self) -> dict[str, np.ndarray]:
        """Index arrays over the messages that kept points, sorted by stamp.

        Keys: ``stamp_ns``, ``end_ns``, ``record_ns``, ``header_ns``, ``n_points``, and
        ``empty_before``: how many empty messages (no valid point: all NaN, zero or out of
        range) arrived right before each kept scan, since the previous kept one.
        """
        keep, empty_before, run = [], [], 0
        for i, s in enumerate(self.stats):
            if s.n_kept > 0:
                keep.append(i)
                empty_before.append(run)
                run = 0
            else:
                run += 1
        out = {
            "stamp_ns": np.array([self.stats[i].stamp_ns for i in keep], dtype=np.int64),
            "end_ns": np.array([self.stats[i].end_ns for i in keep], dtype=np.int64),
            "record_ns": np.array([self.record_ns[i] for i in keep], dtype=np.int64),
            "header_ns": np.array([self.header_ns[i] for i in keep], dtype=np.int64),
            "n_points": np.array([self.stats[i].n_kept for i in keep], dtype=np.int64),
            "empty_before": np.array(empty_before, dtype=np.int64),
        }
        order = np.argsort(out["stamp_ns"], kind="stable")
        return {k: v[order] for k, v in out.items()}
