"""The report's figures: ``report.png`` (training, per-axis uncertainty), ``trajectories.png``.

``report.png`` has four panels: the reward per iteration; the translation of the policy's mode
(cm, ±σ, dashed: the truth when known); its rotation as the **error to the final estimate**
(the rotation vector of ``R_finalᵀ R_iteration`` about the LiDAR axes, deg, so it never jumps
by 360° the way roll/pitch/yaw do near ±180°); and each axis's 95 % bound on the error
(:mod:`l2calib.assess.uncertainty`; the probe's resolution when the bounds were not estimated)
as bars against the limits beyond which an axis is reported undetermined. ``trajectories.png``
draws, for every segment, the LiDAR trajectory from the odometry with the extrinsic before
(identity or the prior) and after calibration beside the reference (top view).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

COLORS = ("tab:red", "tab:green", "tab:blue")
#: Beyond these an axis is listed as undetermined
#: (``l2calib.assess.result_bounds.undetermined_axes``).
ROT_LIMIT_DEG, TRANS_LIMIT_M = 1.0, 0.05


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def rotation_errors_deg(rpy_deg: np.ndarray, R_final: np.ndarray) -> np.ndarray:
    """Rotation vectors of ``R_finalᵀ R_i`` (deg) for roll/pitch/yaw rows ``[N,3]`` → ``[N,3]``."""
    import torch

    from l2calib import geometry as geo

    R = geo.euler_rpy_to_matrix(torch.deg2rad(torch.as_tensor(rpy_deg, dtype=torch.float64)))
    R_f = torch.as_tensor(R_final, dtype=torch.float64)
    return torch.rad2deg(geo.so3_log(R_f.transpose(-1, -2) @ R)).numpy()


def _reward(ax, it: np.ndarray, history: list[Any]) -> None:
    ax.plot(it, [h.reward_mean for h in history], label="mean of candidates")
    ax.plot(it, [h.reward_max for h in history], label="best candidate", alpha=0.7)
    ax.set(xlabel="iteration", ylabel="reward", title="Reward")
    ax.legend(fontsize=8)


def _bands(ax, it, values, sigma, truth, names) -> None:
    for i, (name, color) in enumerate(zip(names, COLORS, strict=True)):
        if len(values):
            ax.plot(it, values[:, i], color=color, label=name)
            ax.fill_between(it, values[:, i] - sigma[:, i], values[:, i] + sigma[:, i],
                            color=color, alpha=0.15)  # fmt: skip
        if truth is not None:
            ax.axhline(truth[i], color=color, ls="--", lw=0.8)
    ax.legend(fontsize=8)


def _resolution(ax, resolution: Any | None) -> None:
    """Bars: each axis's resolution as a fraction of its limit; flat axes drawn full in red."""
    if resolution is None:
        ax.axis("off")
        return
    labels = [f"t{a}" for a in "xyz"] + [f"r{a}" for a in "xyz"]
    values = [v / TRANS_LIMIT_M for v in resolution.translation_m]
    values += [v / ROT_LIMIT_DEG for v in resolution.rotation_deg]
    texts = [f"{100 * v:.2f} cm" for v in resolution.translation_m]
    texts += [f"{v:.3f}°" for v in resolution.rotation_deg]
    for i, (v, text) in enumerate(zip(values, texts, strict=True)):
        flat = not np.isfinite(v)
        weak = flat or v > 1.0
        ax.barh(i, 1.2 if flat else min(v, 1.2), color="tab:red" if weak else "tab:green")
        ax.text(0.02, i, "flat: not determined" if flat else text, va="center", fontsize=8)
    ax.axvline(1.0, color="k", ls="--", lw=0.8)
    ax.set_yticks(range(6), labels)
    ax.invert_yaxis()
    ax.set_xlim(0, 1.25)
    ax.set(
        xlabel=f"smallest step that lowers the reward, / limit ({100 * TRANS_LIMIT_M:.0f} cm, "
        f"{ROT_LIMIT_DEG:.0f}°)",
        title="Per-axis resolution (shorter is sharper; red: not determined)",
    )


