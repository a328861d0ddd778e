"""LIO backends: accuracy, extrinsic sensitivity per map mode, throughput, and a peer LIO.

Run: ``python -m benchmarks.bench_backends [--quick] [--out PATH]`` (prefix ``OMP_NUM_THREADS=1`` on
a shared machine); prints rich tables and writes ``benchmarks/results/backends.json`` and
``backends.md``. Backends are built through their ``l2calib.backends`` plugin, so every function
here works for any backend plugin.

* APE: the true extrinsic on a simulated 40 s handheld run (Ouster OS1-16 1024 columns, VN100),
  translation RMSE of the estimated LiDAR poses against ``gt_lidar`` without alignment (the
  backends start in the reference frame); targets < 5 cm (iekf), < 10 cm (gtsam); default options,
  one continuous run on the shared map, one continuous run on the candidate's own map. Also after
  an SE(3) alignment, to compare with the peer LIO, which starts in its own frame.
* Sensitivity (handheld and uav, 10 s segment): the extrinsic rotated by 0.5-5 deg about x, y, z
  and translated by 1-10 cm along x, y, z (right-multiplied, LiDAR axes) must lower the paper
  reward (``align="none"``); plus large errors (10-90 deg, 20-50 cm) for monotonicity. Run for
  every map mode / window case of :data:`CASES` (``shared``: shared map, ``odom``: own map per
  candidate, ``wN``: ``window_scans``, start priors loose (0.1 m/s²) unless ``tight`` (0.01),
  ``default``: the backend's own defaults, window and priors ``auto``), so the numbers behind the
  default are here.
* Throughput: candidate-scans per second of ``evaluate`` at K = 1, 8, 32 on the 10 s handheld
  segment per case (best of ``repeats``; wall and process CPU time; torch threads as the
  environment sets them). Simulation and ``prepare`` are not timed.
* Peer: ``rko-lio`` (PRBonn, C++ LIO, one trajectory per run) on the same 40 s run with the true
  extrinsic: scans/s and SE(3)-aligned APE (see :mod:`benchmarks.backends_peer`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.machine import machine_info
from l2calib import geometry as geo
from l2calib.alignment import ape as aligned_ape
from l2calib.alignment import pose_errors
from l2calib.interfaces import CandidateStatus, ReferenceTrajectory
from l2calib.plugins import get_plugin
from l2calib.recipe import ImuInput
from l2calib.reward import trajectory_reward
from l2calib.sim import SimConfig, simulate
from l2calib.trajectory import Trajectory

RESULTS = Path(__file__).parent / "results"
APE_TARGET_M = {"iekf": 0.05, "gtsam": 0.10}
SIM = {
    "lidar": {"model": "ouster-os1-16", "columns": 1024},
    "imu": {"model": "vn100"},
    "motion": {"profile": "handheld"},
}
ROT_DEG = (0.5, 1.0, 2.0, 5.0)  # the sweep: each must lower the reward
TRANS_M = (0.01, 0.02, 0.05, 0.10)
LARGE_ROT_DEG = (10.0, 20.0, 30.0, 45.0, 60.0, 90.0)  # monotonicity / smoothness only
LARGE_TRANS_M = (0.20, 0.30, 0.50)
SEGMENT_S = (1.0, 11.0)  # sensitivity and throughput segment of each run (s after its start)
APE_CASES = {  # label -> options
    "default": {},  # shared map, window_scans auto (re-anchored every 10 scans on handheld)
    "shared map, 1 run": {"window_scans": 0},
    "own map, 1 run": {"map_mode": "odometry", "window_scans": 0},
}
TIGHT = {"init_sigma_accel_bias_m_s2": 0.01, "init_sigma_gravity_m_s2": 0.01}
LOOSE = {"init_sigma_accel_bias_m_s2": 0.1, "init_sigma_gravity_m_s2": 0.1}
LOOSE_GTSAM = {"init_sigma_accel_bias_m_s2": 0.1}  # gravity is fixed in the graph
# (backend, label, options, timed): the map-mode / window / prior grid of the sensitivity
# section; the throughput section times the cases with ``timed`` (priors change no cost; the
# default resolves to "shared w10" on the handheld throughput run). "default" is the backend's
# default options: window_scans and start priors "auto" (10-scan windows and loose priors on
# well-excited data, one continuous run and tight accel-bias/gravity priors on weak excitation).
CASES = [
    ("iekf", "default (auto)", {}, False),
    ("iekf", "shared w10", {"window_scans": 10, **LOOSE}, True),
    ("iekf", "shared w20", {"window_scans": 20, **LOOSE}, True),
    ("iekf", "shared w30", {"window_scans": 30, **LOOSE}, True),
    ("iekf", "shared w0", {"window_scans": 0, **LOOSE}, True),
    ("iekf", "shared w0 tight", {"window_scans": 0, **TIGHT}, False),
    ("iekf", "odom w10", {"map_mode": "odometry", "window_scans": 10, **LOOSE}, True),
    ("iekf", "odom w0", {"map_mode": "odometry", "window_scans": 0, **LOOSE}, True),
    ("gtsam", "default (auto)", {}, False),
    ("gtsam", "shared w10", {"window_scans": 10, **LOOSE_GTSAM}, True),
    ("gtsam", "shared w0", {"window_scans": 0, **LOOSE_GTSAM}, True),
    ("gtsam", "odom w0", {"map_mode": "odometry", "window_scans": 0, **LOOSE_GTSAM}, True),
]
QUICK_CASES = [CASES[0], CASES[1], CASES[9]]


def simulate_run(duration_s: float = 40.0, seed: int = 0, profile: str = "handheld"):
    """The benchmark's simulated run (:class:`l2calib.sim.SimRun`)."""
    cfg = {**SIM, "motion": {"profile": profile}, "duration_s": duration_s, "seed": seed}
    return simulate(SimConfig.model_validate(cfg))


