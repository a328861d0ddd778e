"""``l2calib select``: chosen windows, per-axis report, timeline PNG and JSON from bags."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "io"))
from io_scenes import make_scene  # noqa: E402

from l2calib.cli.cmd_select import parse_duration  # noqa: E402
from l2calib.errors import ConfigError  # noqa: E402


def cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "l2calib.cli.app", *args], capture_output=True, text=True
    )


def test_select_cli_prints_windows_and_writes_plot_and_json(tmp_path):
    a = make_scene(
        tmp_path,
        vendor="ouster",
        storage="ros1",
        n_scans=100,
        n_points=20,
        seed=1,
        lidar_topic="/os/points",
        imu_topic="/imu/data",
    )
    (tmp_path / "b").mkdir()
    b = make_scene(tmp_path / "b", vendor="custom", storage="mcap", n_scans=80, n_points=20, seed=2)
    png, js = tmp_path / "out" / "sel.png", tmp_path / "sel.json"
    out = cli(
        "select",
        str(a.path),
        str(b.path),
        "--budget",
        "9s",
        "--window",
        "3s",
        "--plot",
        str(png),
        "--json",
        str(js),
    )
    assert out.returncode == 0, out.stderr
    assert "chosen windows (9.0 s of 9.0 s)" in out.stdout
    assert "selection RMS per IMU axis" in out.stdout and "all axes excited" in out.stdout
    assert png.stat().st_size > 10_000
    sel = json.loads(js.read_text())
    assert len(sel["chosen"]) == 3 and sel["config"]["window_s"] == 3.0
    assert {c["sequence"] for c in sel["chosen"]} <= {"ouster_ros1", "custom_mcap"}


def test_select_cli_errors(tmp_path):
    out = cli("select", "nothing.bag", "--budget", "ten")
    assert out.returncode == 1
    assert out.stderr.strip() == (
        "error: --budget 'ten' is not a positive duration — fix: write "
        "e.g. --budget 30s (units: ms, s, m, h)"
    )
    scene = make_scene(
        tmp_path,
        vendor="hesai",
        n_scans=40,
        n_points=20,
        imu_kw={"rot_amp_rad": (0, 0, 0), "acc_amp_m_s2": (0, 0, 0)},
    )
    out = cli("select", str(scene.path), "--budget", "10s", "--plot", str(tmp_path / "p.png"))
    assert (
        out.returncode == 1
        and "error: no window was selected: no eligible window: hesai_ros1: every window is still"
        in out.stderr
        and "fix: record motion" in out.stderr
    )


def test_parse_duration():
    assert parse_duration("30s", "--budget") == 30.0
    assert parse_duration("1.5m", "--budget") == 90.0
    assert parse_duration("500ms", "--window") == 0.5
    assert parse_duration("12", "--budget") == 12.0
    with pytest.raises(ConfigError, match="--step '-1s' is not a positive duration"):
        parse_duration("-1s", "--step")
