"""Writes a :class:`~l2calib.sim.scenario.SimRun` as a ROS1 bag or a ROS2 bag (sqlite3 / mcap).

Messages are written in record-time order, the way a recorder would store them: IMU samples
1 ms after their stamp, a scan 5 ms after its last point (both converted to the recorder's clock,
which is the IMU clock here). IMU readings can be emitted in deg/s and g as some drivers do.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field

from l2calib.errors import ConfigError
from l2calib.recipe import StrictModel
from l2calib.sim import messages as msgs

if TYPE_CHECKING:
    from l2calib.sim.scenario import SimRun

BagFormat = Literal["ros1", "ros2-sqlite3", "ros2-mcap"]
BAG_FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap")
_DEFAULT_TOPICS = {
    "ouster": "/ouster/points",
    "velodyne": "/velodyne_points",
    "hesai": "/lidar_points",
    "livox": "/livox/lidar",
}
_DEFAULT_FRAMES = {
    "ouster": "os_sensor",
    "velodyne": "velodyne",
    "hesai": "hesai_lidar",
    "livox": "livox_frame",
}


class BagOptions(StrictModel):
    """How to write the bag (topics, message kinds, stamp convention, IMU units)."""

    format: BagFormat = "ros1"
    lidar_msg: Literal["auto", "pointcloud2", "livox-custom"] = Field(
        "auto", description="auto: Livox CustomMsg for Livox, PointCloud2 otherwise"
    )
    stamp_position: Literal["driver", "start", "end"] = Field(
        "driver", description="header stamp at the scan start or end; driver: as the vendor"
    )
    lidar_topic: str | None = Field(None, description="default: the vendor driver's topic")
    imu_topic: str | None = Field(None, description="default: /imu/data (/livox/imu for Livox)")
    lidar_frame: str | None = None
    imu_frame: str = "imu_link"
    gyro_unit: Literal["rad/s", "deg/s"] = "rad/s"
    accel_unit: Literal["m/s^2", "g"] = "m/s^2"
    livox_package: Literal["auto", "livox_ros_driver", "livox_ros_driver2"] = Field(
        "auto", description="CustomMsg package; auto: livox_ros_driver (ROS1), driver2 (ROS2)"
    )

    def resolved(self, vendor: str) -> BagOptions:
        """Fills the vendor-dependent defaults."""
        data = self.model_dump()
        ros1 = self.format == "ros1"
        if self.lidar_msg == "auto":
            data["lidar_msg"] = "livox-custom" if vendor == "livox" else "pointcloud2"
        if data["lidar_msg"] == "livox-custom" and vendor != "livox":
            raise ConfigError(
                f"lidar_msg 'livox-custom' needs a Livox LiDAR, not a {vendor} one",
                fix="use --lidar livox-mid360 or --lidar-msg pointcloud2",
            )
        if vendor == "ouster" and data["lidar_msg"] == "pointcloud2":
            msgs.header_stamp(vendor, self.stamp_position, (0, 0))  # raises for "end"
        data["lidar_topic"] = self.lidar_topic or _DEFAULT_TOPICS[vendor]
        data["imu_topic"] = self.imu_topic or ("/livox/imu" if vendor == "livox" else "/imu/data")
        data["lidar_frame"] = self.lidar_frame or _DEFAULT_FRAMES[vendor]
        if self.livox_package == "auto":
            data["livox_package"] = "livox_ros_driver" if ros1 else "livox_ros_driver2"
        return BagOptions.model_validate(data)


def bag_path(out_dir: Path, fmt: str) -> Path:
    """Where the bag goes: ``out_dir/sim.bag`` (ROS1) or the directory ``out_dir/sim`` (ROS2)."""
    return out_dir / ("sim.bag" if fmt == "ros1" else "sim")


def _open(path: Path, fmt: str) -> Any:
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        return Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
    return Writer(path, version=9, storage_plugin=plugin)


def write_bag(run: SimRun, path: Path, options: BagOptions, progress: bool = False) -> dict:
    """Writes the run's IMU and LiDAR messages to ``path``.

    Returns:
        A summary (topics, message types, counts, stamp convention, units) for scenario.json.
    """
    from rosbags.typesys import Stores, get_typestore

    from l2calib.io.rosmsgs import register_livox_types

    spec = run.lidar_spec
    opt = options.resolved(spec.vendor)
    ros1 = opt.format == "ros1"
    store = register_livox_types(get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE))
    types = store.types
    custom = opt.lidar_msg == "livox-custom"
    lidar_type = f"{opt.livox_package}/msg/CustomMsg" if custom else "sensor_msgs/msg/PointCloud2"
    stamps = [
        msgs.header_stamp(spec.vendor, opt.stamp_position, tuple(n)) for n in run.scan_nominal_ns
    ]
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr

    g_scale = 180.0 / np.pi if opt.gyro_unit == "deg/s" else 1.0
    a_scale = 1.0 / run.config.gravity_m_s2 if opt.accel_unit == "g" else 1.0
    gyro = run.imu.gyro_rad_s * g_scale
    accel = run.imu.accel_m_s2 * a_scale
    rate = run.config.imu.rate_hz or run.imu_spec.rate_hz
    gyro_var = (run.imu_spec.gyro_noise_density * g_scale) ** 2 * rate
    accel_var = (run.imu_spec.accel_noise_density * a_scale) ** 2 * rate

    # Record order: (record time on the IMU clock, kind, index).
    off = run.offset_ns
    events = [(int(s) + 1_000_000, 0, i) for i, s in enumerate(run.imu.stamps_ns)]
    events += [(int(n[1]) + off + 5_000_000, 1, i) for i, n in enumerate(run.scan_nominal_ns)]
    events.sort()

    with _open(path, opt.format) as writer:
        kw = {"typestore": store}
        c_imu = writer.add_connection(opt.imu_topic, "sensor_msgs/msg/Imu", **kw)
        c_lidar = writer.add_connection(opt.lidar_topic, lidar_type, **kw)
        for rec_ns, kind, i in _track(events, progress, f"writing {path.name}"):
            if kind == 0:
                m = msgs.imu_message(
                    types,
                    ros1,
                    int(run.imu.stamps_ns[i]),
                    opt.imu_frame,
                    i,
                    gyro[i],
                    accel[i],
                    gyro_var,
                    accel_var,
                )
                writer.write(c_imu, rec_ns, serialize(m, "sensor_msgs/msg/Imu"))
                continue
            scan = run.scans[i]
            if custom:
                m = msgs.livox_custom(
                    types, ros1, opt.livox_package, scan, stamps[i], opt.lidar_frame, i
                )
            else:
                pts, h, w = msgs.encode_points(
                    spec, scan, run.scan_columns[i], tuple(run.scan_nominal_ns[i]), stamps[i]
                )
                m = msgs.pointcloud2(types, ros1, pts, h, w, stamps[i], opt.lidar_frame, i)
            writer.write(c_lidar, rec_ns, serialize(m, lidar_type))
    return {
        "path": str(path),
        "format": opt.format,
        "lidar": {
            "topic": opt.lidar_topic,
            "msgtype": lidar_type,
            "frame_id": opt.lidar_frame,
            "count": len(run.scans),
            "vendor": spec.vendor,
            "stamp_position": msgs.DRIVER_STAMP[spec.vendor]
            if opt.stamp_position == "driver"
            else opt.stamp_position,
            "point_layout": None
            if custom
            else {n: {"datatype": dt, "offset": o} for n, dt, o in msgs.LAYOUTS[spec.vendor][0]},
            "point_step": None if custom else msgs.LAYOUTS[spec.vendor][1],
            "organized": spec.vendor == "ouster" and not custom,
        },
        "imu": {
            "topic": opt.imu_topic,
            "msgtype": "sensor_msgs/msg/Imu",
            "frame_id": opt.imu_frame,
            "count": len(run.imu),
            "gyro_unit": opt.gyro_unit,
            "accel_unit": opt.accel_unit,
            "g_m_s2": run.config.gravity_m_s2,
        },
        "record_time": "IMU clock; IMU +1 ms after its stamp, scans +5 ms after their last point",
    }


def _track(items: list, progress: bool, label: str) -> Any:
    if not progress:
        return items
    from rich.progress import track

    return track(items, description=label)
