"""Training on prepared data: PPO attempts, each refined and probed, into a calibration result.

:func:`train_policy` opens the training env once, runs PPO (restarting with another seed when
the result disagrees with the reference, :mod:`l2calib.assess.agreement`), refines the policy's
mode on the reward (:mod:`l2calib.assess.refine`), probes the reward around it (per-axis
resolution, :mod:`l2calib.assess.sensitivity`; the time offset's,
:mod:`l2calib.assess.time_offset_probe`), bounds each axis
(:mod:`l2calib.assess.result_bounds`) and returns the
:class:`~l2calib.assess.result.CalibrationResult`. The data comes from
:mod:`l2calib.pipeline`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from l2calib.assess.agreement import disagreement_warnings, finite_or_none
from l2calib.assess.result import CalibrationResult
from l2calib.errors import TrainingError
from l2calib.interfaces import Extrinsic
from l2calib.interrupt import Interrupted, stop_workers
from l2calib.pipeline import PreparedData
from l2calib.recipe import Recipe
from l2calib.train.env_build import set_data_fraction
from l2calib.train.offset_hold import offset_from_rates, offset_start_s

log = logging.getLogger("l2calib")


class _Scorer:
    """Rewards ``[N]`` of ``N`` extrinsics on the training env (spread over its workers).

    Args:
        env: The open training env (a ``CalibrationEnv`` or a ``ParallelEnv`` of them).
        time_offset_s: The time offset (s) every candidate is scored with, or ``None``.
    """

    def __init__(self, env, time_offset_s: float | None):
        self.env, self.offset = env, time_offset_s
        self.last = None  # the latest call's RewardBreakdown (reward ingredients per candidate)

    def __call__(
        self, T_imu_lidar: torch.Tensor, offsets: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Rewards of ``T_imu_lidar [N,4,4]``, at ``offsets [N]`` (s) or the fixed offset."""
        from l2calib.train.env_build import score_batch

        if offsets is None and self.offset is not None:
            offsets = torch.full((T_imu_lidar.shape[0],), float(self.offset), dtype=torch.float64)
        self.last = score_batch(self.env, T_imu_lidar, offsets)
        return self.last.reward.detach().to(torch.float64)


