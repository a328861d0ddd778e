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

from l2calib.data import Segment
from l2calib.data import Sequence as DataSequence
from l2calib.errors import DataError
from l2calib.interfaces import ReferenceTrajectory
from l2calib.outputs.calibration_file import CalibrationResult
from l2calib.recipe import Recipe

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


def read_sequences(recipe: Recipe, bags: Sequence[Path], progress: bool = False):
    """Opens the bags as sequences with the recipe's topics and conventions."""
    from l2calib.io.sequences import open_sequences

    return open_sequences([Path(b) for b in bags], recipe.data, progress=progress)


def select_segments(recipe: Recipe, sequences: Sequence[DataSequence]):
    """Segments to calibrate on: the selection's windows, or every sequence whole."""
    if not recipe.selection.enabled:
        return [seq.segment() for seq in sequences], None
    from l2calib.selection.greedy import select_windows

    selection = select_windows(sequences, recipe.selection)
    if not selection.chosen:
        raise DataError(
            "the data selection found no informative window (the recordings are still or too "
            "short for selection.window_s)",
            fix="record some motion, lower selection.window_s, or set selection.enabled=false",
        )
    return selection.segments(sequences), selection


def compute_references(
    recipe: Recipe,
    segments: Sequence[Segment],
    sequences: Sequence[DataSequence] | None = None,
) -> list[ReferenceTrajectory]:
    """Runs the recipe's reference plugin on the segments.

    Args:
        recipe: The resolved recipe (``reference`` and ``data`` sections are used).
        segments: Selected segments.
        sequences: The sequences the segments were cut from: LiDAR-odometry references start
            ``margin_s`` before each segment on their scans (warm-up).
    """
    from l2calib.plugins import get_plugin

    source = get_plugin("l2calib.references", recipe.reference.name).build(
        recipe.reference.options, data=recipe.data, sequences=sequences
    )
    refs = source.compute(list(segments))
    if any(r.constrains == "position" for r in refs):
        log.info("the reference constrains positions only: the reward's rotation term is dropped")
    return refs


def prepare_data(
    recipe: Recipe,
    bags: Sequence[Path] | None = None,
    sequences: Sequence[DataSequence] | None = None,
    stage: Callable[[str], None] | None = None,
) -> PreparedData:
    """Reads (or takes) sequences, selects segments and computes their references."""
    say = stage or (lambda _msg: None)
    if sequences is None:
        say("reading recordings")
        sequences = read_sequences(recipe, bags or [])
    say("selecting informative data")
    segments, selection = select_segments(recipe, sequences)
    say(f"computing the {recipe.reference.name} reference")
    references = compute_references(recipe, segments, sequences)
    return PreparedData(list(sequences), segments, references, selection)


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


#: Mean odometry-vs-reference error at the result above which the reference (or the odometry)
#: is named as unreliable. Measured on the simulator at the true extrinsic: 0.3–0.6 cm and
#: 0.01–0.04° with the true LiDAR trajectory (handheld, uav, ugv; OS1-16 and MID-360) or with
#: ct-lidar (handheld MID-360); 103 cm and 4.6° with KISS-ICP on a
#: hand-swung 16-beam LiDAR (whose calibration is then 43 cm off while every axis looks sharp);
#: ~50 cm / 50° at the local optimum a ugv single-sequence run stopped in (137 cm / 180° off).
DISAGREEMENT_LIMITS = {"translation_m": 0.03, "rotation_deg": 0.5}


def disagreement_warnings(agreement: dict[str, float | None], sources: Sequence[str]) -> list[str]:
    """A warning when the odometry and the reference still disagree at the calibrated extrinsic.

    The resolution probe measures how sharp the reward is, not whether its peak is in the right
    place: a reference that is itself wrong gives a sharp peak at a wrong extrinsic, and a search
    stuck in a local optimum looks sharp too. Both show as a large remaining error between the
    odometry and the reference.

    Args:
        agreement: mean errors at the result, ``translation_m`` (m) and ``rotation_deg`` (deg;
            ``None`` when the reference has no orientation).
        sources: the references' source names, for the message.
    """
    if not any(v is not None and v > DISAGREEMENT_LIMITS[k] for k, v in agreement.items()):
        return []
    t, r = agreement["translation_m"], agreement["rotation_deg"]
    size = " / ".join(txt for txt in (_fmt(t, 100, "cm", 1), _fmt(r, 1, "deg", 2)) if txt)
    return [
        f"even at the calibrated extrinsic the odometry and the reference "
        f"({', '.join(sources)}) disagree by {size} on average (a few mm with a good "
        "reference): the reference or the odometry is inaccurate on this data, or the search "
        "stopped far from the best extrinsic, and the result may be off by as much; check the "
        "reference (docs/references.md), use a more accurate one, or calibrate over more "
        "sequences"
    ]