def build(backend: str, options: dict[str, Any], run, start_s: float, end_s: float | None):
    """A prepared backend on the segment ``[start_s, end_s]`` of ``run`` (reference: gt)."""
    seq = run.sequence()
    end = seq.end_ns if end_s is None else seq.start_ns + int(end_s * 1e9)
    seg = seq.segment(seq.start_ns + int(start_s * 1e9), end)
    ref = ReferenceTrajectory(seg.name, run.gt_lidar)
    be = get_plugin("l2calib.backends", backend).build(options, imu=ImuInput())
    be.prepare([seg], [ref])
    return be, ref


def ape(backend: str, options: dict[str, Any], run) -> dict[str, Any]:
    """Translation APE (m, no alignment) of the true extrinsic over the whole run (from 1 s on)."""
    be, ref = build(backend, options, run, 1.0, None)
    t = time.perf_counter()
    out = be.evaluate(torch.from_numpy(run.T_imu_lidar)[None])[0]
    seconds = time.perf_counter() - t
    gt = ref.trajectory.interpolate(out.stamps_ns).matrices()
    valid = out.valid[0]
    e_t, e_r = pose_errors(out.T_world_lidar[0][valid], gt[valid])
    rmse = float(e_t.pow(2).mean().sqrt())
    est = Trajectory.from_matrices(out.stamps_ns[valid.numpy()], out.T_world_lidar[0][valid])
    aligned = aligned_ape(ref.trajectory, est)  # SE(3) Umeyama, as for the peer LIO
    return {
        "backend": backend,
        "options": options,
        "scans": int(out.T_world_lidar.shape[1]),
        "status": CandidateStatus(int(out.status[0])).name,
        "valid": bool(valid.all()),
        "ape_rmse_m": rmse,
        "ape_max_m": float(e_t.max()),
        "ape_rot_rmse_deg": math.degrees(float(e_r.pow(2).mean().sqrt())),
        "ape_se3_rmse_m": aligned.rmse_t,
        "seconds": seconds,
        "target_m": APE_TARGET_M.get(backend),
        "pass": rmse < APE_TARGET_M.get(backend, 0.10) and bool(valid.all()),
    }


