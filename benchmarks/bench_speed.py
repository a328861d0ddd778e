"""Work per calibration: today's settings against coarse-to-fine data and the plateau stop.

Run: ``python -m benchmarks.bench_speed [--cases demo handheld ...] [--seeds 1 2 3]
[--configs today fast] [--render]``.

Each case runs with each configuration and training seed, side by side in one run:

* ``today`` (the settings before issue 23): every PPO iteration scores all the selected data,
  PPO runs to its budget (or the strict convergence rule), 6 refinement rounds, and its rotation
  starts uniform and its translation at zero (``train.rotation_from_rates=off``,
  ``train.translation_from_accelerations=off``; rows before 2026-12-05 had no start to turn
  off);
* ``fast`` (the defaults since): coarse-to-fine data (``train.coarse_to_fine``,
  :mod:`l2calib.train.coarse`; continuous odometry runs, on weakly excited data, keep all their
  data), PPO hands over to the refinement once the policy is narrow
  (``train.handover_rotation_sigma_deg``, also on planar data, where the defaults run the
  budget), 12 refinement rounds, and (since 2026-12-05) the first attempt's rotation starts at
  the references' body rates fitted to the gyro (:mod:`l2calib.train.rotation_start`) and its
  translation at the lever arm fitted to their accelerations (:mod:`l2calib.train.lever_start`).
  The
  reward-plateau stop
  (``train.stop_on_plateau``) was part of it until it proved harmful on weakly excited data
  (``benchmarks/results/experiments/speed_plateau.json``); on the other cases it never fired.

The work is counted in **candidate-scans** (Σ over odometry evaluations of the scans each
estimated), written by the run itself (``calibration.yaml`` → ``training.candidate_scans``).
The lever arm's error is judged over the axes the run estimated (``t_err_estimated_cm``: on
planar data the held vertical is left out).
Cases: ``demo`` (``l2calib demo`` in a fresh process, ct-lidar reference), and the
:mod:`benchmarks.bench_calibration` cases ``handheld`` (OS1-16, 40 s), ``MID-360`` (the paper's
hand-held rig), ``uav`` and ``ugv`` (three sequences each, calibrated jointly), and
``handheld ct-lidar`` (the 40 s OS1-16 run with the LiDAR-only reference, as a user without
ground truth runs it: its wall time includes the reference; run it with an empty
``L2CALIB_CACHE`` for a cold start).

Goal (issue 23): ``fast`` needs ≤ 1/4 of ``today``'s candidate-scans, with errors no worse than
``today``'s by more than 10 % or 0.2 cm / 0.02° (mean over the seeds). Results:
``benchmarks/results/speed.json`` and ``speed.md``.
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

RESULTS = Path(__file__).parent / "results" / "speed.json"
CONFIGS = {
    "today": [
        "train.coarse_to_fine=false", "train.stop_on_plateau=false",
        "train.handover_rotation_sigma_deg=null", "train.refine_rounds=6",
        "train.rotation_from_rates=off", "train.translation_from_accelerations=off",
    ],
    "fast": [
        "train.coarse_to_fine=true", "train.stop_on_plateau=false",
        "train.handover_rotation_sigma_deg=2.5", "train.handover_translation_sigma_m=0.2",
        "train.refine_rounds=12",
    ],
}  # fmt: skip
#: Speed-benchmark case -> bench_calibration case (``demo`` runs the CLI instead).
CASES = {
    "demo": None,
    "handheld": "handheld",
    "MID-360": "handheld MID-360 gt",
    "uav": "uav all",
    "ugv": "ugv all",
    "handheld ct-lidar": "handheld ct-lidar",  # the 40 s hand-held run from the LiDAR alone
}


def run_row(case: str, config: str, seed: int) -> dict[str, Any]:
    """One calibration of ``case`` with ``config``'s settings and training ``seed``."""
    if CASES[case] is None:
        from benchmarks.bench_demo import run_demo

        row = run_demo("ct-lidar", seed, CONFIGS[config])
    else:
        from benchmarks.bench_calibration import cases, run_case

        spec = next(c for c in cases(quick=False) if c.name == CASES[case])
        row = run_case(spec, seed, CONFIGS[config])
        row["machine"] = machine_info()
    return {
        "case": case, "config": config, "seed": seed,
        **{k: row.get(k) for k in (
            "t_err_cm", "t_err_estimated_cm", "r_err_deg", "dt_cm", "dr_deg", "wall_s",
            "evaluations", "candidate_scans", "iterations", "stop", "stage_s", "T_imu_lidar",
            "time_offset_s", "vertical_hold", "rotation_start", "translation_start",
        )},
        "machine": row["machine"],
    }  # fmt: skip


def _judged(row: dict[str, Any], key: str) -> float:
    """``row[key]``; ``t_err_judged_cm`` is the error over the estimated axes (a held vertical
    lever arm on planar data is left out; rows from before that field: the whole error)."""
    if key == "t_err_judged_cm":
        key = "t_err_estimated_cm" if row.get("t_err_estimated_cm") is not None else "t_err_cm"
    return row[key]


def summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per case, the two configurations over their common seeds, and whether the goal is met."""
    out = []
    for case in CASES:
        by = {c: {r["seed"]: r for r in rows if r["case"] == case and r["config"] == c}
              for c in CONFIGS}  # fmt: skip
        seeds = sorted(set(by["today"]) & set(by["fast"]))
        if not seeds:
            continue

        def mean(config: str, key: str, _seeds=seeds, _by=by) -> float:
            return float(np.mean([_judged(_by[config][s], key) for s in _seeds]))

        ratio = mean("fast", "candidate_scans") / mean("today", "candidate_scans")
        t0, t1 = mean("today", "t_err_judged_cm"), mean("fast", "t_err_judged_cm")
        r0, r1 = mean("today", "r_err_deg"), mean("fast", "r_err_deg")
        accurate = (t1 <= max(1.1 * t0, t0 + 0.2)) and (r1 <= max(1.1 * r0, r0 + 0.02))
        out.append({
            "case": case, "seeds": seeds, "scans_ratio": round(ratio, 3),
            "t_err_cm": [round(t0, 2), round(t1, 2)], "r_err_deg": [round(r0, 3), round(r1, 3)],
            "wall_s": [round(mean("today", "wall_s")), round(mean("fast", "wall_s"))],
            "met": bool(ratio <= 0.25 and accurate),
        })  # fmt: skip
    return out


def render(results: dict[str, Any]) -> str:
    """The markdown of a results JSON: every row, then the per-case summary."""
    lines = [
        "| case | config | seed | t cm | r deg | wall s | load | evals | candidate-scans | date "
        "| stop |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results["rows"], key=lambda r: (r["case"], r["seed"], r["config"])):
        load = (r["machine"].get("load") or ["?"])[0]  # 1-min load average at the row's end
        lines.append(
            f"| {r['case']} | {r['config']} | {r['seed']} | {_judged(r, 't_err_judged_cm'):.2f} | "
            f"{r['r_err_deg']:.3f} | {r['wall_s']:.0f} | {load} | {r['evaluations']} | "
            f"{r['candidate_scans']:,} | {r['machine'].get('date', '?')} | {r['stop']} |"
        )
    lines += [
        "",
        "Per case, over the seeds both configurations ran (mean; today → fast):",
        "",
        "| case | seeds | candidate-scans fast/today | t cm | r deg | wall s | goal met |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary(results["rows"]):
        lines.append(
            f"| {s['case']} | {len(s['seeds'])} | {s['scans_ratio']:.2f} | "
            f"{s['t_err_cm'][0]:.2f} → {s['t_err_cm'][1]:.2f} | "
            f"{s['r_err_deg'][0]:.3f} → {s['r_err_deg'][1]:.3f} | "
            f"{s['wall_s'][0]} → {s['wall_s'][1]} | {'yes' if s['met'] else 'NO'} |"
        )
    cpus = sorted({r["machine"]["cpu"] for r in results["rows"]})
    lines += [
        "",
        f"Machines: {', '.join(cpus)} (2 cores). Candidate-scans and errors do not depend on the "
        "load; wall times do (rows run side by side with other benchmarks are slower). t cm is "
        "the error over the estimated axes (a held vertical lever arm left out; `today` rows "
        "before that field: all three). The `today` rows are issue 23's baseline: the settings "
        "before its changes, run on the code of their date.",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    """Runs the rows (merged into ``speed.json`` after each), prints and writes the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--render", action="store_true", help="only rewrite the markdown")
    args, _ = parser.parse_known_args()

    def load() -> dict[str, Any]:
        return json.loads(args.out.read_text()) if args.out.is_file() else {"rows": []}

    old = load()
    if not args.render:
        torch.set_default_dtype(torch.float64)
        console = Console()
        for case in args.cases:
            for seed in args.seeds:
                for config in args.configs:
                    console.print(f"[cyan]•[/] {case} / {config} / seed {seed}")
                    row = run_row(case, config, seed)
                    key = (case, config, seed)
                    old = load()  # rows another run wrote meanwhile are kept
                    old["rows"] = [
                        r for r in old["rows"] if (r["case"], r["config"], r["seed"]) != key
                    ] + [row]
                    args.out.parent.mkdir(parents=True, exist_ok=True)
                    args.out.write_text(json.dumps({"benchmark": "bench_speed", **old}, indent=1))
    args.out.with_suffix(".md").write_text(render(old))
    table = Table(title="work per calibration: today → fast")
    for col in ("case", "seeds", "scans ratio", "t cm", "r deg", "wall s", "met"):
        table.add_column(col)
    for s in summary(old["rows"]):
        table.add_row(
            s["case"], str(len(s["seeds"])), f"{s['scans_ratio']:.2f}",
            f"{s['t_err_cm'][0]:.2f} → {s['t_err_cm'][1]:.2f}",
            f"{s['r_err_deg'][0]:.3f} → {s['r_err_deg'][1]:.3f}",
            f"{s['wall_s'][0]} → {s['wall_s'][1]}", "yes" if s["met"] else "NO",
        )  # fmt: skip
    Console().print(table)


if __name__ == "__main__":
    main()
