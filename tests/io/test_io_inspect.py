"""``inspect``: per-topic report, issues that say what to change, suggested recipe; the CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import yaml

from l2calib.io.imu_reader import DEG, STANDARD_GRAVITY
from l2calib.preflight import inspect_bag
from l2calib.recipe import DataConfig


def cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "l2calib.cli.app", *args], capture_output=True, text=True
    )


def messages(report, severity=None):
    return [str(i) for i in report.issues if severity is None or i.severity == severity]


def test_healthy_bag_report_and_suggestion(scene_factory):
    scene = scene_factory(vendor="velodyne", storage="mcap", n_scans=15)
    rep = inspect_bag(scene.path)
    assert not rep.errors, messages(rep)
    (lidar,), (imu,) = rep.lidar, rep.imu
    assert lidar.layout == "velodyne" and lidar.stamps.count == 15
    assert abs(lidar.stamps.rate_hz - 10.0) < 0.5
    assert 0.05 < lidar.nan_share < 0.15 and 0.05 < lidar.zero_share < 0.15
    assert -0.1 < lidar.rel_time_s[0] < -0.09 and lidar.rel_time_s[1] == 0.0
    assert abs(imu.stamps.rate_hz - 200.0) < 1 and not imu.stamps.gaps_ns
    assert imu.units.gyro_unit == "rad/s" and imu.units.gyro_confirmed
    assert all(0.3 < w < 2.0 for w in imu.mean_abs_gyro_rad_s)
    assert abs(imu.stamps.record_minus_header_s[0] - 0.001) < 1e-6
    assert abs(lidar.stamps.record_minus_header_s[0] - 0.005) < 1e-6
    assert rep.overlap_s > 1.3
    assert rep.suggested == {
        "data": {
            "lidar": {
                "topic": "/points",
                "time_field": "time",
                "time_unit": "s",
                "time_reference": "relative",
                "stamp_position": "end",
            },
            "imu": {"topic": "/imu", "gyro_unit": "rad/s", "accel_unit": "m/s^2"},
        }
    }


def test_units_gaps_and_no_overlap_become_issues(scene_factory, tmp_path):
    scene = scene_factory(
        vendor="ouster", gyro_scale=1 / DEG, accel_scale=1 / STANDARD_GRAVITY, imu_drop=(0.4, 0.7)
    )
    rep = inspect_bag(scene.path)
    warn = "\n".join(messages(rep, "warning"))
    assert "gyro reads in deg/s" in warn and "keep data.imu.gyro_unit: deg/s" in warn
    assert "accelerometer reads in g" in warn
    assert "/imu: 1 gap(s) longer than 0.025 s; longest 0.30" in warn
    assert rep.suggested["data"]["imu"] == {
        "topic": "/imu",
        "gyro_unit": "deg/s",
        "accel_unit": "g",
    }
    (tmp_path / "b").mkdir()
    scene = scene_factory(vendor="hesai", imu_offset_s=-50.0)
    rep = inspect_bag(scene.path)
    assert any(
        "time ranges do not overlap" in m and "same clock" in m for m in messages(rep, "error")
    )


def test_recipe_topic_and_time_field_problems(scene_factory):
    scene = scene_factory(vendor="livox_v1")
    rep = inspect_bag(scene.path)
    errs = messages(rep, "error")
    assert any("/points: " in e and "no per-point time field" in e for e in errs), errs
    data = DataConfig.model_validate({"lidar": {"topic": "/imu", "time_field": "none"}})
    rep = inspect_bag(scene.path, data)
    errs = messages(rep, "error")
    assert errs == [
        f"error: {scene.path}: data.lidar.topic '/imu' has type sensor_msgs/msg/Imu"
        " — fix: set data.lidar.topic to one of: /points"
    ]


def test_empty_scans_and_lidar_gaps(scene_factory):
    scene = scene_factory(vendor="hesai", empty_scans=(2, 3), drop_scans=(7, 8, 9), n_scans=14)
    rep = inspect_bag(scene.path)
    assert rep.lidar[0].empty_scans == 2
    warn = messages(rep, "warning")
    assert any("/points: 2 empty scan(s)" in w for w in warn)
    assert any("/points: 1 gap(s) longer than 0.18" in w and "longest 0.4" in w for w in warn)


def test_cli_inspect_prints_suggestion_and_json(scene_factory, tmp_path):
    scene = scene_factory(vendor="custom", storage="sqlite3")
    out = cli("inspect", str(scene.path), "--json", str(tmp_path / "r.json"))
    assert out.returncode == 0, out.stderr
    assert "suggested recipe settings" in out.stdout and "livox-custom" in out.stdout
    suggestion = yaml.safe_load(out.stdout.split("suggested recipe settings:")[1])
    assert suggestion["data"]["lidar"]["time_field"] == "offset_time"
    (report,) = json.loads((tmp_path / "r.json").read_text())
    assert report["lidar"][0]["convention"]["unit"] == "ns"


def test_cli_inspect_fails_with_one_line_for_errors(scene_factory, tmp_path):
    scene = scene_factory(vendor="ouster", imu_offset_s=30.0)
    out = cli("inspect", str(scene.path))
    assert out.returncode == 1
    last = out.stderr.strip().splitlines()
    assert len(last) == 1 and last[0].startswith("error: 1 error(s) found; first: ")
    assert "do not overlap" in last[0] and " — fix: " in last[0]
    bad = tmp_path / "x.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 100)
    out = cli("inspect", str(bad))
    assert out.returncode == 1 and out.stderr.startswith(f"error: {bad}: cannot open bag")
