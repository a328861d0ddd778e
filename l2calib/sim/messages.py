"""Vendor-faithful ROS messages for simulated scans and IMU samples (rosbags message objects).

Point layouts follow the public drivers (read in their sources, not copied):

* Ouster (ouster-ros, ``ouster_ros::Point`` via PCL): organized ``channels × columns`` cloud,
  invalid returns as zero points; x, y, z, intensity ``float32`` at 0/4/8/16, ``t`` ``uint32`` ns
  since the header stamp at 20, reflectivity ``uint16`` 24, ring ``uint16`` 26, ambient
  ``uint16`` 28, range ``uint32`` mm 32; ``point_step`` 48. Header stamp = first column.
* Velodyne (velodyne_pointcloud ``PointcloudXYZIRT``): x, y, z, intensity ``float32`` 0-12,
  ring ``uint16`` 16, time ``float32`` s relative to the header stamp 18; ``point_step`` 22.
  The driver stamps the scan with its last packet, so times are negative.
* Hesai (HesaiLidar_ROS_2.0): x, y, z, intensity ``float32``, ring ``uint16`` 16, timestamp
  ``float64`` absolute seconds 18; ``point_step`` 26. Header stamp = first point.
* Livox PointCloud2 (livox_ros_driver2): x, y, z, intensity ``float32``, tag, line ``uint8``
  16/17, timestamp ``float64`` absolute ns 18; ``point_step`` 26. Header stamp = first point.
* Livox ``CustomMsg``: ``timebase`` = first point (ns), ``offset_time`` ns after it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from l2calib.data import NS_PER_S, LidarScan
from l2calib.errors import ConfigError
from l2calib.sim.lidar_models import LidarSpec, column_times_ns

_F4, _F8, _U1, _U2, _U4 = "<f4", "<f8", "u1", "<u2", "<u4"
# name -> (dtype, offset); plus point_step, per vendor.
LAYOUTS: dict[str, tuple[list[tuple[str, str, int]], int]] = {
    "ouster": (
        [
            ("x", _F4, 0),
            ("y", _F4, 4),
            ("z", _F4, 8),
            ("intensity", _F4, 16),
            ("t", _U4, 20),
            ("reflectivity", _U2, 24),
            ("ring", _U2, 26),
            ("ambient", _U2, 28),
            ("range", _U4, 32),
        ],
        48,
    ),
    "velodyne": (
        [
            ("x", _F4, 0),
            ("y", _F4, 4),
            ("z", _F4, 8),
            ("intensity", _F4, 12),
            ("ring", _U2, 16),
            ("time", _F4, 18),
        ],
        22,
    ),
    "hesai": (
        [
            ("x", _F4, 0),
            ("y", _F4, 4),
            ("z", _F4, 8),
            ("intensity", _F4, 12),
            ("ring", _U2, 16),
            ("timestamp", _F8, 18),
        ],
        26,
    ),
    "livox": (
        [
            ("x", _F4, 0),
            ("y", _F4, 4),
            ("z", _F4, 8),
            ("intensity", _F4, 12),
            ("tag", _U1, 16),
            ("line", _U1, 17),
            ("timestamp", _F8, 18),
        ],
        26,
    ),
}
_DATATYPE = {_F4: 7, _F8: 8, _U1: 2, _U2: 4, _U4: 6}  # sensor_msgs/PointField constants
DRIVER_STAMP = {"ouster": "start", "velodyne": "end", "hesai": "start", "livox": "start"}


def point_dtype(vendor: str) -> np.dtype:
    """Numpy structured dtype with the vendor's offsets and ``point_step`` as itemsize."""
    fields, step = LAYOUTS[vendor]
    return np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [f[1] for f in fields],
            "offsets": [f[2] for f in fields],
            "itemsize": step,
        }
    )


def header_stamp(vendor: str, position: str, nominal_ns: tuple[int, int]) -> int:
    """Header stamp (LiDAR clock, ns) for ``position`` ``driver``/``start``/``end``."""
    pos = DRIVER_STAMP[vendor] if position == "driver" else position
    if pos == "end" and vendor == "ouster":
        raise ConfigError(
            "Ouster clouds cannot be stamped at the scan end: their 't' field is an unsigned "
            "time since the header stamp",
            fix="use stamp position 'start' or 'driver' for Ouster LiDARs",
        )
    return int(nominal_ns[0] if pos == "start" else nominal_ns[1])