@dataclass
class TrainedRun:
    """What :func:`train_policy` hands back.

    Attributes:
        result: The kept attempt's calibration (costs summed over every attempt).
        outcome: The kept attempt's PPO outcome (``history``: one record per iteration).
        trajectories: Per segment, the LiDAR trajectory with the extrinsic before (identity or
            the prior) and after calibration beside the reference, run on the training env
            before it closed (``{"name", "reference", "before", "after"}``, [N,3] m); empty
            when that failed (``problems`` says why).
        problems: What went wrong with the extras (never with the calibration).
    """

    result: CalibrationResult
    outcome: Any
    trajectories: list[dict[str, Any]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


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
    before: np.ndarray | None = None,
) -> TrainedRun:
    """Builds env + policy from the recipe, runs PPO; returns the calibration and the outcome.

    Before the env closes, the kept result and ``before`` (the report's "before" extrinsic,
    4×4; default identity) run once more on it for the report's trajectories.

    When the result fails the reference-agreement check (:mod:`l2calib.assess.agreement`), PPO
    starts again from scratch with another seed (and from no guess where the first attempt
    started at the rate rotation, :mod:`l2calib.train.rotation_start`), up to
    ``train.restarts`` times, and the attempt
    with the highest reward is kept: on weakly excited data a run can settle in a local optimum
    that the reward itself ranks far below the truth. Restart ``k`` keeps its checkpoint and
    metrics in ``out_dir/restart-k``. The outcome returned is the kept attempt's; the result's
    evaluations, iterations and wall time count every attempt.

    Raises:
        TrainingError: if ``resume`` is asked without an ``out_dir`` to resume from.
    """
    from l2calib.train.checkpoint import CHECKPOINT_NAME
    from l2calib.train.env_build import make_training_env

    if resume and out_dir is None:
        raise TrainingError(
            "resume needs the output directory of the run to continue", fix="pass its out_dir"
        )
    from l2calib.train.lever_start import lever_start
    from l2calib.train.rotation_start import rotation_start, start_offset_s

    say = stage or (lambda _msg: None)
    recipe, offset_method = offset_from_rates(recipe, data, say)
    rot_start = rotation_start(recipe, data, say)
    t_start = lever_start(recipe, data, rot_start, start_offset_s(recipe, data), say)
    hold = _vertical_hold(recipe, data, say, rate_start=rot_start is not None)
    where = " on Ray actors" if recipe.train.executor == "ray" else ""
    say(f"preparing the {recipe.backend.name} odometry{where}")
    t0 = time.monotonic()
    env = make_training_env(recipe, data.segments, data.references, hold=hold)
    attempts: list[tuple[CalibrationResult, Any, int]] = []  # (result, outcome, seed)
    k = 0
    try:  # the workers serve every attempt, its refinement and probe; down on any error
        set_data_fraction(env, 1.0)  # starts the workers: each prepares its backend now
        prepared_s = time.monotonic() - t0
        for k in range(recipe.train.restarts + 1):
            seed = recipe.train.seed + k * RESTART_SEED_STRIDE
            sub = out_dir if out_dir is None or k == 0 else out_dir / f"restart-{k}"
            # A restart that had not begun when the run was killed starts afresh on --resume.
            again = resume and (k == 0 or (sub / CHECKPOINT_NAME).is_file())
            result_outcome = _attempt(
                recipe, data, env, seed, sub, again, progress, say, k, hold=hold,
                start=rot_start if k == 0 else None, t_start=t_start if k == 0 else None,
            )  # fmt: skip
            attempts.append((*result_outcome, seed))
            result = attempts[-1][0]
            if not result.warnings or k == recipe.train.restarts:
                break
            agreement = result.reference_agreement
            say(
                f"the result disagrees with the reference ({_agreement_text(agreement)}): "
                f"PPO starts again with seed {seed + RESTART_SEED_STRIDE}"
                + (" from no guess " if k == 0 and rot_start is not None else " ")
                + f"(restart {k + 1} of at most {recipe.train.restarts})"
            )
        run = TrainedRun(*_keep_best(attempts))
        if run.result.time_offset_s is not None:
            run.result.time_offset_method = offset_method
        if rot_start is not None:
            run.result.extra["rotation_start"] = rot_start.to_dict()
        if t_start is not None:
            run.result.extra["translation_start"] = t_start.to_dict()
        run.result.stage_s = {"odometry_preparation": prepared_s, **run.result.stage_s}
        t0 = time.monotonic()
        _add_trajectories(run, env, np.eye(4) if before is None else before)
        run.result.stage_s["report_trajectories"] = time.monotonic() - t0
    except Interrupted as exc:
        stop_workers(env)  # they may be mid-batch: a polite close would wait for them
        env.__dict__["is_closed"] = True
        if out_dir is not None:
            _locate_checkpoint(exc, out_dir, k)
        raise
    finally:
        if not getattr(env, "is_closed", False):
            env.close()
    return run


def _add_trajectories(run: TrainedRun, env, before: np.ndarray) -> None:
    """Fills ``run.trajectories`` from the open env (a failure is noted, never raised)."""
    from l2calib.train.env_build import trajectory_previews

    after = run.result.extrinsic
    T = torch.stack([torch.as_tensor(before, dtype=torch.float64), after.T_imu_lidar])
    offsets = None
    if after.time_offset_s is not None:
        offsets = torch.tensor([0.0, after.time_offset_s], dtype=torch.float64)
    try:
        previews = trajectory_previews(env, T, offsets)
    except Exception as exc:  # the report's extra must not lose the calibration
        run.problems.append(f"trajectory preview failed: {exc}")
        return
    run.trajectories = [
        {"name": p["name"], "reference": p["reference"], "before": p["positions"][0],
         "after": p["positions"][1]}
        for p in previews
    ]  # fmt: skip


