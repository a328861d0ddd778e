"""The calibration report: ``report.png`` (+ ``report.html`` around it).

Panels: reward per iteration; per-axis convergence of translation and rotation with the
policy's ±σ band (and the ground truth when it is known); the LiDAR trajectory of the first
segment before (identity or prior extrinsic) and after calibration beside the reference.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from l2calib.assess.result import CalibrationResult

COLORS = ("tab:red", "tab:green", "tab:blue")


def plot_report(
    path: Path,
    history: list[Any],
    result: CalibrationResult,
    trajectories: dict[str, np.ndarray] | None = None,
    truth: np.ndarray | None = None,
) -> Path:
    """Draws the report figure.

    Args:
        path: PNG to write.
        history: Iteration records (``l2calib.train.ppo.IterationRecord``).
        result: The calibration.
        trajectories: Optional ``{"reference": [N,3], "before": [N,3], "after": [N,3]}``.
        truth: Optional ground-truth ``T_imu_lidar`` (4×4), e.g. from the simulator.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from l2calib.assess.result import CalibrationResult as _CR

    it = np.array([h.iteration for h in history])
    fig, ax = plt.subplots(2, 2, figsize=(12, 8.5))
    a = ax[0, 0]
    a.plot(it, [h.reward_mean for h in history], label="mean of candidates")
    a.plot(it, [h.reward_max for h in history], label="best candidate", alpha=0.7)
    a.set(xlabel="iteration", ylabel="reward", title="Reward")
    a.legend()
    t = np.array([h.translation_m for h in history]) * 100
    ts = np.array([h.translation_sigma_m for h in history]) * 100
    r = np.array([h.rpy_deg for h in history])
    rs = np.array([h.rotation_sigma_deg for h in history])
    gt_t = gt_r = None
    if truth is not None:
        gt = _CR(np.asarray(truth))
        gt_t, gt_r = np.asarray(truth)[:3, 3] * 100, gt.rpy_deg
    for panel, values, sig, gt_v, unit, names in (
        (ax[0, 1], t, ts, gt_t, "cm", ("x", "y", "z")),
        (ax[1, 0], r, rs, gt_r, "deg", ("roll", "pitch", "yaw")),
    ):
        for i, (name, color) in enumerate(zip(names, COLORS, strict=True)):
            if len(values):
                panel.plot(it, values[:, i], color=color, label=name)
                panel.fill_between(it, values[:, i] - sig[:, i], values[:, i] + sig[:, i],
                                   color=color, alpha=0.15)  # fmt: skip
            if gt_v is not None:
                panel.axhline(gt_v[i], color=color, ls="--", lw=0.8)
        panel.set(xlabel="iteration", ylabel=unit)
        panel.legend(fontsize=8)
    ax[0, 1].set_title("Translation of the policy's mode (±σ; dashed: truth)")
    ax[1, 0].set_title("Rotation (roll/pitch/yaw of the mode, ±σ per body axis)")
    a = ax[1, 1]
    if trajectories:
        for name, style in (("reference", "k-"), ("before", "r:"), ("after", "b--")):
            if name in trajectories:
                xy = trajectories[name]
                a.plot(xy[:, 0], xy[:, 1], style, label=name, lw=1.2)
        a.axis("equal")
        a.legend()
        a.set(xlabel="x (m)", ylabel="y (m)", title="LiDAR trajectory, first segment (top view)")
    else:
        a.axis("off")
    fig.suptitle(
        f"l2calib: {result.evaluations} odometry evaluations, {result.iterations} iterations, "
        f"{result.wall_time_s:.0f} s — {result.stop_reason}"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_html(path: Path, result: CalibrationResult, images: list[str]) -> Path:
    """A small HTML page with the summary table and the report images."""
    d = result.to_dict()
    rows = "".join(
        f"<tr><th>{html.escape(k)}</th><td><pre>{html.escape(str(v))}</pre></td></tr>"
        for k, v in d.items()
        if k not in ("T_lidar_imu",)
    )
    imgs = "".join(f'<p><img src="{html.escape(i)}" style="max-width:100%"></p>' for i in images)
    warn = ""
    if result.undetermined:
        items = "".join(f"<li>{html.escape(u)}</li>" for u in result.undetermined)
        warn = f"<h2>Not determined by the data</h2><ul>{items}</ul>"
    if result.warnings:
        items = "".join(f"<li>{html.escape(w)}</li>" for w in result.warnings)
        warn += f"<h2>Warnings</h2><ul>{items}</ul>"
    path.write_text(
        "<!doctype html><meta charset=utf-8><title>l2calib report</title>"
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
        "th{text-align:left;vertical-align:top;padding-right:1em}</style>"
        f"<h1>l2calib calibration</h1>{warn}<table>{rows}</table>{imgs}"
    )
    return path
