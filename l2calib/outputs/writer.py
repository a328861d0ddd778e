"""Writing a calibration run's directory without ever destroying what a user made."""

from __future__ import annotations

import csv
import json
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from l2calib.assess.result import CalibrationResult
from l2calib.errors import ConfigError, OutputError
from l2calib.outputs.calibration_file import write_calibration
from l2calib.outputs.report import write_html
from l2calib.outputs.report_figures import plot_report, plot_trajectories
from l2calib.outputs.writable import check_writable
from l2calib.recipe import Recipe, dump_recipe

OWN_FILES = ("calibration.yaml", "checkpoint.pt", "recipe.yaml", "report.png", "report.html")


def prepare_out_dir(out: Path, resume: bool, force: bool) -> Path:
    """Creates ``out``; refuses to reuse a non-empty one unless resuming or forced.

    With ``force``, an existing directory is moved aside to ``<out>.previous-<time>`` (never
    deleted). Called before any work, so an unwritable ``out`` fails at once.

    Raises:
        OutputError: if ``out`` cannot be created or written (:mod:`l2calib.outputs.writable`).
        ConfigError: if ``out`` is not empty (without ``resume`` or ``force``), or there is
            nothing to resume.
    """
    out = check_writable(out, "--out")
    if resume:
        if not (out / "checkpoint.pt").is_file():
            _refuse_to_resume_a_stopped_run(out)
            raise ConfigError(
                f"{out}: nothing to resume (no checkpoint.pt)",
                fix="run without --resume, or point --out at the killed run's directory",
            )
        return out
    if out.exists() and any(out.iterdir()):
        if not force:
            raise ConfigError(
                f"{out} is not empty",
                fix="choose a new --out, add --resume to continue a killed run, or --force to "
                "move the old directory aside",
            )
        backup = out.with_name(f"{out.name}.previous-{time.strftime('%Y%m%d-%H%M%S')}")
        try:
            shutil.move(str(out), str(backup))
        except OSError as exc:
            raise OutputError(
                f"--out {out}: cannot move it aside to {backup} ({exc.strerror})",
                fix="choose a new --out, or move the old directory yourself",
            ) from None
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"--out {out}: cannot create it ({exc.strerror})",
            fix="pass a --out in a place you can write to",
        ) from None
    return out


def _refuse_to_resume_a_stopped_run(out: Path) -> None:
    """A clear error for ``--resume`` in a run that stopped before training (nothing to resume).

    Raises:
        ConfigError: if ``out/calibration.yaml`` says ``not-calibrated`` with no checkpoint.
    """
    from l2calib.assess.status import NOT_CALIBRATED
    from l2calib.outputs.calibration_read import read_status

    path = out / "calibration.yaml"
    if not path.is_file() or read_status(path) != NOT_CALIBRATED:
        return
    raise ConfigError(
        f"{out}: nothing to resume: that run stopped before training ({path}: status "
        f"{NOT_CALIBRATED}, the data being too short or too still) and a run on the same data "
        "stops again",
        fix="record the motion its status_reasons ask for and calibrate the new bag into a new "
        "--out (or --force to move this one aside)",
    )


def write_stopped_outputs(
    out: Path, recipe: Recipe, result: CalibrationResult, data
) -> dict[str, Path]:
    """Writes the outputs of a run that stopped before training.

    These are ``calibration.yaml`` (status, reasons, data summary, no extrinsic),
    ``recipe.yaml``, and the selection files when the selection ran.
    """
    out = Path(out)
    paths = {"calibration": write_calibration(out / "calibration.yaml", result)}
    (out / "recipe.yaml").write_text(dump_recipe(recipe))
    paths["recipe"] = out / "recipe.yaml"
    if data.selection is not None:
        paths.update(_write_selection(out, data.selection))
    return paths


def _write_selection(out: Path, selection) -> dict[str, Path]:
    """selection.png and selection.json."""
    from l2calib.selection.plot import plot_selection

    path = out / "selection.json"
    path.write_text(json.dumps(selection.as_dict(), indent=1))
    return {"selection_plot": plot_selection(selection, out / "selection.png"), "selection": path}


def write_metrics_csv(path: Path, history: list[Any]) -> Path:
    """All per-iteration scalars in one CSV (the TorchRL logger also keeps one file per key)."""
    rows = [h.scalars() for h in history]
    keys = sorted({k for r in rows for k in r})
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_outputs(
    out: Path,
    recipe: Recipe,
    result: CalibrationResult,
    history: list[Any],
    data,
    truth: np.ndarray | None = None,
    trajectories: list[dict[str, Any]] | None = None,
    problems: list[str] | None = None,
) -> dict[str, Path]:
    """Writes calibration.yaml, recipe.yaml, metrics.csv, the report and the selection files.

    The report is ``report.html`` with ``report.png`` and ``trajectories.png`` (from
    ``trajectories``, computed by training on its open env). ``problems`` (what failed in those
    extras) go to ``report-warnings.txt``; ``calibration.yaml`` is written first.
    """
    out = Path(out)
    paths = {
        "calibration": write_calibration(out / "calibration.yaml", result),
        "metrics": write_metrics_csv(out / "metrics.csv", history),
    }
    (out / "recipe.yaml").write_text(dump_recipe(recipe))
    paths["recipe"] = out / "recipe.yaml"
    problems = list(problems or [])
    if trajectories:
        paths["trajectories"] = plot_trajectories(out / "trajectories.png", trajectories)
    paths["report"] = plot_report(out / "report.png", history, result, truth)
    if data.selection is not None:
        paths.update(_write_selection(out, data.selection))
    if problems:
        (out / "report-warnings.txt").write_text("\n".join(problems) + "\n")
        paths["report_warnings"] = out / "report-warnings.txt"
    figures = [
        (out / "report.png", "Training: reward, the policy's mode per iteration, per-axis "
         "resolution of the result"),
        (out / "trajectories.png", "Every segment: the odometry's LiDAR trajectory with the "
         "extrinsic before (identity or the prior) and after calibration, and the reference"),
        (out / "selection.png", "Data selection: the IMU's excitation and the windows kept"),
    ]  # fmt: skip
    paths["html"] = write_html(
        out / "report.html", result, figures, paths["calibration"],
        None if truth is None else np.asarray(truth),
    )  # fmt: skip
    return paths
