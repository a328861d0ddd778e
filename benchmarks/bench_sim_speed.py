"""Simulator speed: a 60 s, 10 Hz, 16x1024 Ouster + 200 Hz IMU sequence written in < 60 s.

Run: ``python -m benchmarks.bench_sim_speed``; prints a table and writes
``benchmarks/results/bench_sim_speed.json``. Also times the in-memory API on the test-sized case
(10 s handheld, 16x512: "a few seconds"). Timings include world building and every output file;
on a shared machine they are pessimistic (the load average is recorded).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info
from l2calib.sim import SimConfig, simulate, write_run

TARGET_S = 60.0
RESULTS = Path(__file__).parent / "results" / "bench_sim_speed.json"


def _case(label: str, cfg: SimConfig, fmt: str | None) -> dict:
    t0 = time.perf_counter()
    run = simulate(cfg)
    t_sim = time.perf_counter() - t0
    t_write, size = 0.0, 0
    if fmt is not None:
        with tempfile.TemporaryDirectory() as tmp:
            t1 = time.perf_counter()
            files = write_run(run, tmp, format=fmt)
            t_write = time.perf_counter() - t1
            bag = Path(files["bag"])
            size = sum(p.stat().st_size for p in ([bag] if bag.is_file() else bag.iterdir()))
    return {
        "case": label,
        "format": fmt or "-",
        "duration_s": cfg.duration_s,
        "scans": len(run.scans),
        "points": run.stats["points"],
        "imu_samples": len(run.imu),
        "simulate_s": round(t_sim, 2),
        "write_s": round(t_write, 2),
        "total_s": round(t_sim + t_write, 2),
        "bag_mb": round(size / 1e6, 1),
    }


def main() -> None:
    load_before = os.getloadavg()
    big = SimConfig.model_validate(
        {
            "duration_s": 60.0,
            "seed": 1,
            "world": {"name": "urban"},
            "motion": {"profile": "handheld"},
            "lidar": {"model": "ouster-os1-16", "columns": 1024, "rate_hz": 10.0},
            "imu": {"model": "vn100", "rate_hz": 200.0},
        }
    )
    small = SimConfig.model_validate(
        {"duration_s": 10.0, "seed": 1, "lidar": {"model": "ouster-os1-16", "columns": 512}}
    )
    rows = [
        _case("10 s handheld, OS1-16 x512, in memory", small, None),
        _case("60 s handheld, OS1-16 x1024, 200 Hz IMU", big, "ros1"),
        _case("60 s handheld, OS1-16 x1024, 200 Hz IMU", big, "ros2-mcap"),
    ]
    table = Table(title=f"Simulator speed (target: 60 s sequence written in < {TARGET_S:.0f} s)")
    for col in ("case", "format", "scans", "points", "simulate_s", "write_s", "total_s", "bag_mb"):
        table.add_column(col, justify="left" if col == "case" else "right")
    for r in rows:
        table.add_row(
            *(
                str(r[c])
                for c in (
                    "case",
                    "format",
                    "scans",
                    "points",
                    "simulate_s",
                    "write_s",
                    "total_s",
                    "bag_mb",
                )
            )
        )
    Console().print(table)
    ok = all(r["total_s"] < TARGET_S for r in rows if r["format"] != "-")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "benchmark": "bench_sim_speed",
                "target_s": TARGET_S,
                "passed": ok,
                "rows": rows,
                "machine": {**machine_info(), "loadavg_before": load_before},
            },
            indent=2,
        )
        + "\n"
    )
    Console().print(f"{'PASS' if ok else 'FAIL'}; wrote {RESULTS}")


if __name__ == "__main__":
    main()
