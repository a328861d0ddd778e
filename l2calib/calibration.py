"""One calibration run, owned by one object: ``prepare → train → assess → write``.

In the spirit of KISS-ICP's ``OdometryPipeline.run()``: :class:`Calibration` holds the recipe,
the output directory and what each stage produced, so ``calibrate``, ``demo`` and the
benchmarks run the same steps in the same order, and ``evaluate`` scores given extrinsics with
the same recipe (:meth:`Calibration.evaluate`). The CLI keeps argument parsing and the live
display (it passes :class:`RunHooks`); nothing here prints.

Stages:

* :meth:`Calibration.prepare` reads the recordings (or takes sequences), selects segments,
  judges the selected data (:func:`l2calib.assess.status.before_training`) and, unless that
  stops the run, computes the references (:mod:`l2calib.pipeline`).
* :meth:`Calibration.train` runs PPO with its restarts, refinement and probes
  (:mod:`l2calib.training`).
* :meth:`Calibration.assess` gives the result its status and data summary
  (:mod:`l2calib.assess.status`).
* :meth:`Calibration.write` writes the output directory (:mod:`l2calib.outputs.writer`).
* :meth:`Calibration.evaluate` (instead of the four above) runs the odometry with given
  extrinsics on whole sequences and compares it with the reference
  (:mod:`l2calib.assess.evaluation`).

A run whose data is too short or too still stops after ``prepare``: ``train`` is skipped and
``assess`` / ``write`` produce the ``not-calibrated`` result without an extrinsic.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from l2calib.errors import ConfigError
from l2calib.recipe import Recipe

#: ``training.stop_reason`` of a run that stopped before training.
STOPPED_BEFORE_TRAINING = "stopped before training: the data is too short or too still"


def _silent(_msg: str) -> None:
    return None


@dataclass
class RunHooks:
    """How a run reports to its caller (the CLI's live display); silent by default.

    Attributes:
        stage: Called with a one-line description when a stage starts or has news.
        progress: Called with each PPO iteration's record (:class:`~l2calib.train.ppo.
            IterationRecord`), or ``None``.
        skip_training: Called (no arguments) when the data stops the run before training.
    """

    stage: Callable[[str], None] = _silent
    progress: Callable[[Any], None] | None = None
    skip_training: Callable[[], None] = lambda: None


class Calibration:
    """One calibration of ``T_imu_lidar`` from a recipe and recordings.

    Args:
        recipe: The validated recipe.
        out: Output directory, or ``None`` to write nothing (benchmarks, tests).
        resume: Continue a killed run in ``out`` from its checkpoint.
        force: Move a non-empty ``out`` aside first (never deleted).
        hooks: Progress callbacks (:class:`RunHooks`).

    Raises:
        OutputError / ConfigError: if ``out`` cannot be used (checked at once, before any work).
    """

    def __init__(
        self,
        recipe: Recipe,
        out: Path | None = None,
        *,
        resume: bool = False,
        force: bool = False,
        hooks: RunHooks | None = None,
    ):
        from l2calib.outputs.writer import prepare_out_dir

        self.recipe = recipe
        self.resume = resume
        self.hooks = hooks or RunHooks()
        self.out = None if out is None else prepare_out_dir(Path(out), resume, force)
        self.data = None  # PreparedData, after prepare()
        self.verdict = None  # status.Status of the selected data, after prepare()
        self.result = None  # CalibrationResult, after train() (or assess() when stopped)
        self.history: list[Any] = []  # PPO iteration records of the kept attempt
        self.trajectories: list[dict[str, Any]] = []  # before/after per segment, after train()
        self.problems: list[str] = []  # what failed in the report's extras (not the result)
        self.stage_s: dict[str, float] = {}  # wall time of each stage (s), as they finish

    @property
    def stopped(self) -> bool:
        """Whether the selected data stopped the run before training."""
        from l2calib.assess.status import NOT_CALIBRATED

        return self.verdict is not None and self.verdict.status == NOT_CALIBRATED

    def prepare(
        self,
        bags: Sequence[Path] | None = None,
        sequences: Sequence[Any] | None = None,
        references: Callable[[list[Any]], list[Any]] | None = None,
    ):
        """Reads and selects the data, judges it, and computes the references.

        Args:
            bags: Recordings to read (or ``sequences``).
            sequences: In-memory :class:`~l2calib.data.Sequence` objects instead of bags.
            references: Builds the references from the selected segments instead of the
                recipe's reference (e.g. a benchmark's exact simulated trajectory).

        Returns:
            The :class:`~l2calib.pipeline.PreparedData` (without references when the data
            stopped the run: see :attr:`stopped`).
        """
        from l2calib.assess.status import before_training
        from l2calib.pipeline import add_references, read_sequences, select_data

        say = self.hooks.stage
        if sequences is None:
            say("reading recordings")
            clock = time.monotonic()
            sequences = read_sequences(self.recipe, bags or [])
            self.stage_s["reading"] = time.monotonic() - clock
        clock = time.monotonic()
        self.data = select_data(self.recipe, sequences=sequences, stage=say)
        self.stage_s["selection"] = time.monotonic() - clock
        self._tell_data()
        self.verdict = before_training(self.data, self.recipe.selection)
        if self.stopped:
            self.hooks.skip_training()
            return self.data
        clock = time.monotonic()
        if references is not None:
            self.data.references = references(self.data.segments)
        else:
            add_references(self.recipe, self.data, stage=say)
        self.stage_s["reference"] = time.monotonic() - clock
        for note in self.data.notes:
            say(f"[yellow]note[/]: {note}")
        return self.data

    def train(self):
        """PPO from no initial guess (or the recipe's prior), refined and probed.

        Returns:
            The :class:`~l2calib.assess.result.CalibrationResult` (before
            :meth:`assess`).

        Raises:
            ConfigError: if called before :meth:`prepare` or on data that stopped the run.
        """
        from l2calib.training import train_policy

        if self.data is None or self.stopped:
            raise ConfigError(
                "Calibration.train: nothing to train on",
                fix="call prepare() first; when it stops the run (too little data), skip train()",
            )
        prior = self.recipe.policy.prior
        run = train_policy(
            self.recipe,
            self.data,
            self.out,
            resume=self.resume,
            progress=self.hooks.progress,
            stage=self.hooks.stage,
            before=None if prior is None else prior.T_imu_lidar(),
        )
        self.result, self.history = run.result, run.outcome.history
        self.trajectories, self.problems = run.trajectories, run.problems
        self.stage_s.update(self.result.stage_s)
        self.result.stage_s = self.stage_s  # one record of every stage, in order
        return self.result

    def assess(self):
        """Gives the result its status (``calibrated`` / ``unreliable`` / ``not-calibrated``).

        Returns:
            The assessed :class:`~l2calib.assess.result.CalibrationResult`; without
            an extrinsic when the data stopped the run before training.
        """
        from l2calib.assess.result import CalibrationResult
        from l2calib.assess.status import assess
        from l2calib.outputs.data_summary import data_summary

        summary = data_summary(self.data, self.recipe.selection)
        if self.stopped:
            self.result = CalibrationResult(
                None,
                stop_reason=STOPPED_BEFORE_TRAINING,
                status=self.verdict.status,
                status_reasons=self.verdict.reasons,
                extra={"data": summary},
                stage_s=self.stage_s,
            )
            return self.result
        verdict = assess(self.result, self.data, self.recipe.selection)
        self.result.status, self.result.status_reasons = verdict.status, verdict.reasons
        self.result.extra["data"] = summary
        return self.result

    def write(self, truth: np.ndarray | None = None) -> dict[str, Path]:
        """Writes ``calibration.yaml``, ``recipe.yaml``, metrics and the report into ``out``.

        Args:
            truth: The true ``T_imu_lidar`` ``[4, 4]`` when known (simulations): drawn in the
                report beside the result.

        Returns:
            The written files by kind (none when ``out`` is ``None``).
        """
        from l2calib.outputs.calibration_file import write_calibration
        from l2calib.outputs.writer import write_outputs, write_stopped_outputs

        if self.out is None:
            return {}
        if self.stopped:
            return write_stopped_outputs(self.out, self.recipe, self.result, self.data)
        self.hooks.stage("writing the report")
        clock = time.monotonic()
        files = write_outputs(
            self.out, self.recipe, self.result, self.history, self.data, truth=truth,
            trajectories=self.trajectories, problems=self.problems,
        )  # fmt: skip
        # calibration.yaml (written first, so nothing is lost) again with the report's time
        self.stage_s["report"] = time.monotonic() - clock
        write_calibration(files["calibration"], self.result)
        return files

    def run(
        self,
        bags: Sequence[Path] | None = None,
        sequences: Sequence[Any] | None = None,
        truth: np.ndarray | None = None,
    ):
        """All four stages; returns the assessed result (see :meth:`assess`)."""
        self.prepare(bags=bags, sequences=sequences)
        if not self.stopped:
            self.train()
        self.assess()
        self.write(truth)
        return self.result

    def evaluate(
        self,
        extrinsics: dict[str, Any],
        bags: Sequence[Path] | None = None,
        sequences: Sequence[Any] | None = None,
    ):
        """Scores given extrinsics: odometry APE against the reference on every whole sequence.

        No selection and no training: each sequence is used whole, as a user would run the
        odometry with the extrinsic (the backend's evaluation mode).

        Args:
            extrinsics: ``label -> Extrinsic`` (:class:`~l2calib.interfaces.Extrinsic`).
            bags: Recordings to read (or ``sequences``).
            sequences: In-memory :class:`~l2calib.data.Sequence` objects instead of bags.

        Returns:
            :class:`~l2calib.assess.evaluation.EvaluationRow` per sequence and extrinsic.
        """
        from l2calib.assess.evaluation import evaluate_extrinsics
        from l2calib.pipeline import read_sequences

        if sequences is None:
            self.hooks.stage("reading recordings")
            sequences = read_sequences(self.recipe, bags or [])
        self.hooks.stage("running the odometry (own map, one continuous run per bag)")
        return evaluate_extrinsics(self.recipe, sequences, extrinsics)

    def _tell_data(self) -> None:
        """Reports the reading warnings, the selection's notes and how much was selected."""
        say, data = self.hooks.stage, self.data
        for seq in data.sequences:
            for warning in seq.meta.get("warnings", []):
                say(f"[yellow]warning[/]: {warning}")
        for note in data.selection.notes if data.selection is not None else []:
            say(f"[yellow]note[/]: {note}")
        total = sum(s.duration_s for s in data.segments)
        say(f"{len(data.segments)} segment(s), {total:.1f} s of data")
