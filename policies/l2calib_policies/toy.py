"""A toy single-step calibration problem with a known optimum, trained by the real trainer.

No odometry: the reward of a candidate ``(q, t)`` is
``exp(-θ(q, q*)/θ0 - |t - t*|/d0)`` with ``θ`` the geodesic rotation angle. :class:`ToyEnv`
has the calibration environment's specs (it shares :class:`l2calib.train.env.ScoringEnv`), and
:func:`run_toy_ppo` trains a policy plugin on it with the production
:class:`l2calib.train.ppo.PpoTrainer` (TorchRL collector, ``ClipPPOLoss``, the same learning-rate
rules), so there is one training loop in the project. It is the acceptance test of the policies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from l2calib.geometry import quat_to_matrix, rotation_angle
from l2calib.plugins import get_plugin
from l2calib.reward import RewardBreakdown
from l2calib.train.env import ScoringEnv


def toy_reward(
    action: Tensor, q_star: Tensor, t_star: Tensor, theta0: float = 0.5, d0: float = 0.2
) -> Tensor:
    """Reward ``[...]`` of actions ``[..., 7]`` for the optimum ``(q*, t*)``."""
    theta, dist = _errors(quat_to_matrix(action[..., :4]), action[..., 4:7], q_star, t_star)
    return torch.exp(-theta / theta0 - dist / d0)


def _errors(R: Tensor, t: Tensor, q_star: Tensor, t_star: Tensor) -> tuple[Tensor, Tensor]:
    """Geodesic angle (rad) and distance (m) of ``(R [..., 3, 3], t [..., 3])`` from the optimum."""
    R_star = quat_to_matrix(q_star.to(R.dtype)).expand_as(R)
    return rotation_angle(R_star.transpose(-1, -2) @ R), (t - t_star.to(t.dtype)).norm(dim=-1)


class ToyEnv(ScoringEnv):
    """Scores K candidates with :func:`toy_reward` (``mean_e_t``: distance, ``mean_e_r``: angle).

    Args:
        q_star: Optimum rotation (xyzw) ``[4]``.
        t_star: Optimum translation (m) ``[3]``.
        num_candidates: K, the batch size.
    """

    def __init__(self, q_star: Tensor, t_star: Tensor, num_candidates: int) -> None:
        super().__init__(num_candidates, action_dim=7)
        self.q_star, self.t_star = q_star, t_star

    def score_candidates(self, T_imu_lidar: Tensor, time_offset_s: Tensor | None = None):
        """The toy reward of ``T_imu_lidar [K, 4, 4]``; every candidate's status is OK (0)."""
        R, t = T_imu_lidar[:, :3, :3], T_imu_lidar[:, :3, 3]
        theta, dist = _errors(R, t, self.q_star, self.t_star)
        reward = torch.exp(-theta / 0.5 - dist / 0.2)  # toy_reward's defaults
        K = T_imu_lidar.shape[0]
        self.evaluations += K
        ones = torch.ones(K, dtype=torch.int64)
        return RewardBreakdown(reward, dist, theta, ones), torch.zeros(K, dtype=torch.int64)


@dataclass
class ToyResult:
    """Per-iteration history of a toy run (errors of the policy's mode)."""

    rotation_error_deg: list[float] = field(default_factory=list)
    translation_error_m: list[float] = field(default_factory=list)
    mean_reward: list[float] = field(default_factory=list)
    rotation_sigma_deg: list[list[float]] = field(default_factory=list)
    stop_reason: str = ""


def run_toy_ppo(
    policy_name: str,
    q_star: Tensor,
    t_star: Tensor,
    iterations: int = 200,
    candidates: int = 32,
    seed: int = 0,
    options: dict | None = None,
    **train: float | int | str,
) -> ToyResult:
    """Trains a policy plugin on :func:`toy_reward` from "no idea" and records its mode error.

    Args:
        policy_name: ``"bingham"`` or ``"gaussian"``.
        q_star: Optimum rotation (xyzw) ``[4]``.
        t_star: Optimum translation (m) ``[3]``.
        iterations: Most PPO iterations (the trainer's convergence rule may stop it sooner).
        candidates: Actions sampled per iteration.
        seed: Seeds the actor's sampler.
        options: Plugin options.
        **train: Other ``train`` recipe fields (``lr``, ``ppo_epochs``, ...); the production
            defaults otherwise, except the early stops that hand over to the refinement
            (the toy has none: PPO alone must converge here).

    Returns:
        The history of the mode's errors, mean reward and rotation σ per iteration.
    """
    from l2calib.recipe import TrainConfig
    from l2calib.train.ppo import PpoTrainer

    torch.manual_seed(seed)
    cfg = TrainConfig(
        seed=seed,
        candidates_per_iteration=candidates,
        max_iterations=iterations,
        max_evaluations=iterations * candidates,
        workers=1,
        **{"handover_rotation_sigma_deg": None, "stop_on_plateau": False, **train},
    )
    policy = get_plugin("l2calib.policies", policy_name).build(
        options or {}, action_dim=7, prior=None, seed=seed
    )
    env = ToyEnv(q_star, t_star, candidates)
    out = ToyResult()

    def record(rec) -> None:
        T = policy.mode().T_imu_lidar
        theta, dist = _errors(T[:3, :3], T[:3, 3], q_star, t_star)
        out.rotation_error_deg.append(math.degrees(float(theta)))
        out.translation_error_m.append(float(dist))
        out.mean_reward.append(rec.reward_mean)
        out.rotation_sigma_deg.append(list(rec.rotation_sigma_deg))

    trainer = PpoTrainer(policy, env, cfg, out_dir=None, fingerprint="toy")
    try:
        out.stop_reason = trainer.run(record).stop_reason
    finally:
        env.close()
    return out
