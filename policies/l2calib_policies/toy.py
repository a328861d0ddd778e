"""A toy single-step calibration problem with a known optimum, trained by TorchRL's PPO.

No odometry: the reward of a candidate ``(q, t)`` is
``exp(-θ(q, q*)/θ0 - |t - t*|/d0)`` with ``θ`` the geodesic rotation angle. It exercises the
same pieces the real trainer uses (``ProbabilisticActor`` sampling with
``ExplorationType.RANDOM``, ``"action_log_prob"``, ``ClipPPOLoss`` with the entropy bonus, the
value module as the baseline of a one-step episode) and is the acceptance test of the policies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import ClipPPOLoss

from l2calib.geometry import quat_to_matrix, rotation_angle
from l2calib.plugins import get_plugin


def toy_reward(
    action: Tensor, q_star: Tensor, t_star: Tensor, theta0: float = 0.5, d0: float = 0.2
) -> Tensor:
    """Reward ``[...]`` of actions ``[..., 7]`` for the optimum ``(q*, t*)``."""
    R = quat_to_matrix(action[..., :4])
    R_star = quat_to_matrix(q_star).expand_as(R)
    theta = rotation_angle(R_star.transpose(-1, -2) @ R)
    dist = (action[..., 4:7] - t_star).norm(dim=-1)
    return torch.exp(-theta / theta0 - dist / d0)


@dataclass
class ToyResult:
    """Per-iteration history of a toy run (errors of the policy's mode)."""

    rotation_error_deg: list[float] = field(default_factory=list)
    translation_error_m: list[float] = field(default_factory=list)
    mean_reward: list[float] = field(default_factory=list)
    rotation_sigma_deg: list[list[float]] = field(default_factory=list)


def run_toy_ppo(
    policy_name: str,
    q_star: Tensor,
    t_star: Tensor,
    iterations: int = 200,
    candidates: int = 32,
    epochs: int = 4,
    lr: float = 3e-2,
    entropy_coef: float = 1e-3,
    seed: int = 0,
    options: dict | None = None,
) -> ToyResult:
    """Trains a policy plugin on :func:`toy_reward` from "no idea" and records its mode error.

    Args:
        policy_name: ``"bingham"`` or ``"gaussian"``.
        q_star: Optimum rotation (xyzw) ``[4]``.
        t_star: Optimum translation (m) ``[3]``.
        iterations: PPO iterations (each: ``candidates`` samples, ``epochs`` full-batch steps).
        candidates: Actions sampled per iteration.
        epochs: Gradient steps per iteration.
        lr: Adam learning rate (cosine-annealed to 10 % over the run).
        entropy_coef: PPO entropy bonus.
        seed: Seeds the actor's sampler.
        options: Plugin options.

    Returns:
        The history of the mode's errors, mean reward and rotation σ per iteration.
    """
    torch.manual_seed(seed)
    policy = get_plugin("l2calib.policies", policy_name).build(
        options or {}, action_dim=7, prior=None, seed=seed
    )
    loss = ClipPPOLoss(
        policy.actor, policy.value, entropy_coeff=entropy_coef, normalize_advantage=True
    )
    opt = torch.optim.Adam(loss.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iterations * epochs, eta_min=0.1 * lr)
    q_star = q_star.to(torch.float64)
    t_star = t_star.to(torch.float64)
    out = ToyResult()
    for _ in range(iterations):
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            td = policy.actor(policy.observation((candidates,)))
            reward = toy_reward(td["action"], q_star, t_star)[..., None]
            value = policy.value(td.clone())["state_value"]
        # One-step episodes: the value target is the reward, the advantage r - V.
        td["value_target"] = reward
        td["advantage"] = reward - value
        for _ in range(epochs):
            losses = loss(td)
            total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
            opt.zero_grad()
            total.backward()
            torch.nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
            opt.step()
            sched.step()
        mode = policy.mode()
        R_err = quat_to_matrix(q_star).T @ mode["T_imu_lidar"][:3, :3]
        out.rotation_error_deg.append(math.degrees(float(rotation_angle(R_err))))
        out.translation_error_m.append(float((mode["t_imu_lidar"] - t_star).norm()))
        out.mean_reward.append(float(reward.mean()))
        out.rotation_sigma_deg.append(policy.uncertainty()["rotation_sigma_deg"].tolist())
    return out
