"""The uncertainty table names rows assessed at an older result of their calibration."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_uncertainty import _stale_note, stale_runs


def _row(case: str, seed: int, rot_deg: float, trans_cm: float) -> dict:
    """An uncertainty row (no stored transform) whose errors have the given norms."""
    r, t = rot_deg / np.sqrt(2), trans_cm / np.sqrt(2)
    return {"case": case, "train_seed": seed, "error": [r, r, 0.0, t, 0.0, t, 0.5]}


def _cal(case: str, seed: int, rot_deg: float, dt_cm: list) -> dict:
    return {
        "case": case,
        "train_seed": seed,
        "r_err_deg": rot_deg,
        "t_err_cm": round(float(np.linalg.norm(dt_cm)), 2),
        "dt_cm": dt_cm,
        "T_imu_lidar": np.eye(4).tolist(),
    }


def test_rows_matching_their_calibration_are_not_stale() -> None:
    rows = [_row("a", 0, 0.123, 8.31), _row("a", 1, 0.05, 0.4)]
    cal = [_cal("a", 0, 0.123, [0.0, 0.0, 8.31]), _cal("a", 1, 0.050, [0.4, 0.0, 0.0])]
    assert stale_runs(rows, cal) == set()
    assert _stale_note(rows, set()) == ""


def test_a_re_run_calibration_or_a_missing_one_makes_the_row_stale() -> None:
    rows = [_row("a", 0, 0.133, 8.48), _row("a", 1, 0.05, 0.4), _row("b", 0, 0.02, 0.3)]
    cal = [
        _cal("a", 0, 0.093, [0.0, 0.0, 8.31]),  # re-run
        _cal("a", 1, 0.050, [0.52, 0.0, 0.0]),  # only the translation moved
    ]
    stale = stale_runs(rows, cal)
    assert stale == {("a", 0), ("a", 1), ("b", 0)}
    note = _stale_note(rows, stale)
    assert "3 runs" in note and '--cases "a" "b"' in note


def test_a_ground_vehicle_row_compares_the_horizontal_part_not_the_held_vertical() -> None:
    # LiDAR x / y errors 0.43 / 0.24 cm beside the held 8 cm; the re-run moved them to 0.49 /
    # 0.29 (IMU y / x): the full norms differ by 0.005 cm only, the horizontal ones by 0.077.
    row = {
        "case": "ugv", "train_seed": 0, "held": ["trans z"],
        "error": [0.04, 0.03, 0.0, 0.43, 0.24, 8.0, 0.5],
    }  # fmt: skip
    same = _cal("ugv", 0, 0.05, [0.24, 0.43, 8.0])
    moved = _cal("ugv", 0, 0.05, [0.29, 0.49, 8.0])
    assert stale_runs([row], [same]) == set()
    assert stale_runs([row], [moved]) == {("ugv", 0)}


def test_a_row_with_its_assessed_transform_is_compared_exactly() -> None:
    row = _row("a", 0, 0.1, 1.0) | {"T_imu_lidar": np.eye(4).tolist()}
    cal = _cal("a", 0, 0.1, [1.0, 0.0, 0.0])
    assert stale_runs([row], [cal]) == set()
    moved = np.eye(4)
    moved[0, 3] = 1e-4  # 0.1 mm: sizes alike, the result is not
    assert stale_runs([row], [cal | {"T_imu_lidar": moved.tolist()}]) == {("a", 0)}
