"""How sharply does the reward grade the lever arm on a ground vehicle's drive? (issue 27)

Run: ``python -m benchmarks.experiment_planar_lever [--cases "ugv all"] [--variants ...]``.

Issue 27 asks why x and y of the lever arm come out flat on planar drives *with a perfect
reference*. This experiment scores 1-D sweeps through the simulated true extrinsic (the exact
LiDAR trajectory as reference, the vertical hold off) along each IMU axis — translation x, y, z
in cm, rotation about x, y, z in degrees — on a :mod:`benchmarks.bench_calibration` case's
selected data, and fits a parabola to each sweep. Per axis it reports:

* ``drop_1cm`` / ``drop_01deg``: the reward lost 1 cm (0.1°) from the fitted peak;
* ``peak``: where the parabola peaks (cm / deg from the truth): the reward's own bias;
* ``jitter``: the RMS of the sweep about the parabola — the reward's roughness as the
  candidate moves, which decides where a climb stops;
* ``resolution = sqrt(jitter / curvature)``: how far a candidate can be from the peak before
  the reward it loses exceeds that roughness (cm / deg).

A variant changes one thing (comma-separated ``key=value``): ``sim=`` the IMU's corruption as
in :mod:`benchmarks.experiment_start_bias` (``default``, ``no-turn-on``, ``white-only``,
``no-white``, ``off``), ``budget=`` / ``window=`` the selection (seconds), ``o.NAME=`` a
backend option (e.g. ``o.point_sigma_m=0.2``, ``o.window_scans=10``), ``r.NAME=`` a reference
option (e.g. ``r.scan_voxel_m=0.25`` for ct-lidar), ``ref=case`` the
case's own reference instead of the exact trajectory; ``estimates=CASE`` also scores the stored
calibrations of ``CASE`` (``calibration.json``) beside the truth and continues each with the
refinement and the Newton polish (did the search stop short of the reward's peak?). Every row
also holds the reward's Hessian over x, y, roll, pitch, yaw and the time offset at the truth
(:func:`hessian`): how strongly the axes trade off.

Beside the sweeps, ``physics`` rows give the lever arm's Cramér-Rao bound from the IMU alone:
the specific force a lever-arm error ``δr`` adds at the IMU is ``([ω̇]× + [ω]×²) δr`` (body
frame, from the simulated motion's exact ω and ω̇); with the accelerometer's white noise and
an unknown constant bias per selected segment (the part a filter's bias estimate can absorb),
the bound per axis is ``sqrt(diag(I⁻¹))``, ``I = Σ_k J_kᵀ J_k / σ²`` over the de-meaned
``J_k``. It says what the data could give; the sweeps say what the reward gives.

What it showed (2026-12-05, ``ugv all``, 20 s of three drives): docs/backends.md, "Where x and y
were lost on ground vehicles". Results: ``benchmarks/results/experiments/planar_lever.json``
(rows with the same case and variant are replaced).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from benchmarks.experiment_start_bias import env_with_imu
from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "experiments" / "planar_lever.json"
TRANS_CM = [-6.0, -4.0, -3.0, -2.0, -1.5, -1.0, -0.5, -0.25, 0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0]  # fmt: skip  # noqa: E501
ROT_DEG = [-1.0, -0.6, -0.4, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.4, 0.6, 1.0]
AXES = ["x", "y", "z", "roll", "pitch", "yaw"]
DEFAULT_VARIANTS = ["sim=default", "sim=off", "budget=60,window=30", "o.point_sigma_m=0.2"]


def _case(name: str, spec: dict[str, str]):
    """The bench_calibration case with the variant's recipe overrides (vertical hold off)."""
    from benchmarks.bench_calibration import cases

    base = next(c for c in cases(quick=False) if c.name == name)
    overrides = [
        o for o in base.overrides if not o.startswith(("selection.budget_s", "selection.window_s"))
    ]
    budget = dict(o.split("=", 1) for o in base.overrides if o.startswith("selection."))
    overrides += [
        f"selection.budget_s={spec.get('budget', budget.get('selection.budget_s', 20))}",
        f"selection.window_s={spec.get('window', budget.get('selection.window_s', 8))}",
        "train.hold_vertical_translation=off",
    ]
    overrides += [f"backend.options.{k[2:]}={v}" for k, v in spec.items() if k.startswith("o.")]
    overrides += [f"reference.options.{k[2:]}={v}" for k, v in spec.items() if k.startswith("r.")]
    return dataclasses.replace(base, overrides=overrides)


