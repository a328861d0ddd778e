"""The README's main job, timed as a user runs it: ``l2calib demo`` in a fresh process.

Run: ``python -m benchmarks.bench_demo [--reference NAME]`` (also part of ``make bench``).
With an empty reference cache (``L2CALIB_CACHE`` in a temporary directory), as on a fresh
machine. Reads the demo's ``calibration.yaml`` and the simulator's ``extrinsic_gt.yaml``
afterwards and writes the wall time (the whole process: simulation, reference, training,
report), the error against the truth and the machine to ``benchmarks/results/demo.json`` (one
entry per reference).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info
from l2calib import geometry as geo

RESULTS = Path(__file__).parent / "results" / "demo.json"


def run_demo(reference: str, seed: int, overrides: list[str] | None = None) -> dict:
    """Runs ``l2calib demo`` once; returns its row (error, wall time, evaluations, machine).

    ``overrides`` are passed as ``--set`` (e.g. ``train.coarse_to_fine=false``).
    """
    from l2calib.outputs.calibration_file import read_extrinsic

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        cmd = [sys.executable, "-m", "l2calib.cli.app", "demo", "--out", str(out)]
        cmd += ["--seed", str(seed), "--reference", reference]
        for item in overrides or []:
            cmd += ["--set", item]
        # a newcomer's cold start: no reference cached by an earlier run of the same data
        env = {**os.environ, "L2CALIB_CACHE": str(Path(tmp) / "cache")}
        t0 = time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            raise SystemExit(f"l2calib demo failed:\n{proc.stdout}\n{proc.stderr}")
        T = read_extrinsic(out / "calibration" / "calibration.yaml").T_imu_lidar.numpy()
        gt = yaml.safe_load((out / "simulated" / "extrinsic_gt.yaml").read_text())
        written = yaml.safe_load((out / "calibration" / "calibration.yaml").read_text())
    T_true = np.asarray(gt["T_imu_lidar"])
    return {
        "command": " ".join(["l2calib", *cmd[3:]]),
        "reference": reference,
        "seed": seed,
        "t_err_cm": round(float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])) * 100, 3),
        "r_err_deg": round(
            math.degrees(float(geo.rotation_angle(torch.from_numpy(T_true[:3, :3].T @ T[:3, :3])))),
            4,
        ),
        "wall_s": round(wall, 1),
        "evaluations": written.get("training", {}).get("evaluations"),
        "candidate_scans": written.get("training", {}).get("candidate_scans"),
        "iterations": written.get("training", {}).get("iterations"),
        "stop": written.get("training", {}).get("stop_reason"),
        "stage_s": written.get("training", {}).get("stage_s"),
        # what docs/design.md quotes: the refinement's move, the policy's σ, the resolution
        "refine": written.get("refine"),
        "uncertainty": written.get("uncertainty"),
        "warnings": written.get("uncertainty", {}).get("warnings", []),
        "machine": machine_info(),
    }


def main() -> None:
    """Runs the demo, prints a one-row table, merges the row into ``demo.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", default=None, help="the demo's --reference (its default)")
    parser.add_argument("--seed", type=int, default=1, help="the demo's --seed (its default: 1)")
    args, _ = parser.parse_known_args()  # `python -m benchmarks -- --quick` passes extras
    from l2calib.cli.cmd_demo import DEFAULT_REFERENCE

    row = run_demo(args.reference or DEFAULT_REFERENCE, args.seed)
    table = Table(title="l2calib demo (whole process)")
    for col in ("reference", "t cm", "r deg", "wall s", "evaluations", "cores / load"):
        table.add_column(col)
    m = row["machine"]
    table.add_row(
        row["reference"], f"{row['t_err_cm']:.2f}", f"{row['r_err_deg']:.3f}",
        f"{row['wall_s']:.0f}", str(row["evaluations"]), f"{m['cores']} / {m['load']}",
    )  # fmt: skip
    Console().print(table)
    old = json.loads(RESULTS.read_text()) if RESULTS.is_file() else {"rows": []}
    same = (row["reference"], row["seed"])
    rows = [r for r in old["rows"] if (r["reference"], r["seed"]) != same]
    RESULTS.write_text(json.dumps({"benchmark": "bench_demo", "rows": [*rows, row]}, indent=1))


if __name__ == "__main__":
    main()
