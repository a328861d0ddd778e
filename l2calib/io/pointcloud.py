"""Decoding LiDAR messages into flat arrays: ``sensor_msgs/PointCloud2`` and Livox ``CustomMsg``.

PointCloud2 data is viewed through a numpy structured dtype built from the message's
``fields`` (every ``PointField`` datatype, ``count`` > 1, padding up to ``point_step``, padded
rows via ``row_step``, ``is_bigendian``), so decoding is a view plus one copy per used field.

Livox ``CustomMsg`` is parsed straight from its serialised bytes: rosbags builds one Python
object per point, about 3 ms per 1,000 points, which would make an hour of Livox data take half
an hour to read. The byte layout is fixed (ROS1 packed, 19 bytes per point; CDR aligned, 20
bytes per point); anything that does not parse exactly falls back to rosbags.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from l2calib.errors import FormatError

# sensor_msgs/PointField datatype constants -> numpy type codes.
POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
INTENSITY_FIELDS = ("intensity", "reflectivity", "i")
RING_FIELDS = ("ring", "line", "channel", "laser_id")


@dataclass(frozen=True, eq=False)
class RawCloud:
    """One LiDAR message as flat arrays, before time conventions and filtering.

    Attributes:
        header_ns: ``header.stamp`` (ns).
        xyz: ``[P, 3]`` float32 coordinates in the LiDAR frame, invalid points included.
        time_raw: ``[P]`` per-point time values as stored (float64, or int64 for integer
            fields), or ``None`` without a time field.
        time_field: Name of the time field used, or ``None``.
        time_dtype: Numpy type code of the stored time field (``"u4"``, ``"f8"``, ...).
        intensity: ``[P]`` float32 or ``None``.
        ring: ``[P]`` uint16 or ``None``.
        fields: Names of all fields of the message.
    """

    header_ns: int
    xyz: np.ndarray
    time_raw: np.ndarray | None
    time_field: str | None
    time_dtype: str
    intensity: np.ndarray | None
    ring: np.ndarray | None
    fields: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def pointcloud2_dtype(msg: Any, where: str) -> np.dtype:
    """Numpy structured dtype of a PointCloud2's points (itemsize = ``point_step``).

    Raises:
        FormatError: for unknown datatypes, fields past ``point_step`` or duplicate names.
    """
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    step = int(msg.point_step)
    for f in msg.fields:
        code = POINTFIELD_DTYPES.get(int(f.datatype))
        if code is None:
            raise FormatError(
                f"{where}: field {f.name!r} has unknown PointField datatype {f.datatype}",
                fix="the driver writes a non-standard cloud",
            )
        count = max(int(f.count), 1)
        base = np.dtype(order + code)
        if f.name in names:
            raise FormatError(f"{where}: field {f.name!r} appears twice in the cloud")
        if int(f.offset) + base.itemsize * count > step:
            raise FormatError(
                f"{where}: field {f.name!r} (offset {f.offset}) ends past point_step {step}",
                fix="the cloud's layout is inconsistent",
            )
        names.append(f.name)
        formats.append(base if count == 1 else (base, (count,)))
        offsets.append(int(f.offset))
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})


def decode_pointcloud2(msg: Any, where: str) -> np.ndarray:
    """``[height * width]`` structured array of a PointCloud2's points (row-major).

    Raises:
        FormatError: if ``point_step``/``row_step`` do not fit the data (truncated message).
    """
    height, width, step = int(msg.height), int(msg.width), int(msg.point_step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if height * width == 0:
        return np.zeros(0, dtype=pointcloud2_dtype(msg, where) if step else np.float32)
    if step <= 0:
        raise FormatError(f"{where}: point_step is {step}")
    dtype = pointcloud2_dtype(msg, where)
    row_step = int(msg.row_step) or width * step
    need = (height - 1) * row_step + width * step
    if row_step < width * step or data.size < need:
        raise FormatError(
            f"{where}: cloud data holds {data.size} bytes but {height}x{width} points of "
            f"{step} bytes (row_step {row_step}) need {need}",
            fix="the message is truncated or its header is wrong; re-record the bag",
        )
    buf = data.tobytes() if not data.flags.c_contiguous else data
    if row_step == width * step:  # a view on the message's buffer (no copy)
        return np.frombuffer(buf, dtype=dtype, count=height * width)
    rows = [
        np.frombuffer(buf, dtype=dtype, count=width, offset=r * row_step) for r in range(height)
    ]
    return np.concatenate(rows)


def _first_field(names: tuple[str, ...], candidates: tuple[str, ...]) -> str | None:
    lower = {n.lower(): n for n in names}
    return next((lower[c] for c in candidates if c in lower), None)


def _column(points: np.ndarray, name: str) -> np.ndarray:
    col = points[name]
    return col[:, 0] if col.ndim == 2 else col


def raw_from_pointcloud2(msg: Any, header_ns: int, time_field: str | None, where: str) -> RawCloud:
    """Flattens a PointCloud2 into a :class:`RawCloud`.

    Args:
        msg: Deserialised ``sensor_msgs/PointCloud2``.
        header_ns: Its header stamp (ns).
        time_field: Per-point time field to read (``None``: no times).
        where: ``"<bag>: <topic>"`` for error messages.

    Raises:
        FormatError: if x/y/z or the requested time field are missing.
    """
    points = decode_pointcloud2(msg, where)
    names = tuple(f.name for f in msg.fields)
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise FormatError(
            f"{where}: cloud has no {'/'.join(missing)} field (fields: {', '.join(names)})",
            fix="point the LiDAR topic at a cloud with x, y, z coordinates",
        )
    xyz = np.empty((points.shape[0], 3), dtype=np.float32)
    for i, c in enumerate("xyz"):
        xyz[:, i] = _column(points, c)
    time_raw, tdtype = None, ""
    if time_field is not None:
        if time_field not in names:
            raise FormatError(
                f"{where}: cloud has no field {time_field!r} (fields: {', '.join(names)})",
                fix="set data.lidar.time_field to one of the fields, or null to detect it",
            )
        col = _column(points, time_field)
        tdtype = col.dtype.kind + str(col.dtype.itemsize)
        time_raw = col.astype(np.int64 if col.dtype.kind in "iu" else np.float64)
    ifield, rfield = _first_field(names, INTENSITY_FIELDS), _first_field(names, RING_FIELDS)
    intensity = None if ifield is None else _column(points, ifield).astype(np.float32)
    ring = None if rfield is None else _column(points, rfield).astype(np.uint16)
    return RawCloud(header_ns, xyz, time_raw, time_field, tdtype, intensity, ring, names)


# ------------------------------------------------------------------------ Livox CustomMsg
_LIVOX_FIELDS = ("offset_time", "x", "y", "z", "reflectivity", "tag", "line")


def _livox_point_dtype(order: str, itemsize: int) -> np.dtype:
    return np.dtype(
        {
            "names": list(_LIVOX_FIELDS),
            "formats": [order + "u4", order + "f4", order + "f4", order + "f4", "u1", "u1", "u1"],
            "offsets": [0, 4, 8, 12, 16, 17, 18],
            "itemsize": itemsize,
        }
    )


def parse_livox_custom(raw: bytes, ros2: bool) -> tuple[int, int, np.ndarray] | None:
    """Parses a serialised Livox ``CustomMsg`` without rosbags.

    Returns:
        ``(header_ns, timebase_ns, points)`` with ``points`` a structured array with fields
        offset_time, x, y, z, reflectivity, tag, line; or ``None`` if the bytes do not follow
        the expected layout exactly (the caller then deserialises with rosbags).
    """
    try:
        if ros2:
            if len(raw) < 4 or raw[1] != 1:  # only little-endian CDR
                return None
            p, base = raw, 4

            def align(pos: int, n: int) -> int:
                return pos + (-(pos - base)) % n

            pos = base
            sec, nsec = struct.unpack_from("<iI", p, pos)
            pos += 8
            (slen,) = struct.unpack_from("<I", p, pos)
            pos += 4 + slen
            pos = align(pos, 8)
            (timebase,) = struct.unpack_from("<Q", p, pos)
            pos = align(pos + 8, 4)
            (point_num,) = struct.unpack_from("<I", p, pos)
            pos += 4 + 1 + 3
            pos = align(pos, 4)
            (n,) = struct.unpack_from("<I", p, pos)
            pos += 4
            stride = 20
        else:
            p, pos = raw, 0
            _seq, sec, nsec, slen = struct.unpack_from("<IIII", p, pos)
            pos += 16 + slen
            timebase, point_num = struct.unpack_from("<QI", p, pos)
            pos += 12 + 1 + 3
            (n,) = struct.unpack_from("<I", p, pos)
            pos += 4
            stride = 19
    except struct.error:
        return None
    end = pos + (stride * (n - 1) + 19 if n else 0)
    if end != len(raw) or (point_num != n and point_num != 0):
        return None
    header_ns = int(sec) * 1_000_000_000 + int(nsec)
    if n == 0:
        return header_ns, int(timebase), np.zeros(0, _livox_point_dtype("<", stride))
    buf = raw if stride == 19 else raw + b"\0"  # the last CDR element has no trailing pad
    pts = np.frombuffer(buf, dtype=_livox_point_dtype("<", stride), count=n, offset=pos)
    return header_ns, int(timebase), pts


def raw_from_livox_custom(raw: bytes, ros2: bool, deserialize: Any, header_of: Any) -> RawCloud:
    """Flattens a Livox ``CustomMsg`` into a :class:`RawCloud` with absolute point times (ns).

    Args:
        raw: Serialised message.
        ros2: CDR (ROS2) rather than ROS1 serialisation.
        deserialize: Fallback ``raw -> message`` (rosbags) for layouts the fast path rejects.
        header_of: ``message -> header stamp ns``.
    """
    parsed = parse_livox_custom(raw, ros2)
    if parsed is not None:
        header_ns, timebase, pts = parsed
        off, refl, line = pts["offset_time"], pts["reflectivity"], pts["line"]
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float32)
    else:
        msg = deserialize(raw)
        header_ns, timebase = header_of(msg), int(msg.timebase)
        ps = msg.points
        off = np.array([q.offset_time for q in ps], dtype=np.int64)
        xyz = np.array([[q.x, q.y, q.z] for q in ps], dtype=np.float32).reshape(-1, 3)
        refl = np.array([q.reflectivity for q in ps], dtype=np.float32)
        line = np.array([q.line for q in ps], dtype=np.uint16)
    t = np.int64(timebase) + np.asarray(off, dtype=np.int64)
    return RawCloud(
        header_ns,
        xyz,
        t,
        "offset_time",
        "u4",
        np.asarray(refl, dtype=np.float32),
        np.asarray(line, dtype=np.uint16),
        _LIVOX_FIELDS,
    )
