from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from l2calib import geometry as geo
from l2calib.reward import lidar_poses_from_imu, paper_reward, position_reward, trajectory_reward


def _imu_trajectory(n=200, seed=0):
    """A rotating, translating IMU trajectory (so a wrong extrinsic cannot be aligned away)."""
    t = np.linspace(0, 20, n)
    rotvec = np.column_stack([0.6 * np.sin(0.7 * t), 0.5 * np.sin(1.1 * t + 1), 0.9 * t])
    pos = np.column_stack([3 * np.cos(0.3 * t), 2 * np.sin(0.4 * t), 0.5 * np.sin(0.9 * t)])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:, :3, 3] = pos
    return torch.from_numpy(T)


T_IMU_LIDAR = geo.make_transform(
    geo.euler_rpy_to_matrix(torch.tensor([0.1, -0.2, 0.3])), torch.tensor([0.3, -0.1, 0.05])
)


def test_identical_trajectories_score_one():
    T_world_imu = _imu_trajectory()
    ref = T_world_imu @ T_IMU_LIDAR
    est = lidar_poses_from_imu(T_world_imu[None], T_IMU_LIDAR[None])
    out = trajectory_reward(ref, est)
    # Alignment of identical trajectories leaves only float64 round-off (sqrt amplifies it).
    assert abs(float(out.reward[0]) - 1.0) < 1e-7
    # Without alignment, zero errors give exactly 1.
    zeros = torch.zeros(1, 50)
    assert float(paper_reward(zeros, zeros)[0]) == 1.0
    assert float(position_reward(zeros)[0]) == 1.0


def test_reward_formula_matches_paper():
    e_t = torch.tensor([[0.1, 0.3, 0.2]])
    e_r = torch.tensor([[0.01, 0.02, 0.03]])
    expected = math.exp(-math.sqrt(0.6 / 12) - math.sqrt(0.06 / (math.pi**2 * 3)))
    assert abs(float(paper_reward(e_t, e_r)[0]) - expected) < 1e-15
    rmse = math.sqrt((0.01 + 0.09 + 0.04) / 3)
    assert abs(float(position_reward(e_t)[0]) - math.exp(-rmse / 2)) < 1e-15


def _rewards_for(perturbations: torch.Tensor) -> torch.Tensor:
    """Reward of the LiDAR trajectory produced with extrinsic T_true ∘ exp(perturbation)."""
    T_world_imu = _imu_trajectory()
    ref = T_world_imu @ T_IMU_LIDAR
    T_candidates = T_IMU_LIDAR @ geo.se3_exp(perturbations)
    est = lidar_poses_from_imu(T_world_imu.expand(len(perturbations), -1, -1, -1), T_candidates)
    return trajectory_reward(ref, est).reward


def test_reward_strictly_decreases_with_rotation_error_grid():
    for axis in range(3):
        angles = torch.tensor([0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0]) * math.pi / 180
        xi = torch.zeros(len(angles), 6)
        xi[:, 3 + axis] = angles
        r = _rewards_for(xi)
        assert torch.all(r[1:] < r[:-1]), (axis, r)


def test_reward_strictly_decreases_with_translation_error_grid():
    for axis in range(3):
        offsets = torch.tensor([0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.5])
        xi = torch.zeros(len(offsets), 6)
        xi[:, axis] = offsets
        r = _rewards_for(xi)
        assert torch.all(r[1:] < r[:-1]), (axis, r)


def test_failed_candidates_and_position_only():
    T_world_imu = _imu_trajectory()
    ref = T_world_imu @ T_IMU_LIDAR
    est = lidar_poses_from_imu(T_world_imu.expand(3, -1, -1, -1), T_IMU_LIDAR.expand(3, -1, -1))
    est = est.clone()
    valid = torch.ones(3, est.shape[1], dtype=torch.bool)
    valid[2, 100:] = False
    est[2, 100:] = float("nan")  # what a careless backend might leave behind invalid poses
    failed = torch.tensor([False, True, False])
    out = trajectory_reward(ref, est, valid, failed=failed)
    assert float(out.reward[1]) == 0.0
    assert out.reward[0] > 0.999999 and out.reward[2] > 0.999999
    assert int(out.num_poses[2]) == 100
    pos_only = trajectory_reward(ref, est, valid, use_rotation=False)
    assert torch.isnan(pos_only.mean_e_r).all()
