"""``l2calib select BAG...``: choose the most exciting windows and plot the timeline."""

from __future__ import annotations

import json
import re
from pathlib import Path

import typer

_SET_HELP = "Override a recipe field, e.g. --set selection.step_s=0.5 (repeatable)."
_UNITS = {"ms": 1e-3, "s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}


def parse_duration(text: str, option: str) -> float:
    """``"30s"``, ``"1.5m"``, ``"500ms"`` or ``"30"`` (seconds) to seconds.

    Raises:
        ConfigError: for anything else or a non-positive duration.
    """
    from l2calib.errors import ConfigError

    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(ms|s|min|m|h)?\s*", text)
    if not m or float(m.group(1)) <= 0:
        raise ConfigError(
            f"{option} {text!r} is not a positive duration",
            fix=f"write e.g. {option} 30s (units: ms, s, m, h)",
        )
    return float(m.group(1)) * _UNITS[m.group(2) or "s"]


def select(
    bags: list[Path] = typer.Argument(
        ..., help="ROS1 .bag files, ROS2 bag directories, .db3 or .mcap files (one sequence each)."
    ),
    budget: str | None = typer.Option(None, "--budget", "-b", help="Total length, e.g. 30s."),
    window: str | None = typer.Option(None, "--window", "-w", help="Window length, e.g. 10s."),
    step: str | None = typer.Option(None, "--step", help="Window stride, e.g. 1s."),
    recipe: Path | None = typer.Option(
        None, "--recipe", "-r", help="Recipe (topics, units, selection settings)."
    ),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
    plot: Path = typer.Option(Path("selection.png"), "--plot", help="Timeline PNG to write."),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the selection as JSON."),
) -> None:
    """Pick the windows with the most IMU excitation (paper Sec. III-D) up to a time budget."""
    from rich.console import Console
    from rich.table import Table

    from l2calib.data import NS_PER_S
    from l2calib.io.sequences import open_sequences
    from l2calib.outputs.writable import check_writable
    from l2calib.recipe import load_recipe
    from l2calib.selection import select_windows
    from l2calib.selection.plot import plot_selection

    check_writable(plot, "--plot", kind="file")
    if json_out is not None:
        check_writable(json_out, "--json", kind="file")
    rec = load_recipe(recipe, set_, check_plugins=False)
    cfg = rec.selection
    for value, key, opt in (
        (budget, "budget_s", "--budget"),
        (window, "window_s", "--window"),
        (step, "step_s", "--step"),
    ):
        if value is not None:
            setattr(cfg, key, parse_duration(value, opt))
    console = Console()
    sequences = open_sequences(
        bags, rec.data, auto_topics=recipe is None, progress=console.is_terminal
    )
    for seq in sequences:
        for w in seq.meta.get("warnings", []):
            console.print(f"[yellow]warning[/]: {w}", highlight=False)
    sel = select_windows(sequences, cfg)
    starts = {s.name: s.start_ns for s in sequences}
    t = Table(
        title=f"chosen windows ({sel.total_s:.1f} s of {sel.budget_s:.1f} s)", title_justify="left"
    )
    for col in ("#", "sequence", "start s", "end s", "score", "√λ gyro rad/s", "√λ accel m/s²"):
        t.add_column(col)
    for i, c in enumerate(sel.chosen, 1):
        t0 = starts[c.sequence]
        t.add_row(
            str(i),
            c.sequence,
            f"{(c.start_ns - t0) / NS_PER_S:.1f}",
            f"{(c.end_ns - t0) / NS_PER_S:.1f}",
            f"{c.score:.2f}",
            f"{c.lambda_gyro**0.5:.3f}",
            f"{c.lambda_accel**0.5:.3f}",
        )
    console.print(t)
    g, a = sel.gyro_rms_rad_s, sel.accel_rms_m_s2
    console.print(
        f"selection RMS per IMU axis: rotation x {g[0]:.3f} y {g[1]:.3f} z {g[2]:.3f} "
        f"rad/s (threshold {cfg.min_gyro_rad_s:g}); acceleration x {a[0]:.3f} "
        f"y {a[1]:.3f} z {a[2]:.3f} m/s² (threshold {cfg.min_accel_m_s2:g})",
        highlight=False,
    )
    if sel.weak_axes:
        console.print(
            f"[yellow]weak[/]: {', '.join(sel.weak_axes)} — calibration is less "
            "certain about these; add motion that excites them",
            highlight=False,
        )
    else:
        console.print("all axes excited")
    for note in sel.notes:
        console.print(f"note: {note}", highlight=False)
    out = plot_selection(sel, plot)
    console.print(f"timeline: {out}", highlight=False)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(sel.as_dict(), indent=1))
    if not sel.chosen:
        from l2calib.errors import DataError

        raise DataError(
            "no window was selected: " + "; ".join(sel.notes),
            fix="record motion (rotate and accelerate the rig), or shorten --window",
        )


def register(app: typer.Typer) -> None:
    """Adds the ``select`` command to ``app``."""
    app.command("select")(select)