def _vertical_hold(
    recipe: Recipe, data: PreparedData, say: Callable[[str], None], rate_start: bool = False
):
    """The vertical lever-arm hold for this data (``train.hold_vertical_translation``) or None.

    ``rate_start``: the first attempt starts at the rate rotation (the settings it is told).
    """
    from l2calib.train.vertical_hold import decide_hold, planar_train_settings

    hold = decide_hold(recipe.train, recipe.policy.prior, [s.imu for s in data.segments])
    if hold is not None:
        value = f"{100 * hold.value_m:.1f} cm" + (
            " (policy.prior)" if hold.source == "prior" else " (no prior: not a measurement)"
        )
        first = planar_train_settings(recipe.train, rate_start)[1]
        later = planar_train_settings(recipe.train)[1]  # a restart starts from no rotation guess
        restarts = {k: v for k, v in later.items() if k not in first}
        also = "; ".join(
            [_settings_text(first)] * bool(first)
            + [f"restarts (from no rotation guess) also {_settings_text(restarts)}"]
            * bool(restarts)
        )
        say(
            f"planar motion ({hold.motion.describe()}): the lever arm's vertical component "
            f"cannot be determined from it and is held at {value}"
            + (f"; weak-data settings {also} (set them in the recipe to override)" if also else "")
        )
    return hold


