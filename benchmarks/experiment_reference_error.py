"""Which part of a LiDAR-only reference's error moves the reward's peak? (issue 27)

Run: ``python -m benchmarks.experiment_reference_error [--cases "ugv drive ouster-os1-16 ct-lidar"]
[--kinds gt ct ct_pos ct_rot ct_slow ct_fast] [--reward paper|position] [--set budget=60 ...]``.

On a :mod:`benchmarks.bench_calibration` case with a LiDAR-only reference (``ct-lidar``), the
case's selected data is scored along 1-D sweeps through the simulated true extrinsic (x, y in
cm; roll, pitch, yaw in degrees; the vertical hold off, as in
:mod:`benchmarks.experiment_planar_lever`), each time against a *hybrid* reference built from
the truth and the case's own reference (``ct``), so that one part of the reference's error is
present at a time:

* ``gt`` the exact LiDAR trajectory; ``ct`` the case's reference as computed;
* ``ct_pos`` ct's positions with the true orientations; ``ct_rot`` the true positions with
  ct's orientations;
* ``ct_slow`` / ``ct_fast`` the truth plus the part of ct's error (position and rotation, in
  the world frame after a position-only Umeyama alignment onto the truth) that is slower /
  faster than a moving average of ``±lowpass_half_s``.

Per axis: where the parabola through the sweep's inner part peaks (cm / deg from the truth) —
the bias that part of the reference error puts into any search on that reward — and the
resolution (as in :mod:`benchmarks.experiment_planar_lever`). ``--reward position`` scores
without the rotation term. Every row also holds, per selected segment, how far the case's
reference is from the truth (:func:`reference_vs_truth`: position RMS, and in the LiDAR frame the
constant offset, the orientation's fast jitter and slow drift); ``--kinds`` with no kind computes
these alone (kind ``none``). ``--set r.NAME=V`` changes a reference option (e.g.
``r.scan_voxel_m=0.25`` for ct-lidar), ``budget=`` / ``window=`` the selection. Results:
``benchmarks/results/experiments/reference_error.json`` (rows with the same case, kind, reward
and settings are replaced).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "experiments" / "reference_error.json"
KINDS = ["gt", "ct", "ct_pos", "ct_rot", "ct_slow", "ct_fast"]
SWEEP_AXES = {"x": 0, "y": 1, "roll": 3, "pitch": 4, "yaw": 5}  # index as in planar_lever


def hybrid_trajectory(truth, reference, kind: str, lowpass_half_s: float):
    """``kind``'s mix of the true and the reference's poses, at the reference's stamps.

    Args:
        truth: the exact LiDAR :class:`~l2calib.trajectory.Trajectory` of the sequence.
        reference: the case's reference trajectory of one segment (any world frame).
        kind: one of :data:`KINDS` (module docstring).
        lowpass_half_s: half-width (s) of the moving average splitting slow from fast error.

    Returns:
        A :class:`~l2calib.trajectory.Trajectory` in the truth's world frame.
    """
    from scipy.ndimage import uniform_filter1d
    from scipy.spatial.transform import Rotation

    from l2calib.alignment import umeyama
    from l2calib.trajectory import Trajectory

    g = truth.interpolate(reference.stamps_ns)
    p_g, R_g = g.t_world_body, Rotation.from_quat(g.quat_xyzw)
    R, t, _ = umeyama(torch.from_numpy(reference.t_world_body), torch.from_numpy(p_g))
    A = R.numpy()
    p_c = reference.t_world_body @ A.T + t.numpy()
    R_c = Rotation.from_matrix(A) * Rotation.from_quat(reference.quat_xyzw)
    dp, dr = p_c - p_g, (R_c * R_g.inv()).as_rotvec()  # world-frame errors
    step_s = float(np.median(np.diff(reference.stamps_ns))) * 1e-9
    k = max(1, int(round(2 * lowpass_half_s / step_s)))
    slow_p, slow_r = (uniform_filter1d(x, k, axis=0, mode="nearest") for x in (dp, dr))
    pose = {
        "gt": (p_g, R_g),
        "ct": (p_c, R_c),
        "ct_pos": (p_c, R_g),
        "ct_rot": (p_g, R_c),
        "ct_slow": (p_g + slow_p, Rotation.from_rotvec(slow_r) * R_g),
        "ct_fast": (p_g + dp - slow_p, Rotation.from_rotvec(dr - slow_r) * R_g),
    }
    if kind not in pose:
        raise ValueError(f"unknown kind {kind!r}; one of {KINDS}")
    p, rot = pose[kind]
    return Trajectory(reference.stamps_ns, p, rot.as_quat(), "lidar", "world")


def reference_vs_truth(truth, reference, lowpass_half_s: float) -> dict[str, Any]:
    """How far one segment's reference is from the truth, after a rigid (Umeyama) alignment.

    Args:
        truth: the exact LiDAR :class:`~l2calib.trajectory.Trajectory` of the sequence.
        reference: the reference trajectory of one segment (any world frame).
        lowpass_half_s: half-width (s) of the moving average splitting slow from fast error.

    Returns:
        ``rms_pos_cm``; in the LiDAR (body) frame per axis: ``pos_mean_cm`` (a constant offset
        the alignment cannot take), ``rot_mean_deg``, ``rot_jitter_deg`` (RMS of the part
        faster than ``±lowpass_half_s``) and ``rot_drift_deg`` (peak-to-peak of the slower
        part); ``duration_s``.
    """
    from scipy.ndimage import uniform_filter1d
    from scipy.spatial.transform import Rotation

    aligned = hybrid_trajectory(truth, reference, "ct", lowpass_half_s)
    g = truth.interpolate(reference.stamps_ns)
    R_g = Rotation.from_quat(g.quat_xyzw)
    dp_world = aligned.t_world_body - g.t_world_body
    dp_body = R_g.inv().apply(dp_world)
    dr_body = (R_g.inv() * Rotation.from_quat(aligned.quat_xyzw)).as_rotvec()
    step_s = float(np.median(np.diff(reference.stamps_ns))) * 1e-9
    k = max(1, int(round(2 * lowpass_half_s / step_s)))
    slow = uniform_filter1d(dr_body, k, axis=0, mode="nearest")
    deg = np.rad2deg
    return {
        "duration_s": round(float(reference.stamps_ns[-1] - reference.stamps_ns[0]) * 1e-9, 1),
        "rms_pos_cm": round(float(np.sqrt((dp_world**2).sum(1).mean()) * 100), 3),
        "pos_mean_cm": np.round(dp_body.mean(0) * 100, 3).tolist(),
        "rot_mean_deg": np.round(deg(dr_body.mean(0)), 4).tolist(),
        "rot_jitter_deg": np.round(deg(np.sqrt(((dr_body - slow) ** 2).mean(0))), 4).tolist(),
        "rot_drift_deg": np.round(deg(slow.max(0) - slow.min(0)), 4).tolist(),
    }


def sweep_kinds(
    name: str, kinds: list[str], reward: str, lowpass_half_s: float, spec: dict[str, str]
) -> Iterator[dict[str, Any]]:
    """One row per kind (yielded as each ends): the reward's peak per axis against that hybrid."""
    from benchmarks.bench_calibration import prepare_case
    from benchmarks.experiment_planar_lever import ROT_DEG, TRANS_CM, _case, _fit, _perturbed
    from l2calib.interfaces import ReferenceTrajectory
    from l2calib.train.env import make_env
    from l2calib.train.env_build import score_batch

    case = _case(name, spec)
    runs, data, recipe = prepare_case(case, exact=False)
    truth = {r.sequence().name: r.gt_lidar for r in runs}
    T_gt = torch.from_numpy(runs[0].T_imu_lidar)
    config = recipe.model_dump(mode="json")
    config["reward"]["kind"] = reward
    versus = {
        s.name: reference_vs_truth(truth[s.sequence], r.trajectory, lowpass_half_s)
        for s, r in zip(data.segments, data.references, strict=True)
    }
    for seg, v in versus.items():
        Console().print(f"{name} reference vs truth {seg}: {v}")
    if not kinds:
        yield _row(name, "none", reward, lowpass_half_s, spec, recipe, data, {}, versus)
    for kind in kinds:
        refs = [
            ReferenceTrajectory(
                s.name, hybrid_trajectory(truth[s.sequence], r.trajectory, kind, lowpass_half_s)
            )
            for s, r in zip(data.segments, data.references, strict=True)
        ]
        env = make_env(config, data.segments, refs, 8)
        axes = {}
        for axis, i in SWEEP_AXES.items():
            deltas = TRANS_CM if i < 3 else ROT_DEG
            scores = score_batch(env, _perturbed(T_gt, i, deltas)).reward.double().numpy()
            fit = _fit(np.array(deltas), scores, 1.0 if i < 3 else 0.1)
            axes[axis] = {k: fit[k] for k in ("peak", "best_at", "resolution")}
        Console().print(f"{name} {kind} ({reward}): y peak {axes['y']['peak']:+.2f} cm")
        yield _row(name, kind, reward, lowpass_half_s, spec, recipe, data, axes, versus)


