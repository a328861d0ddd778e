"""Where one odometry evaluation spends its time (cProfile), as a training worker runs it.

Run: ``python -m benchmarks.profile_backend [--backend iekf] [--candidates 16]``.
One worker's share of a PPO iteration (16 of 32 candidates on 2 cores, one thread) on 10 s of
the demo's simulated hand-held motion, with the recipe's backend settings; prints the wall
time of one ``evaluate`` and the functions by their own time, and writes both to
``benchmarks/results/profile_backend.txt`` (quoted in ``docs/backends.md``).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
from pathlib import Path

import torch

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "profile_backend.txt"


def main() -> None:
    """Profiles one evaluation and writes the report."""
    from l2calib import geometry as geo
    from l2calib.interfaces import ReferenceTrajectory
    from l2calib.plugins import get_plugin
    from l2calib.recipe import load_recipe
    from l2calib.sim import SimConfig, simulate

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="iekf")
    parser.add_argument("--candidates", type=int, default=16)
    parser.add_argument(
        "--binary-search",
        action="store_true",
        help="look the shared map up by binary search (as before the dense grid), to compare",
    )
    args, _ = parser.parse_known_args()
    if args.binary_search:
        from l2calib_backends import plane_map

        plane_map.MAX_DENSE_CELLS = 0
    torch.set_num_threads(1)  # as in a training worker
    recipe = load_recipe("simulator", [f"backend.name={args.backend}"])
    run = simulate(
        SimConfig.model_validate({"duration_s": 12.0, "seed": 1, "motion": {"profile": "handheld"}})
    )
    seq = run.sequence()
    seg = seq.segment(seq.start_ns + 2_000_000_000, seq.start_ns + 12_000_000_000)
    backend = get_plugin("l2calib.backends", args.backend).build(
        recipe.backend.options, imu=recipe.data.imu
    )
    backend.prepare([seg], [ReferenceTrajectory(seg.name, run.gt_lidar)])
    g = torch.Generator().manual_seed(0)
    scale = torch.tensor([0.05] * 3 + [0.03] * 3, dtype=torch.float64)
    xi = torch.randn(args.candidates, 6, generator=g, dtype=torch.float64) * scale
    T = torch.from_numpy(run.T_imu_lidar)[None] @ geo.se3_exp(xi)
    backend.evaluate(T)  # warm-up (lazy allocations)
    walls = []
    for _ in range(3):
        t0 = time.perf_counter()
        backend.evaluate(T)
        walls.append(time.perf_counter() - t0)
    profile = cProfile.Profile()
    profile.enable()
    backend.evaluate(T)
    profile.disable()
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(20)
    scans = backend.measurements_per_candidate()
    wall = sorted(walls)[1]
    head = (
        f"backend {args.backend}, {args.candidates} candidates x {scans} scans, one thread"
        f"{', map by binary search' if args.binary_search else ''}\n"
        f"one evaluate: {wall:.3f} s (median of 3), "
        f"{1000 * wall / (args.candidates * scans):.3f} ms per candidate-scan\n"
        f"machine: {machine_info()}\n\n"
    )
    report = head + text.getvalue()
    out = RESULTS.with_name(RESULTS.stem + ("_binary_search" if args.binary_search else ""))
    out.with_suffix(".txt").write_text(report)
    print(report)


if __name__ == "__main__":
    main()
