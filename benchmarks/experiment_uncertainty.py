"""Experiment (issue 25, not a feature yet): a block-sandwich covariance at stored results.

Run: ``python -m benchmarks.experiment_uncertainty --cases "handheld gtsam" "ugv all"``.

For each stored row of ``benchmarks/results/calibration.json`` that has a ``T_imu_lidar`` and used
the exact simulated LiDAR trajectory as reference (the case's data rebuilt by
:func:`benchmarks.bench_calibration.exact_reference_env`), the odometry is run at the result
perturbed by ±h along each axis (rotation about / translation along the LiDAR axes, right-
multiplied as the resolution probe does; and the time offset) and at every pair of axes, in one
batch. The cost is the reward's own sum of pose errors, ``C = Σ e_t/4 + e_r/π²``, split into
blocks of ``--block-s`` seconds of each segment. Then:

* ``H``: the Hessian of ``C`` (central differences on :mod:`l2calib.assess.polish`'s stencil:
  0.5°, 2 cm, 1 ms);
* ``g_b``: each block's gradient; ``M = B/(B−1) Σ (g_b − ḡ)(g_b − ḡ)ᵀ``;
* covariance ``H⁻¹ M H⁻¹`` (a sandwich / block-HAC estimate of the minimiser's spread), its
  95 % bound per axis (1.96 σ), and the Newton step ``−H⁻¹ Σ g_b`` (how far the cost's own
  minimum lies from the result).

It compares those with the true per-axis error (``log(T⁻¹ T_true)``). Results:
``benchmarks/results/experiments/uncertainty_sandwich.json``.

What it showed (2026-12-04; hand-held gtsam, ugv all, uav all gtsam, 3 seeds each, 2 s blocks):
the true error lies inside the 95 % bound on 49 of 63 axis-runs (78 %, the issue asks 90 %).
Misses are systematic, not noise: the hand-held yaw error is 0.03–0.05° on all three seeds
against bounds of 0.01° (a bias every block shares, which no resampling of blocks can see), the
ugv roll 0.13–0.30° against 0.02–0.11°. On the uav flights the bounds are wide (z 3–17 cm
against errors of 0.6–1.9 cm) and on the ugv the held vertical axis gets 1–25 cm (the cost is
flat there: the curvature is noise). Translation errors on hand-held runs are mostly where the
optimiser stopped: the Newton step of the cost predicts them (x: error 0.34 cm, step 0.29 cm).
So a bound needs a bias term beside the data's noise, and a flat-axis test beside the curvature.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

RESULTS = Path(__file__).parent / "results" / "experiments" / "uncertainty_sandwich.json"


def block_costs(env, T: torch.Tensor, offsets: torch.Tensor, block_s: float) -> np.ndarray:
    """``[K, B]`` cost of each candidate on each block of every segment (module docstring).

    The pipeline's own per-block cost (:meth:`l2calib.train.env.CalibrationEnv.block_cost_share`).
    """
    return env.block_cost_share(T, offsets, 1, block_s)[0]


def sandwich(C: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Covariance ``H⁻¹ M H⁻¹``, ``H`` and the Newton step from the stencil's block costs."""
    from l2calib.assess.polish import derivatives

    g, H = derivatives(C, 7)  # g: [7, B] per-block gradients
    B = C.shape[1]
    gc = g - g.mean(1, keepdims=True)
    Hi = np.linalg.pinv(H)
    return Hi @ (B / (B - 1) * gc @ gc.T) @ Hi, H, -Hi @ g.sum(1)


def _axes(v: np.ndarray) -> list[float]:
    """deg, deg, deg, cm, cm, cm, ms."""
    return (
        [round(math.degrees(x), 3) for x in v[:3]]
        + [round(100 * x, 2) for x in v[3:6]]
        + [round(1000 * float(v[6]), 3)]
    )


def run_case(case: str, rows: list[dict[str, Any]], block_s: float) -> list[dict[str, Any]]:
    """The experiment on one case's stored rows."""
    from benchmarks.bench_calibration import exact_reference_env
    from l2calib import geometry as geo
    from l2calib.assess.polish import moved as perturbed
    from l2calib.assess.polish import stencil

    env, runs, _, _ = exact_reference_env(case)
    T_true = torch.from_numpy(runs[0].T_imu_lidar)
    true_offset = float(runs[0].time_offset_s)
    d, out = stencil(7), []
    for r in rows:
        T = torch.tensor(r["T_imu_lidar"], dtype=torch.float64)
        offset = r.get("time_offset_s") or 0.0
        C = block_costs(env, perturbed(T, d), torch.as_tensor(offset + d[:, 6]), block_s)
        cov, H, newton = sandwich(C)
        E = torch.linalg.inv(T) @ T_true
        err = np.concatenate(
            [geo.so3_log(E[:3, :3]).numpy(), E[:3, 3].numpy(), [true_offset - offset]]
        )
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        row = {
            "case": case, "train_seed": r["train_seed"], "blocks": C.shape[1],
            "error": _axes(err), "bound95": _axes(1.96 * sd), "newton_step": _axes(newton),
            "hessian_diag": [float(f"{x:.4g}") for x in np.diag(H)],
        }  # fmt: skip
        print(row, flush=True)
        out.append(row)
    return out


def main() -> None:
    """Runs the cases, writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["handheld gtsam", "ugv all"])
    parser.add_argument("--block-s", type=float, default=2.0)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    torch.set_default_dtype(torch.float64)
    from benchmarks.machine import machine_info

    stored = json.loads((Path(__file__).parent / "results" / "calibration.json").read_text())
    rows = []
    for case in args.cases:
        mine = [r for r in stored["rows"] if r["case"] == case and "T_imu_lidar" in r]
        rows += run_case(case, mine, args.block_s)
    units = "error / bound95 / newton_step: rot x y z (deg), trans x y z (cm), offset (ms)"
    result = {"units": units, "block_s": args.block_s, "rows": rows, "machine": machine_info()}
    args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
