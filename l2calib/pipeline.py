"""Calibration from a recipe and recordings: read → select → reference → train → result.

Each stage is one call so the CLI can show progress between them and tests can enter anywhere
(e.g. with in-memory simulated sequences instead of bags).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from l2calib.agreement import (  # noqa: F401  (re-exported: the pipeline's public names)
    DISAGREEMENT_LIMITS,
    disagreement_warnings,
    finite_or_none,
)
from l2calib.data import Segment
from l2calib.data import Sequence as DataSequence
from l2calib.errors import DataError, ReferenceLostTrackError, TrainingError
from l2calib.interfaces import ReferenceTrajectory
from l2calib.interrupt import Interrupted, stop_workers
from l2calib.outputs.calibration_file import CalibrationResult
from l2calib.recipe import PluginChoice, Recipe

log = logging.getLogger("l2calib")


@dataclass
class PreparedData:
    """Everything the training needs, computed once."""

    sequences: list[DataSequence]
    segments: list[Segment]
    references: list[ReferenceTrajectory]
    selection: Any | None = None
    notes: list[str] = field(default_factory=list)

    def identity(self) -> list[str]:
        """Names and spans of the segments (part of the resume fingerprint)."""
        return [f"{s.name}:{s.start_ns}-{s.end_ns}:{len(s.measurements)}" for s in self.segments]

    @property
    def time_offset_hint_s(self) -> float | None:
        """Median LiDAR–IMU offset (s) the references measured, or ``None`` (see interfaces)."""
        hints = [r.time_offset_hint_s for r in self.references if r.time_offset_hint_s is not None]
        return float(np.median(hints)) if hints else None


def time_offset_bound_s(recipe: Recipe) -> float | None:
    """The policy's ``time_offset_bound_s`` (s) with its plugin default; ``None``: unbounded."""
    from l2calib.plugins import get_plugin

    spec = get_plugin("l2calib.policies", recipe.policy.name)
    return getattr(spec.config.model_validate(recipe.policy.options), "time_offset_bound_s", None)


def offset_start_s(train: Any, hint_s: float | None) -> float | None:
    """The time offset's starting mean (s), ``None`` when it is not estimated (or from 0).

    The recipe's ``train.init_time_offset_s`` (the user's, e.g. from ``inspect``) wins over the
    reference's clock-check hint ``hint_s``.
    """
    if not train.estimate_time_offset:
        return None
    return hint_s if train.init_time_offset_s is None else train.init_time_offset_s


def read_sequences(recipe: Recipe, bags: Sequence[Path], progress: bool = False):
    """Opens the bags as sequences with the recipe's topics and conventions."""
    from l2calib.io.sequences import open_sequences

    return open_sequences([Path(b) for b in bags], recipe.data, progress=progress)


def select_segments(recipe: Recipe, sequences: Sequence[DataSequence]):
    """Segments to calibrate on: the selection's windows, or every sequence whole.

    Raises:
        DataError: no window is eligible (the message names the gaps, dropped scans and still
            periods that rule them out), or, with the selection disabled, an IMU gap inside a
            recording (named with its topic, time and length).
    """
    from l2calib.selection.gaps import check_imu_gaps_whole, no_window_reason

    if not recipe.selection.enabled:
        check_imu_gaps_whole(sequences)
        return [seq.segment() for seq in sequences], None
    from l2calib.selection.greedy import select_windows

    selection = select_windows(sequences, recipe.selection)
    if not selection.chosen:
        window = selection.config.window_s
        raise DataError(
            "the data selection found no window to calibrate on (each is still or spans a gap): "
            + no_window_reason(sequences, selection.windows, window),
            fix=f"record at least {window:g} s of motion free of gaps (check the drivers for "
            "dropped messages), lower selection.window_s, or set selection.enabled=false",
        )
    return selection.segments(sequences), selection


