"""Does a part of a continuous run rank candidates like all of it? (coarse-to-fine, issue 23)

Run: ``python -m benchmarks.bench_coarse_ranking [--cases "ugv all" "uav all"]``.

On the weakly excited :mod:`benchmarks.bench_calibration` cases (one continuous odometry run per
segment, ground-truth reference) this scores fixed sets of candidates around the true extrinsic
on all the data and on a part of it, and reports the Spearman rank correlation between the two
sets of rewards (1 = the part ranks them exactly as all the data does). Candidate sets (48 each,
seeded): ``mid`` (rotation up to 3°, translation ~6 cm), ``rot-narrow`` (1°, ~15 cm: the policy
once the rotation is found), ``narrow`` (1°, ~2 cm). The part is a stretch of each segment
starting at share ``p`` of the room left (``p = 0``: its first part, the backend's choice
before; 1: its end). The answer decides :mod:`l2calib_backends.data_fraction`: how well a part
ranks depends on where it lies, so continuous runs keep all their data. Results:
``benchmarks/results/experiments/coarse_ranking.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.table import Table
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "experiments" / "coarse_ranking.json"
SETS = {"mid": (3.0, 0.06), "rot-narrow": (1.0, 0.15), "narrow": (1.0, 0.02)}  # (deg, m)
FRACTIONS = (0.25, 0.5)
POSITIONS = (0.0, 0.33, 0.67, 1.0)


def candidates(T_gt: torch.Tensor, deg: float, m: float, rng: np.random.Generator, K: int = 48):
    """``K`` extrinsics around ``T_gt``: rotations up to ``deg``, translations of scale ``m``."""
    axes = rng.normal(size=(K, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.radians(deg) * rng.uniform(0, 1, K)
    dt = rng.normal(size=(K, 3)) * m / np.sqrt(3) * rng.uniform(0, 1.5, (K, 1))
    T = T_gt.repeat(K, 1, 1).clone()
    R = torch.from_numpy(Rotation.from_rotvec(axes * angles[:, None]).as_matrix())
    T[:, :3, :3] = R @ T[:, :3, :3]
    T[:, :3, 3] += torch.from_numpy(dt)
    return T


def run_case(name: str) -> list[dict]:
    """The rank correlations of one case (module docstring)."""
    from benchmarks.bench_calibration import exact_reference_env
    from l2calib.train.env_build import score_batch
    from l2calib_backends.data_fraction import WindowPlan
    from l2calib_backends.initialise import reference_motion

    env, runs, data, _ = exact_reference_env(name)
    backend = env.backend
    if backend.window_scans != 0:
        raise RuntimeError(f"{name}: needs continuous runs, not {backend.window_scans}-scan ones")
    rng = np.random.default_rng(0)
    T_gt = torch.from_numpy(runs[0].T_imu_lidar)
    sets = {k: candidates(T_gt, deg, m, rng) for k, (deg, m) in SETS.items()}
    backend.use_data_fraction(1.0)
    full = {k: score_batch(env, T).reward.numpy() for k, T in sets.items()}
    truth = float(score_batch(env, T_gt[None]).reward[0])  # the true extrinsic on all the data

    def at(position: float, fraction: float) -> tuple[list[WindowPlan], list]:
        """Per segment the stretch and the reference motion at its start (filters start there)."""
        plans, motions = [], []
        for seg, ref in zip(backend._segments, data.references, strict=True):
            n = len(seg.end_t) - 1
            scans = int(np.ceil(fraction * n))
            start = int(round(position * (n - scans)))
            plans.append(WindowPlan([start], [start + scans], [0]))
            motions.append(reference_motion(seg, ref.trajectory, [start]))
        return plans, motions

    rows = []
    full_motions = list(backend._motions)
    for fraction in FRACTIONS:
        for position in POSITIONS:
            backend._plans, backend._motions = at(position, fraction)
            row = {"case": name, "fraction": fraction, "placement": f"at {position:g}",
                   "starts": [p.starts[0] for p in backend._plans],
                   "reward_at_truth_all_data": round(truth, 4)}  # fmt: skip
            for k, T in sets.items():
                rewards = score_batch(env, T).reward.numpy()
                row[k] = round(float(spearmanr(rewards, full[k])[0]), 3)
            rows.append(row)
    backend._motions = full_motions
    backend.use_data_fraction(1.0)
    return rows


def main() -> None:
    """Runs the cases, prints the table and writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["ugv all", "uav all"])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    rows = [row for name in args.cases for row in run_case(name)]
    table = Table(title="Spearman rank correlation with the full data's rewards")
    for col in ("case", "fraction", "placement", "starts", *SETS):
        table.add_column(col)
    for r in rows:
        table.add_row(r["case"], f"{r['fraction']:g}", r["placement"], str(r["starts"]),
                      *(f"{r[k]:.2f}" for k in SETS))  # fmt: skip
    Console().print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {"benchmark": "coarse_ranking", "sets": SETS, "rows": rows, "machine": machine_info()},
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
