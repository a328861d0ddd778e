"""calibration.yaml: content, round trip, and the demo command end to end (tiny budget)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import yaml

from l2calib import geometry as geo
from l2calib.assess.result import CalibrationResult
from l2calib.assess.sensitivity import AxisResolution
from l2calib.errors import DataError, NotCalibratedError
from l2calib.outputs.calibration_file import read_extrinsic, write_calibration


def _T() -> np.ndarray:
    R = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor([180.0, 0.0, 90.0])))
    return geo.make_transform(R, torch.tensor([0.12, -0.05, 0.08])).numpy()


def test_round_trip_and_paste_ready_forms(tmp_path):
    res = AxisResolution([0.2, math.inf, 0.1], [0.01, 0.02, math.inf], 0.95)
    result = CalibrationResult(_T(), resolution=res, undetermined=["rotation about LiDAR y"])
    path = write_calibration(tmp_path / "calibration.yaml", result)
    data = yaml.safe_load(path.read_text())
    read = read_extrinsic(path)
    assert np.allclose(read.T_imu_lidar.numpy(), _T(), atol=1e-9) and read.time_offset_s is None
    assert np.allclose(np.array(data["T_lidar_imu"]) @ _T(), np.eye(4), atol=1e-8)
    assert data["fast_lio"]["extrinsic_T"] == pytest.approx([0.12, -0.05, 0.08])
    assert np.allclose(np.reshape(data["fast_lio"]["extrinsic_R"], (3, 3)), _T()[:3, :3], atol=1e-8)
    R_rpy = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor(data["rpy_deg"])))
    assert np.allclose(R_rpy.numpy(), _T()[:3, :3], atol=1e-5)  # roll ±180 are the same
    assert 'xyz="0.120000 -0.050000 0.080000"' in data["urdf"]
    unc = data["uncertainty"]
    assert unc["resolution_rotation_deg"] == [0.2, None, 0.1]
    assert unc["resolution_translation_m"] == [0.01, 0.02, None]
    assert unc["undetermined"] == ["rotation about LiDAR y"]


def test_the_per_axis_bounds_are_written_in_the_users_units(tmp_path):
    """95 % bounds: deg / m / s, null where flat or held, with their meaning and what was held."""
    from l2calib.assess.uncertainty import AxisUncertainty

    bound = np.array([math.radians(0.05), math.radians(0.1), math.inf, 0.004, 0.006, math.inf])
    zeros = np.zeros(6)
    flat = ~np.isfinite(bound)
    unc = AxisUncertainty(bound, zeros, zeros, zeros, flat, 10, 200, 0.1, held=[5], tau=6.25)
    path = write_calibration(tmp_path / "c.yaml", CalibrationResult(_T(), axis_uncertainty=unc))
    written = yaml.safe_load(path.read_text())["uncertainty"]
    assert written["bound95_rotation_deg"] == [0.05, 0.1, None]
    assert written["bound95_translation_m"] == [0.004, 0.006, None]
    assert "bound95_time_offset_s" not in written  # not estimated
    assert written["bound95_held"] == ["translation along LiDAR z"]
    assert "95 %" in written["bound95_meaning"]
    assert written["bound95_correlation_scans"] == 6.25
    assert "bound95_reference_translation_m" not in written  # no second reference estimate
    # with one (ct-lidar's two passes), the reference's part is written beside the bound
    ref = np.array([math.radians(0.02), 0, 0, 0.003, 0.001, 0])
    unc.reference95 = ref
    path = write_calibration(tmp_path / "r.yaml", CalibrationResult(_T(), axis_uncertainty=unc))
    written = yaml.safe_load(path.read_text())["uncertainty"]
    assert written["bound95_reference_translation_m"] == [0.003, 0.001, 0.0]
    assert written["bound95_reference_rotation_deg"] == [0.02, 0.0, 0.0]
    assert "bound95_caveats" not in written
    unc.caveats = ["one drive and a LiDAR-only reference: ..."]
    path = write_calibration(tmp_path / "c2.yaml", CalibrationResult(_T(), axis_uncertainty=unc))
    written = yaml.safe_load(path.read_text())["uncertainty"]
    assert written["bound95_caveats"] == unc.caveats


def test_unreliable_result_warns_above_the_paste_ready_blocks(tmp_path):
    reason = "the odometry and the reference disagree by 63 cm"
    result = CalibrationResult(_T(), status="unreliable", status_reasons=[reason])
    text = write_calibration(tmp_path / "calibration.yaml", result).read_text()
    lines = text.splitlines()
    for block in ("fast_lio:", "urdf:"):
        above = lines[lines.index(next(x for x in lines if x.startswith(block))) - 1]
        assert above.startswith("# WARNING: status unreliable")
    data = yaml.safe_load(text)
    assert data["status"] == "unreliable" and data["status_reasons"] == [reason]
    assert "UNRELIABLE" in data["urdf"]  # the warning travels with a pasted URDF origin


def test_not_calibrated_result_has_no_paste_ready_blocks(tmp_path):
    result = CalibrationResult(_T(), status="not-calibrated", status_reasons=["too short"])
    text = write_calibration(tmp_path / "calibration.yaml", result).read_text()
    data = yaml.safe_load(text)
    assert "# NOT CALIBRATED" in text and data["status"] == "not-calibrated"
    assert "fast_lio" not in data and "urdf" not in data


def _stopped() -> CalibrationResult:
    return CalibrationResult(
        None,
        stop_reason="stopped before training: the data is too short or too still",
        status="not-calibrated",
        status_reasons=["only 0.9 s of usable data: record at least 5 s of motion"],
        extra={"data": {"selected_s": 0.9}},
    )


def test_a_run_stopped_before_training_writes_no_extrinsic(tmp_path):
    text = write_calibration(tmp_path / "calibration.yaml", _stopped()).read_text()
    assert "# NOT CALIBRATED: calibrate stopped before training" in text
    data = yaml.safe_load(text)
    assert data["status"] == "not-calibrated" and data["data"] == {"selected_s": 0.9}
    assert data["training"]["iterations"] == 0
    for key in ("T_imu_lidar", "translation_m", "quaternion_xyzw", "rpy_deg", "T_lidar_imu"):
        assert key not in data
    assert "fast_lio" not in data and "urdf" not in data and "uncertainty" not in data
    with pytest.raises(NotCalibratedError, match="stopped before training"):
        _stopped().rpy_deg  # noqa: B018  (the property raises)


@pytest.mark.parametrize(
    ("result", "says"),
    [
        (_stopped(), "calibrate stopped before training and wrote no extrinsic"),
        (
            CalibrationResult(_T(), status="not-calibrated", status_reasons=["flat"]),
            "its values are a partial result for diagnosis only",
        ),
    ],
    ids=["stopped-before-training", "flat-after-training"],
)
def test_reading_the_extrinsic_of_a_not_calibrated_file_is_a_clear_error(tmp_path, result, says):
    path = write_calibration(tmp_path / "calibration.yaml", result)
    with pytest.raises(NotCalibratedError) as info:
        read_extrinsic(path)
    assert isinstance(info.value, DataError)  # an L2CalibError: one line from the CLI
    message = str(info.value)
    assert message.startswith(f"{path}: status not-calibrated: {says}")
    assert "status_reasons[0]:" in message and " — fix: record the motion" in message


def test_reading_a_file_that_is_not_a_mapping_is_a_clear_error(tmp_path):
    p = tmp_path / "list.yaml"
    p.write_text("- 1\n- 2\n")
    with pytest.raises(DataError, match="list.yaml: not a calibration file"):
        read_extrinsic(p)


def test_reading_a_file_without_an_extrinsic_names_the_fix(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("foo: 1\n")
    with pytest.raises(DataError, match="no extrinsic found") as info:
        read_extrinsic(p)
    assert "x.yaml" in str(info.value)


def test_demo_command_runs_end_to_end_on_a_tiny_budget(tmp_path):
    from typer.testing import CliRunner

    from l2calib.cli.app import app

    out = tmp_path / "demo"
    res = CliRunner(env={"COLUMNS": "140"}).invoke(
        app,
        [
            "demo", "--out", str(out), "--duration", "5",
            "--set", "train.max_iterations=2", "--set", "train.candidates_per_iteration=8",
            "--set", "selection.window_s=3", "--set", "selection.budget_s=3",
            # from a uniform rotation (the rates' start would make 2 iterations good enough)
            "--set", "train.rotation_from_rates=off",
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "ground truth translation" in res.output and "demo finished" in res.output
    T = read_extrinsic(out / "calibration" / "calibration.yaml").T_imu_lidar
    assert T.shape == (4, 4) and (out / "simulated" / "gt_lidar.tum").is_file()
    written = yaml.safe_load((out / "calibration" / "calibration.yaml").read_text())
    # 2 iterations end far off: the agreement check fails and PPO starts once more
    assert written["uncertainty"]["warnings"] and "starts again" in res.output
    assert [a["kept"] for a in written["attempts"]].count(True) == 1
    assert (out / "calibration" / "restart-1" / "checkpoint.pt").is_file()
    assert written["data"]["segments"] >= 1 and written["data"]["selected_s"] >= 1.5
    # The report page holds its figures (the odometry's trajectories for every segment too)
    page = (out / "calibration" / "report.html").read_text()
    assert (out / "calibration" / "trajectories.png").stat().st_size > 10_000
    assert page.count("data:image/png;base64,") == 3 and "ground truth translation" in page


def test_the_printed_table_shows_the_references_part_of_the_bound_only_when_there_is_one():
    from rich.console import Console

    from l2calib.assess.uncertainty import AxisUncertainty
    from l2calib.outputs.console_summary import print_result

    bound = np.array([math.radians(0.05)] * 3 + [0.012, 0.018, math.inf])
    zeros = np.zeros(6)
    unc = AxisUncertainty(bound, zeros, zeros, zeros, ~np.isfinite(bound), 10, 200, 0.1, [5])

    def printed() -> str:
        console = Console(record=True, width=140)
        print_result(console, CalibrationResult(_T(), final_reward=0.5, axis_uncertainty=unc))
        return console.export_text()

    assert "±1.20" in printed() and "reference's error" not in printed()
    unc.reference95 = np.array([0, 0, 0, 0.004, 0.009, 0.0])
    row = next(x for x in printed().splitlines() if "reference's error" in x)
    assert "±0.40" in row and "±0.90" in row and "held" in row
    assert "not in the 95 % bounds" not in printed()
    unc.caveats = ["one drive and a LiDAR-only reference: the drift both passes share"]
    assert "not in the 95 % bounds: one drive and a LiDAR-only reference" in printed()