def compute_references(
    recipe: Recipe,
    segments: Sequence[Segment],
    sequences: Sequence[DataSequence] | None = None,
    note: Callable[[str], None] | None = None,
    progress: bool = False,
) -> list[ReferenceTrajectory]:
    """Runs the recipe's reference plugin on the segments (its fallback if it loses track).

    Where the reference loses track on some segments but not all, those segments are dropped
    (named in a note) and the references of the others returned; where it loses track on
    every segment, the recipe's fallback computes them all.

    Args:
        recipe: The resolved recipe (``reference`` and ``data`` sections are used).
        segments: Selected segments.
        sequences: The sequences the segments were cut from: LiDAR-odometry references start
            ``margin_s`` before each segment on their scans (warm-up).
        note: Called with a message for the user when segments are dropped or the fallback
            takes over.
        progress: Let the reference show progress bars (LiDAR odometry, per segment).

    Returns:
        One reference per kept segment, in order (``ref.segment`` names it).

    Raises:
        ReferenceLostTrackError: if the reference loses track on every segment and the recipe
            has no fallback.
    """
    from l2calib.plugins import get_plugin

    def compute(choice: PluginChoice) -> list[ReferenceTrajectory]:
        source = get_plugin("l2calib.references", choice.name).build(
            choice.options,
            data=recipe.data,
            sequences=sequences,
            progress=progress,
            estimate_time_offset=recipe.train.estimate_time_offset,
            time_offset_bound_s=time_offset_bound_s(recipe),
        )
        return source.compute(list(segments))

    fallback = recipe.reference.fallback
    try:
        refs = compute(recipe.reference)
    except ReferenceLostTrackError as exc:
        if exc.tracked:  # lost on some segments only: those go, the rest is calibrated on
            msg = (
                f"segment(s) {', '.join(exc.lost)} dropped: {exc.message}; calibrating on the "
                f"{len(exc.tracked)} other(s)"
            )
            log.warning(msg)
            if note is not None:
                note(msg)
            return exc.tracked
        if fallback is None:
            raise
        msg = (
            f"the {recipe.reference.name} reference failed ({exc.message}); the recipe's "
            f"fallback, {fallback.name}, is used instead"
        )
        log.warning(msg)
        if note is not None:
            note(msg)
        refs = compute(fallback)
    if any(r.constrains == "position" for r in refs):
        log.info("the reference constrains positions only: the reward's rotation term is dropped")
    return refs


def kept_segments(segments: Sequence[Segment], refs: Sequence[ReferenceTrajectory]) -> list:
    """The segments that have a reference (one dropped where the reference lost track)."""
    names = {r.segment for r in refs}
    return [s for s in segments if s.name in names]


def prepare_data(
    recipe: Recipe,
    bags: Sequence[Path] | None = None,
    sequences: Sequence[DataSequence] | None = None,
    stage: Callable[[str], None] | None = None,
) -> PreparedData:
    """Reads (or takes) sequences, selects segments and computes their references."""
    data = select_data(recipe, bags=bags, sequences=sequences, stage=stage)
    return add_references(recipe, data, stage=stage)


def select_data(
    recipe: Recipe,
    bags: Sequence[Path] | None = None,
    sequences: Sequence[DataSequence] | None = None,
    stage: Callable[[str], None] | None = None,
) -> PreparedData:
    """Reads (or takes) sequences and selects segments, without references yet.

    ``calibrate`` judges the selected data (:func:`l2calib.status.before_training`) before it
    spends anything on a reference; :func:`add_references` completes the data.
    """
    say = stage or (lambda _msg: None)
    if sequences is None:
        say("reading recordings")
        sequences = read_sequences(recipe, bags or [])
    say("selecting informative data")
    segments, selection = select_segments(recipe, sequences)
    return PreparedData(list(sequences), segments, [], selection)


