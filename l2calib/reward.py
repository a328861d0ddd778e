"""Rewards that turn trajectory agreement into a number in (0, 1].

* ``paper`` (L2Calib, Sec. III-C): after Umeyama-aligning the reference onto the estimate,

  ``R = exp(-sqrt(Σ e_t / (4N)) - sqrt(Σ e_r / (π² N)))``

  with ``e_t(i) = |R_e(i) t_BA + t_e(i) - t_r(i)|`` and
  ``e_r(i) = arccos((tr(R_e(i) R_BA R_r(i)ᵀ) - 1) / 2)``: the estimated IMU pose composed with the
  candidate extrinsic (= estimated LiDAR pose) against the aligned reference LiDAR pose. Note the
  paper sums the errors themselves, not their squares.
* ``position``: ``exp(-RMSE_t / 2)``, what the paper's public code computes; also used when the
  reference constrains positions only (RTK).

A candidate whose odometry failed gets reward 0 (worse than any finite error), never a score
computed on the poses it produced before failing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from l2calib.alignment import align_reference_to_estimates, pose_errors

RewardKind = Literal["paper", "position"]
AlignKind = Literal["se3", "sim3", "none"]


@dataclass(frozen=True)
class RewardBreakdown:
    """Reward and its ingredients for K candidates.

    Attributes:
        reward: ``[K]`` in ``[0, 1]``.
        mean_e_t: ``[K]`` mean translation error (m) over valid poses.
        mean_e_r: ``[K]`` mean rotation error (rad) over valid poses (NaN if not used).
        num_poses: ``[K]`` number of poses that entered the reward.
    """

    reward: Tensor
    mean_e_t: Tensor
    mean_e_r: Tensor
    num_poses: Tensor


def paper_reward(
    e_t: Tensor, e_r: Tensor, valid: Tensor | None = None, valid_r: Tensor | None = None
) -> Tensor:
    """``exp(-sqrt(Σe_t/(4N)) - sqrt(Σe_r/(π²N)))`` over the last dim (paper, Sec. III-C).

    ``valid`` masks the poses of both terms; ``valid_r``, when given, those of the rotation term
    (a term over no pose is 0).
    """
    w = torch.ones_like(e_t) if valid is None else valid.to(e_t.dtype)
    w_r = w if valid_r is None else valid_r.to(e_r.dtype)
    term_t = torch.sqrt((e_t * w).sum(-1) / (4 * w.sum(-1).clamp_min(1)))
    term_r = torch.sqrt((e_r * w_r).sum(-1) / (math.pi**2 * w_r.sum(-1).clamp_min(1)))
    return torch.exp(-term_t - term_r)


def position_reward(e_t: Tensor, valid: Tensor | None = None) -> Tensor:
    """``exp(-RMSE_t / 2)`` over the last dim (the paper's public code)."""
    w = torch.ones_like(e_t) if valid is None else valid.to(e_t.dtype)
    n = w.sum(-1).clamp_min(1)
    return torch.exp(-torch.sqrt((e_t**2 * w).sum(-1) / n) / 2)


def lidar_poses_from_imu(T_world_imu: Tensor, T_imu_lidar: Tensor) -> Tensor:
    """Estimated LiDAR poses ``T_world_imu · T_imu_lidar`` (``[K, N, 4, 4]`` and ``[K, 4, 4]``)."""
    return T_world_imu @ T_imu_lidar[..., None, :, :]


def aligned_errors(
    T_ref_lidar: Tensor,
    T_est_lidar: Tensor,
    valid: Tensor | None = None,
    align: AlignKind = "se3",
) -> tuple[Tensor, Tensor]:
    """Per-pose errors ``e_t [K, N]`` (m) and ``e_r [K, N]`` (rad) after aligning the reference.

    Args:
        T_ref_lidar: ``[N, 4, 4]`` (or ``[K, N, 4, 4]``) reference LiDAR poses at the estimate's
            stamps (see :func:`l2calib.alignment.associate`).
        T_est_lidar: ``[K, N, 4, 4]`` estimated LiDAR poses.
        valid: ``[K, N]`` poses that exist in both (others may hold anything, even NaN).
        align: ``"se3"`` (Umeyama on positions, the paper), ``"sim3"``, or ``"none"`` when the
            estimate is already expressed in the reference's frame (e.g. a backend started from
            the reference pose): position-only alignment of a nearly straight trajectory leaves
            the rotation about its direction to noise, which then pollutes ``e_r``.
    """
    K, N = T_est_lidar.shape[:2]
    if valid is None:
        valid = torch.ones(K, N, dtype=torch.bool, device=T_est_lidar.device)
    # Neutralise invalid poses so they cannot poison the masked sums of the alignment.
    eye = torch.eye(4, dtype=T_est_lidar.dtype, device=T_est_lidar.device)
    T_est_lidar = torch.where(valid[..., None, None], T_est_lidar, eye)
    if align == "none":
        aligned = T_ref_lidar.expand_as(T_est_lidar)
    else:
        aligned = align_reference_to_estimates(T_ref_lidar, T_est_lidar, valid, align == "sim3")
    return pose_errors(T_est_lidar, aligned)


def score(
    e_t: Tensor,
    e_r: Tensor,
    valid: Tensor,
    kind: RewardKind = "paper",
    valid_r: Tensor | None = None,
    failed: Tensor | None = None,
    min_poses: int = 3,
) -> RewardBreakdown:
    """Turns per-pose errors ``[K, N]`` (possibly pooled from several segments) into rewards.

    Args:
        e_t: Translation errors (m).
        e_r: Rotation errors (rad).
        valid: Poses that enter the translation term.
        kind: ``"paper"`` or ``"position"``.
        valid_r: Poses that enter the rotation term (default: ``valid``); poses of
            position-only references (RTK) are excluded here, which drops their rotation term.
        failed: ``[K]`` candidates whose odometry failed: reward 0.
        min_poses: Candidates with fewer valid poses than this get reward 0.
    """
    valid_r = valid if valid_r is None else valid_r & valid
    w = valid.to(e_t.dtype)
    n = w.sum(-1)
    if kind == "paper":
        reward = paper_reward(e_t, e_r, valid, valid_r)
    elif kind == "position":
        reward = position_reward(e_t, valid)
    else:
        raise ValueError(f"unknown reward kind {kind!r}")
    bad = n < min_poses
    if failed is not None:
        bad = bad | failed.to(torch.bool)
    reward = torch.where(bad, torch.zeros_like(reward), reward)
    mean_t = (e_t * w).sum(-1) / n.clamp_min(1)
    n_r = valid_r.sum(-1)
    mean_r = torch.where(
        n_r > 0, (e_r * valid_r).sum(-1) / n_r.clamp_min(1), torch.full_like(mean_t, float("nan"))
    )
    return RewardBreakdown(reward, mean_t, mean_r, n.to(torch.int64))


def trajectory_reward(
    T_ref_lidar: Tensor,
    T_est_lidar: Tensor,
    valid: Tensor | None = None,
    kind: RewardKind = "paper",
    use_rotation: bool = True,
    failed: Tensor | None = None,
    min_poses: int = 3,
    align: AlignKind = "se3",
) -> RewardBreakdown:
    """Aligns the reference onto each estimate and scores the candidates (one segment).

    See :func:`aligned_errors` and :func:`score`; ``use_rotation=False`` drops the rotation
    term (position-only references).
    """
    K, N = T_est_lidar.shape[:2]
    if valid is None:
        valid = torch.ones(K, N, dtype=torch.bool, device=T_est_lidar.device)
    e_t, e_r = aligned_errors(T_ref_lidar, T_est_lidar, valid, align)
    valid_r = valid if use_rotation else torch.zeros_like(valid)
    return score(e_t, e_r, valid, kind, valid_r, failed, min_poses)
