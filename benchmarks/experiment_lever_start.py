"""How close does the translation start from the accelerations land? (issue 23)

Run: ``python -m benchmarks.experiment_lever_start [--cases handheld "uav all" ...]``.

For each :mod:`benchmarks.bench_calibration` case, the pipeline up to training (selection, the
case's own reference, the rate time offset), then the training's two starts: the rotation from
the rates (:mod:`l2calib.train.rotation_start`) and, at that rotation, the lever arm from the
accelerations (:mod:`l2calib.train.lever_start`). Per IMU axis: the start's error against the
simulated truth, the fit's own 1-σ and the σ PPO starts with. No odometry run, no training.
Results: ``benchmarks/results/experiments/lever_start.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from benchmarks.bench_calibration import cases, prepare_case
from benchmarks.machine import machine_info

OUT = Path(__file__).parent / "results" / "experiments" / "lever_start.json"
DEFAULT_CASES = [
    "handheld", "handheld ct-lidar", "uav all", "ugv all", "ugv drive velodyne-vlp-32c gt",
    "ugv drive velodyne-vlp-32c ct-lidar",
]  # fmt: skip


def lever_row(case, half_widths: list[float] | None = None) -> dict[str, object]:
    """Both starts on the case's prepared data, against the truth.

    ``half_widths``: also fit the lever arm with each of these kernel half-widths (s), rejected
    fits included (``half_width_fits``: error, fit σ and relative residual each).
    """
    from scipy.spatial.transform import Rotation

    from l2calib.train.lever_start import lever_start
    from l2calib.train.offset_hold import offset_from_rates
    from l2calib.train.rotation_start import rotation_start, start_offset_s

    runs, data, recipe = prepare_case(case, exact="reference.name=gt" in case.overrides)
    recipe, _ = offset_from_rates(recipe, data, lambda _m: None)
    offset = start_offset_s(recipe, data)
    rot = rotation_start(recipe, data, lambda _m: None)
    lever = lever_start(recipe, data, rot, offset, lambda _m: None)
    T = runs[0].T_imu_lidar
    row: dict[str, object] = {
        "reference": recipe.reference.name if "reference.name=gt" not in case.overrides else "gt",
        "data_s": round(sum(s.duration_s for s in data.segments), 1),
        "offset_used_ms": round(1000 * offset, 3),
    }
    if rot is not None:
        R = Rotation.from_quat(rot.quat_xyzw).as_matrix()
        row["rotation_error_deg"] = round(float(np.degrees(Rotation.from_matrix(T[:3, :3].T @ R).magnitude())), 4)  # fmt: skip  # noqa: E501
    if half_widths and rot is not None:
        row["half_width_fits"] = _half_width_fits(data, rot, offset, T, half_widths)
    if lever is None:
        return {**row, "lever": None}
    err = np.array(lever.translation_m) - T[:3, 3]
    return {
        **row,
        "lever_error_cm": np.round(100 * err, 3).tolist(),
        "lever_error_norm_cm": round(float(100 * np.linalg.norm(err)), 3),
        "error_over_fit_sigma": np.round(
            np.abs(err) / np.maximum(lever.fit_sigma_m, 1e-9), 2
        ).tolist(),  # noqa: E501
        "lever": lever.to_dict(),
    }


def _half_width_fits(data, rot, offset: float, T: np.ndarray, half_widths: list[float]):
    """The lever-arm fit at each kernel half-width, its rejection rule switched off."""
    from scipy.spatial.transform import Rotation

    from l2calib.train import lever_start as ls

    R = Rotation.from_quat(rot.quat_xyzw).as_matrix()
    out = []
    for h in half_widths:
        fit = ls.lever_arm_from_accelerations(
            data.references, data.segments, data.sequences, R, offset, half_width_s=h,
            max_relative_residual=np.inf,
        )  # fmt: skip
        if fit is None:
            out.append({"half_width_s": h, "fit": None})
            continue
        err = np.array(fit.translation_m) - T[:3, 3]
        out.append({
            "half_width_s": h, "error_cm": np.round(100 * err, 2).tolist(),
            "fit_sigma_cm": np.round(100 * np.array(fit.fit_sigma_m), 2).tolist(),
            "relative_residual": round(fit.relative_residual, 3), "windows": fit.windows,
        })  # fmt: skip
    return out


def main() -> None:
    """Runs the cases, prints a line each, writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--half-widths", type=float, nargs="*", default=None,
        help="also fit with these kernel half-widths (s), rejected fits included",
    )  # fmt: skip
    args = parser.parse_args()
    torch.set_default_dtype(torch.float64)
    rows = []
    for name in args.cases:
        case = next(c for c in cases(quick=False) if c.name == name)
        rows.append({"case": name, **lever_row(case, args.half_widths)})
        print(rows[-1], flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"rows": rows, "machine": machine_info()}, indent=1))


if __name__ == "__main__":
    main()
