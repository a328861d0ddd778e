"""``inspect`` estimates the LiDAR-IMU time offset on a simulated bag (issue 21 item 3)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from l2calib.preflight import inspect_bag


def _bag(tmp_path, profile: str, offset_s: float):
    out = tmp_path / profile
    cmd = [sys.executable, "-m", "l2calib.cli.app", "simulate", "-o", str(out), "--duration",
           "9", "--seed", "4", "--profile", profile, "--time-offset", str(offset_s),
           "--lidar", "ouster-os1-16"]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=600)
    return out / "sim.bag"


def test_inspect_finds_a_30_ms_offset_and_suggests_the_recipe_lines(tmp_path):
    rep = inspect_bag(_bag(tmp_path, "handheld", 0.03), time_offset=True)
    est = rep.time_offset
    assert est is not None and est.observable, est
    assert est.time_offset_s == pytest.approx(0.03, abs=0.005)
    assert rep.suggested["train"]["estimate_time_offset"] is True
    assert rep.suggested["train"]["init_time_offset_s"] == pytest.approx(0.03, abs=0.005)
    (issue,) = [i for i in rep.issues if i.where.endswith("time offset")]
    assert issue.severity == "warning" and "+30." in issue.message
    assert "train.init_time_offset_s=0.03" in issue.fix


def test_inspect_names_a_cruising_uav_offset_weakly_observable(tmp_path):
    rep = inspect_bag(_bag(tmp_path, "uav", 0.03), time_offset=True)
    assert rep.time_offset is not None and not rep.time_offset.observable
    (issue,) = [i for i in rep.issues if i.where.endswith("time offset")]
    assert "weakly observable" in issue.message and "no offset claimed" in issue.message
    assert "train" not in rep.suggested


def test_a_short_bag_is_not_estimated(scene_factory):
    rep = inspect_bag(scene_factory(vendor="velodyne", n_scans=15).path, time_offset=True)
    assert rep.time_offset is None
    (issue,) = [i for i in rep.issues if i.where.endswith("time offset")]
    assert issue.severity == "info" and "needs 7 s" in issue.message


def test_the_recipe_start_value_wins_over_the_reference_hint():
    from l2calib.recipe import TrainConfig
    from l2calib.train.offset_hold import offset_start_s

    on = TrainConfig(estimate_time_offset=True)
    assert offset_start_s(on, 0.05) == 0.05  # the gt-file clock check's hint
    assert offset_start_s(on.model_copy(update={"init_time_offset_s": 0.03}), 0.05) == 0.03
    off = TrainConfig(estimate_time_offset=False, init_time_offset_s=0.03)
    assert offset_start_s(off, 0.05) is None  # not estimated
    assert offset_start_s(on, None) is None  # from 0