def add_references(
    recipe: Recipe, data: PreparedData, stage: Callable[[str], None] | None = None
) -> PreparedData:
    """Computes the references of ``data``'s segments (in place); returns ``data``."""
    say = stage or (lambda _msg: None)
    say(f"computing the {recipe.reference.name} reference")
    data.references = compute_references(recipe, data.segments, data.sequences, data.notes.append)
    data.segments = kept_segments(data.segments, data.references)
    if data.time_offset_hint_s is not None:
        data.notes.append(
            f"the {recipe.reference.name} reference's clock check measured a LiDAR–IMU time "
            f"offset of {1000 * data.time_offset_hint_s:+.1f} ms (t_imu = t_lidar + offset): "
            "the estimation starts from it"
        )
    return data


def undetermined_axes(
    resolution: Any,
    selection: Any | None,
    rot_limit_deg: float = 1.0,
    trans_limit_m: float = 0.05,
) -> list[str]:
    """Axes the data could not determine: flat reward along them, or weak excitation."""
    from l2calib.sensitivity import undetermined

    out = undetermined(resolution, rot_limit_deg, trans_limit_m)
    if selection is not None:
        out += [f"weakly excited: {w}" for w in selection.weak_axes]
    return out


class _Scorer:
    """Rewards ``[N]`` of ``N`` extrinsics on the training env (spread over its workers).

    Args:
        env: The open training env (a ``CalibrationEnv`` or a ``ParallelEnv`` of them).
        time_offset_s: The time offset (s) every candidate is scored with, or ``None``.
    """

    def __init__(self, env, time_offset_s: float | None):
        self.env, self.offset = env, time_offset_s
        self.last = None  # the latest call's RewardBreakdown (reward ingredients per candidate)

    def __call__(self, T_imu_lidar: torch.Tensor) -> torch.Tensor:
        from l2calib.train.envs import score_batch

        offsets = None
        if self.offset is not None:
            offsets = torch.full((T_imu_lidar.shape[0],), float(self.offset), dtype=torch.float64)
        self.last = score_batch(self.env, T_imu_lidar, offsets)
        return self.last.reward.detach().to(torch.float64)


#: Seed of restart ``k``: ``train.seed + k · RESTART_SEED_STRIDE`` (far from the seeds users
#: and the benchmarks pick by hand, so a restart does not repeat another run's first attempt).
RESTART_SEED_STRIDE = 10_007


