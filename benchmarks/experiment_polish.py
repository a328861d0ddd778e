"""Experiment: the Newton polish (``train.polish_rounds``) against the same runs without it.

Run: ``python -m benchmarks.experiment_polish [--rounds 3]``.

Everything before the polish is deterministic, so each row here is a stored row of
``calibration.json`` / ``time_offset.json`` (same case, seed and code) continued by the polish:
the difference is the polish alone. Results: ``benchmarks/results/experiments/polish.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from benchmarks.bench_calibration import cases, run_case
from benchmarks.bench_time_offset import _case
from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results"
OUT = RESULTS / "experiments" / "polish.json"


def main() -> None:
    """Runs the rows, prints them beside the stored ones, writes the JSON after each."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = parser.parse_args()
    torch.set_default_dtype(torch.float64)
    stored = json.loads((RESULTS / "calibration.json").read_text())["rows"]
    stored_to = json.loads((RESULTS / "time_offset.json").read_text())["rows"]
    plan = [("handheld", next(c for c in cases(False) if c.name == "handheld"))]
    plan.append(("time offset +50 ms gt", _case(50.0, "gt", True)))
    rows = []
    for label, case in plan:
        for seed in args.seeds:
            row = run_case(case, train_seed=seed, extra=[f"train.polish_rounds={args.rounds}"])
            if label == "handheld":
                old = [r for r in stored if r["case"] == "handheld" and r["train_seed"] == seed]
            else:
                old = [
                    r for r in stored_to
                    if (r["profile"], r["reference"], r["offset_ms"], r["estimate"])
                    == ("handheld", "gt", 50, True) and r.get("train_seed") == seed
                ]  # fmt: skip
            before = old[0] if old else {}
            out = {
                "case": label, "train_seed": seed, "polish_rounds": args.rounds,
                "t_err_cm": row["t_err_cm"], "r_err_deg": row["r_err_deg"],
                "evaluations": row["evaluations"], "wall_s": row["wall_s"],
                "without": {k: before.get(k) for k in ("t_err_cm", "r_err_deg", "evaluations")},
                "machine": row["machine"],
            }  # fmt: skip
            print(out, flush=True)
            rows.append(out)
            OUT.write_text(json.dumps({"rows": rows, "machine": machine_info()}, indent=1))


if __name__ == "__main__":
    main()
