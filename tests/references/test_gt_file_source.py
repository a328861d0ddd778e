"""gt-file reference: formats, frames, clock offsets and bad input."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.errors import ConfigError, FormatError, ReferenceSourceError
from l2calib.io.trajectory_files import write_csv, write_kitti, write_tum
from l2calib.plugins import get_plugin
from l2calib.recipe import recipe_from_dict
from l2calib.trajectory import Trajectory


def build(**options):
    return get_plugin("l2calib.references", "gt-file").build(options)


def close_to_gt(case, traj, atol=1e-6):
    gt = case.run.gt_lidar.interpolate(traj.stamps_ns)
    assert np.abs(gt.t_world_body - traj.t_world_body).max() < atol
    dots = np.abs(np.sum(gt.quat_xyzw * traj.quat_xyzw, axis=1))
    assert dots.min() > 1 - 1e-9


def test_lidar_tum_covers_the_segment(sway, tmp_path):
    path = tmp_path / "gt.tum"
    write_tum(path, sway.run.gt_lidar)
    ref = build(path=str(path)).compute([sway.segment])[0]
    tr, scans = ref.trajectory, sway.segment.scans
    assert ref.constrains == "pose" and ref.source == "gt-file" and tr.body_frame == "lidar"
    assert tr.stamps_ns[0] <= scans[0].stamp_ns and tr.stamps_ns[-1] >= scans[-1].end_stamp_ns
    assert tr.stamps_ns[1] > scans[0].stamp_ns  # cut to the segment, one pose either side
    close_to_gt(sway, tr)


def test_imu_csv_with_extrinsic_matrix_is_position_only(sway, tmp_path, caplog):
    path = tmp_path / "imu.csv"
    write_csv(path, sway.run.gt_imu)
    T = sway.run.T_imu_lidar.tolist()
    offset = sway.run.time_offset_s  # gt_imu is on the IMU clock: t_lidar = t_imu - offset
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        src = build(path=str(path), body_frame="imu", T_body_lidar=T, time_offset_s=-offset)
        ref = src.compute([sway.segment])[0]
    assert ref.constrains == "position"
    assert "quantity being calibrated" in caplog.text and "drops its rotation term" in caplog.text
    close_to_gt(sway, ref.trajectory, atol=1e-5)
    pose = build(path=str(path), body_frame="imu", T_body_lidar=T, constrains="pose")
    assert pose.compute([sway.segment])[0].constrains == "pose"


def test_other_body_kitti_with_rpy_transform(sway, tmp_path):
    rpy_deg, t = (10.0, -20.0, 95.0), (0.3, -0.2, 1.1)
    R = geo.euler_rpy_to_matrix(torch.tensor(np.radians(rpy_deg)))
    T_body_lidar = geo.make_transform(R, torch.tensor(t))
    body = sway.run.gt_lidar.with_body(geo.transform_inverse(T_body_lidar), "mocap")
    poses, times = tmp_path / "poses.kitti", tmp_path / "times.txt"
    write_kitti(poses, body, times)
    src = build(
        path=str(poses),
        times_path=str(times),
        body_frame="other",
        T_body_lidar={"translation_m": t, "rpy_deg": rpy_deg},
    )
    ref = src.compute([sway.segment])[0]
    assert ref.constrains == "pose"
    close_to_gt(sway, ref.trajectory, atol=1e-6)


@pytest.mark.parametrize(
    "options, match",
    [
        ({"body_frame": "imu"}, "body_frame imu needs T_body_lidar"),
        ({"T_body_lidar": np.eye(4).tolist()}, "body_frame is lidar but T_body_lidar is given"),
        ({"body_frame": "other", "T_body_lidar": [[1, 0, 0]]}, "4 rows of 4 numbers"),
        ({"format": "kitti"}, "needs times_path"),
    ],
)
def test_frame_mismatch_in_the_recipe_names_the_field(options, match):
    data = {"reference": {"name": "gt-file", "options": {"path": "gt.tum", **options}}}
    with pytest.raises(ConfigError, match=f"reference.options.*{match}"):
        recipe_from_dict(data, "recipe.yaml")


def test_non_rigid_matrix_is_rejected(sway, tmp_path):
    path = tmp_path / "imu.tum"
    write_tum(path, sway.run.gt_imu)
    T = np.eye(4)
    T[0, 0] = 2.0
    src = build(path=str(path), body_frame="imu", T_body_lidar=T.tolist())
    with pytest.raises(ConfigError, match="T_body_lidar is not a rigid transform"):
        src.compute([sway.segment])


def test_file_that_does_not_overlap_the_bag(sway, tmp_path):
    gt = sway.run.gt_lidar
    path = tmp_path / "gt.tum"
    write_tum(path, gt.shifted(-int(gt.stamps_ns[0])))  # the file's clock starts at 0
    with pytest.raises(ReferenceSourceError, match="does not overlap segment") as err:
        build(path=str(path)).compute([sway.segment])
    assert "time_offset_s" in err.value.fix
    hint = float(err.value.fix.rsplit(":", 1)[1].strip(" )"))
    fixed = build(path=str(path), time_offset_s=hint, check_imu=False)
    ref = fixed.compute([sway.segment])[0]  # the hint is the file start at the segment start
    assert ref.trajectory.stamps_ns[0] <= sway.segment.scans[0].stamp_ns


def test_partial_coverage_and_gaps(sway, tmp_path):
    gt, seg = sway.run.gt_lidar, sway.segment
    short = gt.slice_time(int(gt.stamps_ns[0]), seg.scans[10].stamp_ns)
    write_tum(tmp_path / "short.tum", short)
    with pytest.raises(ReferenceSourceError, match="covers .* but segment .* needs"):
        build(path=str(tmp_path / "short.tum")).compute([seg])
    keep = (gt.stamps_ns < seg.scans[15].stamp_ns) | (gt.stamps_ns > seg.scans[18].stamp_ns)
    holed = Trajectory(gt.stamps_ns[keep], gt.t_world_body[keep], gt.quat_xyzw[keep])
    write_tum(tmp_path / "holed.tum", holed)
    with pytest.raises(ReferenceSourceError, match=r"s gap at .* inside segment"):
        build(path=str(tmp_path / "holed.tum")).compute([seg])


def test_clock_offset_is_detected_from_the_gyro(sway, tmp_path):
    path = tmp_path / "late.tum"
    write_tum(path, sway.run.gt_lidar.shifted(300_000_000))  # file stamps 0.3 s late
    with pytest.raises(ReferenceSourceError, match=r"shifted by \+0.30") as err:
        build(path=str(path)).compute([sway.segment])
    assert "time_offset_s to -0.300" in err.value.fix
    ref = build(path=str(path), time_offset_s=-0.3).compute([sway.segment])[0]
    close_to_gt(sway, ref.trajectory)


def test_wrong_quaternion_order_is_detected(sway, tmp_path):
    gt = sway.run.gt_lidar
    wxyz = np.roll(gt.quat_xyzw, 1, axis=1)  # written as qw qx qy qz
    path = tmp_path / "wxyz.tum"
    write_tum(path, Trajectory(gt.stamps_ns, gt.t_world_body, wxyz))
    with pytest.raises(ReferenceSourceError, match="not a fixed rotation of the IMU") as err:
        build(path=str(path)).compute([sway.segment])
    assert "qx qy qz qw" in err.value.fix


def test_inverted_poses_are_detected(sway, tmp_path):
    gt = sway.run.gt_lidar
    inv = Trajectory.from_matrices(gt.stamps_ns, geo.transform_inverse(gt.matrices()))
    write_tum(tmp_path / "inv.tum", inv)  # T_body_world instead of T_world_body
    with pytest.raises(ReferenceSourceError, match="not a fixed rotation of the IMU"):
        build(path=str(tmp_path / "inv.tum")).compute([sway.segment])
    ok = build(path=str(tmp_path / "inv.tum"), check_imu=False).compute([sway.segment])
    assert len(ok[0].trajectory) > 10


def test_bad_file_content_names_the_line(sway, tmp_path):
    path = tmp_path / "bad.tum"
    path.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"bad.tum:2: 7 columns, expected 8"):
        build(path=str(path)).compute([sway.segment])
