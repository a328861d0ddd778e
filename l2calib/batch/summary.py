"""A batch's summary: ``summary.csv`` and the table printed at the end."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from rich.table import Table

from l2calib.batch.jobs import JobState

COLUMNS = (
    "job", "state", "status", "tx_m", "ty_m", "tz_m", "roll_deg", "pitch_deg", "yaw_deg",
    "time_offset_s", "warnings", "error", "wall_s", "out",
)  # fmt: skip


def row(job: JobState) -> dict[str, str]:
    """One job as CSV fields: ``T_imu_lidar`` as translation (m) and roll/pitch/yaw (deg).

    roll, pitch, yaw follow the recipes' convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
    """
    out = dict.fromkeys(COLUMNS, "")
    out.update(job=job.name, state=job.state, status=job.status, error=job.error, out=job.out)
    out["warnings"] = "; ".join(job.warnings)
    out["wall_s"] = f"{job.wall_s:.1f}"
    if job.T_imu_lidar is not None:
        import torch

        from l2calib.geometry import matrix_to_euler_rpy

        T = np.asarray(job.T_imu_lidar)
        rpy = matrix_to_euler_rpy(torch.as_tensor(T[:3, :3], dtype=torch.float64))
        roll, pitch, yaw = np.degrees(rpy.numpy())
        for key, value in zip(("tx_m", "ty_m", "tz_m"), T[:3, 3], strict=True):
            out[key] = f"{value:.4f}"
        for key, value in (("roll_deg", roll), ("pitch_deg", pitch), ("yaw_deg", yaw)):
            out[key] = f"{value:.3f}"
    if job.time_offset_s is not None:
        out["time_offset_s"] = f"{job.time_offset_s:.5f}"
    return out


def write_csv(jobs: Sequence[JobState], path: Path) -> Path:
    """Writes ``summary.csv`` (one row per job, :data:`COLUMNS`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(row(job) for job in jobs)
    return path


def table(jobs: Sequence[JobState]) -> Table:
    """The summary as a rich table: job, status, T_imu_lidar, warnings or error, wall time."""
    t = Table(title="batch summary", show_lines=False)
    for col in ("job", "status", "t_imu_lidar cm", "rpy deg", "warnings / error", "wall"):
        t.add_column(col)
    for job in jobs:
        r = row(job)
        trans = rpy = "-"
        if job.T_imu_lidar is not None:
            trans = ", ".join(f"{100 * float(r[k]):+.2f}" for k in ("tx_m", "ty_m", "tz_m"))
            rpy = ", ".join(f"{float(r[k]):+.3f}" for k in ("roll_deg", "pitch_deg", "yaw_deg"))
        status = job.status if job.state == "done" else f"[red]{job.state}[/]"
        notes = f"[red]{_short(job.error, 160)}[/]" if job.error else "-"
        if not job.error and job.warnings:  # all of them are in summary.csv and calibration.yaml
            notes = f"{len(job.warnings)}: {_short(job.warnings[0], 60)}"
        t.add_row(job.name, status, trans, rpy, notes, f"{job.wall_s:.0f} s")
    return t


def _short(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"
