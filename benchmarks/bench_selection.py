"""Data-selection speed: scoring + greedy choice on simulated 90 s sequences (target < 2 s).

Run: ``python -m benchmarks.bench_selection``; prints a table and writes
``benchmarks/results/selection.json``. The simulation itself is not timed.
"""

from __future__ import annotations

import json
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info
from l2calib.recipe import SelectionConfig
from l2calib.selection import select_windows
from l2calib.selection.plot import plot_selection
from l2calib.sim import SimConfig, simulate

TARGET_S = 2.0
RESULTS = Path(__file__).parent / "results" / "selection.json"


def _best_of(fn, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    cfg = SimConfig.model_validate(
        {
            "duration_s": 90.0,
            "seed": 0,
            "imu": {"rate_hz": 400.0},
            "lidar": {"model": "velodyne-vlp-16", "columns": 32},
            "motion": {"profile": "handheld", "still_segments": [[30.0, 40.0]]},
        }
    )
    seq = simulate(cfg).sequence("handheld-90s")
    sel_cfg = SelectionConfig(budget_s=30.0)
    rows = []
    for label, seqs in (
        ("1 x 90 s", [seq]),
        ("10 x 90 s", [replace(seq, name=f"s{i}") for i in range(10)]),
    ):
        t = _best_of(lambda seqs=seqs: select_windows(seqs, sel_cfg))
        sel = select_windows(seqs, sel_cfg)
        rows.append(
            {
                "case": label,
                "imu_samples": sum(len(s.imu) for s in seqs),
                "windows": sum(len(w) for w in sel.windows.values()),
                "chosen": len(sel.chosen),
                "seconds": t,
                "target_s": TARGET_S if label == "1 x 90 s" else None,
                "pass": t < TARGET_S if label == "1 x 90 s" else None,
            }
        )
    sel = select_windows([seq], sel_cfg)
    with tempfile.TemporaryDirectory() as tmp:
        t_plot = _best_of(lambda: plot_selection(sel, Path(tmp) / "timeline.png"), repeats=2)
    rows.append(
        {
            "case": "timeline plot (1 seq)",
            "imu_samples": len(seq.imu),
            "windows": len(sel.windows[seq.name]),
            "chosen": len(sel.chosen),
            "seconds": t_plot,
            "target_s": None,
            "pass": None,
        }
    )
    table = Table(title="data selection (best of 5, shared CPU: pessimistic)")
    for col in ("case", "IMU samples", "windows", "chosen", "seconds", "target"):
        table.add_column(col)
    for r in rows:
        target = (
            ""
            if r["target_s"] is None
            else f"< {r['target_s']:g} s " + ("[green]ok[/]" if r["pass"] else "[red]FAIL[/]")
        )
        table.add_row(
            r["case"],
            str(r["imu_samples"]),
            str(r["windows"]),
            str(r["chosen"]),
            f"{r['seconds']:.3f}",
            target,
        )
    Console().print(table)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "benchmark": "selection",
                "python": platform.python_version(),
                "machine": machine_info(),
                "rows": rows,
            },
            indent=1,
        )
    )
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
