"""The gt-file clock check tells a LiDAR–IMU offset from a file on another clock (issue 21)."""

from __future__ import annotations

import logging

import pytest

from l2calib.errors import ReferenceSourceError
from l2calib.io.trajectory_files import write_csv, write_tum
from l2calib.plugins import get_plugin


@pytest.fixture(scope="module")
def lagging():
    """6 s hand-held sway, IMU clock 50 ms ahead of the LiDAR's (t_imu = t_lidar + 0.05)."""
    from ref_helpers import make_case

    cfg = {
        "duration_s": 6.0,
        "seed": 4,
        "world": {"name": "hall"},
        "motion": {"profile": "handheld", "still_start_s": 0.5},
        "lidar": {"model": "ouster-os1-16", "columns": 64},
        "rig": {"time_offset_s": 0.05},
    }
    return make_case(cfg, first=10, last=50)


def build(**options):
    context = {k: options.pop(k) for k in ("estimate_time_offset",) if k in options}
    return get_plugin("l2calib.references", "gt-file").build(options, **context)


def test_lidar_file_against_a_shifted_imu_names_the_lidar_imu_offset(lagging, tmp_path):
    path = tmp_path / "gt_lidar.tum"
    write_tum(path, lagging.run.gt_lidar)  # exactly on the LiDAR clock
    with pytest.raises(ReferenceSourceError, match=r"shifted by -0.050 s") as err:
        build(path=str(path)).compute([lagging.segment])
    msg, fix = err.value.message, err.value.fix
    assert "the IMU is shifted against the LiDAR (t_imu = t_lidar + 0.050 s)" in msg
    assert "train.estimate_time_offset=true (it starts from +0.050 s)" in fix
    assert "correct the IMU stamps in the bag by -0.050 s" in fix
    assert "time_offset_s to" not in fix  # the file is right: moving it is the wrong fix


def test_with_estimation_the_shift_is_the_starting_value(lagging, tmp_path, caplog):
    path = tmp_path / "gt_lidar.tum"
    write_tum(path, lagging.run.gt_lidar)
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        refs = build(path=str(path), estimate_time_offset=True).compute([lagging.segment])
    assert refs[0].time_offset_hint_s == pytest.approx(0.05, abs=0.011)  # 10 ms grid
    assert "LiDAR–IMU time offset (t_imu = t_lidar + 0.050 s)" in caplog.text
    assert "starting from there" in caplog.text


def test_imu_framed_file_on_another_clock_names_the_file(lagging, tmp_path):
    path = tmp_path / "ins.csv"
    write_csv(path, lagging.run.gt_imu.shifted(-80_000_000))  # INS stamps 80 ms early
    T = lagging.run.T_imu_lidar.tolist()
    src = build(path=str(path), body_frame="imu", T_body_lidar=T, estimate_time_offset=True)
    with pytest.raises(ReferenceSourceError, match=r"shifted by -0.080 s") as err:
        src.compute([lagging.segment])  # estimation on: the file's clock still stops the run
    assert "describes the IMU (body_frame imu)" in err.value.message
    assert "the file is on another clock" in err.value.message
    assert "set reference.options.time_offset_s to 0.080" in err.value.fix
    assert "estimate_time_offset" not in err.value.fix
