"""The Newton polish (:mod:`l2calib.assess.polish`) on a reward with coupled axes."""

from __future__ import annotations

import math

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.assess.polish import polish
from l2calib.interfaces import Extrinsic

#: The reward's peak relative to the start: 0.3° about z, 1 cm along x, 0.4 ms.
PEAK = np.array([0.0, 0.0, math.radians(0.3), 0.01, 0.0, 0.0, 0.0004])
#: A ridge: rotation about z and the time offset trade off (scaled to the stencil's units).
SCALE = np.array([math.radians(0.5)] * 3 + [0.02] * 3 + [0.001])
A = np.eye(7)
A[2, 6] = A[6, 2] = 0.95  # strongly coupled: a per-axis climb crawls along it


def _reward(T: torch.Tensor, offsets: torch.Tensor | None) -> torch.Tensor:
    rot = geo.so3_log(T[:, :3, :3]).numpy()
    delta = np.concatenate([rot, T[:, :3, 3].numpy()], 1)
    off = np.zeros(len(T)) if offsets is None else offsets.numpy()
    z = (np.column_stack([delta, off]) - PEAK) / SCALE
    return torch.as_tensor(np.exp(-0.02 * np.einsum("ki,ij,kj->k", z, A, z)))


def test_the_polish_climbs_a_coupled_ridge_to_its_top():
    start = Extrinsic(torch.eye(4, dtype=torch.float64), 0.0)
    before = float(_reward(start.T_imu_lidar[None], torch.zeros(1))[0])
    out = polish(_reward, start, rounds=3)
    assert out.rounds >= 1 and out.reward > before and out.start_reward == before
    rot = geo.so3_log(out.extrinsic.T_imu_lidar[:3, :3]).numpy()
    assert abs(math.degrees(rot[2]) - 0.3) < 0.01
    assert abs(float(out.extrinsic.T_imu_lidar[0, 3]) - 0.01) < 1e-4
    assert abs(out.extrinsic.time_offset_s - 0.0004) < 1e-5
    assert out.evaluations == 3 * 102  # 99 stencil points + 3 along the step, per round


def test_the_polish_never_lowers_the_reward_and_keeps_a_hold():
    start = Extrinsic(torch.eye(4, dtype=torch.float64), 0.0004)
    start.T_imu_lidar[:3, :3] = geo.so3_exp(torch.tensor([0.0, 0.0, math.radians(0.3)]))
    start.T_imu_lidar[0, 3] = 0.01  # the peak itself: no step can raise the reward

    def hold(T: torch.Tensor) -> torch.Tensor:
        T = T.clone()
        T[:, 2, 3] = 0.05
        return T

    out = polish(_reward, start, rounds=3, hold=hold)
    assert out.rounds == 0 and out.reward == out.start_reward
    assert float(out.extrinsic.T_imu_lidar[2, 3]) == 0.05  # the held value, not the start's 0


def _cusp(T: torch.Tensor, offsets: torch.Tensor | None) -> torch.Tensor:
    """The paper's reward shape: ``exp(−sqrt(mean |error|))`` has a cusp at its peak, here much
    narrower than the polish's first stencil (an eighth of it), on the same coupled ridge."""
    rot = geo.so3_log(T[:, :3, :3]).numpy()
    delta = np.concatenate([rot, T[:, :3, 3].numpy()], 1)
    off = np.zeros(len(T)) if offsets is None else offsets.numpy()
    z = 8 * (np.column_stack([delta, off]) - PEAK) / SCALE
    return torch.as_tensor(np.exp(-np.sqrt(1e-4 + np.sqrt(np.einsum("ki,ij,kj->k", z, A, z)))))


def test_the_polish_narrows_its_stencil_to_climb_a_sharp_cusp():
    start = Extrinsic(torch.eye(4, dtype=torch.float64), 0.0)
    out = polish(_cusp, start, rounds=12)  # one stencil width throughout: no step at all
    rot = geo.so3_log(out.extrinsic.T_imu_lidar[:3, :3]).numpy()
    assert abs(math.degrees(rot[2]) - 0.3) < 0.05  # along the 0.95-coupled ridge: most of it
    assert abs(float(out.extrinsic.T_imu_lidar[0, 3]) - 0.01) < 1e-3
    assert abs(out.extrinsic.time_offset_s - 0.0004) < 1.5e-4