def _perturbed(T_gt: torch.Tensor, axis: int, deltas: list[float]) -> torch.Tensor:
    """``[len(deltas), 4, 4]``: the truth moved along one IMU axis (cm, or deg about it)."""
    from l2calib import geometry as geo

    out = T_gt.repeat(len(deltas), 1, 1).clone()
    d = torch.tensor(deltas, dtype=torch.float64)
    if axis < 3:
        out[:, axis, 3] += d / 100
    else:
        rotvec = torch.zeros(len(deltas), 3, dtype=torch.float64)
        rotvec[:, axis - 3] = torch.deg2rad(d)
        out[:, :3, :3] = geo.so3_exp(rotvec) @ T_gt[:3, :3]
    return out


def _fit(deltas: np.ndarray, reward: np.ndarray, unit_step: float) -> dict[str, float]:
    """Parabola ``a + b δ + c δ²`` through a sweep's inner part (``|δ| ≤ 2.5`` steps): its peak,
    curvature and the roughness about it (further out the reward grows like ``|δ|``)."""
    inner = np.abs(deltas) <= 2.5 * unit_step
    deltas, reward = deltas[inner], reward[inner]
    c2, c1, c0 = np.polyfit(deltas, reward, 2)
    jitter = float(np.sqrt(np.mean((np.polyval([c2, c1, c0], deltas) - reward) ** 2)))
    curv = max(-float(c2), 1e-12)
    return {
        "peak": round(float(-c1 / (2 * c2)) if c2 < 0 else float("nan"), 3),
        "drop_per_step": float(f"{curv * unit_step**2:.3g}"),
        "jitter": float(f"{jitter:.3g}"),
        "resolution": round(float(np.sqrt(jitter / curv)), 3),
        "best_at": float(deltas[int(np.argmax(reward))]),
    }


def sweep_variant(name: str, variant: str) -> dict[str, Any]:
    """Sweeps every axis through the truth on case ``name`` under ``variant``."""
    from l2calib.train.env_build import score_batch

    spec = dict(part.split("=", 1) for part in variant.split(",") if part)
    case = _case(name, spec)
    env, runs, data, _ = env_with_imu(case, spec.get("sim", "default"), spec.get("ref") != "case")
    T_gt = torch.from_numpy(runs[0].T_imu_lidar)
    axes = {}
    for i, axis in enumerate(AXES):
        deltas = TRANS_CM if i < 3 else ROT_DEG
        reward = score_batch(env, _perturbed(T_gt, i, deltas)).reward.double().numpy()
        fit = _fit(np.array(deltas), reward, 1.0 if i < 3 else 0.1)
        axes[axis] = {**fit, "reward": reward.round(6).tolist()}
    offset = float(runs[0].time_offset_s)
    roughness = float(np.std(axes["z"]["reward"]))  # z is flat on planar drives: pure jitter
    return {
        "case": name,
        "variant": variant,
        "hessian": hessian(env, T_gt, offset, roughness),
        "estimates": score_estimates(env, T_gt, offset, spec["estimates"])
        if "estimates" in spec
        else [],
        "data_s": round(sum(s.duration_s for s in data.segments), 1),
        "segments": len(data.segments),
        "axes": axes,
        "physics": physics_bound(runs, data.segments),
        "machine": machine_info(),
    }


HESSIAN_AXES = ["x", "y", "roll", "pitch", "yaw", "offset"]
HESSIAN_STEPS = [2.0, 2.0, 0.2, 0.2, 0.2, 2.0]  # cm, cm, deg, deg, deg, ms


def _moved(T_gt: torch.Tensor, offset_s: float, steps: np.ndarray):
    """Candidates ``[N, 4, 4]`` and offsets ``[N]`` (s) moved by ``steps [N, 6]`` (HESSIAN_AXES)."""
    from l2calib import geometry as geo

    st = torch.from_numpy(steps)
    T = T_gt.repeat(len(steps), 1, 1).clone()
    T[:, :2, 3] += st[:, :2] / 100
    T[:, :3, :3] = geo.so3_exp(torch.deg2rad(st[:, 2:5])) @ T_gt[:3, :3]
    return T, offset_s + st[:, 5] / 1000


