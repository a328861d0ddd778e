from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2calib.errors import DataError, FormatError
from l2calib.io import trajectory_files as tf
from l2calib.trajectory import Trajectory


@pytest.fixture
def traj(rng):
    n = 15
    stamps = 1_403_636_580_838_555_648 + np.arange(n, dtype=np.int64) * 50_000_001
    return Trajectory(stamps, rng.normal(size=(n, 3)), Rotation.random(n, random_state=3).as_quat())


def _same(a: Trajectory, b: Trajectory, atol=1e-8):
    assert np.array_equal(a.stamps_ns, b.stamps_ns)
    np.testing.assert_allclose(a.t_world_body, b.t_world_body, atol=atol)
    dots = np.abs(np.sum(a.quat_xyzw * b.quat_xyzw, axis=1))
    np.testing.assert_allclose(dots, 1, atol=1e-8)


@pytest.mark.parametrize("fmt", ["tum", "csv", "kitti"])
def test_roundtrip_keeps_nanoseconds(tmp_path, traj, fmt):
    path = tmp_path / f"t.{fmt}"
    times = tmp_path / "times.txt"
    tf.write_trajectory(path, traj, fmt, times_path=times)
    back = tf.read_trajectory(path, fmt, times_path=times)
    _same(traj, back)


def test_parse_seconds_exact():
    assert tf.parse_seconds_ns("1403636580.838555648") == 1403636580838555648
    assert tf.parse_seconds_ns("12") == 12_000_000_000
    assert tf.parse_seconds_ns("-0.5") == -500_000_000
    assert tf.parse_seconds_ns("1.5e3") == 1_500_000_000_000
    assert tf.format_seconds(12_000_000_001) == "12.000000001"
    with pytest.raises(ValueError):
        tf.parse_seconds_ns("1.2.3")


def test_tum_wrong_column_count(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("# comment\n0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 1\n")
    with pytest.raises(FormatError) as err:
        tf.read_tum(p)
    msg = str(err.value)
    assert f"{p}:3: 7 columns, expected 8" in msg
    assert "timestamp tx ty tz qx qy qz qw" in msg


def test_tum_non_numeric_and_bad_stamp(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("0.0 0 0 zero 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"bad.tum:1: non-numeric value"):
        tf.read_tum(p)
    p.write_text("abc 0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"bad.tum:1: timestamp 'abc' is not a number"):
        tf.read_tum(p)


def test_tum_unsorted_and_non_unit(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match="not strictly increasing at pose 2"):
        tf.read_tum(p)
    p.write_text("0.0 0 0 0 1 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match="quaternion of pose 1 has norm 1.4142"):
        tf.read_tum(p)


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        tf.read_tum(tmp_path / "nope.tum")
    p = tmp_path / "empty.tum"
    p.write_text("# only a comment\n")
    with pytest.raises(FormatError, match="holds no poses"):
        tf.read_tum(p)


def test_kitti_errors(tmp_path, traj):
    p, times = tmp_path / "poses.txt", tmp_path / "times.txt"
    tf.write_kitti(p, traj, times)
    with pytest.raises(FormatError, match="KITTI poses carry no time stamps"):
        tf.read_kitti(p, None)
    times.write_text("0.0\n0.1\n")
    with pytest.raises(FormatError, match="has 15 poses but .*times.txt has 2 times"):
        tf.read_kitti(p, times)
    p.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"poses.txt:1: 11 columns, expected 12 \('r11 r12"):
        tf.read_kitti(p, times)
    p.write_text("2 0 0 0 0 1 0 0 0 0 1 0\n")
    times.write_text("0.0\n")
    with pytest.raises(FormatError, match="non-orthonormal rotation"):
        tf.read_kitti(p, times)


def test_csv_headers(tmp_path):
    p = tmp_path / "gt.csv"
    p.write_text(
        "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
        "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1]\n"
        "1403636580838555648,1,2,3,1,0,0,0,0.5\n"
        "1403636580843555328,1,2,4,0,1,0,0,0.5\n"
    )
    t = tf.read_csv(p)
    assert t.stamps_ns[0] == 1403636580838555648
    np.testing.assert_allclose(t.quat_xyzw, [[0, 0, 0, 1], [1, 0, 0, 0]])
    p.write_text("timestamp_s,qx,qy,qz,qw,x,y,z\n0.5,0,0,0,1,1,2,3\n")
    t = tf.read_csv(p)
    assert t.stamps_ns[0] == 500_000_000
    np.testing.assert_allclose(t.t_world_body, [[1, 2, 3]])


def test_csv_bad_header_and_row(tmp_path):
    p = tmp_path / "gt.csv"
    p.write_text("time,a,b\n1,2,3\n")
    with pytest.raises(FormatError) as err:
        tf.read_csv(p)
    assert "gt.csv:1: unrecognised CSV header 'time,a,b'" in str(err.value)
    assert "stamp_ns,x,y,z,qx,qy,qz,qw" in str(err.value)
    p.write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n1.5,0,0,0,0,0,0,1\n")
    with pytest.raises(FormatError, match="gt.csv:2: stamp '1.5' is not an integer number of nano"):
        tf.read_csv(p)
    p.write_text("stamp_ns,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,1\n")
    with pytest.raises(FormatError, match="gt.csv:2: 7 columns, expected 8"):
        tf.read_csv(p)


def test_unknown_extension(tmp_path):
    with pytest.raises(FormatError, match="cannot tell the trajectory format"):
        tf.read_trajectory(tmp_path / "x.json")