def perturbations() -> list[dict[str, Any]]:
    """The sweep: dicts with ``label``, ``kind`` (rot/trans), ``axis``, ``size``, ``large`` and
    ``xi``, the ``[6]`` twist ``(v, ω)`` right-multiplied onto the true extrinsic."""
    rows = []
    for axis, name in enumerate("xyz"):
        for kind, sizes, off, unit in (
            ("rot", ROT_DEG + LARGE_ROT_DEG, 3, "deg"),
            ("trans", TRANS_M + LARGE_TRANS_M, 0, "cm"),
        ):
            for size in sizes:
                xi = torch.zeros(6, dtype=torch.float64)
                xi[off + axis] = np.radians(size) if kind == "rot" else size
                shown = size if kind == "rot" else size * 100
                large = size > (ROT_DEG[-1] if kind == "rot" else TRANS_M[-1])
                rows.append(
                    {"label": f"{kind} {name} {shown:g} {unit}", "kind": kind, "axis": name,
                     "size": shown, "large": large, "xi": xi}
                )  # fmt: skip
    return rows


def sensitivity(backend: str, options: dict[str, Any], run) -> dict[str, Any]:
    """Rewards of the true extrinsic and of every perturbation, in one ``evaluate`` call."""
    be, ref = build(backend, options, run, *SEGMENT_S)
    rows = perturbations()
    T_true = torch.from_numpy(run.T_imu_lidar)
    T = torch.cat([T_true[None], T_true @ geo.se3_exp(torch.stack([r["xi"] for r in rows]))])
    t = time.perf_counter()
    out = be.evaluate(T)[0]
    seconds = time.perf_counter() - t
    gt = ref.trajectory.interpolate(out.stamps_ns).matrices()
    failed = out.status == int(CandidateStatus.DIVERGED)
    reward = trajectory_reward(gt, out.T_world_lidar, out.valid, failed=failed, align="none")
    r = reward.reward.tolist()
    status = [CandidateStatus(int(s)).name for s in out.status]
    table = [
        {k: v for k, v in row.items() if k != "xi"}
        | {"reward": rew, "drop": r[0] - rew, "lower": rew < r[0], "status": st}
        for row, rew, st in zip(rows, r[1:], status[1:], strict=True)
    ]
    small = [x for x in table if not x["large"]]
    return {
        "backend": backend,
        "options": options,
        "true_reward": r[0],
        "true_status": status[0],
        "seconds": seconds,
        "rows": table,
        "flagged": [x["label"] for x in small if not x["lower"]],
        "pass": all(x["lower"] for x in small) and status[0] == "OK",
        "summary": summarise(r[0], table),
    }