def train_policy(
    recipe: Recipe,
    data: PreparedData,
    out_dir: Path | None,
    resume: bool = False,
    progress: Callable[[Any], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> tuple[CalibrationResult, Any]:
    """Builds env + policy from the recipe, runs PPO; returns the calibration and the outcome.

    When the result fails the reference-agreement check (:mod:`l2calib.agreement`), PPO starts
    again from scratch with another seed, up to ``train.restarts`` times, and the attempt with the
    highest reward is kept: on weakly excited data a run can settle in a local optimum that the
    reward itself ranks far below the truth. Restart ``k`` keeps its checkpoint and metrics in
    ``out_dir/restart-k``. The outcome returned is the kept attempt's; the result's evaluations,
    iterations and wall time count every attempt.

    Raises:
        TrainingError: if ``resume`` is asked without an ``out_dir`` to resume from.
    """
    from l2calib.train.checkpoint import CHECKPOINT_NAME
    from l2calib.train.envs import make_training_env

    if resume and out_dir is None:
        raise TrainingError(
            "resume needs the output directory of the run to continue", fix="pass its out_dir"
        )
    say = stage or (lambda _msg: None)
    say(f"preparing the {recipe.backend.name} odometry")
    env = make_training_env(recipe, data.segments, data.references)
    attempts: list[tuple[CalibrationResult, Any, int]] = []  # (result, outcome, seed)
    k = 0
    try:  # the workers serve every attempt, its refinement and probe; down on any error
        for k in range(recipe.train.restarts + 1):
            seed = recipe.train.seed + k * RESTART_SEED_STRIDE
            sub = out_dir if out_dir is None or k == 0 else out_dir / f"restart-{k}"
            # A restart that had not begun when the run was killed starts afresh on --resume.
            again = resume and (k == 0 or (sub / CHECKPOINT_NAME).is_file())
            result_outcome = _attempt(recipe, data, env, seed, sub, again, progress, say, k)
            attempts.append((*result_outcome, seed))
            result = attempts[-1][0]
            if not result.warnings or k == recipe.train.restarts:
                break
            agreement = result.reference_agreement
            say(
                f"the result disagrees with the reference ({_agreement_text(agreement)}): "
                f"PPO starts again with seed {seed + RESTART_SEED_STRIDE} "
                f"(restart {k + 1} of at most {recipe.train.restarts})"
            )
    except Interrupted as exc:
        stop_workers(env)  # they may be mid-batch: a polite close would wait for them
        env.__dict__["is_closed"] = True
        if out_dir is not None:
            _locate_checkpoint(exc, out_dir, k)
        raise
    finally:
        if not getattr(env, "is_closed", False):
            env.close()
    return _keep_best(attempts)


def _locate_checkpoint(exc: Interrupted, out_dir: Path, attempt: int) -> None:
    """Fills in where a ``--resume`` of an interrupted run continues (attempt, iteration).

    The trainer says so itself when it was interrupted; an interruption elsewhere (refinement,
    probe, between attempts) continues from the newest checkpoint on disk.
    """
    from l2calib.train.checkpoint import CHECKPOINT_NAME, checkpoint_iterations

    if exc.checkpoint is not None:
        exc.attempt = attempt
        return
    for k in range(attempt, -1, -1):
        path = (out_dir if k == 0 else out_dir / f"restart-{k}") / CHECKPOINT_NAME
        if path.is_file():
            exc.attempt, exc.checkpoint = k, path
            exc.iteration = checkpoint_iterations(path)
            return


def _agreement_text(agreement: dict[str, float | None]) -> str:
    t, r = agreement["translation_m"], agreement["rotation_deg"]
    return " / ".join(f"{v:.3g} {u}" for v, u in ((t and 100 * t, "cm"), (r, "deg")) if v)


def _keep_best(attempts: list[tuple[CalibrationResult, Any, int]]):
    """The attempt with the highest reward, charged with every attempt's cost.

    Evaluations, iterations and wall time are summed over the attempts.

    Returns:
        ``(result, outcome)``; with restarts, ``result.extra["attempts"]`` lists every attempt
        (``calibration.yaml`` → ``attempts``).
    """
    best, outcome, _ = max(attempts, key=lambda a: a[0].final_reward)
    if len(attempts) > 1:
        best.evaluations = sum(r.evaluations for r, _, _ in attempts)
        best.wall_time_s = sum(r.wall_time_s for r, _, _ in attempts)
        best.iterations = sum(r.iterations for r, _, _ in attempts)
        best.extra["attempts"] = [
            {
                "seed": seed,
                "final_reward": round(r.final_reward, 6),
                "reference_agreement": r.reference_agreement,
                "kept": r is best,
            }
            for r, _, seed in attempts
        ]
    return best, outcome


def _attempt(
    recipe: Recipe,
    data: PreparedData,
    env,
    seed: int,
    out_dir: Path | None,
    resume: bool,
    progress: Callable[[Any], None] | None,
    say: Callable[[str], None],
    attempt: int = 0,
) -> tuple[CalibrationResult, Any]:
    """One PPO run from scratch with ``seed``, its refinement and its resolution probe.

    ``attempt`` numbers the run (0: the first, k: restart k) in what it tells the user.
    """
    from l2calib import sensitivity
    from l2calib.plugins import get_plugin
    from l2calib.refine import refine
    from l2calib.time_offset_probe import probe_evaluations, probe_time_offset
    from l2calib.train.checkpoint import CHECKPOINT_NAME, recipe_fingerprint
    from l2calib.train.ppo import PpoTrainer

    cfg = recipe.train.model_copy(update={"seed": seed})
    torch.manual_seed(seed)
    np.random.seed(seed)
    action_dim = 8 if cfg.estimate_time_offset else 7
    start = offset_start_s(cfg, data.time_offset_hint_s)
    policy = get_plugin("l2calib.policies", recipe.policy.name).build(
        recipe.policy.options,
        action_dim=action_dim,
        prior=recipe.policy.prior,
        seed=seed,
        **({} if start is None else {"init_time_offset_s": start}),
    )
    fingerprint = recipe_fingerprint(recipe.model_dump(mode="json"), data.identity())
    trainer = PpoTrainer(policy, env, cfg, out_dir, fingerprint)
    if resume:
        trainer.resume()
        which = "the first PPO run" if attempt == 0 else f"restart {attempt}"
        say(
            f"resuming {which} (seed {seed}) at iteration {len(trainer.outcome.history)} "
            f"from {out_dir / CHECKPOINT_NAME}"
        )
    say("training")
    outcome = trainer.run(progress)
    mode = policy.mode()
    T_mode = torch.as_tensor(np.asarray(mode["T_imu_lidar"]), dtype=torch.float64)
    offset = mode.get("time_offset_s") if cfg.estimate_time_offset else None
    score = _Scorer(env, offset)
    refined = None
    if cfg.refine_rounds > 0:
        say(f"refining the result on the reward ({cfg.refine_rounds} batched probe rounds)")
        refined = refine(
            score, T_mode, cfg.refine_rounds, cfg.refine_rot_step_deg, cfg.refine_trans_step_m
        )
        T_mode = torch.from_numpy(refined.T_imu_lidar)
        log.info(
            "refine: reward %.5f -> %.5f, moved %.3f deg / %.2f cm (%d evaluations)",
            refined.start_reward, refined.reward, refined.moved_deg, 100 * refined.moved_m,
            refined.evaluations,
        )  # fmt: skip
    say("probing the reward around the result (per-axis resolution)")
    candidates = sensitivity.probe(T_mode)
    resolution = sensitivity.resolve(score(candidates))
    agreement = {  # probe candidate 0 is the result itself (rotation: None for RTK positions)
        "translation_m": finite_or_none(score.last.mean_e_t[0], 5),
        "rotation_deg": finite_or_none(torch.rad2deg(score.last.mean_e_r[0]), 4),
    }
    offset_res = None
    if offset is not None:
        say("probing the reward along the time offset (its resolution)")
        offset_res = probe_time_offset(env, T_mode, offset)
    unc = policy.uncertainty()
    sources = sorted({r.source for r in data.references})
    return CalibrationResult(
        T_imu_lidar=T_mode.numpy(),
        time_offset_s=offset,
        rotation_sigma_deg=[float(x) for x in unc["rotation_sigma_deg"]],
        translation_sigma_m=[float(x) for x in unc["translation_sigma_m"]],
        time_offset_sigma_s=unc.get("time_offset_sigma_s"),
        final_reward=resolution.reward,
        evaluations=outcome.evaluations
        + candidates.shape[0]
        + (refined.evaluations if refined else 0)
        + (probe_evaluations() if offset_res else 0),
        iterations=len(outcome.history),
        wall_time_s=outcome.wall_s,
        stop_reason=outcome.stop_reason,
        resolution=resolution,
        undetermined=undetermined_axes(resolution, data.selection)
        + (offset_res.undetermined() if offset_res else []),
        time_offset_resolution=offset_res,
        time_offset_start_s=(start or 0.0) if offset is not None else None,
        reference_agreement=agreement,
        warnings=disagreement_warnings(agreement, sources),
        extra={
            # which reference the reward compared with, and why (e.g. the recipe's fallback)
            "reference": {"sources": sources, "notes": list(data.notes)},
            **({"refine": _refine_summary(refined)} if refined else {}),
        },
    ), outcome


def _refine_summary(refined: Any) -> dict[str, Any]:
    """What the post-PPO refinement did (``calibration.yaml`` → ``refine``)."""
    return {
        "policy_mode_reward": round(refined.start_reward, 6),
        "refined_reward": round(refined.reward, 6),
        "moved_deg": round(refined.moved_deg, 4),
        "moved_m": round(refined.moved_m, 5),
        "evaluations": int(refined.evaluations),
    }
