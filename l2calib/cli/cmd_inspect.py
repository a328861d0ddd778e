"""``l2calib inspect BAG...``: pre-flight checks of recordings, with the recipe settings found."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

_SET_HELP = "Override a recipe field, e.g. --set data.imu.gyro_unit=deg/s (repeatable)."


def _fmt(x: float, spec: str = ".3g") -> str:
    return "-" if x is None or x != x else format(x, spec)


def _render(report: Any, console: Any) -> None:
    import yaml
    from rich.table import Table

    console.rule(f"[bold]{report.path}[/] ({report.storage}, {report.duration_s:.1f} s)")
    t = Table(title="topics", title_justify="left")
    for col in ("topic", "type", "count", "rate Hz", "span s", "gaps", "non-mono", "rec-hdr s"):
        t.add_column(col)
    stamps = {r.topic: r.stamps for r in (*report.lidar, *report.imu, *report.navsat)}
    for info in report.topics:
        st = stamps.get(info.name)
        if st is None:
            t.add_row(info.name, info.msgtype, str(info.count), "", "", "", "", "")
            continue
        rmh = "-" if st.record_minus_header_s is None else f"{st.record_minus_header_s[0]:+.3f}"
        gaps = f"{len(st.gaps_ns)} (max {st.max_gap_s:.3f} s)" if st.gaps_ns else "0"
        t.add_row(
            info.name,
            info.msgtype,
            str(info.count),
            _fmt(st.rate_hz, ".1f"),
            _fmt(st.span_s, ".1f"),
            gaps,
            str(st.non_monotonic),
            rmh,
        )
    console.print(t)
    for r in report.lidar:
        c = r.convention
        t = Table(title=f"LiDAR {r.topic} ({r.layout})", title_justify="left", show_header=False)
        t.add_column("k")
        t.add_column("v")
        if c is not None:
            t.add_row(
                "time field",
                f"{c.field} -> unit {c.unit}, {c.reference}, header stamp at "
                f"scan {c.stamp_position}" + (" [detected]" if c.detected else ""),
            )
            t.add_row("evidence", c.evidence)
        t.add_row(
            "point time - header",
            f"[{_fmt(r.rel_time_s[0] * 1e3, '.2f')}, {_fmt(r.rel_time_s[1] * 1e3, '.2f')}] ms",
        )
        t.add_row("scan duration", f"{_fmt(r.scan_duration_s * 1e3, '.1f')} ms")
        t.add_row("points / scan", _fmt(r.points_per_scan, ".0f"))
        t.add_row(
            "NaN / zero / out of range",
            f"{100 * r.nan_share:.1f} % / {100 * r.zero_share:.1f} % / {100 * r.range_share:.1f} %",
        )
        t.add_row("empty scans", str(r.empty_scans))
        console.print(t)
    for r in report.imu:
        t = Table(title=f"IMU {r.topic}", title_justify="left", show_header=False)
        t.add_column("k")
        t.add_column("v")
        u = r.units
        if u is not None:
            t.add_row(
                "gyro unit",
                f"{u.gyro_unit}{'' if u.gyro_confirmed else ' (unconfirmed)'}: {u.gyro_evidence}",
            )
            t.add_row(
                "accel unit",
                f"{u.accel_unit}{'' if u.accel_confirmed else ' (unclear)'}: {u.accel_evidence}",
            )
        t.add_row(
            "gravity",
            f"{_fmt(r.gravity_m_s2, '.3f')} m/s^2"
            + (" (at rest)" if r.gravity_at_rest else " (no still period: estimate while moving)"),
        )
        w = r.mean_abs_gyro_rad_s
        t.add_row(
            "mean |w| x y z",
            f"{_fmt(w[0])} {_fmt(w[1])} {_fmt(w[2])} rad/s (max |w| {_fmt(r.max_gyro_rad_s)})",
        )
        console.print(t)
    for r in report.navsat:
        console.print(
            f"NavSatFix {r.topic}: {r.stamps.count} fixes, "
            f"{100 * r.fix_share:.0f} % valid, {100 * r.rtk_share:.0f} % RTK"
        )
    if report.overlap_s is not None and report.overlap_s > 0:
        console.print(f"LiDAR-IMU overlap: {report.overlap_s:.2f} s")
    elif report.overlap_s is not None:
        console.print(
            f"LiDAR-IMU overlap: none — the streams are {-report.overlap_s:.2f} s apart and do "
            "not overlap (fix: stamp both sensors on one clock; see the error below)",
            highlight=False,
        )
    m = report.motion
    if m is not None:
        g, a = (" / ".join(f"{v:.2f}" for v in x) for x in (m.gyro_rms_rad_s, m.accel_rms_m_s2))
        console.print(
            f"motion: {m.moving_s:.1f} s of {m.overlap_s:.1f} s overlap; selectable "
            f"{m.selected_s:.1f} s (selection.window_s {m.window_s:g} s, budget_s "
            f"{m.budget_s:g} s); RMS rate x/y/z {g} rad/s, gravity-free acceleration {a} m/s^2",
            highlight=False,
        )
    styles = {"error": "bold red", "warning": "yellow", "info": "cyan"}
    for i in report.issues:
        fix = f" — fix: {i.fix}" if i.fix else ""
        console.print(
            f"[{styles[i.severity]}]{i.severity}[/]: {i.where}: {i.message}{fix}",
            markup=True,
            highlight=False,
        )
    if report.suggested:
        console.print("suggested recipe settings:")
        console.print(yaml.safe_dump(report.suggested, sort_keys=False), highlight=False)


def _jsonable(report: Any) -> dict:
    from dataclasses import asdict, is_dataclass

    def conv(o: Any) -> Any:
        if is_dataclass(o):
            return {k: conv(v) for k, v in asdict(o).items()}
        if isinstance(o, dict):
            return {k: conv(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [conv(v) for v in o]
        if isinstance(o, float) and o != o:
            return None
        return o

    return conv(report)


def inspect(
    bags: list[Path] = typer.Argument(
        ..., help="ROS1 .bag files, ROS2 bag directories, .db3 or .mcap files."
    ),
    recipe: Path | None = typer.Option(None, "--recipe", "-r", help="Recipe (topics, overrides)."),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the reports as JSON."),
    time_offset: bool = typer.Option(
        True,
        "--time-offset/--no-time-offset",
        help="Estimate the LiDAR-IMU time offset (a few seconds of LiDAR odometry per bag).",
    ),
) -> None:
    """Check bags before calibrating: streams, units, overlap, motion and time offset."""
    from rich.console import Console

    from l2calib.errors import DataError
    from l2calib.outputs.writable import check_writable
    from l2calib.preflight import inspect_bag
    from l2calib.recipe import load_recipe

    if json_out is not None:
        check_writable(json_out, "--json", kind="file")
    rec = load_recipe(recipe, set_, check_plugins=False)
    console = Console()
    reports = []
    for bag in bags:
        report = inspect_bag(
            bag,
            rec.data,
            progress=console.is_terminal,
            selection=rec.selection,
            time_offset=time_offset,
        )
        _render(report, console)
        reports.append(report)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps([_jsonable(r) for r in reports], indent=1))
    errors = [e for r in reports for e in r.errors]
    if errors:
        first = errors[0]
        raise DataError(
            f"{len(errors)} error(s) found; first: {first.where}: {first.message}",
            fix=first.fix or "see the errors above",
        )


def register(app: typer.Typer) -> None:
    """Adds the ``inspect`` command to ``app``."""
    app.command("inspect")(inspect)
