"""Bag-backed sequences: windows stream only their own messages; NavSatFix; segments."""

from __future__ import annotations

import numpy as np
import pytest
from io_bagkit import T0, Msgs

from l2calib.errors import DataError
from l2calib.io import lidar_scans
from l2calib.io.navsat import read_navsat
from l2calib.io.sequences import BagScans, open_sequence
from l2calib.recipe import DataConfig


def wide() -> DataConfig:
    c = DataConfig()
    c.lidar.min_range_m, c.lidar.max_range_m = 0.01, 1000.0
    return c


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
def test_window_load_decodes_only_the_window(scene_factory, storage, monkeypatch):
    scene = scene_factory(vendor="ouster", storage=storage, n_scans=30)
    seq = open_sequence(scene.path, wide())
    assert isinstance(seq.scans, BagScans)
    st = seq.scans.stamps_ns
    decoded = []
    real = lidar_scans.decode_lidar

    def counting(bag, message, field):
        decoded.append(message.record_ns)
        return real(bag, message, field)

    monkeypatch.setattr("l2calib.io.sequences.decode_lidar", counting)
    scans = seq.scans.load(int(st[10]), int(st[14]))
    assert [s.stamp_ns for s in scans] == list(st[10:15])
    assert len(decoded) == 5  # record-time seek: nothing outside the window is decoded
    seg = seq.segment(int(st[10]), int(st[14]))
    assert len(seg.scans) == 5 and seg.imu.stamps_ns[0] <= st[10] - 50_000_000
    assert seq.scans.load(0, T0 - 1) == []


def test_sequence_meta_is_json_and_names_the_conventions(scene_factory):
    import json

    scene = scene_factory(vendor="robosense", storage="sqlite3")
    seq = open_sequence(scene.path, wide())
    meta = json.loads(json.dumps(seq.meta))
    assert meta["time_convention"]["field"] == "timestamp"
    assert meta["imu_units"]["gyro_unit"] == "rad/s"
    assert meta["lidar_topic"] == "/points" and meta["path"] == str(scene.path)
    assert seq.start_ns >= T0 and seq.end_ns > seq.start_ns


def test_navsat_fixes_are_read(scene_factory):
    m = Msgs(True)
    fixes = [
        (
            "/gps/fix",
            "sensor_msgs/msg/NavSatFix",
            T0 + i * 100_000_000 + 1,
            m.navsat(
                T0 + i * 100_000_000, 47.0 + i * 1e-6, 8.0, 400.0 + i, status=2 if i != 3 else -1
            ),
        )
        for i in range(8)
    ]
    scene = scene_factory(vendor="livox", storage="mcap", extra=fixes)
    nav = read_navsat(scene.path, "/gps/fix")
    assert len(nav) == 8 and nav.valid.sum() == 7
    np.testing.assert_allclose(nav.altitude_m, 400.0 + np.arange(8))
    np.testing.assert_allclose(nav.position_covariance_m2[0], np.eye(3) * 0.01)
    assert nav.status[3] == -1 and nav.covariance_type[0] == 2
    with pytest.raises(
        DataError,
        match="topic '/imu' has type sensor_msgs/msg/Imu, expected "
        "sensor_msgs/msg/NavSatFix.*data.rtk_topic to one of: /gps/fix",
    ):
        read_navsat(scene.path, "/imu")