def _bounds(ax, unc: Any) -> None:
    """Bars: each axis's 95 % bound as a fraction of its limit; flat axes full in red."""
    rot_deg, trans_m, _ = unc.limits or (0.5, 0.02, 0.005)
    labels = [f"t{a}" for a in "xyz"] + [f"r{a}" for a in "xyz"]
    values = [v / trans_m for v in unc.translation_m] + [v / rot_deg for v in unc.rotation_deg]
    texts = [f"±{100 * v:.2f} cm" for v in unc.translation_m]
    texts += [f"±{v:.3f}°" for v in unc.rotation_deg]
    for i, (v, text) in enumerate(zip(values, texts, strict=True)):
        held, flat = (i in unc.held), not np.isfinite(v)
        weak = (flat or v > 1.0) and not held
        ax.barh(i, 1.2 if flat else min(v, 1.2), color="tab:gray" if held else
                ("tab:red" if weak else "tab:green"))  # fmt: skip
        label = "held (not estimated)" if held else ("flat: not determined" if flat else text)
        ax.text(0.02, i, label, va="center", fontsize=8)
    ax.axvline(1.0, color="k", ls="--", lw=0.8)
    ax.set_yticks(range(6), labels)
    ax.invert_yaxis()
    ax.set_xlim(0, 1.25)
    ax.set(
        xlabel=f"95 % bound on the error / limit ({100 * trans_m:g} cm, {rot_deg:g}°)",
        title="Per-axis uncertainty (shorter is better; red: not determined)",
    )


def plot_report(
    path: Path,
    history: list[Any],
    result: Any,
    truth: np.ndarray | None = None,
) -> Path:
    """Draws ``report.png``.

    Args:
        path: PNG to write.
        history: Iteration records (``l2calib.train.ppo.IterationRecord``).
        result: The :class:`~l2calib.assess.result.CalibrationResult` (with an extrinsic).
        truth: Optional ground-truth ``T_imu_lidar`` (4×4), e.g. from the simulator.
    """
    plt = _pyplot()
    it = np.array([h.iteration for h in history])
    fig, ax = plt.subplots(2, 2, figsize=(12, 8.5))
    _reward(ax[0, 0], it, history)
    t = np.array([h.translation_m for h in history]).reshape(-1, 3) * 100
    ts = np.array([h.translation_sigma_m for h in history]).reshape(-1, 3) * 100
    R_final = result.matrix[:3, :3]
    r = rotation_errors_deg(np.array([h.rpy_deg for h in history]).reshape(-1, 3), R_final)
    rs = np.array([h.rotation_sigma_deg for h in history]).reshape(-1, 3)
    gt_t = gt_r = None
    if truth is not None:
        truth = np.asarray(truth, dtype=np.float64)
        gt_t = truth[:3, 3] * 100
        gt_r = rotation_errors_deg(_rpy_deg(truth[:3, :3])[None], R_final)[0]
    _bands(ax[0, 1], it, t, ts, gt_t, ("x", "y", "z"))
    ax[0, 1].set(xlabel="iteration", ylabel="cm",
                 title="Translation of the policy's mode (±σ; dashed: truth)")  # fmt: skip
    _bands(ax[1, 0], it, r, rs, gt_r, ("about x", "about y", "about z"))
    title = "Rotation of the mode: error to the final estimate (±σ; dashed: truth)"
    ax[1, 0].set(xlabel="iteration", ylabel="deg", title=title)
    if getattr(result, "axis_uncertainty", None) is not None:
        _bounds(ax[1, 1], result.axis_uncertainty)
    else:
        _resolution(ax[1, 1], result.resolution)
    fig.suptitle(
        f"l2calib: {result.evaluations} odometry evaluations, {result.iterations} iterations, "
        f"{result.wall_time_s:.0f} s — {result.stop_reason}"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _rpy_deg(R: np.ndarray) -> np.ndarray:
    import torch

    from l2calib import geometry as geo

    return torch.rad2deg(geo.matrix_to_euler_rpy(torch.as_tensor(R))).numpy()


def plot_trajectories(path: Path, trajectories: list[dict[str, np.ndarray]]) -> Path:
    """Draws ``trajectories.png``: one top view per segment.

    Args:
        path: PNG to write.
        trajectories: Per segment ``{"reference", "before", "after": [N,3] positions (m),
            "name": str}``, the positions at the odometry's stamps in the reference's world.
    """
    plt = _pyplot()
    n = len(trajectories)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(max(4.6 * cols, 7.0), 4.2 * rows), squeeze=False)
    for a in axes.flat[n:]:
        a.axis("off")
    for a, traj in zip(axes.flat, trajectories, strict=False):
        for name, style in (("reference", "k-"), ("before", "r:"), ("after", "b--")):
            xy = traj[name]
            a.plot(xy[:, 0], xy[:, 1], style, label=name, lw=1.2)
        # Limits from the reference and the result: a diverged "before" may leave the panel.
        xy = np.concatenate([traj["reference"][:, :2], traj["after"][:, :2]])
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            pad = 0.15 * max(float((hi - lo).max()), 0.5)
            a.set_xlim(lo[0] - pad, hi[0] + pad)
            a.set_ylim(lo[1] - pad, hi[1] + pad)
        a.set_aspect("equal", adjustable="datalim")
        a.set(xlabel="x (m)", ylabel="y (m)", title=traj["name"])
        a.legend(fontsize=8)
    fig.suptitle("LiDAR trajectory, extrinsic before / after calibration (top view)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