def _fmt(value: float | None, scale: float, unit: str, digits: int) -> str:
    return "" if value is None else f"{scale * value:.{digits}f} {unit}"


def _finite_or_none(value: Any, digits: int) -> float | None:
    v = float(value)
    return round(v, digits) if np.isfinite(v) else None


class _Scorer:
    """Rewards ``[N]`` of ``N`` extrinsics in this process, one batched backend call each.

    Uses the training env when it is in this process; with worker processes, builds one local
    env on first use (the same recipe, segments and references) and reuses it.
    """

    def __init__(self, recipe: Recipe, env, data: PreparedData, time_offset_s: float | None):
        from l2calib.env import CalibrationEnv

        self.recipe, self.data, self.offset = recipe, data, time_offset_s
        self.env = env if isinstance(env, CalibrationEnv) else None
        self.last = None  # the latest call's RewardBreakdown (reward ingredients per candidate)

    def __call__(self, T_imu_lidar: torch.Tensor) -> torch.Tensor:
        from l2calib.train.envs import make_env

        n = T_imu_lidar.shape[0]
        if self.env is None:
            recipe, data = self.recipe, self.data
            self.env = make_env(recipe.model_dump(mode="json"), data.segments, data.references, n)
        offsets = None
        if self.offset is not None:
            offsets = torch.full((n,), float(self.offset), dtype=torch.float64)
        breakdown, _ = self.env.score_candidates(T_imu_lidar, offsets)
        self.last = breakdown
        return breakdown.reward.detach().to(torch.float64)


def train_policy(
    recipe: Recipe,
    data: PreparedData,
    out_dir: Path | None,
    resume: bool = False,
    progress: Callable[[Any], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> tuple[CalibrationResult, Any]:
    """Builds env + policy from the recipe, runs PPO; returns the calibration and the outcome."""
    from l2calib import sensitivity
    from l2calib.plugins import get_plugin
    from l2calib.refine import refine
    from l2calib.train.checkpoint import recipe_fingerprint
    from l2calib.train.envs import make_training_env
    from l2calib.train.ppo import PpoTrainer

    say = stage or (lambda _msg: None)
    cfg = recipe.train
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    say(f"preparing the {recipe.backend.name} odometry")
    env = make_training_env(recipe, data.segments, data.references)
    action_dim = 8 if cfg.estimate_time_offset else 7
    policy = get_plugin("l2calib.policies", recipe.policy.name).build(
        recipe.policy.options, action_dim=action_dim, prior=recipe.policy.prior, seed=cfg.seed
    )
    fingerprint = recipe_fingerprint(recipe.model_dump(mode="json"), data.identity())
    trainer = PpoTrainer(policy, env, cfg, out_dir, fingerprint)
    if resume:
        trainer.resume()
    say("training")
    outcome = trainer.run(progress)
    mode = policy.mode()
    T_mode = torch.as_tensor(np.asarray(mode["T_imu_lidar"]), dtype=torch.float64)
    offset = mode.get("time_offset_s") if cfg.estimate_time_offset else None
    score = _Scorer(recipe, env, data, offset)
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
    rewards = score(candidates)
    if not getattr(env, "is_closed", False):  # the collector may have closed worker envs
        env.close()
    resolution = sensitivity.resolve(rewards)
    agreement = {  # probe candidate 0 is the result itself (rotation: None for RTK positions)
        "translation_m": _finite_or_none(score.last.mean_e_t[0], 5),
        "rotation_deg": _finite_or_none(torch.rad2deg(score.last.mean_e_r[0]), 4),
    }
    unc = policy.uncertainty()
    rot_sigma = [float(x) for x in unc["rotation_sigma_deg"]]
    trans_sigma = [float(x) for x in unc["translation_sigma_m"]]
    return CalibrationResult(
        T_imu_lidar=T_mode.numpy(),
        time_offset_s=offset,
        rotation_sigma_deg=rot_sigma,
        translation_sigma_m=trans_sigma,
        time_offset_sigma_s=unc.get("time_offset_sigma_s"),
        final_reward=resolution.reward,
        evaluations=outcome.evaluations
        + candidates.shape[0]
        + (refined.evaluations if refined else 0),
        iterations=len(outcome.history),
        wall_time_s=outcome.wall_s,
        stop_reason=outcome.stop_reason,
        resolution=resolution,
        undetermined=undetermined_axes(resolution, data.selection),
        reference_agreement=agreement,
        warnings=disagreement_warnings(agreement, sorted({r.source for r in data.references})),
        extra={"refine": _refine_summary(refined)} if refined else {},
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
