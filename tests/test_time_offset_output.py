"""calibration.yaml with an estimated LiDAR–IMU time offset (issue 21): convention, resolution,
FAST-LIO / LI-Init forms, and the starting value from the reference's clock check."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from l2calib.assess.result import CalibrationResult
from l2calib.assess.time_offset_probe import OFFSET_STEPS_S, probe_offsets, resolve_offset
from l2calib.outputs.calibration_file import read_extrinsic, write_calibration


def test_probe_ladder_resolves_a_peak_and_names_a_flat_reward():
    offsets = probe_offsets(0.02).numpy()
    assert offsets[0] == 0.02 and len(offsets) == 1 + 2 * len(OFFSET_STEPS_S)
    peaked = resolve_offset(1.0 - 20.0 * np.abs(offsets - 0.02))  # drops 0.02 per ms
    assert peaked.resolution_s == pytest.approx(0.00025)  # 0.5 % of 1.0 at 0.02 per ms
    assert peaked.undetermined() == []
    flat = resolve_offset(np.full(len(offsets), 0.9))
    assert np.isinf(flat.resolution_s) and flat.undetermined() == ["time offset (resolution flat)"]
    off_peak = resolve_offset(1.0 - 20.0 * np.abs(offsets - 0.05))  # the optimum is 30 ms away
    assert "not converged" in off_peak.undetermined()[-1]


def test_written_offset_carries_its_convention_and_pasteable_forms(tmp_path):
    offsets = probe_offsets(0.031).numpy()
    res = CalibrationResult(
        np.eye(4),
        time_offset_s=0.031,
        time_offset_resolution=resolve_offset(np.full(len(offsets), 0.9)),
        time_offset_start_s=0.03,
    )
    path = write_calibration(tmp_path / "calibration.yaml", res)
    text = path.read_text()
    assert "# time_offset_s: t_imu = t_lidar + time_offset_s" in text
    assert "common/time_offset_lidar_to_imu" in text and "Time Lag IMU to LiDAR" in text
    data = yaml.safe_load(text)
    assert data["time_offset_s"] == 0.031
    block = data["time_offset"]
    assert block["convention"].startswith("t_imu = t_lidar + time_offset_s")
    assert block["start_s"] == 0.03 and block["resolution_s"] is None
    assert "flat" in block["undetermined"]
    assert data["fast_lio"]["time_offset_lidar_to_imu"] == 0.031
    assert data["fast_lio"]["time_sync_en"] is False
    assert data["li_init"]["time_lag_imu_to_lidar_s"] == 0.031
    assert read_extrinsic(path).time_offset_s == 0.031
    plain = yaml.safe_load(
        write_calibration(tmp_path / "p.yaml", CalibrationResult(np.eye(4))).read_text()
    )
    assert plain["time_offset_s"] is None and "time_offset" not in plain
    assert "time_offset_lidar_to_imu" not in plain["fast_lio"] and "li_init" not in plain


def test_two_iteration_calibrate_with_estimation_writes_the_offset(tmp_path):
    """A 50 ms offset: the clock check and the rate correlation find it; held and written."""
    from l2calib.sim import SimConfig, simulate, write_run

    cfg = {"duration_s": 6.0, "seed": 4, "lidar": {"model": "ouster-os1-16", "columns": 256}}
    cfg["rig"] = {"time_offset_s": 0.05}
    run = simulate(SimConfig.model_validate(cfg))
    files = write_run(run, tmp_path / "sim")
    out = tmp_path / "out"
    # a prior at the truth: two iterations from no guess are a coin toss (a "not-calibrated"
    # status writes no paste-ready blocks); this test is about the offset, not the search
    truth = CalibrationResult(run.T_imu_lidar)
    prior = {"translation_m": truth.T_imu_lidar[:3, 3].round(4).tolist(),
             "rpy_deg": truth.rpy_deg.round(3).tolist(),
             "sigma_translation_m": 0.02, "sigma_rotation_deg": 2.0}  # fmt: skip
    sets = [
        f"policy.prior={json.dumps(prior)}",
        "train.candidates_per_iteration=8", "train.refine_rounds=1", "train.restarts=0",
        "selection.window_s=3", "selection.budget_s=3", "train.max_iterations=2",
        "train.estimate_time_offset=true", "reference.name=gt-file",
        f"reference.options.path={files['gt_lidar']}",
    ]  # fmt: skip
    cmd = [sys.executable, "-m", "l2calib.cli.app", "calibrate", "simulator", "--bag"]
    cmd += [files["bag"], "--out", str(out), *[a for s in sets for a in ("--set", s)]]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)  # hang guard
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = " ".join(proc.stdout.split())
    assert "measured a LiDAR–IMU time offset of +50.0 ms" in text
    data = yaml.safe_load((out / "calibration.yaml").read_text())
    assert 1 <= data["training"]["iterations"] <= 2  # a prior this narrow may hand over at 1
    assert isinstance(data["time_offset_s"], float) and abs(data["time_offset_s"]) < 0.2
    assert data["time_offset"]["start_s"] == pytest.approx(0.05, abs=0.011)
    # the clock check and the references' rate agree and are sharp: the offset is held there
    assert data["time_offset"]["method"].startswith("held at the references' rotation-rate")
    assert data["time_offset_s"] == pytest.approx(0.05, abs=0.001)
    assert len(data["time_offset"]["probe_drops"]) == len(OFFSET_STEPS_S)
    assert data["fast_lio"]["time_offset_lidar_to_imu"] == data["time_offset_s"]