def hessian(env, T_gt: torch.Tensor, offset_s: float, roughness: float) -> dict[str, Any]:
    """The reward's Hessian over x, y, roll, pitch, yaw and the time offset at the truth.

    Central differences (steps ``HESSIAN_STEPS``). ``roughness`` (the reward's jitter along the
    flat z axis) turns it into half-widths: a candidate whose reward is within ``roughness``
    of the peak cannot be told from it. Conditional: one axis moved, the others at the truth
    (what a 1-D sweep shows); marginal: the others free to compensate (what an optimiser
    searching all axes at once faces), ``sqrt(2 ε (−H)⁻¹_ii)``.
    """
    from l2calib.train.env_build import score_batch

    n, h = len(HESSIAN_AXES), np.array(HESSIAN_STEPS)
    rows = [np.zeros(n)]
    for i in range(n):
        for s in (1, -1):
            e = np.zeros(n)
            e[i] = s * h[i]
            rows.append(e)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    for i, j in pairs:
        for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            e = np.zeros(n)
            e[i], e[j] = si * h[i], sj * h[j]
            rows.append(e)
    T, off = _moved(T_gt, offset_s, np.array(rows))
    f = score_batch(env, T, off).reward.double().numpy()
    H = np.zeros((n, n))
    for i in range(n):
        H[i, i] = (f[1 + 2 * i] - 2 * f[0] + f[2 + 2 * i]) / h[i] ** 2
    k = 1 + 2 * n
    for i, j in pairs:
        pp, pm, mp, mm = f[k : k + 4]
        H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
        k += 4
    A = -H
    eps = max(roughness, 1e-9)
    cond = np.sqrt(2 * eps / np.clip(np.diag(A), 1e-15, None))
    marg = np.sqrt(2 * eps * np.clip(np.diag(np.linalg.pinv(A)), 0, None))
    d = np.sqrt(np.clip(np.diag(A), 1e-15, None))
    return {
        "axes": HESSIAN_AXES,
        "units": "cm, cm, deg, deg, deg, ms",
        "neg_hessian": A.round(8).tolist(),
        "correlation": (A / np.outer(d, d)).round(3).tolist(),
        "eigenvalues": np.linalg.eigvalsh(A).round(8).tolist(),
        "roughness": roughness,
        "conditional_half_width": dict(zip(HESSIAN_AXES, cond.round(3).tolist(), strict=True)),
        "marginal_half_width": dict(zip(HESSIAN_AXES, marg.round(3).tolist(), strict=True)),
    }


def score_estimates(env, T_gt: torch.Tensor, offset_s: float, case: str) -> list[dict[str, Any]]:
    """The reward at the truth and at the stored calibrations of ``case`` (calibration.json).

    Both with the estimate's vertical component (held, so not graded) and its time offset;
    an estimate scoring above the truth means the reward peaks away from the truth there, one
    below means the search stopped short of the reward's peak.
    """
    from benchmarks.bench_calibration import RESULTS as CAL
    from l2calib.train.env_build import score_batch

    rows = [
        r for r in json.loads((CAL / "calibration.json").read_text())["rows"] if r["case"] == case
    ]
    out = []
    for r in rows:
        T_est = torch.tensor(r["T_imu_lidar"], dtype=torch.float64)
        T_true = T_gt.clone()
        T_true[2, 3] = T_est[2, 3]  # z is held in the calibration: compare on the graded axes
        T = torch.stack([T_true, T_est])
        offs = torch.tensor([offset_s, r.get("time_offset_s") or offset_s], dtype=torch.float64)
        f = score_batch(env, T, offs).reward.double().numpy()
        out.append(
            {"train_seed": r["train_seed"], "reference": r["reference"], "dt_cm": r["dt_cm"],
             "dr_deg": r["dr_deg"], "reward_truth": round(float(f[0]), 6),
             "reward_estimate": round(float(f[1]), 6),
             "line_to_truth": _line_to_truth(env, T_true, T_est, float(offs[1]), offset_s),
             "continued": _continue(env, T_true, T_est, float(offs[1]))}
        )  # fmt: skip
    return out


def _line_to_truth(env, T_true, T_est, est_offset_s: float, offset_s: float) -> dict[str, Any]:
    """Rewards on the straight line (geodesic in rotation) from the estimate (0) to the truth (1)
    and 20 % past it; and each half swapped: the estimate's rotation with the true translation,
    the true rotation with the estimate's translation (do the errors compensate each other?)."""
    from l2calib import geometry as geo
    from l2calib.train.env_build import score_batch

    alphas = np.linspace(0.0, 1.2, 13)
    dR = geo.so3_log(T_true[:3, :3] @ T_est[:3, :3].T)
    T = T_est.repeat(len(alphas) + 2, 1, 1).clone()
    for k, a in enumerate(alphas):
        T[k, :3, :3] = geo.so3_exp(float(a) * dR) @ T_est[:3, :3]
        T[k, :3, 3] = T_est[:3, 3] + float(a) * (T_true[:3, 3] - T_est[:3, 3])
    T[-2, :3, 3] = T_true[:3, 3]
    T[-1] = T_true
    T[-1, :3, 3] = T_est[:3, 3]
    offs = [(1 - a) * est_offset_s + a * offset_s for a in alphas] + [offset_s, offset_s]
    f = score_batch(env, T, torch.tensor(offs, dtype=torch.float64)).reward.double().numpy()
    return {
        "alpha": alphas.round(2).tolist(),
        "reward": f[:-2].round(5).tolist(),
        "estimate_rotation_true_translation": round(float(f[-2]), 5),
        "true_rotation_estimate_translation": round(float(f[-1]), 5),
    }


