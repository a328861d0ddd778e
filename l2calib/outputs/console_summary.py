"""The result as the CLI prints it (rich), shared by ``calibrate``/``demo`` and ``report.html``.

``report.html`` records these prints with a recording :class:`rich.console.Console` and embeds
them, so the page shows the same table, in the same colours, as the terminal.
"""

from __future__ import annotations

from l2calib.assess.status import NOT_CALIBRATED, UNRELIABLE


def print_status(console, result) -> None:
    """Prints the run's status (``calibration.yaml`` → ``status``) and what is missing."""
    if result.stopped_before_training:
        console.print(
            "[bold red]status: not-calibrated[/] — stopped before training: the data is too "
            "short or too still to calibrate; calibration.yaml holds the reasons and a summary "
            "of the data, and no extrinsic. What is missing:"
        )
    elif result.status == NOT_CALIBRATED:
        console.print(
            "[bold red]status: not-calibrated[/] — the data could not determine the extrinsic; "
            "calibration.yaml holds the partial result, marked as such, without paste-ready "
            "blocks. What is missing:"
        )
    elif result.status == UNRELIABLE:
        console.print(
            "[bold yellow]status: unreliable[/] — check the extrinsic before using it "
            "(the paste-ready blocks in calibration.yaml carry this warning):"
        )
    else:
        console.print("[bold green]status: calibrated[/]")
    for reason in result.status_reasons:
        console.print(f"  - {reason}", highlight=False)


def print_result(console, result, truth=None) -> None:
    """Prints the extrinsic (and, when known, its error against the truth)."""
    import numpy as np
    import torch
    from rich.table import Table

    from l2calib import geometry as geo
    from l2calib.assess.result import CalibrationResult

    table = Table(title="T_imu_lidar (LiDAR → IMU)", title_justify="left")
    table.add_column("")
    for col in ("x / roll", "y / pitch", "z / yaw"):
        table.add_column(col, justify="right")
    t = result.T_imu_lidar[:3, 3]
    table.add_row("calibrated translation (m)", *(f"{v:+.4f}" for v in t))
    table.add_row("calibrated rotation (deg)", *(f"{v:+.3f}" for v in result.rpy_deg))
    unc = result.axis_uncertainty
    if unc is not None:

        def bound(v: float, i: int, text: str) -> str:
            return "held" if i in unc.held else ("flat" if not np.isfinite(v) else text)

        table.add_row(
            "95 % bound translation (cm)",
            *(bound(v, 3 + i, f"±{100 * v:.2f}") for i, v in enumerate(unc.translation_m)),
        )
        table.add_row(
            "95 % bound rotation (deg)",
            *(bound(v, i, f"±{v:.3f}") for i, v in enumerate(unc.rotation_deg)),
        )
        ref = getattr(unc, "reference95", None)
        if ref is not None and np.any(ref[3:6] > 0):
            table.add_row(
                "  of it the reference's error (cm)",
                *(bound(v, 3 + i, f"±{100 * v:.2f}") for i, v in enumerate(ref[3:6])),
            )
    if result.resolution is not None:
        res = result.resolution
        table.add_row(
            "resolution translation (cm)",
            *("flat" if not np.isfinite(v) else f"{100 * v:.2f}" for v in res.translation_m),
        )
        table.add_row(
            "resolution rotation (deg)",
            *("flat" if not np.isfinite(v) else f"{v:.3f}" for v in res.rotation_deg),
        )
    if result.translation_sigma_m:
        table.add_row(
            "policy σ translation (cm)", *(f"{100 * v:.2f}" for v in result.translation_sigma_m)
        )
        table.add_row("policy σ rotation (deg)", *(f"{v:.3f}" for v in result.rotation_sigma_deg))
    if truth is not None:
        gt = CalibrationResult(truth)
        table.add_row("ground truth translation (m)", *(f"{v:+.4f}" for v in truth[:3, 3]))
        table.add_row("ground truth rotation (deg)", *(f"{v:+.3f}" for v in gt.rpy_deg))
        err_t = np.abs(t - truth[:3, 3]) * 100
        R_err = torch.from_numpy(truth[:3, :3].T @ result.T_imu_lidar[:3, :3])
        err_r = torch.rad2deg(geo.matrix_to_euler_rpy(R_err)).abs().numpy()
        table.add_row(
            "|error| (cm / deg)", *(f"{e:.2f} / {r:.3f}" for e, r in zip(err_t, err_r, strict=True))
        )
        angle = float(torch.rad2deg(geo.rotation_angle(R_err)))
        table.caption = (
            f"error: {np.linalg.norm(t - truth[:3, 3]) * 100:.2f} cm, {angle:.3f} deg "
            "(per-axis rotation error: Euler angles of R_gtᵀ R_est)"
        )
    console.print(table)
    for caveat in getattr(unc, "caveats", None) or []:
        console.print(f"[yellow]not in the 95 % bounds[/]: {caveat}", highlight=False)
    if result.time_offset_s is not None:
        res = result.time_offset_resolution
        how = "" if res is None else f", resolution {_ms(res.resolution_s)}"
        if unc is not None and unc.time_offset_s is not None:
            how += f", 95 % bound ±{_ms(unc.time_offset_s)}"
        if (result.time_offset_method or "").startswith("held"):
            how += "; held at the rotation-rate correlation"
        console.print(
            f"time offset {1000 * result.time_offset_s:+.2f} ms (t_imu = t_lidar + offset"
            f"{how}); FAST-LIO: common/time_offset_lidar_to_imu: {result.time_offset_s:.6f}"
        )
    console.print(
        f"final reward {result.final_reward:.4f}, {result.evaluations} odometry evaluations, "
        f"{result.iterations} iterations, {result.wall_time_s:.0f} s ({result.stop_reason})"
    )
    attempts = result.extra.get("attempts") or []
    if len(attempts) > 1:
        runs = ", ".join(
            f"seed {a['seed']}: {a['final_reward']:.4f}" + (" (kept)" if a["kept"] else "")
            for a in attempts
        )
        console.print(f"{len(attempts)} PPO runs (rewards {runs}); the totals count every run")
    if result.undetermined:
        console.print(
            "[bold yellow]warning[/]: the data could not determine: "
            + "; ".join(result.undetermined)
            + " — do not trust these components; record motion that excites them."
        )
    for w in result.warnings:
        console.print(f"[bold yellow]warning[/]: {w}")


def _ms(value_s: float) -> str:
    import numpy as np

    return "flat (undetermined)" if not np.isfinite(value_s) else f"{1000 * value_s:.1f} ms"
