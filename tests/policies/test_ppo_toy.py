"""Acceptance: the production trainer (PpoTrainer) converges on a toy reward with known optimum."""

from __future__ import annotations

import math

import pytest
import torch

from l2calib.geometry import euler_rpy_to_matrix, matrix_to_quat
from l2calib_policies.toy import run_toy_ppo, toy_reward

F64 = torch.float64
# The paper's handheld rig: rpy (180°, 90°, 0°), t = (0.650, -0.372, -0.016) m; far from identity.
Q_STAR = matrix_to_quat(euler_rpy_to_matrix(torch.deg2rad(torch.tensor([180.0, 90.0, 0.0]))))
T_STAR = torch.tensor([0.650, -0.372, -0.016], dtype=F64)


def test_toy_reward_peaks_at_the_optimum_and_ignores_quaternion_sign():
    best = torch.cat([Q_STAR, T_STAR])
    flipped = torch.cat([-Q_STAR, T_STAR])
    off = torch.cat([Q_STAR, T_STAR + 0.1])
    r = toy_reward(torch.stack([best, flipped, off]), Q_STAR, T_STAR)
    assert r[0].item() == pytest.approx(1.0) and r[1].item() == pytest.approx(1.0)
    assert r[2] < r[0]


@pytest.mark.slow
def test_bingham_ppo_converges_within_one_degree():
    hist = run_toy_ppo("bingham", Q_STAR, T_STAR, iterations=200, seed=0)
    last = hist.rotation_error_deg[-10:]
    assert sum(last) / len(last) < 1.0, last
    assert hist.translation_error_m[-1] < 0.01
    assert hist.rotation_error_deg[0] > 20  # it really started from "no idea"
    assert max(hist.rotation_sigma_deg[-1]) < 2.0  # and became confident


@pytest.mark.slow
def test_gaussian_ppo_runs():
    hist = run_toy_ppo("gaussian", Q_STAR, T_STAR, iterations=60, seed=0)
    assert len(hist.rotation_error_deg) == 60
    assert all(math.isfinite(e) for e in hist.rotation_error_deg + hist.mean_reward)
    early, late = hist.mean_reward[:10], hist.mean_reward[-10:]
    assert sum(late) > sum(early)
