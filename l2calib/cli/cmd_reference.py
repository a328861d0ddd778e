"""``l2calib reference RECIPE --bag BAG --out traj.tum``: the reference the reward would use.

Computes the recipe's reference (with its fallback) on the segments the calibration would
select, or on every bag whole with ``--all``, and writes it as TUM: the LiDAR's pose
``T_world_lidar`` on the LiDAR clock, one file per segment when there are several. With
``--compare`` it prints the SE(3)-aligned APE against a trajectory file of the LiDAR (e.g. from
motion capture), so a reference can be checked before a calibration is trusted.
"""

from __future__ import annotations

from pathlib import Path

import typer

_SET_HELP = "Override a recipe field, e.g. --set reference.name=ct-lidar (repeatable)."


def output_paths(out: Path, count: int) -> list[Path]:
    """``out`` itself for one segment; ``<stem>-01<suffix>``, ``-02`` … for several."""
    if count == 1:
        return [out]
    return [out.with_name(f"{out.stem}-{i:02d}{out.suffix}") for i in range(1, count + 1)]


def reference(
    recipe: Path = typer.Argument(..., help="Recipe YAML or built-in recipe name."),
    bag: list[Path] = typer.Option(..., "--bag", "-b", help="Bag(s) to compute it on."),
    out: Path = typer.Option(..., "--out", "-o", help="TUM file to write (traj.tum)."),
    all_: bool = typer.Option(
        False, "--all", help="Every bag whole, instead of the segments the selection picks."
    ),
    compare: Path | None = typer.Option(
        None, "--compare", help="A LiDAR trajectory file (TUM, CSV or KITTI) to compare with."
    ),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
    force: bool = typer.Option(False, "--force", help="Overwrite existing output files."),
) -> None:
    """Compute the LiDAR reference trajectory of a recording and write it as TUM."""
    from rich.console import Console
    from rich.table import Table

    from l2calib.alignment import ape
    from l2calib.data import NS_PER_S
    from l2calib.errors import ConfigError
    from l2calib.io.trajectory_files import read_trajectory, write_tum
    from l2calib.outputs.writable import check_writable
    from l2calib.pipeline import compute_references, read_sequences, select_segments
    from l2calib.recipe import load_recipe

    console = Console()
    check_writable(out, "--out", kind="file")  # before minutes of odometry
    rec = load_recipe(recipe, [*set_, *(["selection.enabled=false"] if all_ else [])])
    truth = read_trajectory(compare, body_frame="lidar") if compare is not None else None
    sequences = read_sequences(rec, bag, progress=console.is_terminal)
    segments, _ = select_segments(rec, sequences, lambda m: console.print(f"[yellow]note[/]: {m}"))
    paths = output_paths(out, len(segments))
    existing = [str(p) for p in paths if p.exists()]
    if existing and not force:  # nothing a user made is overwritten unasked
        raise ConfigError(
            f"{', '.join(existing)} already exist(s)", fix="choose another --out or pass --force"
        )
    console.print(f"[cyan]•[/] computing the {rec.reference.name} reference on "
                  f"{len(segments)} segment(s)")  # fmt: skip
    refs = compute_references(
        rec,
        segments,
        sequences,
        note=lambda msg: console.print(f"[yellow]note[/]: {msg}"),
        progress=console.is_terminal,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    table = Table(title=f"{rec.reference.name} reference (T_world_lidar, LiDAR clock)")
    for col in ("segment", "source", "poses", "span s", "file"):
        table.add_column(col)
    if truth is not None:
        table.add_column("APE RMSE cm (SE(3))")
        table.add_column("max cm")
    path_of = {seg.name: path for seg, path in zip(segments, paths, strict=True)}
    for ref in refs:  # a segment where the reference lost track has none (noted above)
        path = path_of[ref.segment]
        traj = ref.trajectory
        write_tum(path, traj)
        span = (int(traj.stamps_ns[-1]) - int(traj.stamps_ns[0])) / NS_PER_S
        row = [ref.segment, ref.source, str(len(traj.stamps_ns)), f"{span:.1f}", str(path)]
        if truth is not None:
            res = ape(truth, traj)
            row += [f"{100 * res.rmse_t:.2f}", f"{100 * float(res.e_t.max()):.2f}"]
        table.add_row(*row)
    console.print(table)


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("reference")(reference)
