"""Sensor data model shared by every stage (input, selection, references, backends).

Whatever the source (a ROS1/ROS2 bag, the built-in simulator, a test fixture), later stages see
the same objects:

* :class:`ImuSamples` — IMU stamps in ns, gyro in rad/s, accel in m/s² (units are fixed here;
  readers convert).
* :class:`LidarScan` — one sweep: points in the LiDAR frame with a per-point time offset from the
  scan's start stamp (so deskewing never depends on a driver's convention).
* :class:`Segment` — a time window of one sequence with its IMU samples and exteroceptive
  measurements (LiDAR scans today; other kinds of :class:`Measurement` later).

All stamps are int64 nanoseconds on the recording's clock. ``time_offset_s`` candidates follow
``t_imu = t_lidar + time_offset_s``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from l2calib.errors import DataError

NS_PER_S = 1_000_000_000
#: IMU kept after a segment's end (s): the last sweep (<= 0.2 s) plus a positive time offset.
IMU_MARGIN_AFTER_S = 0.5


@dataclass(frozen=True, eq=False)
class ImuSamples:
    """IMU measurements in SI units.

    Attributes:
        stamps_ns: ``[M]`` int64, strictly increasing.
        gyro_rad_s: ``[M, 3]`` float64 angular velocity of the IMU frame in the IMU frame (rad/s).
        accel_m_s2: ``[M, 3]`` float64 specific force in the IMU frame (m/s², ~+9.81 up at rest).
    """

    stamps_ns: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.stamps_ns).shape[0]
        g = np.asarray(self.gyro_rad_s, dtype=np.float64)
        a = np.asarray(self.accel_m_s2, dtype=np.float64)
        if g.shape != (n, 3) or a.shape != (n, 3):
            raise DataError(
                f"IMU arrays disagree: {n} stamps, gyro {g.shape}, accel {a.shape} "
                f"(expected [{n}, 3] each)"
            )
        object.__setattr__(self, "stamps_ns", np.asarray(self.stamps_ns, dtype=np.int64))
        object.__setattr__(self, "gyro_rad_s", g)
        object.__setattr__(self, "accel_m_s2", a)

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    def slice_time(self, start_ns: int, end_ns: int) -> ImuSamples:
        """Samples with ``start_ns <= stamp <= end_ns``."""
        keep = (self.stamps_ns >= start_ns) & (self.stamps_ns <= end_ns)
        return ImuSamples(self.stamps_ns[keep], self.gyro_rad_s[keep], self.accel_m_s2[keep])


@dataclass(frozen=True, eq=False)
class Measurement:
    """Base of exteroceptive measurements: anything with a reference stamp (ns)."""

    stamp_ns: int


@dataclass(frozen=True, eq=False)
class LidarScan(Measurement):
    """One LiDAR sweep in the LiDAR frame.

    Attributes:
        stamp_ns: Start of the sweep (time of the earliest point), int ns, LiDAR clock.
        points_lidar: ``[P, 3]`` float32 or float64 point coordinates in the LiDAR frame (m).
        offset_s: ``[P]`` float32/float64 time of each point after ``stamp_ns`` (s, >= 0).
        intensity: ``[P]`` float32 intensities, or ``None``.
        ring: ``[P]`` uint16 laser ring, or ``None`` (spinning LiDARs only).
    """

    points_lidar: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    offset_s: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.points_lidar)
        o = np.asarray(self.offset_s)
        if p.ndim != 2 or p.shape[1] != 3 or o.shape != (p.shape[0],):
            raise DataError(
                f"LiDAR scan at {self.stamp_ns} ns: points {p.shape} and per-point times "
                f"{o.shape} disagree (expected [P, 3] and [P])"
            )
        object.__setattr__(self, "stamp_ns", int(self.stamp_ns))

    def __len__(self) -> int:
        return int(self.points_lidar.shape[0])

    @property
    def end_stamp_ns(self) -> int:
        """Stamp of the latest point (ns)."""
        if len(self) == 0:
            return self.stamp_ns
        return self.stamp_ns + int(round(float(np.max(self.offset_s)) * NS_PER_S))

    @property
    def point_stamps_ns(self) -> np.ndarray:
        """``[P]`` int64 absolute stamp of every point."""
        return self.stamp_ns + np.round(np.asarray(self.offset_s, np.float64) * NS_PER_S).astype(
            np.int64
        )


@dataclass(frozen=True, eq=False)
class Segment:
    """A time window ``[start_ns, end_ns]`` of one sequence, ready for calibration.

    Attributes:
        name: Unique name, e.g. ``"seq0:12.0-27.0"``.
        sequence: Name of the sequence it was cut from.
        start_ns: Window start (ns).
        end_ns: Window end (ns).
        imu: IMU samples covering the window (with a margin of a few samples on each side).
        measurements: Exteroceptive measurements in time order (``LidarScan`` for LiDARs).
        meta: Free-form provenance (bag path, topics, sensor model, ...), JSON-serialisable.
    """

    name: str
    sequence: str
    start_ns: int
    end_ns: int
    imu: ImuSamples
    measurements: list[Measurement]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def scans(self) -> list[LidarScan]:
        """The measurements as LiDAR scans; :class:`DataError` if any is not a LiDAR scan."""
        out = [m for m in self.measurements if isinstance(m, LidarScan)]
        if len(out) != len(self.measurements):
            raise DataError(
                f"segment {self.name} holds non-LiDAR measurements",
                fix="use a backend made for this sensor kind",
            )
        return out

    @property
    def duration_s(self) -> float:
        """Window length in seconds."""
        return (self.end_ns - self.start_ns) / NS_PER_S


class ScanSource(Protocol):
    """Where a sequence's exteroceptive measurements come from (memory, a bag, ...).

    Implementations stream from disk when the data is large: only :meth:`load` materialises
    measurements, and only those of the requested window.
    """

    @property
    def stamps_ns(self) -> np.ndarray:
        """``[S]`` int64 stamps of all measurements (scan start times), increasing."""
        ...

    def load(self, start_ns: int, end_ns: int) -> list[Measurement]:
        """Measurements whose stamp lies in ``[start_ns, end_ns]``, in time order."""
        ...


@dataclass(frozen=True, eq=False)
class InMemoryScans:
    """A :class:`ScanSource` over a list of measurements already in memory."""

    measurements: list[Measurement]

    @property
    def stamps_ns(self) -> np.ndarray:
        """``[S]`` int64 stamps."""
        return np.array([m.stamp_ns for m in self.measurements], dtype=np.int64)

    def load(self, start_ns: int, end_ns: int) -> list[Measurement]:
        """Measurements with ``start_ns <= stamp <= end_ns``."""
        return [m for m in self.measurements if start_ns <= m.stamp_ns <= end_ns]


@dataclass(frozen=True, eq=False)
class Sequence:
    """One recording: IMU samples in memory, exteroceptive measurements behind a source.

    Attributes:
        name: Unique name (e.g. the bag's stem).
        imu: All IMU samples (small enough to hold: 1 h at 400 Hz is ~50 MB).
        scans: Source of the LiDAR scans (or other measurements), loaded per window.
        meta: Provenance (paths, topics, detected conventions), JSON-serialisable.
    """

    name: str
    imu: ImuSamples
    scans: ScanSource
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def start_ns(self) -> int:
        """Start of the time range covered by both IMU and scans."""
        return int(max(self.imu.stamps_ns[0], self.scans.stamps_ns[0]))

    @property
    def end_ns(self) -> int:
        """End of the time range covered by both IMU and scans."""
        return int(min(self.imu.stamps_ns[-1], self.scans.stamps_ns[-1]))

    def segment(self, start_ns: int | None = None, end_ns: int | None = None) -> Segment:
        """Cuts a :class:`Segment` (whole overlap by default), loading its measurements.

        The IMU samples keep a margin on each side so that propagation can start before the
        first scan and deskewing can reach past the last point: 0.1 s before ``start``, and
        :data:`IMU_MARGIN_AFTER_S` after ``end``, which bounds the scans' *start* stamps: the last
        scan's sweep (up to 0.2 s) and a positive time offset (its IMU is read at
        ``t_lidar + offset``) reach past it. With 0.1 s there, a +50 ms offset ran the last scan's
        propagation past the IMU (the truth's reward on a hand-held recording 0.908, not 0.96).
        """
        start = self.start_ns if start_ns is None else int(start_ns)
        end = self.end_ns if end_ns is None else int(end_ns)
        if end <= start:
            raise DataError(
                f"sequence {self.name}: empty window [{start}, {end}] ns",
                fix="choose a window inside the sequence's IMU and LiDAR overlap",
            )
        margin = NS_PER_S // 10
        after = int(IMU_MARGIN_AFTER_S * NS_PER_S)
        name = (
            f"{self.name}:{(start - self.start_ns) / NS_PER_S:.1f}-"
            f"{(end - self.start_ns) / NS_PER_S:.1f}"
        )
        return Segment(
            name=name,
            sequence=self.name,
            start_ns=start,
            end_ns=end,
            imu=self.imu.slice_time(start - margin, end + after),
            measurements=self.scans.load(start, end),
            meta=dict(self.meta),
        )