def encode_points(
    spec: LidarSpec,
    scan: LidarScan,
    columns: np.ndarray,
    nominal_ns: tuple[int, int],
    stamp_ns: int,
) -> tuple[np.ndarray, int, int]:
    """Packs a scan into the vendor's point layout.

    Returns:
        ``(points [height * width] structured array, height, width)``.
    """
    p = scan.points_lidar.astype(np.float32)
    t_ns = scan.point_stamps_ns
    intensity = np.zeros(len(scan), np.float32) if scan.intensity is None else scan.intensity
    ring = np.zeros(len(scan), np.uint16) if scan.ring is None else scan.ring
    vendor = spec.vendor
    if vendor == "ouster":
        h, w = spec.channels, spec.columns
        out = np.zeros(h * w, dtype=point_dtype(vendor))
        col_ns = nominal_ns[0] + column_times_ns(spec)
        out["t"] = np.tile((col_ns - stamp_ns).astype(np.uint32), h)
        out["ring"] = np.repeat(np.arange(h, dtype=np.uint16), w)
        idx = ring.astype(np.int64) * w + columns.astype(np.int64)
        out["x"][idx], out["y"][idx], out["z"][idx] = p[:, 0], p[:, 1], p[:, 2]
        out["intensity"][idx] = intensity * 4.0  # signal photons, not 0-255
        out["reflectivity"][idx] = np.clip(intensity, 0, 255).astype(np.uint16)
        out["range"][idx] = np.round(np.linalg.norm(p, axis=1) * 1000.0).astype(np.uint32)
        return out, h, w
    out = np.zeros(len(scan), dtype=point_dtype(vendor))
    out["x"], out["y"], out["z"], out["intensity"] = p[:, 0], p[:, 1], p[:, 2], intensity
    if vendor == "velodyne":
        out["ring"], out["time"] = ring, (t_ns - stamp_ns) / NS_PER_S
    elif vendor == "hesai":
        # Absolute seconds as float64, as the driver writes them (sub-µs resolution at 1.7e9 s).
        out["ring"], out["timestamp"] = ring, t_ns / NS_PER_S
    else:
        out["line"], out["timestamp"] = ring.astype(np.uint8), t_ns.astype(np.float64)
    return out, 1, len(scan)


def _header(types: dict[str, Any], ros1: bool, stamp_ns: int, frame: str, seq: int) -> Any:
    sec, nsec = divmod(int(stamp_ns), NS_PER_S)
    stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    if ros1:
        return types["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def pointcloud2(
    types: dict[str, Any],
    ros1: bool,
    points: np.ndarray,
    height: int,
    width: int,
    stamp_ns: int,
    frame: str,
    seq: int,
) -> Any:
    """A ``sensor_msgs/PointCloud2`` around a structured point array."""
    pf = types["sensor_msgs/msg/PointField"]
    fields = [
        pf(
            name=n,
            offset=points.dtype.fields[n][1],
            count=1,
            datatype=_DATATYPE[points.dtype.fields[n][0].str.replace("|", "")],
        )
        for n in points.dtype.names
    ]
    step = points.dtype.itemsize
    return types["sensor_msgs/msg/PointCloud2"](
        header=_header(types, ros1, stamp_ns, frame, seq),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * width,
        data=np.frombuffer(points.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def livox_custom(
    types: dict[str, Any],
    ros1: bool,
    package: str,
    scan: LidarScan,
    stamp_ns: int,
    frame: str,
    seq: int,
) -> Any:
    """A Livox ``CustomMsg`` (``timebase`` = first point, ``offset_time`` ns after it)."""
    cp = types[f"{package}/msg/CustomPoint"]
    t_ns = scan.point_stamps_ns
    base = int(t_ns.min())
    off = (t_ns - base).astype(np.uint32).tolist()
    refl = np.clip(np.round(scan.intensity), 0, 255).astype(np.uint8).tolist()
    line = scan.ring.astype(np.uint8).tolist()
    xyz = scan.points_lidar.astype(np.float32).tolist()
    pts = [
        cp(offset_time=o, x=x, y=y, z=z, reflectivity=r, tag=0, line=ln)
        for o, (x, y, z), r, ln in zip(off, xyz, refl, line, strict=True)
    ]
    return types[f"{package}/msg/CustomMsg"](
        header=_header(types, ros1, stamp_ns, frame, seq),
        timebase=base,
        point_num=len(pts),
        lidar_id=0,
        rsvd=np.zeros(3, np.uint8),
        points=pts,
    )


def imu_message(
    types: dict[str, Any],
    ros1: bool,
    stamp_ns: int,
    frame: str,
    seq: int,
    gyro: np.ndarray,
    accel: np.ndarray,
    gyro_var: float,
    accel_var: float,
) -> Any:
    """A ``sensor_msgs/Imu`` without orientation (covariance[0] = -1, as the REP says)."""
    v3, q = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
    ocov = np.zeros(9)
    ocov[0] = -1.0
    return types["sensor_msgs/msg/Imu"](
        header=_header(types, ros1, stamp_ns, frame, seq),
        orientation=q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=ocov,
        angular_velocity=v3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
        angular_velocity_covariance=np.diag([gyro_var] * 3).reshape(-1),
        linear_acceleration=v3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
        linear_acceleration_covariance=np.diag([accel_var] * 3).reshape(-1),
    )
