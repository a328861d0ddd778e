"""Every vendor layout, in ROS1 / ROS2 sqlite3 / ROS2 mcap, reads back to the points and times
that were written (hand-made bags; the simulator round trip is in test_io_sim_roundtrip.py)."""

from __future__ import annotations

import numpy as np
import pytest
from io_bagkit import PERIOD_NS, T0, Msgs

from l2calib.io.bag_reader import Bag
from l2calib.io.pointcloud import parse_livox_custom
from l2calib.io.sequences import open_sequence
from l2calib.recipe import DataConfig

# (vendor, expected unit, reference, stamp position, time tolerance ns)
EXPECTED = {
    "ouster": ("ns", "relative", "start", 0),
    "velodyne": ("s", "relative", "end", 20),  # float32 seconds over 0.1 s: ~8 ns resolution
    "hesai": ("s", "absolute", "start", 300),  # float64 seconds at 1.7e9 s: 238 ns resolution
    "robosense": ("s", "absolute", "end", 300),
    "livox": ("ns", "absolute", "start", 300),  # float64 ns at 1.7e18: 256 ns resolution
    "custom": ("ns", "absolute", "start", 0),
}


def wide_range() -> DataConfig:
    cfg = DataConfig()
    cfg.lidar.min_range_m, cfg.lidar.max_range_m = 0.01, 1000.0
    return cfg


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
@pytest.mark.parametrize("vendor", list(EXPECTED))
def test_vendor_layout_reads_back_points_and_times(scene_factory, vendor, storage):
    scene = scene_factory(vendor=vendor, storage=storage)
    seq = open_sequence(scene.path, wide_range())
    unit, ref, pos, tol = EXPECTED[vendor]
    conv = seq.meta["time_convention"]
    assert (conv["unit"], conv["reference"], conv["stamp_position"]) == (unit, ref, pos)
    assert set(conv["detected"]) >= (
        {"stamp_position"}
        if vendor == "custom"
        else {"time_unit", "time_reference", "stamp_position"}
    )
    scans = seq.scans.load(int(seq.scans.stamps_ns[0]), int(seq.scans.stamps_ns[-1]))
    assert len(scans) == len(scene.truth) == 12
    for scan, (xyz, t_ns) in zip(scans, scene.truth, strict=True):
        assert len(scan) == len(t_ns)  # NaN and zero points dropped with their times
        np.testing.assert_array_equal(scan.points_lidar, xyz)
        assert np.abs(scan.point_stamps_ns - t_ns).max() <= tol
        assert scan.stamp_ns == scan.point_stamps_ns.min() and scan.offset_s.min() == 0.0
        assert np.all(scan.offset_s < 0.1)


@pytest.mark.parametrize("ros2", [False, True])
def test_livox_custom_fast_parser_matches_rosbags(ros2, rng):
    m = Msgs(ros2)
    xyz = rng.normal(size=(37, 3)).astype(np.float32)
    off = np.sort(rng.integers(0, PERIOD_NS, 37))
    for frame in ("f", "livox_frame_12"):  # string length changes the CDR alignment
        msg = m.livox_custom(T0 + 5, T0, xyz, off)
        msg.header.frame_id = frame
        typ = "livox_ros_driver/msg/CustomMsg"
        raw = m.ts.serialize_cdr(msg, typ) if ros2 else m.ts.serialize_ros1(msg, typ)
        header_ns, timebase, pts = parse_livox_custom(bytes(raw), ros2)
        assert header_ns == T0 + 5 and timebase == T0
        np.testing.assert_array_equal(pts["offset_time"], off)
        np.testing.assert_array_equal(np.stack([pts["x"], pts["y"], pts["z"]], 1), xyz)
        np.testing.assert_array_equal(pts["line"], np.arange(37) % 4)
        assert parse_livox_custom(bytes(raw) + b"\0\0\0\0\0", ros2) is None  # not exact: fallback


def test_livox_custom_fallback_gives_same_scan(scene_factory, monkeypatch):
    scene = scene_factory(vendor="custom", storage="ros1")
    fast = open_sequence(scene.path, wide_range())
    monkeypatch.setattr("l2calib.io.pointcloud.parse_livox_custom", lambda raw, ros2: None)
    slow = open_sequence(scene.path, wide_range())
    np.testing.assert_array_equal(fast.scans.stamps_ns, slow.scans.stamps_ns)
    a = fast.scans.load(0, 2**62)[3]
    b = slow.scans.load(0, 2**62)[3]
    np.testing.assert_array_equal(a.points_lidar, b.points_lidar)
    np.testing.assert_array_equal(a.offset_s, b.offset_s)


def test_bag_lists_topics_and_types(scene_factory):
    scene = scene_factory(vendor="custom", storage="mcap")
    with Bag(scene.path) as bag:
        topics = bag.topics
    assert topics["/points"].msgtype == "livox_ros_driver/msg/CustomMsg"
    assert topics["/points"].count == 12
    assert topics["/imu"].msgtype == "sensor_msgs/msg/Imu"
