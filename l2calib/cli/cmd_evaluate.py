"""``l2calib evaluate``: odometry APE with a given extrinsic (and a second one, before/after)."""

from __future__ import annotations

from pathlib import Path

import typer

_SET_HELP = "Override a recipe field, e.g. --set data.imu.topic=/imu (repeatable)."


def evaluate(
    extrinsic: Path = typer.Option(..., "--extrinsic", "-e", help="calibration.yaml to test."),
    bag: list[Path] = typer.Option(..., "--bag", "-b", help="Bag(s) to run the odometry on."),
    compare: Path | None = typer.Option(
        None, "--compare", "-c", help="A second extrinsic (e.g. the one before calibration)."
    ),
    recipe: Path | None = typer.Option(None, "--recipe", "-r", help="Recipe (topics, noise)."),
    reference: Path | None = typer.Option(
        None,
        "--reference",
        help="Ground-truth trajectory of the LiDAR (TUM/KITTI/CSV) instead "
        "of the recipe's reference (KISS-ICP by default).",
    ),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
) -> None:
    """Run the LiDAR-inertial odometry with an extrinsic and report its APE against a reference."""
    from rich.console import Console
    from rich.table import Table

    from l2calib.calibration import Calibration, RunHooks
    from l2calib.io.sequences import open_sequences
    from l2calib.outputs.calibration_file import read_extrinsic
    from l2calib.recipe import load_recipe

    overrides = list(set_)
    if reference is not None:
        overrides += ["reference.name=gt-file", f"reference.options.path={reference}"]
    rec = load_recipe(recipe, overrides)
    console = Console()
    paths = [extrinsic] if compare is None else [extrinsic, compare]
    # label by file name; the whole path only when the names clash
    unique = len({p.name for p in paths}) == len(paths)
    extrinsics = {(p.name if unique else str(p)): read_extrinsic(p) for p in paths}
    sequences = open_sequences(
        bag, rec.data, auto_topics=recipe is None, progress=console.is_terminal
    )
    run = Calibration(rec, hooks=RunHooks(stage=lambda msg: console.print(f"[cyan]•[/] {msg}")))
    rows = run.evaluate(extrinsics, sequences=sequences)
    table = Table(
        title=f"odometry APE against the {rec.reference.name} reference", title_justify="left"
    )
    for col in (
        "extrinsic",
        "sequence",
        "APE t RMSE (cm)",
        "t max (cm)",
        "APE rot RMSE (deg)",
        "poses",
        "status",
    ):
        table.add_column(col)
    for row in rows:
        label, seg, res = row.label, row.segment, row.ape
        state = ("ok", "diverged", "lost track", "failed")[int(row.status)]
        if res is None:
            table.add_row(label, seg, "-", "-", "-", "0", state)
        else:
            table.add_row(
                label,
                seg,
                f"{100 * res.rmse_t:.2f}",
                f"{100 * res.e_t.max():.2f}",
                f"{res.rmse_r_deg:.3f}",
                str(len(res.e_t)),
                state,
            )
    console.print(table)


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("evaluate")(evaluate)
