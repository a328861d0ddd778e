"""Tiny bags for reader unit tests, written with rosbags' writers (not a simulator).

Vendor layouts here are written independently of ``l2calib.sim`` (field names, types, offsets
and point_step from the drivers' point structs), so the reader is tested against a second
reading of the drivers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

from l2calib.io.rosmsgs import register_livox_types

T0 = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000
F4, F8, U1, U2, U4 = "f4", "f8", "u1", "u2", "u4"
CODES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}

# vendor -> (fields [(name, code, offset)], point_step, time field, how times are stored)
VENDORS = {
    # ouster-ros: PCL_ADD_POINT4D (16 B), intensity f4, t u4 ns since header (start)
    "ouster": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("intensity", F4, 16),
            ("t", U4, 20),
            ("reflectivity", U2, 24),
            ("ring", U2, 26),
            ("ambient", U2, 28),
            ("range", U4, 32),
        ],
        48,
        "t",
        "rel_ns_start",
    ),
    # velodyne_pointcloud XYZIRT (aligned variant): time f4 s, header at the last packet
    "velodyne": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("intensity", F4, 16),
            ("ring", U2, 20),
            ("time", F4, 24),
        ],
        32,
        "time",
        "rel_s_end",
    ),
    # hesai: timestamp f8 absolute s, header = first point
    "hesai": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("intensity", F4, 16),
            ("timestamp", F8, 24),
            ("ring", U2, 32),
        ],
        48,
        "timestamp",
        "abs_s_start",
    ),
    # rslidar_sdk XYZIRT: intensity u1, ring u2, timestamp f8 absolute s, header = last point
    "robosense": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("intensity", U1, 12),
            ("ring", U2, 14),
            ("timestamp", F8, 16),
        ],
        24,
        "timestamp",
        "abs_s_end",
    ),
    # livox_ros_driver2 PointCloud2: timestamp f8 absolute ns
    "livox": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("intensity", F4, 12),
            ("tag", U1, 16),
            ("line", U1, 17),
            ("timestamp", F8, 18),
        ],
        26,
        "timestamp",
        "abs_ns_start",
    ),
    # livox_ros_driver (v1) PointCloud2, xfer_format 0: no per-point time at all
    "livox_v1": (
        [
            ("x", F4, 0),
            ("y", F4, 4),
            ("z", F4, 8),
            ("reflectivity", F4, 12),
            ("tag", U1, 16),
            ("line", U1, 17),
        ],
        18,
        None,
        "none_start",
    ),
}


def typestore(ros2: bool):
    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    return register_livox_types(ts)


class Msgs:
    """Message constructors for one typestore."""

    def __init__(self, ros2: bool):
        self.ros2 = ros2
        self.ts = typestore(ros2)
        self.t = self.ts.types

    def header(self, stamp_ns: int, frame: str = "f"):
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        stamp = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros2:
            return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)
        return self.t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)

    def imu(self, stamp_ns: int, gyro, accel):
        v3, q = self.t["geometry_msgs/msg/Vector3"], self.t["geometry_msgs/msg/Quaternion"]
        return self.t["sensor_msgs/msg/Imu"](
            header=self.header(stamp_ns),
            orientation=q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=v3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=v3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
            linear_acceleration_covariance=np.zeros(9),
        )

    def cloud(
        self,
        stamp_ns: int,
        points: np.ndarray,
        height: int = 1,
        row_pad: int = 0,
        bigendian: bool = False,
        fields=None,
    ):
        """PointCloud2 around a structured array (fields from its dtype unless given)."""
        pf = self.t["sensor_msgs/msg/PointField"]
        dt = points.dtype
        if fields is None:
            fields = []
            for n in dt.names:
                sub, off = dt.fields[n][0], dt.fields[n][1]
                base, count = (sub.base, int(np.prod(sub.shape))) if sub.shape else (sub, 1)
                code = CODES[base.kind + str(base.itemsize)]
                fields.append(pf(name=n, offset=off, datatype=code, count=count))
        width = points.size // height
        step = dt.itemsize
        rows = points.reshape(height, width)
        raw = b"".join(r.tobytes() + b"\x00" * row_pad for r in rows)
        return self.t["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns),
            height=height,
            width=width,
            fields=fields,
            is_bigendian=bigendian,
            point_step=step,
            row_step=step * width + row_pad,
            data=np.frombuffer(raw, dtype=np.uint8),
            is_dense=False,
        )

    def livox_custom(self, stamp_ns: int, timebase: int, xyz, offsets, package="livox_ros_driver"):
        cp = self.t[f"{package}/msg/CustomPoint"]
        pts = [
            cp(
                offset_time=int(o),
                x=float(p[0]),
                y=float(p[1]),
                z=float(p[2]),
                reflectivity=7,
                tag=0,
                line=int(i % 4),
            )
            for i, (p, o) in enumerate(zip(xyz, offsets, strict=True))
        ]
        return self.t[f"{package}/msg/CustomMsg"](
            header=self.header(stamp_ns),
            timebase=int(timebase),
            point_num=len(pts),
            lidar_id=0,
            rsvd=np.zeros(3, np.uint8),
            points=pts,
        )

    def navsat(self, stamp_ns: int, lat: float, lon: float, alt: float, status: int = 2):
        st = self.t["sensor_msgs/msg/NavSatStatus"](status=status, service=1)
        return self.t["sensor_msgs/msg/NavSatFix"](
            header=self.header(stamp_ns),
            status=st,
            latitude=lat,
            longitude=lon,
            altitude=alt,
            position_covariance=np.eye(3).reshape(9) * 0.01,
            position_covariance_type=2,
        )


def write_bag(path: Path, storage: str, messages: list[tuple[str, str, int, object]]) -> Path:
    """Writes ``(topic, msgtype, record_ns, message)`` tuples; storage: ros1, sqlite3, mcap."""
    ros2 = storage != "ros1"
    ts = typestore(ros2)
    if storage == "ros1":
        from rosbags.rosbag1 import Writer

        path = path.with_suffix(".bag")
        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        ser = ts.serialize_cdr
    conns = {}
    with writer:
        for topic, msgtype, record_ns, msg in sorted(messages, key=lambda m: m[2]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], int(record_ns), ser(msg, msgtype))
    return path


def vendor_points(
    vendor: str, xyz: np.ndarray, t_ns: np.ndarray, header_ns: int, ring: np.ndarray | None = None
) -> np.ndarray:
    """Packs points with absolute times ``t_ns`` into a vendor's layout."""
    fields, step, tfield, how = VENDORS[vendor]
    dt = np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [f[1] for f in fields],
            "offsets": [f[2] for f in fields],
            "itemsize": step,
        }
    )
    out = np.zeros(len(xyz), dtype=dt)
    out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if ring is not None:
        out["line" if vendor.startswith("livox") else "ring"] = ring
    rel = t_ns - header_ns
    if tfield is None:
        return out
    if how == "rel_ns_start":
        out[tfield] = rel.astype(np.uint32)
    elif how == "rel_s_end":
        out[tfield] = (rel / 1e9).astype(np.float32)
    elif how.startswith("abs_s"):
        out[tfield] = t_ns / 1e9
    else:
        out[tfield] = t_ns.astype(np.float64)
    return out


def header_for(vendor: str, t_ns: np.ndarray) -> int:
    how = VENDORS[vendor][3]
    return int(t_ns.max() if how.endswith("end") else t_ns.min())
