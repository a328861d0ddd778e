"""LIO backend accuracy, extrinsic sensitivity and throughput (written for ``gtsam``).

Run: ``python -m benchmarks.bench_gtsam [--backend gtsam] [--quick] [--out PATH]``; prints three
tables and writes ``benchmarks/results/<backend>.json``. Backends are built through their plugin,
so the functions here work for any ``l2calib.backends`` plugin (``--backend iekf`` to compare).

* APE: the true extrinsic on a simulated 40 s handheld run (Ouster OS1-16 1024 columns, VN100),
  translation RMSE of the estimated LiDAR poses against ``gt_lidar`` (target < 10 cm), for the
  default options and for one continuous run per segment (shared map, own map).
* Sensitivity: rotations of the extrinsic by 0.5–5° about x, y, z and translations by 1–10 cm
  along x, y, z, scored on a 10 s segment by the paper reward (``align="none"``): each must
  score below the true extrinsic.
* Throughput: candidate-scans per second of ``evaluate`` at K = 1, 8, 32 on the 10 s segment
  (one run each; the machine is shared, so figures are pessimistic).

Simulation and ``prepare`` are not timed.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from l2calib import geometry as geo
from l2calib.interfaces import CandidateStatus, ReferenceTrajectory
from l2calib.plugins import get_plugin
from l2calib.recipe import ImuInput
from l2calib.reward import trajectory_reward
from l2calib.sim import SimConfig, simulate

RESULTS = Path(__file__).parent / "results"
APE_TARGET_M = 0.10
SIM = {
    "lidar": {"model": "ouster-os1-16", "columns": 1024},
    "imu": {"model": "vn100"},
    "motion": {"profile": "handheld"},
}
ROT_DEG = (0.5, 1.0, 2.0, 5.0)
TRANS_M = (0.01, 0.02, 0.05, 0.10)
APE_CASES = {  # label -> options
    "default": {},  # shared map, re-anchored every 10 scans
    "shared map, 1 run": {"window_scans": 0},
    "own map, 1 run": {"map_mode": "odometry", "window_scans": 0},
}


def simulate_run(duration_s: float = 40.0, seed: int = 0):
    """The benchmark's simulated handheld run (:class:`l2calib.sim.SimRun`)."""
    return simulate(SimConfig.model_validate({"duration_s": duration_s, "seed": seed, **SIM}))


def build(backend: str, options: dict[str, Any], run, start_s: float, end_s: float | None):
    """A prepared backend on the segment ``[start_s, end_s]`` of ``run`` (reference: gt)."""
    seq = run.sequence()
    end = seq.end_ns if end_s is None else seq.start_ns + int(end_s * 1e9)
    seg = seq.segment(seq.start_ns + int(start_s * 1e9), end)
    ref = ReferenceTrajectory(seg.name, run.gt_lidar)
    imu = ImuInput()
    be = get_plugin("l2calib.backends", backend).build(options, imu=imu)
    be.prepare([seg], [ref])
    return be, ref


def ape(backend: str, options: dict[str, Any], run) -> dict[str, Any]:
    """Translation APE (m) of the true extrinsic over the whole run (from 1 s on)."""
    be, ref = build(backend, options, run, 1.0, None)
    t = time.perf_counter()
    out = be.evaluate(torch.from_numpy(run.T_imu_lidar)[None])[0]
    seconds = time.perf_counter() - t
    gt = ref.trajectory.interpolate(out.stamps_ns).matrices()
    err = (out.T_world_lidar[0, :, :3, 3] - gt[:, :3, 3]).norm(dim=-1)[out.valid[0]]
    rmse = float(err.pow(2).mean().sqrt())
    return {
        "options": options,
        "scans": int(out.T_world_lidar.shape[1]),
        "status": CandidateStatus(int(out.status[0])).name,
        "valid": bool(out.valid.all()),
        "ape_rmse_m": rmse,
        "ape_max_m": float(err.max()),
        "seconds": seconds,
        "pass": rmse < APE_TARGET_M and bool(out.valid.all()),
    }


def perturbations() -> tuple[list[str], torch.Tensor]:
    """Labels and ``[P, 6]`` twists ``(v, ω)`` of the sensitivity sweep (right-multiplied)."""
    labels, xis = [], []
    for axis, name in enumerate("xyz"):
        for deg in ROT_DEG:
            xi = torch.zeros(6, dtype=torch.float64)
            xi[3 + axis] = np.radians(deg)
            labels.append(f"rot {name} {deg:g} deg")
            xis.append(xi)
        for m in TRANS_M:
            xi = torch.zeros(6, dtype=torch.float64)
            xi[axis] = m
            labels.append(f"trans {name} {m * 100:g} cm")
            xis.append(xi)
    return labels, torch.stack(xis)


