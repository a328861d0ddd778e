"""Per-point time conventions of LiDAR drivers: detection, overrides and absolute point times.

Drivers disagree on almost everything (read in their public sources):

=================  ===============  =====================================  ===================
layout             field            values                                 header stamp
=================  ===============  =====================================  ===================
Ouster             ``t`` uint32     ns since the header stamp               scan start
Velodyne           ``time`` f32     s relative to the header stamp          start, or end
                                    (negative when stamped at the end)      (last packet)
Hesai              ``timestamp``    absolute s, float64                     start or end
RoboSense          ``timestamp``    absolute s, float64 (rslidar_sdk)       end by default
Livox PointCloud2  ``timestamp``    absolute ns, float64 (livox driver2)    first point
Livox CustomMsg    ``offset_time``  ns after ``timebase`` (absolute ns)     first point
=================  ===============  =====================================  ===================

Detection (:func:`detect_convention`) works on the first scans of a topic:

* **field**: the first of :data:`TIME_FIELDS` the cloud has (``data.lidar.time_field``
  overrides; ``"none"`` accepts clouds without per-point times).
* **unit**: the one that turns the median within-scan spread of the values closest to the scan
  period (median header-stamp interval); units are 1000x apart, so a 10x tolerance is safe.
* **reference**: *absolute* if the values (in s) sit within two periods of the header stamp,
  *relative* if they are within two periods of zero. Absolute values far from the header stamp
  (a LiDAR on its own clock) are kept relative to their scan and placed by the header stamp.
* **stamp position**: relative times ≥ 0 mean the header marks the start, ≤ 0 the end;
  absolute times say it directly (header closer to the first or the last point).

Relative times are offsets from the header stamp. If ``stamp_position`` is forced against
their sign (``end`` with times ≥ 0: offsets count from the scan start but the header marks the
end), they are shifted so that the latest (or earliest) point of the message lands on the
header stamp.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from l2calib.errors import DataError
from l2calib.io.pointcloud import RawCloud
from l2calib.recipe import LidarInput

TIME_FIELDS = ("t", "time", "timestamp", "time_stamp", "offset_time", "time_offset", "ts")
UNIT_SCALE_NS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
NO_TIME = "none"
DEFAULT_PERIOD_S = 0.1


@dataclass(frozen=True)
class TimeConvention:
    """How to turn a message's per-point time values into absolute stamps.

    Attributes:
        field: Time field name, or ``None`` (all points at the header stamp).
        unit: ``s``, ``ms``, ``us`` or ``ns``.
        reference: ``relative`` (to the header stamp) or ``absolute``.
        stamp_position: Whether the header stamp marks the scan ``start`` or ``end``.
        foreign_clock: Absolute times on another clock than the header (placed by the header).
        layout: Guessed driver layout (``ouster``, ``velodyne``, ``hesai/robosense``,
            ``livox``, ``livox-custom``, ``unknown``).
        evidence: What detection saw, for humans.
        detected: Names of the settings that were detected rather than given.
    """

    field: str | None
    unit: str = "ns"
    reference: str = "relative"
    stamp_position: str = "start"
    foreign_clock: bool = False
    layout: str = "unknown"
    evidence: str = ""
    detected: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """JSON-serialisable form."""
        d = asdict(self)
        d["detected"] = list(self.detected)
        return d

    def recipe_settings(self) -> dict[str, str | None]:
        """The ``data.lidar`` recipe fields that reproduce this convention."""
        return {
            "time_field": self.field or NO_TIME,
            "time_unit": self.unit,
            "time_reference": self.reference,
            "stamp_position": self.stamp_position,
        }


def guess_layout(fields: tuple[str, ...], custom: bool = False) -> str:
    """Driver family from the field names (informative only)."""
    f = {n.lower() for n in fields}
    if custom or {"offset_time", "tag", "line"} <= f:
        return "livox-custom"
    if "t" in f and ({"ambient", "reflectivity", "range"} & f):
        return "ouster"
    if "time" in f and "ring" in f:
        return "velodyne"
    if "timestamp" in f and {"tag", "line"} <= f:
        return "livox"
    if "timestamp" in f and "ring" in f:
        return "hesai/robosense"
    return "unknown"


def pick_time_field(fields: tuple[str, ...], cfg: LidarInput, where: str) -> str | None:
    """The per-point time field to read (``None`` for ``time_field: none``).

    Raises:
        DataError: if the recipe names a missing field, or none of :data:`TIME_FIELDS` exists.
    """
    if cfg.time_field is not None:
        if cfg.time_field.lower() == NO_TIME:
            return None
        if cfg.time_field not in fields:
            raise DataError(
                f"{where}: data.lidar.time_field {cfg.time_field!r} is not a field "
                f"of the cloud (fields: {', '.join(fields)})",
                fix="set data.lidar.time_field to one of the fields, or null to detect it",
            )
        return cfg.time_field
    lower = {n.lower(): n for n in fields}
    found = next((lower[c] for c in TIME_FIELDS if c in lower), None)
    if found is None:
        raise DataError(
            f"{where}: the cloud has no per-point time field (fields: {', '.join(fields)}); "
            "scans cannot be deskewed",
            fix="record per-point times (Livox: xfer_format 1 = CustomMsg, or livox_ros_driver2"
            "), or set data.lidar.time_field to the time field, or to 'none' to accept scans "
            "without them",
        )
    return found


def squared_range(xyz: np.ndarray) -> np.ndarray:
    """``[P]`` float64 |p|²; NaN/inf exactly where a coordinate is not finite."""
    x = xyz.astype(np.float64, copy=False)
    # One pass instead of isfinite(...).all(axis=1) and any(... != 0, axis=1): numpy reduces
    # over a length-3 axis slowly, and |p|² carries both facts (non-finite, zero).
    return np.einsum("ij,ij->i", x, x)


def valid_mask(cloud: RawCloud, r2: np.ndarray | None = None) -> np.ndarray:
    """``[P]`` bool: finite, non-zero coordinates and a finite time."""
    r2 = squared_range(cloud.xyz) if r2 is None else r2
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r2) & (r2 > 0)
    if cloud.time_raw is not None and cloud.time_raw.dtype.kind == "f":
        ok &= np.isfinite(cloud.time_raw)
    return ok


def _median_period_s(clouds: list[RawCloud]) -> float:
    h = np.array([c.header_ns for c in clouds], dtype=np.int64)
    d = np.diff(np.sort(h)) / 1e9
    d = d[d > 0]
    return float(np.median(d)) if d.size else DEFAULT_PERIOD_S


def detect_convention(clouds: list[RawCloud], cfg: LidarInput, where: str) -> TimeConvention:
    """Detects the time convention from the first messages of a topic (overrides win).

    Args:
        clouds: A few consecutive messages (non-empty), read with their time field.
        cfg: The recipe's LiDAR input (``time_unit``, ``time_reference``, ``stamp_position``).
        where: ``"<bag>: <topic>"`` for messages.

    Raises:
        DataError: when a setting cannot be inferred; the fix names the recipe field.
    """
    first = clouds[0]
    layout = guess_layout(first.fields)
    if first.time_field is None:
        return TimeConvention(
            None,
            "s",
            "relative",
            "start",
            False,
            layout,
            "no per-point time field: all points at the header stamp",
        )
    period = _median_period_s(clouds)
    stats = []
    for c in clouds:
        v = c.time_raw[valid_mask(c)]
        if v.size:
            stats.append((c.header_ns / 1e9, float(v.min()), float(v.max()), float(np.median(v))))
    if not stats:
        raise DataError(
            f"{where}: the first {len(clouds)} scans have no valid points",
            fix="check the LiDAR topic (all points NaN or zero)",
        )
    h, vmin, vmax, vmed = (np.array(x) for x in zip(*stats, strict=True))
    detected = []
    spread = float(np.median(vmax - vmin))
    unit, reference = cfg.time_unit, cfg.time_reference
    if layout == "livox-custom":  # timebase + offset_time: absolute ns by definition
        unit, reference = "ns", "absolute"
    if unit == "auto":
        detected.append("time_unit")
        if spread <= 0:
            raise DataError(
                f"{where}: field {first.time_field!r} has the same value for every "
                "point of a scan; its unit cannot be inferred",
                fix="set data.lidar.time_unit (s, ms, us, ns), or time_field: none",
            )
        errs = {u: abs(np.log10(spread * s / 1e9 / period)) for u, s in UNIT_SCALE_NS.items()}
        unit = min(errs, key=errs.get)
        if errs[unit] > 1.0:
            raise DataError(
                f"{where}: the per-scan spread of {first.time_field!r} ({spread:g}) fits no unit "
                f"for a {period * 1e3:.0f} ms scan period",
                fix="set data.lidar.time_unit (s, ms, us, ns) and data.lidar.time_reference",
            )
    to_s = UNIT_SCALE_NS[unit] / 1e9
    near_header = float(np.median(np.abs(vmed * to_s - h))) <= 2 * period
    near_zero = float(np.median(np.abs(vmed * to_s))) <= 2 * period
    foreign = False
    if reference == "auto":
        detected.append("time_reference")
        reference = "relative" if near_zero else "absolute"
    if reference == "absolute" and not near_header:
        foreign = True
    position = cfg.stamp_position
    if position == "auto":
        detected.append("stamp_position")
        if reference == "relative":
            position = "end" if float(np.median(vmed)) < 0 else "start"
        elif foreign:
            position = "start"
        else:
            d_start = float(np.median(np.abs(h - vmin * to_s)))
            d_end = float(np.median(np.abs(h - vmax * to_s)))
            position = "start" if d_start <= d_end else "end"
    evidence = (
        f"{first.time_field} ({first.time_dtype}): per-scan spread {spread:g} "
        f"-> {spread * to_s * 1e3:.1f} ms for a {period * 1e3:.1f} ms period; values "
        f"{'near the header stamp' if near_header else 'near 0' if near_zero else 'far'}"
        f" (median {float(np.median(vmed)):.6g})"
    )
    if foreign:
        offset = float(np.median(vmed * to_s - h))
        evidence += f"; absolute times {offset:+.3f} s from the header stamps (another clock)"
    return TimeConvention(
        first.time_field, unit, reference, position, foreign, layout, evidence, tuple(detected)
    )


def point_times_ns(cloud: RawCloud, conv: TimeConvention) -> np.ndarray:
    """``[P]`` int64 absolute stamp of every point (LiDAR clock) under ``conv``."""
    n = len(cloud)
    h = np.int64(cloud.header_ns)
    if cloud.time_raw is None or conv.field is None:
        return np.full(n, h, dtype=np.int64)
    raw = cloud.time_raw
    finite = np.isfinite(raw) if raw.dtype.kind == "f" else np.ones(n, bool)
    if raw.dtype.kind in "iu" and conv.unit == "ns":
        t = raw.astype(np.int64)
    else:
        scaled = np.where(finite, raw.astype(np.float64), 0.0) * UNIT_SCALE_NS[conv.unit]
        t = np.round(scaled).astype(np.int64)
    if conv.reference == "absolute" and not conv.foreign_clock:
        return t
    if not finite.any():
        return np.full(n, h, dtype=np.int64)
    lo, hi = t[finite].min(), t[finite].max()
    if conv.foreign_clock:  # absolute on another clock: keep spacing, place by the header
        return h + (t - (lo if conv.stamp_position == "start" else hi))
    if conv.stamp_position == "end" and lo >= 0 and hi > 0:
        return h + (t - hi)  # offsets from the scan start, header at the end
    if conv.stamp_position == "start" and hi <= 0 and lo < 0:
        return h + (t - lo)  # offsets from the scan end, header at the start
    return h + t
