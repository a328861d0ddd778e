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

AXES = ("x", "y", "z")


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


def compute_references(recipe: Recipe, segments: Sequence[Segment]) -> list[ReferenceTrajectory]:
    """Runs the recipe's reference plugin on the segments."""
    from l2calib.plugins import get_plugin

    source = get_plugin("l2calib.references", recipe.reference.name).build(
        recipe.reference.options, data=recipe.data
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
    references = compute_references(recipe, segments)
    return PreparedData(list(sequences), segments, references, selection)


def undetermined_axes(
    rotation_sigma_deg: Sequence[float],
    translation_sigma_m: Sequence[float],
    selection: Any | None,
    rot_limit_deg: float = 1.0,
    trans_limit_m: float = 0.05,
) -> list[str]:
    """Axes the data could not determine: wide policy spread or weak excitation."""
    out = [
        f"rotation about {a} (sigma {s:.2f} deg)"
        for a, s in zip(AXES, rotation_sigma_deg, strict=True)
        if s > rot_limit_deg
    ]
    out += [
        f"translation along {a} (sigma {100 * s:.1f} cm)"
        for a, s in zip(AXES, translation_sigma_m, strict=True)
        if s > trans_limit_m
    ]
    if selection is not None:
        out += [f"weakly excited: {w}" for w in selection.weak_axes]
    return out


def _score_mode(env, action: torch.Tensor) -> float:
    """Reward of the policy's mode (one backend evaluation per worker)."""
    from l2calib.env import CalibrationEnv, action_to_extrinsic

    if isinstance(env, CalibrationEnv):
        T, offset = action_to_extrinsic(action[None])
        breakdown, _ = env.score_candidates(T, offset)
        return float(breakdown.reward[0])
    td = env.reset()
    td["action"] = action.expand(*td.batch_size, action.shape[-1]).clone()
    return float(env.step(td)["next", "reward"].reshape(-1)[0])


def train_policy(
    recipe: Recipe,
    data: PreparedData,
    out_dir: Path | None,
    resume: bool = False,
    progress: Callable[[Any], None] | None = None,
    stage: Callable[[str], None] | None = None,
) -> tuple[CalibrationResult, Any]:
    """Builds env + policy from the recipe, runs PPO; returns the calibration and the outcome."""
    from l2calib.plugins import get_plugin
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
    action = torch.cat(
        [
            torch.from_numpy(CalibrationResult(np.asarray(mode["T_imu_lidar"])).quat_xyzw),
            torch.as_tensor(mode["T_imu_lidar"])[:3, 3],
        ]
        + ([torch.tensor([mode["time_offset_s"]])] if cfg.estimate_time_offset else [])
    ).to(torch.float64)
    final_reward = _score_mode(env, action)
    env.close()
    unc = policy.uncertainty()
    rot_sigma = [float(x) for x in unc["rotation_sigma_deg"]]
    trans_sigma = [float(x) for x in unc["translation_sigma_m"]]
    return CalibrationResult(
        T_imu_lidar=np.asarray(mode["T_imu_lidar"], dtype=np.float64),
        time_offset_s=mode.get("time_offset_s") if cfg.estimate_time_offset else None,
        rotation_sigma_deg=rot_sigma,
        translation_sigma_m=trans_sigma,
        time_offset_sigma_s=unc.get("time_offset_sigma_s"),
        final_reward=final_reward,
        evaluations=outcome.evaluations + 1,
        iterations=len(outcome.history),
        wall_time_s=outcome.wall_s,
        stop_reason=outcome.stop_reason,
        undetermined=undetermined_axes(rot_sigma, trans_sigma, data.selection),
    ), outcome