def sensitivity(backend: str, options: dict[str, Any], run) -> dict[str, Any]:
    """Rewards of the true extrinsic and of every perturbation, in one ``evaluate`` call."""
    be, ref = build(backend, options, run, 1.0, 11.0)
    labels, xis = perturbations()
    T_true = torch.from_numpy(run.T_imu_lidar)
    T = torch.cat([T_true[None], T_true @ geo.se3_exp(xis)])
    out = be.evaluate(T)[0]
    gt = ref.trajectory.interpolate(out.stamps_ns).matrices()
    failed = out.status == int(CandidateStatus.DIVERGED)
    reward = trajectory_reward(gt, out.T_world_lidar, out.valid, failed=failed, align="none")
    r = reward.reward.tolist()
    return {
        "options": options,
        "true_reward": r[0],
        "rows": [
            {"perturbation": lab, "reward": rew, "lower": rew < r[0]}
            for lab, rew in zip(labels, r[1:], strict=True)
        ],
        "pass": all(rew < r[0] for rew in r[1:]),
    }


def throughput(backend: str, options: dict[str, Any], run, ks=(1, 8, 32)) -> list[dict]:
    """Candidate-scans per second of ``evaluate`` for K random candidates (3 cm / 1.7°)."""
    be, _ = build(backend, options, run, 1.0, 11.0)
    T_true = torch.from_numpy(run.T_imu_lidar)
    gen = torch.Generator().manual_seed(0)
    rows = []
    for k in ks:
        xi = 0.03 * torch.randn(k, 6, generator=gen, dtype=torch.float64)
        T = T_true @ geo.se3_exp(xi)
        t = time.perf_counter()
        out = be.evaluate(T)[0]
        seconds = time.perf_counter() - t
        scans = int(out.T_world_lidar.shape[1])
        rows.append(
            {"K": k, "scans": scans, "seconds": seconds, "cand_scans_per_s": k * scans / seconds}
        )
    return rows


def _tables(backend: str, res: dict[str, Any]) -> None:
    con = Console()
    t = Table(title=f"{backend}: APE, true extrinsic, 40 s handheld (target < 10 cm)")
    for col in ("case", "scans", "status", "APE RMSE (m)", "max (m)", "eval (s)", "target"):
        t.add_column(col)
    for name, r in res["ape"].items():
        ok = "[green]ok[/]" if r["pass"] else "[red]FAIL[/]"
        t.add_row(
            name, str(r["scans"]), r["status"], f"{r['ape_rmse_m']:.4f}",
            f"{r['ape_max_m']:.4f}", f"{r['seconds']:.1f}", ok,
        )  # fmt: skip
    con.print(t)
    s = res["sensitivity"]
    t = Table(title=f"{backend}: reward sensitivity, 10 s segment (true: {s['true_reward']:.4f})")
    for col in ("perturbation", "reward", "drop", "lower"):
        t.add_column(col)
    for r in s["rows"]:
        ok = "[green]yes[/]" if r["lower"] else "[red]NO[/]"
        t.add_row(
            r["perturbation"], f"{r['reward']:.4f}", f"{s['true_reward'] - r['reward']:.4f}", ok
        )
    con.print(t)
    t = Table(title=f"{backend}: throughput, 10 s segment (shared CPU: pessimistic)")
    for col in ("K", "scans", "seconds", "candidate-scans/s"):
        t.add_column(col)
    for r in res["throughput"]:
        t.add_row(
            str(r["K"]), str(r["scans"]), f"{r['seconds']:.2f}", f"{r['cand_scans_per_s']:.0f}"
        )
    con.print(t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default="gtsam")
    parser.add_argument("--quick", action="store_true", help="APE of the default options only")
    parser.add_argument("--out", type=Path, help="JSON path (default results/<backend>.json)")
    args = parser.parse_args()
    torch.manual_seed(0)
    run = simulate_run(40.0)
    cases = dict(list(APE_CASES.items())[:1]) if args.quick else APE_CASES
    res = {
        "benchmark": f"backend-{args.backend}",
        "python": platform.python_version(),
        "machine": platform.machine(),
        "sim": SIM,
        "ape": {name: ape(args.backend, opts, run) for name, opts in cases.items()},
        "sensitivity": sensitivity(args.backend, {}, run),
        "throughput": throughput(args.backend, {}, run),
    }
    _tables(args.backend, res)
    path = args.out or RESULTS / f"{args.backend}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
