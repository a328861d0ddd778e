"""The end-to-end tests' scenario over training seeds: how much margin their tolerance has.

Run: ``python -m benchmarks.bench_e2e [--backends iekf gtsam] [--seeds 0 1 2]``. Each run is
what ``tests/e2e/test_calibration_e2e.py`` does — an 8 s simulated hand-held bag on disk, the
``gt-file`` reference, 35 PPO iterations of 32 candidates from no initial guess, the real backend —
with another training seed, and compares the result with the simulated truth (the tests assert
≤ 3 cm / 0.5°). Rows merge into ``benchmarks/results/e2e.json`` by (backend, seed).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.machine import machine_info
from l2calib import geometry as geo

RESULTS = Path(__file__).parent / "results" / "e2e.json"
#: As in tests/e2e/test_calibration_e2e.py.
RIG = {"preset": None, "translation_m": (0.12, -0.05, 0.08), "rpy_deg": (-100.0, 40.0, 60.0)}
BUDGET = [
    "train.max_iterations=35",
    "train.max_evaluations=1120",
    "train.restarts=0",
    "selection.enabled=false",
]


def run(backend: str, seed: int, tmp: Path) -> dict:
    """One calibration of the e2e scenario with training seed ``seed``."""
    from rich.console import Console

    from l2calib.cli.cmd_calibrate import run_calibration
    from l2calib.recipe import load_recipe
    from l2calib.sim import SIMULATOR_VERSION, SimConfig, simulate, write_run

    sim = simulate(
        SimConfig.model_validate(
            {
                "duration_s": 8.0, "seed": 0, "world": {"name": "urban"},
                "motion": {"profile": "handheld"}, "lidar": {"model": "ouster-os1-16"},
                "imu": {"model": "vn100"}, "rig": RIG,
            }
        )
    )  # fmt: skip
    files = write_run(sim, tmp / f"sim-{backend}-{seed}")
    recipe = load_recipe(
        "simulator",
        [
            "reference.name=gt-file", f"reference.options.path={files['gt_lidar']}",
            f"backend.name={backend}", f"train.seed={seed}", *BUDGET,
        ],
    )  # fmt: skip
    t0 = time.monotonic()
    res = run_calibration(
        recipe, tmp / f"out-{backend}-{seed}", bags=[Path(files["bag"])],
        truth=sim.T_imu_lidar, console=Console(quiet=True),
    )  # fmt: skip
    T, G = res.T_imu_lidar, sim.T_imu_lidar
    return {
        "backend": backend,
        "train_seed": seed,
        "t_err_cm": round(100 * float(np.linalg.norm(T[:3, 3] - G[:3, 3])), 3),
        "r_err_deg": round(
            math.degrees(float(geo.rotation_angle(torch.from_numpy(G[:3, :3].T @ T[:3, :3])))), 4
        ),
        "wall_s": round(time.monotonic() - t0, 1),
        "evaluations": res.evaluations,
        "warnings": res.warnings,
        "undetermined": res.undetermined,
        "simulator_version": SIMULATOR_VERSION,
        "machine": machine_info(),
    }


def main() -> None:
    """Runs the selected backends and seeds, merges the rows, prints them."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", nargs="+", default=["iekf", "gtsam"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    args, _ = ap.parse_known_args()
    rows = json.loads(RESULTS.read_text())["rows"] if RESULTS.is_file() else []
    with tempfile.TemporaryDirectory() as tmp:
        for backend in args.backends:
            for seed in args.seeds:
                row = run(backend, seed, Path(tmp))
                rows = [r for r in rows if (r["backend"], r["train_seed"]) != (backend, seed)]
                rows.append(row)
                print(f"{backend} seed {seed}: {row['t_err_cm']:.2f} cm / {row['r_err_deg']:.3f}"
                      f" deg in {row['wall_s']:.0f} s", flush=True)  # fmt: skip
                RESULTS.write_text(json.dumps({"benchmark": "bench_e2e", "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
