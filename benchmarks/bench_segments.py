"""ct-lidar on segments cut mid-recording, as a calibration cuts them: one by one vs in runs.

Run: ``python -m benchmarks.bench_segments [--lidars ...] [--profiles ...] [--worlds ...]
[--out PATH]`` (``--render`` only rewrites the markdown).

The matrix (``bench_references``) runs whole recordings from rest; a calibration's references are
short segments where the motion is strongest, mid-recording. Each cell simulates a 20 s run
(seed 1) and cuts 4 s segments starting at 3, 6, 9, 12 and 15 s, then computes the ct-lidar
reference of all of them in two ways:

* ``apart``: each segment on its own, warmed up ``margin_s`` (1 s) before it and started again
  2, 4, 8 s before it where it loses track early (``from_start_s: 0``, ``chain_gap_s: 0``: the
  behaviour before runs);
* ``runs`` (the default): the segments cut from one odometry run from the recording's start
  (:mod:`l2calib.references.ct_runs`).

Per cell and mode: how many segments lost track, the APE RMSE of each tracked one (SE(3)-aligned
per segment, against the simulated LiDAR trajectory) and the odometry's wall time. Rows merge
into ``benchmarks/results/segments.json`` by (lidar, profile, world, mode).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "segments.json"
STARTS_S = (3.0, 6.0, 9.0, 12.0, 15.0)
LENGTH_S = 4.0
MODES = {"apart": {"from_start_s": 0.0, "chain_gap_s": 0.0}, "runs": {}}
KEY = ("lidar", "profile", "world", "mode")


def run_cell(lidar: str, profile: str, world: str, mode: str) -> dict[str, Any]:
    """One cell in one mode: the five segments' APE (cm) or ``None`` where track was lost."""
    from l2calib.alignment import ape
    from l2calib.errors import ReferenceLostTrackError
    from l2calib.references.ct_lidar_source import CtLidarReference
    from l2calib.references.options import CtLidarOptions
    from l2calib.sim import SimConfig, simulate

    run = simulate(
        SimConfig.model_validate(
            {"duration_s": 20.0, "seed": 1, "world": {"name": world},
             "motion": {"profile": profile}, "lidar": {"model": lidar}}
        )
    )  # fmt: skip
    seq = run.sequence()
    segs = [
        seq.segment(seq.start_ns + int(s * 1e9), seq.start_ns + int((s + LENGTH_S) * 1e9))
        for s in STARTS_S
    ]
    opts = CtLidarOptions(cache=False, max_range_m=100.0, **MODES[mode])
    t0 = time.monotonic()
    results = CtLidarReference(opts, sequences=[seq]).compute_results(segs)
    wall = time.monotonic() - t0
    ape_cm: list[float | None] = []
    for seg in segs:
        r = results[seg.name]
        if isinstance(r, ReferenceLostTrackError):
            ape_cm.append(None)
        else:
            ape_cm.append(round(100 * ape(run.gt_lidar, r.trajectory).rmse_t, 3))
    return {
        "lidar": lidar, "profile": profile, "world": world, "mode": mode,
        "starts_s": list(STARTS_S), "length_s": LENGTH_S, "ape_cm": ape_cm,
        "lost": sum(a is None for a in ape_cm), "wall_s": round(wall, 1),
        "engine": CtLidarReference(opts).version(),
        "machine": machine_info(),
    }  # fmt: skip


def render(rows: list[dict[str, Any]]) -> str:
    """The markdown table, one line per cell and mode."""
    lines = [
        "# ct-lidar on segments cut mid-recording (benchmarks/bench_segments.py)\n",
        f"20 s simulated runs (seed 1), 4 s segments from {', '.join(f'{s:g}' for s in STARTS_S)}"
        " s. `apart`: each segment on its own (1 s warm-up, earlier starts where lost early); "
        "`runs`: cut from one odometry run from the recording's start. APE RMSE per segment "
        "(cm, SE(3)-aligned per segment); wall: the odometry of all five, under the row's load.\n",
        "| lidar | profile | world | mode | engine | lost | APE per segment (cm) | median | worst "
        "| wall s | load |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: tuple(r[k] for k in KEY)):
        got = [a for a in r["ape_cm"] if a is not None]
        each = " / ".join("lost" if a is None else f"{a:.2f}" for a in r["ape_cm"])
        med = f"{np.median(got):.2f}" if got else "-"
        worst = f"{max(got):.2f}" if got else "-"
        lines.append(
            f"| {r['lidar']} | {r['profile']} | {r['world']} | {r['mode']} "
            f"| {r.get('engine', '-')} | {r['lost']} of "
            f"{len(r['ape_cm'])} | {each} | {med} | {worst} | {r['wall_s']:.0f} "
            f"| {r['machine']['load'][0]:.1f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    """Runs the cells, merging rows into the JSON after each."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lidars", nargs="+", default=["ouster-os1-16", "velodyne-vlp-16"])
    ap.add_argument("--profiles", nargs="+", default=["handheld"])
    ap.add_argument("--worlds", nargs="+", default=["urban", "hall"])
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--render", action="store_true")
    args = ap.parse_args()
    if args.render:
        rows = json.loads(args.out.read_text())["rows"]
        args.out.with_suffix(".md").write_text(render(rows))
        return
    console = Console()
    for lidar in args.lidars:
        for profile in args.profiles:
            for world in args.worlds:
                for mode in args.modes:
                    row = run_cell(lidar, profile, world, mode)
                    old = json.loads(args.out.read_text())["rows"] if args.out.is_file() else []
                    rows = [
                        r for r in old if tuple(r[k] for k in KEY) != tuple(row[k] for k in KEY)
                    ]
                    rows.append(row)
                    args.out.parent.mkdir(parents=True, exist_ok=True)
                    args.out.write_text(
                        json.dumps({"benchmark": "bench_segments", "rows": rows}, indent=1)
                    )
                    args.out.with_suffix(".md").write_text(render(rows))
                    console.print(
                        f"{lidar} {profile} {world} {mode}: lost {row['lost']}, APE {row['ape_cm']}"
                        f" cm, {row['wall_s']:.0f} s"
                    )


if __name__ == "__main__":
    main()