def _row(name, kind, reward, lowpass_half_s, spec, recipe, data, axes, versus) -> dict[str, Any]:  # noqa: ANN001
    """One JSON row (``kind="none"``: the reference-vs-truth statistics alone, no sweep)."""
    return {
        "case": name,
        "kind": kind,
        "reward": reward,
        "lowpass_half_s": lowpass_half_s,
        "settings": spec,
        "reference": recipe.reference.name,
        "reference_options": dict(recipe.reference.options),
        "segments": [s.name for s in data.segments],
        "data_s": round(sum(s.duration_s for s in data.segments), 1),
        "reference_vs_truth": versus,
        "axes": axes,
        "machine": machine_info(),
    }


def main() -> None:
    """Runs the sweeps, merges the rows into the JSON and prints the peaks."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["ugv drive ouster-os1-16 ct-lidar"])
    parser.add_argument(
        "--kinds", nargs="*", default=KINDS, choices=KINDS, help="no kind: the statistics alone"
    )
    parser.add_argument("--reward", default="paper", choices=["paper", "position"])
    parser.add_argument("--lowpass-half-s", type=float, default=2.0)
    parser.add_argument(
        "--set",
        nargs="*",
        action="extend",  # --set a b and --set a --set b alike (a plain list kept the last)
        default=[],
        help="budget=S window=S (selection), r.NAME=V (reference)",
    )
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    spec = dict(s.split("=", 1) for s in args.set)
    rows = json.loads(args.out.read_text())["rows"] if args.out.exists() else []

    def key(r):
        return (r["case"], r["kind"], r["reward"], r["lowpass_half_s"], json.dumps(r["settings"]))

    for c in args.cases:
        for new in sweep_kinds(c, args.kinds, args.reward, args.lowpass_half_s, spec):
            rows = [r for r in rows if key(r) != key(new)] + [new]
            args.out.parent.mkdir(parents=True, exist_ok=True)
            out = {"benchmark": "reference_error", "rows": rows}
            args.out.write_text(json.dumps(out, indent=1))
    table = Table(title="Reward peaks against hybrid references (cm / deg from the truth)")
    for col in ("case", "kind", "reward", "settings", "data s", *SWEEP_AXES):
        table.add_column(col)
    for r in rows:
        peaks = [f"{r['axes'][a]['peak']:+.2f}" if r["axes"] else "-" for a in SWEEP_AXES]
        settings = ",".join(f"{k}={v}" for k, v in r["settings"].items()) or "case"
        table.add_row(r["case"], r["kind"], r["reward"], settings, str(r["data_s"]), *peaks)
    Console().print(table)


if __name__ == "__main__":
    main()
