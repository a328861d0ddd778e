"""``sensor_msgs/NavSatFix`` (GNSS/RTK) messages as arrays, for the RTK reference."""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from l2calib.errors import DataError
from l2calib.io.bag_reader import NAVSAT_TYPE, Bag, BagMessage, header_stamp_ns

# sensor_msgs/NavSatStatus.status
STATUS_NO_FIX, STATUS_FIX, STATUS_SBAS_FIX, STATUS_GBAS_FIX = -1, 0, 1, 2


@dataclass(frozen=True, eq=False)
class NavSatFixes:
    """GNSS fixes of one topic, sorted by stamp.

    Attributes:
        stamps_ns: ``[N]`` int64 header stamps.
        latitude_deg: ``[N]`` WGS84 latitude (deg).
        longitude_deg: ``[N]`` WGS84 longitude (deg).
        altitude_m: ``[N]`` height above the WGS84 ellipsoid (m).
        position_covariance_m2: ``[N, 3, 3]`` ENU covariance (m²) as the driver reports it.
        covariance_type: ``[N]`` uint8 (0 unknown, 1 approximated, 2 diagonal, 3 known).
        status: ``[N]`` int8 fix status (-1 no fix, 0 fix, 1 SBAS, 2 GBAS/RTK).
        service: ``[N]`` uint16 GNSS service bit mask.
    """

    stamps_ns: np.ndarray
    latitude_deg: np.ndarray
    longitude_deg: np.ndarray
    altitude_m: np.ndarray
    position_covariance_m2: np.ndarray
    covariance_type: np.ndarray
    status: np.ndarray
    service: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def valid(self) -> np.ndarray:
        """``[N]`` bool: a fix (status >= 0) with finite latitude, longitude and altitude."""
        return (
            (self.status >= STATUS_FIX)
            & np.isfinite(self.latitude_deg)
            & np.isfinite(self.longitude_deg)
            & np.isfinite(self.altitude_m)
        )


@dataclass
class NavSatTopicReader:
    """Collects one NavSatFix topic message by message."""

    bag: Bag
    topic: str
    _ints: array = field(default_factory=lambda: array("q"))
    _vals: array = field(default_factory=lambda: array("d"))

    def feed(self, message: BagMessage) -> None:
        """Adds one message."""
        m = self.bag.deserialize(message)
        self._ints.extend(
            (
                header_stamp_ns(m),
                int(m.position_covariance_type),
                int(m.status.status),
                int(m.status.service),
            )
        )
        self._vals.extend(
            (
                m.latitude,
                m.longitude,
                m.altitude,
                *np.asarray(m.position_covariance, dtype=np.float64).reshape(9),
            )
        )

    def finish(self) -> NavSatFixes:
        """The fixes, sorted by stamp."""
        ints = np.frombuffer(self._ints, dtype=np.int64).reshape(-1, 4)
        vals = np.frombuffer(self._vals, dtype=np.float64).reshape(-1, 12)
        o = np.argsort(ints[:, 0], kind="stable")
        ints, vals = ints[o], vals[o]
        return NavSatFixes(
            stamps_ns=ints[:, 0].copy(),
            latitude_deg=vals[:, 0].copy(),
            longitude_deg=vals[:, 1].copy(),
            altitude_m=vals[:, 2].copy(),
            position_covariance_m2=vals[:, 3:].reshape(-1, 3, 3).copy(),
            covariance_type=ints[:, 1].astype(np.uint8),
            status=ints[:, 2].astype(np.int8),
            service=ints[:, 3].astype(np.uint16),
        )


def read_navsat(path: str | Path, topic: str) -> NavSatFixes:
    """Reads every fix of a ``sensor_msgs/NavSatFix`` topic (streams the bag once).

    Raises:
        DataError: if the topic is missing, of another type, or has no valid fix.
    """
    with Bag(path) as bag:
        bag.require_topic(topic, {NAVSAT_TYPE}, "data.rtk_topic")
        reader = NavSatTopicReader(bag, topic)
        for message in bag.messages([topic]):
            reader.feed(message)
        fixes = reader.finish()
    if not fixes.valid.any():
        raise DataError(
            f"{path}: topic {topic!r} has no valid fix (all status -1 or NaN)",
            fix="record with GNSS reception, or use another reference",
        )
    return fixes
