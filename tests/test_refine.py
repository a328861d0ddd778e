"""The post-PPO refinement climbs the reward (fake scorers: smooth bowls with known optima)."""

from __future__ import annotations

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.assess.refine import refine
from l2calib.interfaces import Extrinsic

T_OPT = geo.se3_exp(torch.tensor([[0.3, -0.1, 0.2, 0.4, -0.2, 1.0]], dtype=torch.float64))[0]


def _bowl(widths_m: float = 0.05, widths_rad: float = np.radians(2.0)):
    """Reward ``exp(-|Δt|²/w_t² - |Δθ|²/w_r²)`` around ``T_OPT`` with coupled axes, counted."""
    calls = []

    def score(T: torch.Tensor) -> torch.Tensor:
        calls.append(T.shape[0])
        D = geo.transform_inverse(T_OPT)[None] @ T
        dt = D[:, :3, 3] + 0.3 * geo.so3_log(D[:, :3, :3])  # couple rotation into translation
        dr = geo.so3_log(D[:, :3, :3])
        return torch.exp(-(dt**2).sum(-1) / widths_m**2 - (dr**2).sum(-1) / widths_rad**2)

    return score, calls


def _errors(T) -> tuple[float, float]:
    D = geo.transform_inverse(T_OPT) @ torch.as_tensor(T)
    return float(D[:3, 3].norm()), float(np.degrees(float(geo.rotation_angle(D[:3, :3]))))


def test_refine_moves_to_the_reward_optimum():
    score, calls = _bowl()
    start = T_OPT @ geo.se3_exp(torch.tensor([[0.03, -0.02, 0.025, 0.01, -0.012, 0.008]]))[0]
    res = refine(score, Extrinsic(start), rounds=8)
    t_err, r_err = _errors(res.extrinsic.T_imu_lidar)
    assert t_err < 0.005 and r_err < 0.1, (t_err, r_err)
    assert _errors(start)[0] > 0.03
    assert res.reward > res.start_reward
    assert res.evaluations == sum(calls) <= 1 + 8 * 13
    rewards = [h[0] for h in res.history]
    assert all(b >= a for a, b in zip(rewards, rewards[1:], strict=False))  # never worse


def test_refine_keeps_the_start_when_nothing_scores_higher():
    score, _ = _bowl()
    res = refine(score, Extrinsic(T_OPT), rounds=3, start_reward=1.0)
    assert torch.allclose(res.extrinsic.T_imu_lidar, T_OPT)
    assert res.extrinsic.time_offset_s is None
    assert res.reward == 1.0 and res.moved_m == 0.0 and res.moved_deg == 0.0
    assert res.history[-1][2] < 0.04  # steps halved while looking closer


def test_refine_does_not_move_on_a_flat_reward():
    def flat(T: torch.Tensor) -> torch.Tensor:
        return torch.full((T.shape[0],), 0.5, dtype=torch.float64)

    res = refine(flat, Extrinsic(T_OPT), rounds=2)
    assert torch.allclose(res.extrinsic.T_imu_lidar, T_OPT) and res.reward == 0.5


def test_refine_climbs_the_time_offset_with_the_rotation():
    """Offset and rotation trade off (a late IMU looks like a turned LiDAR): both are refined."""
    offset_opt = 0.010

    def score(T: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        D = geo.transform_inverse(T_OPT)[None] @ T
        dr = geo.so3_log(D[:, :3, :3])
        dr[:, 2] = dr[:, 2] + 2.0 * (offsets - offset_opt)  # yaw couples with the offset
        dt, do = D[:, :3, 3], offsets - offset_opt
        return torch.exp(
            -(dt**2).sum(-1) / 0.05**2 - (dr**2).sum(-1) / np.radians(2.0) ** 2 - (do / 0.01) ** 2
        )

    start = T_OPT @ geo.se3_exp(torch.tensor([[0.01, 0.0, 0.0, 0.0, 0.0, 0.01]]))[0]
    res = refine(score, Extrinsic(start, 0.004), rounds=10)
    t_err, r_err = _errors(res.extrinsic.T_imu_lidar)
    off = res.extrinsic.time_offset_s
    assert abs(off - offset_opt) < 0.0005 and r_err < 0.05, (off, r_err)
    assert res.moved_offset_s > 0.005 and res.evaluations <= 1 + 10 * 15
    # Without the seventh axis the rotation absorbs the offset's error instead.
    held = refine(lambda T: score(T, torch.full((T.shape[0],), 0.004)), Extrinsic(start), rounds=10)
    assert _errors(held.extrinsic.T_imu_lidar)[1] > 0.5


def test_refine_stops_once_every_step_is_finer_than_needed():
    """At the optimum every round halves the steps: 4 cm and 1° fall below 1 mm and 0.025° after
    six rounds, and the climb ends there instead of spending the other rounds."""
    score, calls = _bowl()
    res = refine(score, Extrinsic(T_OPT), rounds=20, start_reward=1.0)
    assert len(res.history) == 6 and res.evaluations <= 6 * 13  # 12 probes + 1 move a round
    assert res.history[-1][2] < 0.001
