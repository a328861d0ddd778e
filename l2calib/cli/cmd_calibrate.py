"""``l2calib calibrate RECIPE --bag PATH... --out DIR``: the main job."""

from __future__ import annotations

from pathlib import Path

import typer

from l2calib.assess.status import EXIT_NOT_CALIBRATED, NOT_CALIBRATED

_SET_HELP = "Override a recipe field, e.g. --set train.seed=3 (repeatable)."


def run_calibration(
    recipe,
    out: Path,
    bags: list[Path] | None = None,
    sequences=None,
    resume: bool = False,
    force: bool = False,
    truth=None,
    console=None,
):
    """Runs a :class:`~l2calib.calibration.Calibration` with the live display and prints it.

    Data clearly too short or too still to calibrate (:func:`l2calib.assess.status.before_training`)
    stops the run before the reference and the training: ``calibration.yaml`` then holds the
    ``not-calibrated`` status, the reasons and a data summary, and no extrinsic.

    Returns:
        The :class:`~l2calib.assess.result.CalibrationResult` (its ``T_imu_lidar``
        is ``None`` when the run stopped before training).
    """
    import numpy as np
    from rich.console import Console

    from l2calib.calibration import Calibration, RunHooks
    from l2calib.cli.live import CalibrationDisplay
    from l2calib.outputs.console_summary import print_result, print_status

    console = console or Console()
    run = Calibration(recipe, out, resume=resume, force=force)  # checks --out before any work
    with CalibrationDisplay(console, recipe.train.iteration_budget) as display:
        run.hooks = RunHooks(display.stage, display.update, display.skip_training)
        run.prepare(bags=bags, sequences=sequences)
        if not run.stopped:
            run.train()
    result = run.assess()
    paths = run.write(truth)
    if not run.stopped:
        print_result(console, result, truth=None if truth is None else np.asarray(truth))
    console.print(f"results in [bold]{run.out}[/]: {', '.join(p.name for p in paths.values())}")
    print_status(console, result)
    return result


def calibrate(
    recipe: Path = typer.Argument(..., help="Recipe YAML (see recipes/)."),
    bag: list[Path] = typer.Option(..., "--bag", "-b", help="Bag(s) to calibrate on."),
    out: Path = typer.Option(..., "--out", "-o", help="Output directory."),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
    resume: bool = typer.Option(False, "--resume", help="Continue a killed run in --out."),
    force: bool = typer.Option(False, "--force", help="Move an existing --out aside first."),
) -> None:
    """Calibrate T_imu_lidar from recordings, without targets or an initial guess.

    Exit status: 0 when calibration.yaml has status calibrated or unreliable (then its
    paste-ready blocks carry a warning); 3 when the data could not calibrate (status
    not-calibrated, no paste-ready blocks: data too short or too still stops before training
    and writes no extrinsic; after training, a partial result marked as such); 1 on an error;
    130 / 143 when interrupted by Ctrl-C / SIGTERM (resume with --resume).
    """
    import sys

    from l2calib import interrupt
    from l2calib.recipe import load_recipe

    argv = sys.argv[1:]
    resume_cmd = interrupt.command_line(argv, add="--resume", drop=("--force",))
    with interrupt.handling(
        resume_cmd, interrupt.command_line(argv, add="--force"), exit_process=True
    ):
        rec = load_recipe(recipe, set_)
        result = run_calibration(rec, out, bags=bag, resume=resume, force=force)
    if result.status == NOT_CALIBRATED:
        raise typer.Exit(EXIT_NOT_CALIBRATED)


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("calibrate")(calibrate)