def _settings_text(settings: dict[str, Any]) -> str:
    """``train.key: value, ...`` as a recipe would spell them."""
    return ", ".join(f"train.{k}: {'null' if v is None else v}" for k, v in settings.items())


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
        best.candidate_scans = sum(r.candidate_scans for r, _, _ in attempts)
        best.stage_s = {k: sum(r.stage_s.get(k, 0.0) for r, _, _ in attempts) for k in best.stage_s}
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
    hold: Any | None = None,
    start: Any | None = None,
    t_start: Any | None = None,
) -> tuple[CalibrationResult, Any]:
    """One PPO run from scratch with ``seed``, its refinement and its resolution probe.

    ``attempt`` numbers the run (0: the first, k: restart k) in what it tells the user;
    ``hold`` is the env's vertical lever-arm hold (the result carries the held value);
    ``start`` the rotation start from the rates (:mod:`l2calib.train.rotation_start`) or None,
    ``t_start`` the translation start from the accelerations (:mod:`l2calib.train.lever_start`).
    """
    from l2calib.assess import sensitivity
    from l2calib.assess.refine import refine
    from l2calib.assess.result_bounds import bounds_at_result, undetermined_axes
    from l2calib.assess.time_offset_probe import probe_evaluations, probe_time_offset
    from l2calib.plugins import get_plugin
    from l2calib.train.checkpoint import CHECKPOINT_NAME, recipe_fingerprint
    from l2calib.train.ppo import PpoTrainer

    cfg = recipe.train.model_copy(update={"seed": seed})
    planar_changed: dict[str, Any] = {}
    if hold is not None:  # planar motion: the weak-data settings, unless the recipe sets them
        from l2calib.train.vertical_hold import planar_train_settings

        cfg, planar_changed = planar_train_settings(cfg, rate_start=start is not None)
    data_s = sum(s.duration_s for s in data.segments)
    if cfg.coarse_to_fine and data_s > 0:  # never fewer than coarse_min_data_s seconds
        floor = min(1.0, cfg.coarse_min_data_s / data_s)
        cfg = cfg.model_copy(update={"coarse_data_fraction": max(cfg.coarse_data_fraction, floor)})
    torch.manual_seed(seed)
    np.random.seed(seed)
    action_dim = int(env.action_spec.shape[-1])  # 8 with the time offset, else 7
    offset0 = offset_start_s(cfg, data.time_offset_hint_s)
    policy = get_plugin("l2calib.policies", recipe.policy.name).build(
        recipe.policy.options,
        action_dim=action_dim,
        prior=recipe.policy.prior,
        seed=seed,
        **({} if offset0 is None else {"init_time_offset_s": offset0}),
        **({} if start is None else {"rotation_start": start}),
        **({} if t_start is None else {"translation_start": t_start}),
    )
    fingerprint = recipe_fingerprint(recipe.model_dump(mode="json"), data.identity())
    trainer = PpoTrainer(policy, env, cfg, out_dir, fingerprint, hold=hold)
    if resume:
        trainer.resume()
        which = "the first PPO run" if attempt == 0 else f"restart {attempt}"
        say(
            f"resuming {which} (seed {seed}) at iteration {len(trainer.outcome.history)} "
            f"from {out_dir / CHECKPOINT_NAME}"
        )
    say("training")
    clock = time.monotonic()
    outcome = trainer.run(progress)
    stage_s = {"training": time.monotonic() - clock}
    clock = time.monotonic()
    best = policy.mode()  # an Extrinsic from here to the result
    best = Extrinsic(_held(hold, best.T_imu_lidar.detach().clone()), best.time_offset_s)
    refined = None
    if cfg.refine_rounds > 0:
        say(f"refining the result on the reward ({cfg.refine_rounds} batched probe rounds)")
        refined = refine(
            _Scorer(env, best.time_offset_s), best, cfg.refine_rounds, cfg.refine_rot_step_deg,
            cfg.refine_trans_step_m, offset_step_s=cfg.refine_offset_step_s,
        )  # fmt: skip
        best = refined.extrinsic  # the offset was the refinement's seventh axis, if estimated
        best = Extrinsic(_held(hold, best.T_imu_lidar), best.time_offset_s)
        log.info(
            "refine: reward %.5f -> %.5f, moved %.3f deg / %.2f cm (%d evaluations)",
            refined.start_reward, refined.reward, refined.moved_deg, 100 * refined.moved_m,
            refined.evaluations,
        )  # fmt: skip
    polished = None
    if cfg.polish_rounds > 0:
        from l2calib.assess.polish import polish

        say(f"polishing the result: Newton steps on the reward (at most {cfg.polish_rounds})")
        polished = polish(
            _Scorer(env, best.time_offset_s), best, cfg.polish_rounds,
            hold=None if hold is None else hold.apply, first_scale=cfg.polish_first_scale,
        )  # fmt: skip
        best = polished.extrinsic
    T_mode, offset = best.T_imu_lidar, best.time_offset_s
    if offset is None and cfg.known_time_offset_s is not None:  # held, not estimated
        offset = offset0 = float(cfg.known_time_offset_s)
    score = _Scorer(env, offset)
    stage_s["refinement"] = time.monotonic() - clock
    clock = time.monotonic()
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
    axis_unc = None
    if cfg.uncertainty.enabled:
        say("estimating each axis's uncertainty from the data (95 % bounds)")
        axis_unc = bounds_at_result(
            env, T_mode, best.time_offset_s, hold, cfg.uncertainty, data.segments
        )
    stage_s["probe"] = time.monotonic() - clock
    unc = policy.uncertainty() if hold is None else hold.policy_spread(policy.uncertainty())
    sources = sorted({r.source for r in data.references})
    after_training = (
        candidates.shape[0]
        + (refined.evaluations if refined else 0)
        + (polished.evaluations if polished else 0)
        + (probe_evaluations() if offset_res else 0)
        + (axis_unc.evaluations if axis_unc else 0)
    )  # all on the full data
    return CalibrationResult(
        T_imu_lidar=T_mode.numpy(),
        time_offset_s=offset,
        rotation_sigma_deg=unc.rotation_sigma_deg.tolist(),
        translation_sigma_m=unc.translation_sigma_m.tolist(),
        time_offset_sigma_s=unc.time_offset_sigma_s,
        final_reward=resolution.reward,
        evaluations=outcome.evaluations + after_training,
        candidate_scans=outcome.candidate_scans + after_training * outcome.full_scans,
        stage_s=stage_s,
        iterations=len(outcome.history),
        wall_time_s=outcome.wall_s,
        stop_reason=outcome.stop_reason,
        resolution=resolution,
        axis_uncertainty=axis_unc,
        undetermined=([hold.describe()] if hold is not None else [])
        + undetermined_axes(resolution, data.selection, axis_unc, cfg.uncertainty)
        + (offset_res.undetermined() if offset_res else []),
        time_offset_resolution=offset_res,
        time_offset_start_s=(offset0 or 0.0) if offset is not None else None,
        reference_agreement=agreement,
        warnings=disagreement_warnings(agreement, sources),
        extra={
            # which reference the reward compared with, and why (e.g. the recipe's fallback)
            "reference": {"sources": sources, "notes": list(data.notes)},
            **({"refine": refined.summary()} if refined else {}),
            **({"polish": polished.summary()} if polished else {}),
            **(
                {"vertical_hold": {**hold.to_dict(), "train_settings": planar_changed}}
                if hold is not None
                else {}
            ),
        },
    ), outcome


def _held(hold: Any | None, T_imu_lidar: torch.Tensor) -> torch.Tensor:
    """``T_imu_lidar`` with the held vertical translation (unchanged without a hold)."""
    return T_imu_lidar if hold is None else hold.apply(T_imu_lidar)
