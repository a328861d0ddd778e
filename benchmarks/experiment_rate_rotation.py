"""Experiment: the extrinsic rotation from the gyro against the reference's body rates.

Run: ``python -m benchmarks.experiment_rate_rotation [--cases NAME ...]``.

For the first simulated sequence of each case: the exact LiDAR trajectory's rotation increments
(one per scan interval, as body rates ``w_lidar``) against the gyro averaged over the same
intervals (``w_imu``; the simulated time offset, a few ms, is not removed); the rotation ``R``
with ``R w_lidar ≈ w_imu`` by SVD (Kabsch). Its error is the angle of ``R_trueᵀ R``; the
singular values (normalised by the largest) say how much motion each direction rests on (on a
ground vehicle two are ~0.001-0.004: the yaw about the vertical is then barely determined, only
the vertical axis itself). Issue 27: a search from no initial guess on one drive was trapped 39°
off because the reward is a needle in roll and pitch on planar data (``docs/backends.md``); this
measures how good a start the rates give.
Results: ``benchmarks/results/experiments/rotation_from_rates.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from benchmarks.bench_calibration import cases, simulate_case
from benchmarks.machine import machine_info

OUT = Path(__file__).parent / "results" / "experiments" / "rotation_from_rates.json"
DEFAULT_CASES = ["handheld", "uav seq 1", "ugv seq 1", "ugv drive velodyne-vlp-32c gt"]


def rates_rotation(run) -> dict[str, object]:
    """The Kabsch rotation of one simulated run, its error (deg) and normalised singular values."""
    from scipy.spatial.transform import Rotation

    gt = run.gt_lidar
    M = np.asarray(gt.matrices())
    ts = np.asarray(gt.stamps_s)
    rel = np.einsum("nji,njk->nik", M[:-1, :3, :3], M[1:, :3, :3])
    w_lidar = Rotation.from_matrix(rel).as_rotvec() / np.diff(ts)[:, None]
    imu = run.sequence().imu
    t_imu = imu.stamps_ns / 1e9
    w_imu = np.stack(
        [
            imu.gyro_rad_s[(t_imu >= a) & (t_imu < b)].mean(0)
            for a, b in zip(ts[:-1], ts[1:], strict=True)
        ]
    )
    U, S, Vt = np.linalg.svd(w_lidar.T @ w_imu)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    err = Rotation.from_matrix(run.T_imu_lidar[:3, :3].T @ R).magnitude()
    return {
        "singular_values": np.round(S / S[0], 4).tolist(),
        "rotation_error_deg": round(float(np.degrees(err)), 3),
    }


def main() -> None:
    """Runs the cases, prints a line each, writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    args = parser.parse_args()
    torch.set_default_dtype(torch.float64)
    rows = []
    for name in args.cases:
        case = next(c for c in cases(quick=False) if c.name == name)
        rows.append({"case": name, **rates_rotation(simulate_case(case)[0])})
        print(rows[-1], flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"rows": rows, "machine": machine_info()}, indent=1))


if __name__ == "__main__":
    main()
