"""Simulator bags (every vendor layout, ROS1 and ROS2) read back to the simulator's ground truth.

Points are compared as sets per scan (organised Ouster clouds reorder them): sorted by
(time, x, y, z). Time tolerance 300 ns: float64 absolute times carry 238 ns (s) / 256 ns (ns)
resolution at epoch 1.7e9 s, and the Ouster ``t`` is the nominal column time (the simulator
rounds those to ≤ 128 ns of its per-point times). Livox CustomMsg is exact.
"""

from __future__ import annotations

import numpy as np
import pytest

from l2calib.io.sequences import open_sequence
from l2calib.recipe import DataConfig
from l2calib.sim import SimConfig, simulate
from l2calib.sim.bagwriter import BagOptions, write_bag

MODELS = {
    "ouster": "ouster-os1-16",
    "velodyne": "velodyne-vlp-16",
    "hesai": "hesai-pandar-xt32",
    "livox": "livox-mid360",
}
CASES = [
    (v, fmt, "driver", "auto")
    for v in ("ouster", "velodyne", "hesai", "livox")
    for fmt in ("ros1", "ros2-sqlite3", "ros2-mcap")
]
CASES += [("livox", fmt, "driver", "pointcloud2") for fmt in ("ros1", "ros2-mcap")]
CASES += [
    ("velodyne", "ros1", "start", "auto"),
    ("hesai", "ros2-mcap", "end", "auto"),
    ("livox", "ros1", "end", "pointcloud2"),
]


@pytest.fixture(scope="module")
def runs():
    out = {}
    for vendor, model in MODELS.items():
        lidar = {"model": model, "noise": True}
        if vendor != "livox":
            lidar["columns"] = 128
        duration = 1.5
        cfg = SimConfig.model_validate(
            {"duration_s": duration, "seed": 3, "lidar": lidar, "motion": {"still_start_s": 0.3}}
        )
        out[vendor] = simulate(cfg)
    return out


def _sorted(times: np.ndarray, pts: np.ndarray):
    o = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0], times))
    return times[o], pts[o]


@pytest.mark.parametrize(("vendor", "fmt", "stamp", "msg"), CASES)
def test_simulated_bag_reads_back_to_ground_truth(runs, tmp_path, vendor, fmt, stamp, msg):
    run = runs[vendor]
    ros2 = fmt != "ros1"
    opts = BagOptions(
        format=fmt,
        stamp_position=stamp,
        lidar_msg=msg,
        gyro_unit="deg/s" if ros2 else "rad/s",
        accel_unit="g" if ros2 else "m/s^2",
    )
    info = write_bag(run, tmp_path / ("sim" if ros2 else "sim.bag"), opts)
    data = DataConfig()
    data.lidar.topic, data.imu.topic = info["lidar"]["topic"], info["imu"]["topic"]
    data.lidar.min_range_m, data.lidar.max_range_m = 1e-3, 1e4
    seq = open_sequence(info["path"], data)
    conv = seq.meta["time_convention"]
    assert conv["stamp_position"] == info["lidar"]["stamp_position"]
    assert seq.meta["warnings"] == []
    units = seq.meta["imu_units"]
    assert (units["gyro_unit"], units["accel_unit"]) == (opts.gyro_unit, opts.accel_unit)
    np.testing.assert_array_equal(seq.imu.stamps_ns, run.imu.stamps_ns)
    np.testing.assert_allclose(seq.imu.gyro_rad_s, run.imu.gyro_rad_s, rtol=1e-12, atol=1e-15)
    # 1 g is standard gravity (9.80665 m/s²) for the reader; the simulator divides by its local
    # gravity (9.81) when it writes g, a 3.4e-4 relative difference.
    rtol = 5e-4 if opts.accel_unit == "g" else 1e-12
    np.testing.assert_allclose(seq.imu.accel_m_s2, run.imu.accel_m_s2, rtol=rtol, atol=1e-15)
    scans = seq.scans.load(0, 2**62)
    assert len(scans) == len(run.scans)
    tol = 0 if info["lidar"]["msgtype"].endswith("CustomMsg") else 300
    for got, want in zip(scans, run.scans, strict=True):
        assert len(got) == len(want)
        assert abs(got.stamp_ns - want.stamp_ns) <= tol
        tg, pg = _sorted(got.point_stamps_ns, got.points_lidar)
        tw, pw = _sorted(want.point_stamps_ns, want.points_lidar.astype(np.float32))
        assert np.abs(tg - tw).max() <= tol
        np.testing.assert_array_equal(pg, pw)
