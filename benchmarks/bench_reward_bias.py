"""Where does the reward peak? The refinement started at the true extrinsic (issues 23, 25, 27).

Run: ``python -m benchmarks.bench_reward_bias [--cases "ugv all" "uav all" handheld]``.

A calibration can be no better than the place where its reward peaks. This benchmark starts the
production refinement (:func:`l2calib.assess.refine.refine`, the recipe's steps and
``train.refine_rounds``) at the simulated truth, on the :mod:`benchmarks.bench_calibration`
case's selected data with the exact LiDAR trajectory as reference, and reports how far the climb
moves away from the truth and how much reward it gains. It needs no training, so it does not
depend on a training seed: a move of ~0 means the reward peaks at the truth; a move with a
reward gain measures the bias of the reward on that data (what no optimiser can remove). With
and without the time offset as a seventh axis. Results:
``benchmarks/results/experiments/reward_bias.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "experiments" / "reward_bias.json"


def run_case(name: str) -> list[dict[str, Any]]:
    """Refinements from the truth on one case (module docstring)."""
    from benchmarks.bench_calibration import exact_reference_env, rotation_errors_deg
    from l2calib.assess.refine import refine
    from l2calib.interfaces import Extrinsic
    from l2calib.train.env_build import score_batch

    env, runs, data, recipe = exact_reference_env(name)
    T_gt = torch.from_numpy(runs[0].T_imu_lidar)
    true_offset = float(runs[0].time_offset_s)
    cfg = recipe.train
    rows = []
    for offset in (None, true_offset):

        def score(T, offsets=None, _offset=offset):
            if offsets is None and _offset is not None:
                offsets = torch.full((T.shape[0],), _offset, dtype=torch.float64)
            return score_batch(env, T, offsets).reward.detach().to(torch.float64)

        res = refine(
            score, Extrinsic(T_gt, offset), cfg.refine_rounds, cfg.refine_rot_step_deg,
            cfg.refine_trans_step_m, offset_step_s=cfg.refine_offset_step_s,
        )  # fmt: skip
        T_end = res.extrinsic.T_imu_lidar.numpy()
        dt_cm = np.abs(T_end[:3, 3] - T_gt.numpy()[:3, 3]) * 100
        rows.append(
            {
                "case": name,
                "axes": 6 if offset is None else 7,
                "reward_at_truth": round(float(res.start_reward), 5),
                "reward_at_end": round(float(res.reward), 5),
                "moved_cm": round(100 * float(res.moved_m), 2),
                "moved_deg": round(float(res.moved_deg), 3),
                "dt_cm": dt_cm.round(2).tolist(),
                "dr_deg": rotation_errors_deg(T_gt.numpy(), T_end).round(3).tolist(),
                "time_offset_moved_ms": None
                if offset is None
                else round(1000 * (float(res.extrinsic.time_offset_s) - offset), 2),
                "evaluations": res.evaluations,
                "data_s": round(sum(s.duration_s for s in data.segments), 1),
            }
        )
    return rows


def main() -> None:
    """Runs the cases, prints the table and writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["ugv all", "uav all", "handheld"])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    rows = [row for name in args.cases for row in run_case(name)]
    table = Table(title="The refinement started at the true extrinsic")
    for col in ("case", "axes", "reward truth → end", "moved", "per axis cm", "per axis deg"):
        table.add_column(col)
    for r in rows:
        table.add_row(
            r["case"], str(r["axes"]), f"{r['reward_at_truth']:.5f} → {r['reward_at_end']:.5f}",
            f"{r['moved_cm']:.2f} cm / {r['moved_deg']:.3f}°", str(r["dt_cm"]), str(r["dr_deg"]),
        )  # fmt: skip
    Console().print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"benchmark": "reward_bias", "rows": rows, "machine": machine_info()}, indent=1)
    )


if __name__ == "__main__":
    main()
