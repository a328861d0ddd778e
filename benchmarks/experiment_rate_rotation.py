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
Results: ``benchmarks/results/experiments/rotation_from_rates.json``. With ``--prepared``: the
training's own start (:mod:`l2calib.train.rotation_start`) on the selected data with the case's
reference, its error per LiDAR axis against its starting σ (``rotation_start.json``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from benchmarks.bench_calibration import cases, prepare_case, simulate_case
from benchmarks.machine import machine_info

OUT = Path(__file__).parent / "results" / "experiments" / "rotation_from_rates.json"
OUT_PREPARED = OUT.with_name("rotation_start.json")
DEFAULT_CASES = ["handheld", "uav seq 1", "ugv seq 1", "ugv drive velodyne-vlp-32c gt"]


def rates_rotation(run) -> dict[str, object]:
    """The Kabsch rotation of one simulated run, its error (deg) and normalised singular values."""
    from scipy.spatial.transform import Rotation

    from l2calib.train.rotation_start import fit_rotation

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
    R, _, S = fit_rotation([(w_lidar, w_imu)], iterations=1)  # no bias: Kabsch alone
    err = Rotation.from_matrix(run.T_imu_lidar[:3, :3].T @ R).magnitude()
    return {
        "singular_values": np.round(S, 4).tolist(),
        "rotation_error_deg": round(float(np.degrees(err)), 3),
    }


def prepared_start(case) -> dict[str, object]:
    """The training's own rate start (:mod:`l2calib.train.rotation_start`) on the case's data.

    The full pipeline up to training (selection, the case's reference, the rate time offset),
    then :func:`rotation_from_rates`: its error per LiDAR axis against its starting σ.
    """
    from l2calib.train.offset_hold import offset_from_rates
    from l2calib.train.rotation_start import rotation_from_rates

    runs, data, recipe = prepare_case(case, exact="reference.name=gt" in case.overrides)
    recipe, _ = offset_from_rates(recipe, data, lambda _m: None)
    offset = recipe.train.known_time_offset_s
    offset = data.time_offset_hint_s if offset is None else offset
    start = rotation_from_rates(data.references, data.segments, data.sequences, offset or 0.0)
    if start is None:
        return {"start": None}
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(start.quat_xyzw).as_matrix()
    delta = Rotation.from_matrix(runs[0].T_imu_lidar[:3, :3].T @ R).as_rotvec()
    return {
        "offset_used_ms": None if offset is None else round(1000 * offset, 3),
        "start_error_deg": round(float(np.degrees(np.linalg.norm(delta))), 3),
        "start_error_lidar_axes_deg": np.round(np.degrees(np.abs(delta)), 3).tolist(),
        "start": start.to_dict(),
    }


def main() -> None:
    """Runs the cases, prints a line each, writes the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES)
    parser.add_argument(
        "--prepared",
        action="store_true",
        help="the training's start on the selected data and the case's own reference",
    )
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    torch.set_default_dtype(torch.float64)
    rows = []
    for name in args.cases:
        case = next(c for c in cases(quick=False) if c.name == name)
        row = prepared_start(case) if args.prepared else rates_rotation(simulate_case(case)[0])
        rows.append({"case": name, **row})
        print(rows[-1], flush=True)
    out = args.out or (OUT_PREPARED if args.prepared else OUT)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "machine": machine_info()}, indent=1))


if __name__ == "__main__":
    main()