def _continue(env, T_true: torch.Tensor, T_est: torch.Tensor, offset_s: float) -> dict[str, Any]:
    """Refinement (6 rounds, the planar setting) then Newton polish (3) from a stored estimate.

    The vertical stays at the estimate's (held) value, as in the calibration.
    """
    from benchmarks.bench_calibration import rotation_errors_deg
    from l2calib.assess.polish import polish
    from l2calib.assess.refine import refine
    from l2calib.interfaces import Extrinsic
    from l2calib.train.env_build import score_batch

    z = float(T_est[2, 3])

    def hold(T):
        T = T.clone()
        T[..., 2, 3] = z
        return T

    def score(T, offsets=None):
        return score_batch(env, hold(T), offsets).reward.detach().double()

    def errors(T):
        T = T.numpy()
        return {
            "dt_cm": (100 * np.abs(T[:2, 3] - T_true.numpy()[:2, 3])).round(2).tolist(),
            "dr_deg": rotation_errors_deg(T_true.numpy(), T).round(3).tolist(),
        }

    refined = refine(score, Extrinsic(T_est, offset_s), 6, 1.0, 0.04, offset_step_s=0.002)
    start = Extrinsic(hold(refined.extrinsic.T_imu_lidar), refined.extrinsic.time_offset_s)
    polished = polish(score, start, 3, hold=hold)
    return {
        "refined": {**errors(start.T_imu_lidar), "reward": round(float(refined.reward), 6)},
        "polished": {**errors(polished.extrinsic.T_imu_lidar),
                     "reward": round(float(polished.reward), 6),
                     "offset_ms": round(1000 * float(polished.extrinsic.time_offset_s), 2)},
        "evaluations": refined.evaluations + polished.evaluations,
    }  # fmt: skip


def physics_bound(runs, segments) -> dict[str, float]:
    """Cramér-Rao bound (cm, 1σ) of the lever arm from the accelerometer over the segments."""
    info = np.zeros((3, 3))
    by_name = {r.sequence().name: r for r in runs}
    for seg in segments:
        run = by_name[seg.sequence]
        stamps = seg.imu.stamps_ns[
            (seg.imu.stamps_ns >= seg.start_ns) & (seg.imu.stamps_ns <= seg.end_ns)
        ]
        tau = (stamps - run.t0_ns) * 1e-9
        # ω in the IMU frame: the motion's base frame is LiDAR-aligned (R_imu_base = R_imu_lidar).
        w = run.motion.state(tau, order=1).omega_base @ run.T_imu_lidar[:3, :3].T
        dw = np.gradient(w, tau, axis=0)
        J = _skew(dw) + _skew(w) @ _skew(w)  # [N, 3, 3]: specific force per metre of lever arm
        J = J - J.mean(axis=0)  # an unknown constant bias per segment absorbs the mean
        sigma = run.imu_spec.accel_noise_density * np.sqrt(run.imu_spec.rate_hz)
        info += np.einsum("nij,nik->jk", J, J) / max(sigma, 1e-12) ** 2
    cov = np.linalg.pinv(info)
    return {a: round(100 * float(np.sqrt(cov[i, i])), 3) for i, a in enumerate("xyz")}


def _skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def main() -> None:
    """Runs the sweeps, prints the table and merges the rows into the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["ugv all"])
    parser.add_argument("--variants", nargs="+", default=DEFAULT_VARIANTS)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    old = json.loads(args.out.read_text())["rows"] if args.out.exists() else []
    rows = list(old)
    for c in args.cases:
        for v in args.variants:
            new = sweep_variant(c, v)
            rows = [r for r in rows if (r["case"], r["variant"]) != (c, v)] + [new]
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps({"benchmark": "planar_lever", "rows": rows}, indent=1))
    table = Table(title="Reward sweeps through the true extrinsic (exact reference)")
    columns = ("case", "variant", "axis", "drop 1 cm / 0.1°", "peak", "jitter", "resolution")
    for col in (*columns, "CRB cm"):
        table.add_column(col)
    for r in rows:
        for axis, a in r["axes"].items():
            table.add_row(
                r["case"], r["variant"], axis, f"{a['drop_per_step']:.2g}", f"{a['peak']:.2f}",
                f"{a['jitter']:.2g}", f"{a['resolution']:.2f}", str(r["physics"].get(axis, "")),
            )  # fmt: skip
    Console().print(table)


if __name__ == "__main__":
    main()
