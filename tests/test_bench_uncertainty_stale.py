"""The uncertainty table names rows assessed at an older result of their calibration."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_uncertainty import _stale_note, stale_runs


def _row(case: str, seed: int, rot_deg: float, trans_cm: float) -> dict:
    """An uncertainty row whose rotation / translation errors have the given norms."""
    r, t = rot_deg / np.sqrt(2), trans_cm / np.sqrt(2)
    return {"case": case, "train_seed": seed, "error": [r, r, 0.0, t, 0.0, t, 0.5]}


def test_rows_matching_their_calibration_are_not_stale() -> None:
    rows = [_row("a", 0, 0.123, 8.31), _row("a", 1, 0.05, 0.4)]
    cal = [
        {"case": "a", "train_seed": 0, "r_err_deg": 0.123, "t_err_cm": 8.31},
        {"case": "a", "train_seed": 1, "r_err_deg": 0.050, "t_err_cm": 0.40},
    ]
    assert stale_runs(rows, cal) == set()
    assert _stale_note(rows, set()) == ""


def test_a_re_run_calibration_or_a_missing_one_makes_the_row_stale() -> None:
    rows = [_row("a", 0, 0.133, 8.48), _row("a", 1, 0.05, 0.4), _row("b", 0, 0.02, 0.3)]
    cal = [
        {"case": "a", "train_seed": 0, "r_err_deg": 0.093, "t_err_cm": 8.31},  # re-run
        {"case": "a", "train_seed": 1, "r_err_deg": 0.050, "t_err_cm": 0.52},  # t moved only
    ]
    stale = stale_runs(rows, cal)
    assert stale == {("a", 0), ("a", 1), ("b", 0)}
    note = _stale_note(rows, stale)
    assert "3 runs" in note and '--cases "a" "b"' in note
