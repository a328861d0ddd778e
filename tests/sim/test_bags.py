"""Simulated bags read back with rosbags: fields, offsets, units, stamps and counts per format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from l2calib.errors import ConfigError
from l2calib.io.rosmsgs import register_livox_types
from l2calib.sim import SimConfig, simulate, write_run
from l2calib.sim.messages import LAYOUTS

FORMATS = ("ros1", "ros2-sqlite3", "ros2-mcap")
MODELS = {
    "ouster": ("ouster-os1-16", 128),
    "velodyne": ("velodyne-vlp-16", 180),
    "hesai": ("hesai-pandar-xt32", 200),
    "livox": ("livox-mid360", None),
}
PF = {"<f4": 7, "<f8": 8, "u1": 2, "<u2": 4, "<u4": 6}


@pytest.fixture(scope="module")
def runs():
    out = {}
    for vendor, (model, cols) in MODELS.items():
        lidar = {"model": model} | ({"columns": cols} if cols else {})
        cfg = SimConfig.model_validate(
            {
                "duration_s": 1.0,
                "seed": 5,
                "lidar": lidar,
                "motion": {"still_start_s": 0.2},
                "rig": {"time_offset_s": -0.02},
            }
        )
        out[vendor] = simulate(cfg)
    return out


def _read(files: dict, fmt: str):
    store = register_livox_types(
        get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    )
    with AnyReader([Path(files["bag"])], default_typestore=store) as r:
        topics = {c.topic: (c.msgtype, c.msgcount) for c in r.connections}
        msgs = [(c.topic, t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()]
    return topics, msgs


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _decode(m) -> np.ndarray:
    names = [f.name for f in m.fields]
    inv = {v: k for k, v in PF.items()}
    dt = np.dtype(
        {
            "names": names,
            "formats": [inv[f.datatype] for f in m.fields],
            "offsets": [f.offset for f in m.fields],
            "itemsize": m.point_step,
        }
    )
    return np.frombuffer(m.data.tobytes(), dtype=dt)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("vendor", list(MODELS))
def test_pointcloud_layout_times_and_counts(runs, tmp_path, vendor, fmt):
    run = runs[vendor]
    files = write_run(run, tmp_path, format=fmt, lidar_msg="pointcloud2")
    topics, msgs = _read(files, fmt)
    lidar_topic = [t for t in topics if t != ("/livox/imu" if vendor == "livox" else "/imu/data")]
    assert len(lidar_topic) == 1 and topics[lidar_topic[0]][1] == len(run.scans)
    assert topics["/livox/imu" if vendor == "livox" else "/imu/data"][1] == len(run.imu)
    clouds = [m for t, _, m in msgs if t == lidar_topic[0]]
    layout, step = LAYOUTS[vendor]
    for i, (scan, cols, m) in enumerate(zip(run.scans, run.scan_columns, clouds, strict=True)):
        assert [(f.name, f.offset, f.datatype) for f in m.fields] == [
            (n, o, PF[d]) for n, d, o in layout
        ]
        assert m.point_step == step and m.row_step == step * m.width
        pts = _decode(m)
        stamp = _ns(m.header.stamp)
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1)
        if vendor == "ouster":  # organized, zeros where nothing returned
            assert (m.height, m.width) == (16, 128)
            valid = np.any(xyz != 0, axis=1)
            assert valid.sum() == len(scan)
            t = stamp + pts["t"].astype(np.int64)
            idx = scan.ring.astype(np.int64) * 128 + cols
            assert np.array_equal(t[idx], scan.point_stamps_ns)
            assert np.allclose(xyz[idx], scan.points_lidar)
            assert np.allclose(
                pts["range"][idx] / 1000.0, np.linalg.norm(scan.points_lidar, axis=1), atol=1e-3
            )
            assert stamp == run.scan_nominal_ns[i][0] <= scan.stamp_ns
            continue
        assert (m.height, m.width) == (1, len(scan))
        assert np.allclose(xyz, scan.points_lidar)
        if vendor == "velodyne":  # float32 seconds relative to a stamp at the sweep end
            assert pts["time"].max() <= 0 and stamp >= scan.end_stamp_ns
            t = stamp + np.round(pts["time"].astype(np.float64) * 1e9).astype(np.int64)
            assert np.abs(t - scan.point_stamps_ns).max() < 1000  # float32 resolution
        elif vendor == "hesai":  # float64 absolute seconds
            assert stamp == scan.stamp_ns
            assert np.abs(pts["timestamp"] * 1e9 - scan.point_stamps_ns).max() < 500
        else:  # livox: float64 absolute nanoseconds
            assert stamp == scan.stamp_ns
            assert np.abs(pts["timestamp"] - scan.point_stamps_ns).max() < 300
            assert np.array_equal(pts["line"], scan.ring)


@pytest.mark.parametrize("fmt", FORMATS)
def test_livox_custom_msg_and_imu_units(runs, tmp_path, fmt):
    run = runs["livox"]
    files = write_run(run, tmp_path, format=fmt, gyro_unit="deg/s", accel_unit="g")
    topics, msgs = _read(files, fmt)
    pkg = "livox_ros_driver" if fmt == "ros1" else "livox_ros_driver2"
    assert topics["/livox/lidar"] == (f"{pkg}/msg/CustomMsg", len(run.scans))
    customs = [m for t, _, m in msgs if t == "/livox/lidar"]
    for scan, m in zip(run.scans, customs, strict=True):
        assert m.timebase == scan.stamp_ns == _ns(m.header.stamp)
        assert m.point_num == len(m.points) == len(scan)
        t = m.timebase + np.array([p.offset_time for p in m.points], dtype=np.int64)
        assert np.array_equal(t, scan.point_stamps_ns)
        assert np.array_equal([p.line for p in m.points], scan.ring)
    imus = [m for t, _, m in msgs if t == "/livox/imu"]
    gyro = np.array(
        [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in imus]
    )
    acc = np.array(
        [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imus]
    )
    assert np.array_equal([_ns(m.header.stamp) for m in imus], run.imu.stamps_ns)
    assert np.allclose(np.radians(gyro), run.imu.gyro_rad_s, rtol=1e-12, atol=1e-15)
    assert np.allclose(acc * 9.81, run.imu.accel_m_s2, rtol=1e-12)
    assert np.all(np.abs(np.linalg.norm(acc[:10], axis=1) - 1.0) < 0.05)  # ~1 g at rest
    assert imus[0].orientation_covariance[0] == -1


def test_record_times_are_ordered_and_follow_the_data(runs, tmp_path):
    run = runs["velodyne"]
    files = write_run(run, tmp_path, format="ros2-mcap", stamp_position="start")
    _, msgs = _read(files, "ros2-mcap")
    rec = np.array([t for _, t, _ in msgs])
    assert np.all(np.diff(rec) >= 0)
    clouds = [m for t, _, m in msgs if t == "/velodyne_points"]
    assert all(_ns(m.header.stamp) == s.stamp_ns for m, s in zip(clouds, run.scans, strict=True))


def test_bad_bag_options_are_one_clear_error(runs, tmp_path):
    with pytest.raises(ConfigError, match="Ouster clouds cannot be stamped at the scan end"):
        write_run(runs["ouster"], tmp_path / "a", stamp_position="end")
    with pytest.raises(ConfigError, match="format"):
        write_run(runs["ouster"], tmp_path / "b", format="ros3")
    with pytest.raises(ConfigError, match="needs a Livox LiDAR"):
        write_run(runs["hesai"], tmp_path / "c", lidar_msg="livox-custom")