def summarise(r0: float, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Slope near the optimum, weakest axis, monotonicity and saturation of a sweep."""

    def at(kind: str, axis: str, size: float) -> float:
        return next(
            x["reward"] for x in rows if (x["kind"], x["axis"], x["size"]) == (kind, axis, size)
        )

    out: dict[str, Any] = {}
    for kind, size, key in (("rot", 1.0, "deg"), ("trans", 1.0, "cm")):
        drops = [r0 - at(kind, a, size) for a in "xyz"]
        out[f"drop_per_1{key}_mean"] = float(np.mean(drops))
        out[f"drop_per_1{key}_min"] = float(np.min(drops))
    inversions, flats, pairs, worst = 0, 0, 0, 0.0
    for kind in ("rot", "trans"):
        for axis in "xyz":
            chain = [r0] + [x["reward"] for x in rows if (x["kind"], x["axis"]) == (kind, axis)]
            for a, b in zip(chain, chain[1:], strict=False):
                pairs += 1
                if b > a + 1e-12:
                    inversions, worst = inversions + 1, max(worst, b - a)
                elif abs(b - a) <= 1e-12:
                    flats += 1
    out.update(
        pairs=pairs,
        inversions=inversions,
        flat_pairs=flats,
        worst_rise=worst,
        reward_at_30deg=float(np.mean([at("rot", a, 30.0) for a in "xyz"])),
        reward_at_90deg=float(np.mean([at("rot", a, 90.0) for a in "xyz"])),
        reward_at_50cm=float(np.mean([at("trans", a, 50.0) for a in "xyz"])),
        not_ok=sum(x["status"] != "OK" for x in rows),
    )
    return out


def throughput(backend: str, options: dict[str, Any], run, ks=(1, 8, 32), repeats=3) -> list:
    """Candidate-scans per second of ``evaluate`` for K random candidates (3 cm / 1.7 deg)."""
    be, _ = build(backend, options, run, *SEGMENT_S)
    T_true = torch.from_numpy(run.T_imu_lidar)
    gen = torch.Generator().manual_seed(0)
    rows = []
    for k in ks:
        T = T_true @ geo.se3_exp(0.03 * torch.randn(k, 6, generator=gen, dtype=torch.float64))
        walls, cpus = [], []
        for _ in range(repeats):
            t, c = time.perf_counter(), time.process_time()
            out = be.evaluate(T)[0]
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
        scans = int(out.T_world_lidar.shape[1])
        best = int(np.argmin(walls))
        rows.append(
            {"K": k, "scans": scans, "seconds": walls[best], "cpu_seconds": cpus[best],
             "all_seconds": walls, "cand_scans_per_s": k * scans / walls[best],
             "cand_scans_per_cpu_s": k * scans / cpus[best]}
        )  # fmt: skip
    return rows


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def main() -> None:
    from benchmarks.backends_peer import rko_lio_cases
    from benchmarks.backends_report import print_tables, write_markdown

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs, fewer cases (smoke)")
    parser.add_argument("--out", type=Path, help="JSON path (default results/backends.json)")
    args = parser.parse_args()
    torch.manual_seed(0)
    t_start = time.perf_counter()
    q = args.quick
    cases, repeats = (QUICK_CASES, 1) if q else (CASES, 3)
    res: dict[str, Any] = {
        "benchmark": "backends",
        "quick": q,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "machine": machine_info(),  # cores, CPU model, load at the start
        "torch_threads": torch.get_num_threads(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "sim": SIM,
        "segment_s": SEGMENT_S,
        "load": {"start": _load()},
    }
    runs = {
        "handheld": simulate_run(15.0 if q else 40.0),
        "uav": simulate_run(SEGMENT_S[1] + 1.0, profile="uav"),
    }
    res["sim_stats"] = {k: {**r.stats, "duration_s": r.config.duration_s} for k, r in runs.items()}
    ape_cases = dict(list(APE_CASES.items())[:1]) if q else APE_CASES
    res["ape"] = [
        {"case": name, **ape(be, opts, runs["handheld"])}
        for be in ("iekf", "gtsam")
        for name, opts in ape_cases.items()
    ]
    res["load"]["after_ape"] = _load()
    res["sensitivity"] = {
        prof: [{"case": label, **sensitivity(be, opts, run)} for be, label, opts, _ in cases]
        for prof, run in runs.items()
    }
    res["load"]["after_sensitivity"] = _load()
    res["throughput"] = [
        {"backend": be, "case": label, "options": opts,
         "rows": throughput(be, opts, runs["handheld"], repeats=repeats)}
        for be, label, opts, timed in cases
        if timed
    ]  # fmt: skip
    res["load"]["after_throughput"] = _load()
    res["peer"] = rko_lio_cases(runs["handheld"], quick=q, threads=torch.get_num_threads())
    res["load"]["end"] = _load()
    res["seconds_total"] = time.perf_counter() - t_start
    print_tables(res)
    path = args.out or RESULTS / "backends.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=1))
    md = write_markdown(res, path.with_suffix(".md"))
    print(f"wrote {path} and {md}")


if __name__ == "__main__":
    main()
