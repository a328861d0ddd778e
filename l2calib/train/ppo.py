"""PPO on the single-step calibration MDP with TorchRL (collector, ClipPPOLoss, logger).

One iteration: the collector samples K candidate extrinsics from the policy and the environment
scores them; the value module is the baseline of the one-step episode (advantage ``r - V``,
target ``r``); a few full-batch epochs of ``ClipPPOLoss`` (clipped surrogate + value loss +
entropy bonus) with Adam and gradient clipping follow. The learning rate of the rotation and
translation means follows their current spread; an optional cosine schedule scales all rates.
Training stops on convergence (the policy's mode and spread have settled) or on the budget.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from l2calib import geometry as geo
from l2calib.interrupt import Interrupted, held
from l2calib.recipe import TrainConfig
from l2calib.train.checkpoint import CHECKPOINT_NAME, load_checkpoint, save_checkpoint
from l2calib.train.coarse import data_fraction
from l2calib.train.env_build import set_data_fraction


@dataclass
class IterationRecord:
    """What one iteration produced (one row of the metrics)."""

    iteration: int
    evaluations: int
    wall_s: float
    reward_mean: float
    reward_max: float
    mean_e_t_m: float
    mean_e_r_deg: float
    lost: int
    diverged: int
    translation_m: list[float]
    rpy_deg: list[float]
    time_offset_s: float | None
    rotation_sigma_deg: list[float]
    translation_sigma_m: list[float]
    loss_objective: float
    loss_critic: float
    loss_entropy: float
    lr: float
    time_offset_sigma_s: float | None = None  # the policy's time-offset σ (s), when estimated
    data_fraction: float = 1.0  # of the selected data this iteration scored on (coarse-to-fine)
    candidate_scans: int = 0  # candidates × scans each was estimated on, this iteration

    def scalars(self) -> dict[str, float]:
        """Flat scalars for the logger."""
        out = {k: v for k, v in self.__dict__.items() if isinstance(v, (int, float))}
        for name in ("translation_m", "rpy_deg", "rotation_sigma_deg", "translation_sigma_m"):
            for axis, value in zip("xyz", getattr(self, name), strict=True):
                out[f"{name}_{axis}"] = float(value)
        if self.time_offset_s is not None:
            out["time_offset_s"] = float(self.time_offset_s)
        return out


@dataclass
class TrainOutcome:
    """The end of a training run."""

    history: list[IterationRecord] = field(default_factory=list)
    stop_reason: str = ""
    evaluations: int = 0
    candidate_scans: int = 0  # Σ candidates × scans each was estimated on (0: not counted)
    full_scans: int = 0  # scans per candidate on all the data (what follows training uses)
    wall_s: float = 0.0


def _mode_summary(policy) -> tuple[list[float], list[float], float | None]:
    mode = policy.mode()
    T = mode.T_imu_lidar
    rpy = torch.rad2deg(geo.matrix_to_euler_rpy(T[:3, :3])).tolist()
    return T[:3, 3].tolist(), rpy, mode.time_offset_s


def _converged(history: list[IterationRecord], cfg: TrainConfig) -> bool:
    window = cfg.convergence_window
    if len(history) < window:
        return False
    recent = history[-window:]
    last = recent[-1]
    if max(last.rotation_sigma_deg) > cfg.converged_rotation_sigma_deg:
        return False
    if max(last.translation_sigma_m) > cfg.converged_translation_sigma_m:
        return False
    t = torch.tensor([r.translation_m for r in recent])
    rpy = torch.tensor([r.rpy_deg for r in recent])
    drift_t = float((t - t[-1]).norm(dim=-1).max())
    R = geo.euler_rpy_to_matrix(torch.deg2rad(rpy))
    drift_r = float(torch.rad2deg(geo.rotation_angle(R[-1].T @ R)).max())
    return drift_t < cfg.converged_step_m and drift_r < cfg.converged_step_deg


def _narrow_enough(history: list[IterationRecord], cfg: TrainConfig) -> str | None:
    """Why the policy is narrow enough to hand over to the refinement (a stop reason), or None.

    Late PPO iterations narrow the translation slowly (the reward is shallow there) at the
    full cost of an iteration; the refinement after PPO climbs the same reward
    deterministically from the mode and needs only the right basin. So PPO stops once every
    rotation σ ≤ ``handover_rotation_sigma_deg`` and every translation σ ≤
    ``handover_translation_sigma_m`` (``None``: never), and, where the time offset is
    estimated and ``handover_time_offset_sigma_s`` is set, its σ is at most that too.

    Started at the rate rotation and the lever-arm start, the policy is born narrower than
    the first two gates and hands over after one iteration, its time offset's σ still near
    the start's 20 ms: on 20 s of three simulated ground-vehicle drives (LiDAR-only) the
    refinement then climbed a ridge of time offset, yaw and lateral lever arm to -5.5 ms,
    0.64 deg and 5.9 cm, below the truth's reward. Ground vehicles therefore gate at 10 ms
    (:data:`l2calib.train.vertical_hold.PLANAR_RATE_START`; PPO took 8-14 iterations to get
    there; docs/backends.md, "The hand-over and the time offset").
    """
    if cfg.handover_rotation_sigma_deg is None or not history:
        return None
    last = history[-1]
    if max(last.rotation_sigma_deg) > cfg.handover_rotation_sigma_deg:
        return None
    if max(last.translation_sigma_m) > cfg.handover_translation_sigma_m:
        return None
    gate_s = cfg.handover_time_offset_sigma_s
    offset_text = ""
    if gate_s is not None and last.time_offset_sigma_s is not None:
        if last.time_offset_sigma_s > gate_s:
            return None
        offset_text = f" / {1000 * gate_s:g} ms"
    return (
        f"narrow enough for the refinement after {len(history)} iterations (sigma <= "
        f"{cfg.handover_rotation_sigma_deg:g} deg / {100 * cfg.handover_translation_sigma_m:g} cm"
        f"{offset_text})"
    )


def _plateau(history: list[IterationRecord], cfg: TrainConfig) -> str | None:
    """Why the reward has stopped rising (a stop reason), or ``None``.

    Once the rotation is narrow (σ ≤ ``plateau_rotation_sigma_deg``), the refinement that
    follows PPO finishes faster and more precisely than more PPO iterations: stop when the
    best candidate of the last ``plateau_window`` iterations scored less than
    ``plateau_min_gain`` above the best of the window before. Rewards are compared only on the
    same data, and only on all of it: a part of the data may stop ranking candidates that all
    of it still tells apart (on the simulated ground vehicle, a plateau on partial data ended
    PPO at 20.5 cm / 0.60° where the full budget reached 6.4 cm / 0.22°).
    """
    n = cfg.plateau_window
    if not cfg.stop_on_plateau or len(history) < 2 * n:
        return None
    recent = history[-2 * n :]
    if max(recent[-1].rotation_sigma_deg) > cfg.plateau_rotation_sigma_deg:
        return None
    if any(r.data_fraction < 1.0 for r in recent) or len({r.candidate_scans for r in recent}) > 1:
        return None
    before = max(r.reward_max for r in recent[:n])
    after = max(r.reward_max for r in recent[n:])
    if after - before >= cfg.plateau_min_gain:
        return None
    return (
        f"reward plateau after {len(history)} iterations (best of the last {n}: {after:.4f}, "
        f"of the {n} before: {before:.4f})"
    )


class PpoTrainer:
    """Trains a policy plugin's actor/value on a calibration environment.

    Args:
        policy: A :class:`~l2calib.interfaces.CalibrationPolicy` (built by a policy plugin).
        env: The environment (``CalibrationEnv`` or a ``ParallelEnv`` of them).
        cfg: PPO settings and budgets.
        out_dir: Where checkpoints and metrics go (``None``: nowhere).
        fingerprint: Identity of recipe + data, checked on resume.
        hold: The env's vertical lever-arm hold (:mod:`l2calib.train.vertical_hold`) or
            ``None``; the spreads the trainer judges (hand-over, convergence, data share) are
            then those of the translations actually scored.
    """

    def __init__(
        self,
        policy,
        env,
        cfg: TrainConfig,
        out_dir: Path | None,
        fingerprint: str,
        hold: Any | None = None,
    ):
        from torchrl.collectors import Collector
        from torchrl.envs.utils import ExplorationType
        from torchrl.objectives import ClipPPOLoss

        self.policy, self.env, self.cfg = policy, env, cfg
        self.hold = hold
        self.out_dir = out_dir
        self.fingerprint = fingerprint
        self.K = cfg.candidates_per_iteration
        self.iterations = cfg.iteration_budget
        self.loss = ClipPPOLoss(
            policy.actor,
            policy.value,
            clip_epsilon=cfg.clip_epsilon,
            entropy_coeff=cfg.entropy_coef,
            normalize_advantage=True,
        )
        self.optim = torch.optim.Adam(self._param_groups(), lr=cfg.lr)
        self.collector = Collector(
            env,
            policy.actor,
            frames_per_batch=self.K,
            total_frames=-1,
            exploration_type=ExplorationType.RANDOM,
            auto_register_policy_transforms=False,  # the policy needs no env transform
        )
        self.outcome = TrainOutcome()
        self._saved_iterations: int | None = None  # iterations in the checkpoint on disk
        self._snapshot: dict[str, Any] | None = None  # the state after the last iteration
        self._fraction: float | None = None  # the data fraction the env scores on now
        self._scans = 0  # scans per candidate at that fraction
        self._logger = None
        if out_dir is not None:
            from torchrl.record.loggers.csv import CSVLogger

            self._logger = CSVLogger("metrics", log_dir=str(out_dir))

    def _spread(self):
        """The policy's spreads, translation σ as scored (projected when the env holds it)."""
        spread = self.policy.uncertainty()
        return spread if self.hold is None else self.hold.policy_spread(spread)

    def _param_groups(self) -> list[dict[str, Any]]:
        groups = getattr(self.policy, "param_groups", None)
        if groups is None:
            return [{"params": list(self.loss.parameters()), "role": "other"}]
        return [{"params": params, "role": role} for role, params in groups().items()]

    def _set_learning_rates(self, iteration: int) -> None:
        """Learning rates of this iteration (the schedule is applied by hand, per group).

        The means' step sizes follow their current spread (natural-gradient-like): Adam moves
        every parameter by about ``lr`` per step whatever its gradient, so a fixed rate in metres
        would make the translation mean wander by that much on noisy gradients long after the
        spread has shrunk below it (and crawl while the spread is wide).
        """
        factor = 1.0
        if self.cfg.lr_schedule == "cosine":
            progress = iteration / max(self.iterations - 1, 1)
            factor = 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * progress))
        for group in self.optim.param_groups:
            group["lr"] = self.cfg.lr * factor
        if self.cfg.mean_step_scale <= 0:
            return
        unc = self._spread()
        sigma = {
            "rotation_mean": min(float(unc.rotation_sigma_rad.mean()), 1.0),
            "translation_mean": float(unc.translation_sigma_m.mean()),
        }
        if unc.time_offset_sigma_s is not None:  # s, its own scale (not the translation's m)
            sigma["time_offset_mean"] = unc.time_offset_sigma_s
        for group in self.optim.param_groups:
            if group["role"] in sigma:
                group["lr"] = self.cfg.mean_step_scale * sigma[group["role"]] * factor

    # ------------------------------------------------------------------ checkpoints
    def _generators(self) -> list[torch.Generator]:
        """Sampling generators owned by the policy's modules (TorchRL actors keep their own)."""
        gens = []
        for module in self.policy.modules():
            gen = getattr(module, "_generator", None)
            if isinstance(gen, torch.Generator):
                gens.append(gen)
        return gens

    def _state(self) -> dict[str, Any]:
        return {
            "fingerprint": self.fingerprint,
            "policy": self.policy.state_dict(),
            "optim": self.optim.state_dict(),
            "rng": torch.get_rng_state(),
            "generators": [g.get_state() for g in self._generators()],
            "outcome": self.outcome,
        }

    def resume(self) -> None:
        """Restores the last checkpoint in ``out_dir`` (exact continuation)."""
        state = load_checkpoint(self.out_dir / CHECKPOINT_NAME, self.fingerprint)
        self._saved_iterations = len(state["outcome"].history)
        self.policy.load_state_dict(state["policy"])
        self.optim.load_state_dict(state["optim"])
        torch.set_rng_state(state["rng"])
        for gen, gen_state in zip(self._generators(), state["generators"], strict=True):
            gen.set_state(gen_state)
        self.outcome = state["outcome"]

    def checkpoint(self, state: dict[str, Any] | None = None) -> None:
        """Writes the checkpoint now (``state``: a snapshot taken earlier instead of now)."""
        if self.out_dir is not None:
            state = state if state is not None else self._state()
            save_checkpoint(self.out_dir / CHECKPOINT_NAME, state)
            self._saved_iterations = len(state["outcome"].history)

    def _save_on_interrupt(self, snapshot: dict[str, Any] | None, exc: Interrupted) -> None:
        """Checkpoints the last completed iteration and tells ``exc`` what was kept.

        An iteration cut short is dropped: the snapshot taken at the end of the one before is
        exactly what a periodic checkpoint at that iteration would have written, so a resume
        gives the same result as an uninterrupted run.
        """
        if self.out_dir is None:
            return
        if snapshot is not None and len(snapshot["outcome"].history) != self._saved_iterations:
            self.checkpoint(snapshot)
        if self._saved_iterations is not None:
            exc.iteration = self._saved_iterations
            exc.checkpoint = self.out_dir / CHECKPOINT_NAME

    # ------------------------------------------------------------------ loop
    def _update(self, batch, iteration: int) -> dict[str, float]:
        self._set_learning_rates(iteration)
        with torch.no_grad():
            value = self.policy.value(batch.clone())["state_value"]
        reward = batch["next", "reward"]
        batch["value_target"] = reward  # one-step episodes: the return is the reward
        batch["advantage"] = reward - value
        totals: dict[str, float] = {}
        for _ in range(self.cfg.ppo_epochs):
            losses = self.loss(batch)
            total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
            self.optim.zero_grad()
            total.backward()
            torch.nn.utils.clip_grad_norm_(self.loss.parameters(), self.cfg.max_grad_norm)
            self.optim.step()
            for key in ("loss_objective", "loss_critic", "loss_entropy"):
                totals[key] = float(losses[key].detach())
        return totals

    def run(self, progress: Callable[[IterationRecord], None] | None = None) -> TrainOutcome:
        """Trains until convergence or budget; returns the history and why it stopped.

        Raises:
            Interrupted: on SIGINT / SIGTERM (:mod:`l2calib.interrupt`), after checkpointing the
                last completed iteration.
        """
        self._snapshot = None
        try:
            if self.out_dir is not None:
                self._snapshot = copy.deepcopy(self._state())
            return self._run(progress)
        except Interrupted as exc:
            self._save_on_interrupt(self._snapshot, exc)
            raise

    def _run(self, progress: Callable[[IterationRecord], None] | None) -> TrainOutcome:
        t_start = time.monotonic() - self.outcome.wall_s
        it = len(self.outcome.history)
        collector_iter = iter(self.collector)
        # Scans per candidate on all the data: the share an iteration scored on is the backend's
        # answer over this, not the fraction asked (a continuous run always uses all of it).
        full = set_data_fraction(self.env, 1.0)
        self._fraction, self._scans = 1.0, full
        while True:
            if it >= self.iterations:
                self.outcome.stop_reason = (
                    f"budget: {it} iterations, {self.outcome.evaluations} evaluations"
                )
                break
            if _converged(self.outcome.history, self.cfg):
                self.outcome.stop_reason = f"converged after {it} iterations"
                break
            early = _narrow_enough(self.outcome.history, self.cfg) or _plateau(
                self.outcome.history, self.cfg
            )
            if early is not None:
                self.outcome.stop_reason = early
                break
            fraction = data_fraction(self._spread(), self.cfg)
            if fraction != self._fraction:  # one round trip to the workers when it changes
                self._fraction, self._scans = fraction, set_data_fraction(self.env, fraction)
            scans = self._scans
            batch = next(collector_iter).reshape(-1)
            with held():  # a signal here would come out of TorchRL's loss as another error
                losses = self._update(batch, it)
            self.collector.update_policy_weights_()
            self.outcome.evaluations += int(batch.numel())
            self.outcome.candidate_scans += int(batch.numel()) * scans
            record = self._record(it, batch, losses, time.monotonic() - t_start)
            record.data_fraction = scans / full if full > 0 else 1.0
            record.candidate_scans = int(batch.numel()) * scans
            self.outcome.history.append(record)
            self.outcome.wall_s = record.wall_s
            if self._logger is not None:
                for key, value in record.scalars().items():
                    self._logger.log_scalar(key, value, step=it)
            it += 1
            if self.out_dir is not None:
                # what a checkpoint now would hold, kept for an interruption in the next one
                self._snapshot = copy.deepcopy(self._state())
                if it % self.cfg.checkpoint_every == 0:
                    self.checkpoint(self._snapshot)
            if progress is not None:
                progress(record)
        self.checkpoint()
        if self._fraction != 1.0:  # what follows (refinement, probes) sees all the data
            set_data_fraction(self.env, 1.0)
        self.outcome.full_scans = full
        self._fraction = None
        # The env stays open: the refinement and the probe score on its workers; its owner
        # closes it.
        self.collector.shutdown(close_env=False)
        return self.outcome

    def _record(self, it: int, batch, losses: dict[str, float], wall_s: float) -> IterationRecord:
        reward = batch["next", "reward"].reshape(-1)
        status = batch["next", "status"].reshape(-1)
        e_t = batch["next", "mean_e_t"].reshape(-1)
        e_r = batch["next", "mean_e_r"].reshape(-1)
        best = int(reward.argmax())
        t, rpy, off = _mode_summary(self.policy)
        unc = self._spread()
        return IterationRecord(
            iteration=it,
            evaluations=self.outcome.evaluations,
            wall_s=wall_s,
            reward_mean=float(reward.mean()),
            reward_max=float(reward.max()),
            mean_e_t_m=float(e_t[best]),
            mean_e_r_deg=math.degrees(float(e_r[best])) if float(e_r[best]) >= 0 else -1.0,
            lost=int((status == 2).sum()),
            diverged=int((status == 1).sum()),
            translation_m=t,
            rpy_deg=rpy,
            time_offset_s=off,
            rotation_sigma_deg=unc.rotation_sigma_deg.tolist(),
            translation_sigma_m=unc.translation_sigma_m.tolist(),
            time_offset_sigma_s=unc.time_offset_sigma_s,
            lr=float(self.optim.param_groups[-1]["lr"]),
            **losses,
        )
