"""The post-hoc per-axis resolution probe (l2calib.assess.sensitivity)."""

from __future__ import annotations

import math

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.assess.sensitivity import (
    ROTATION_STEPS_DEG,
    TRANSLATION_STEPS_M,
    probe,
    resolve,
    undetermined,
)

F64 = torch.float64


def _true() -> torch.Tensor:
    R = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor([180.0, 0.0, 90.0], dtype=F64)))
    return geo.make_transform(R, torch.tensor([0.12, -0.05, 0.08], dtype=F64))


def _reward(
    T: torch.Tensor, T_true: torch.Tensor, flat_rot_axis: int | None = None
) -> torch.Tensor:
    """A reward peaked at T_true: 5 %/deg in rotation, 1 %/cm in translation (LiDAR axes)."""
    D = geo.transform_inverse(T_true)[None] @ T
    rot = torch.rad2deg(geo.so3_log(D[:, :3, :3]))
    if flat_rot_axis is not None:
        rot[:, flat_rot_axis] = 0.0
    trans_cm = 100 * D[:, :3, 3]
    return 0.9 * torch.exp(-0.05 * rot.norm(dim=1) - 0.01 * trans_cm.norm(dim=1))


def test_probe_order_and_size_match_resolve():
    T = _true()
    cands = probe(T)
    n = 1 + 2 * 3 * (len(ROTATION_STEPS_DEG) + len(TRANSLATION_STEPS_M))
    assert cands.shape == (n, 4, 4)
    assert torch.equal(cands[0], T)
    # second candidate: +0.25 deg about LiDAR x
    D = geo.transform_inverse(T) @ cands[1]
    assert torch.allclose(
        geo.so3_log(D[:3, :3]), torch.tensor([math.radians(0.25), 0, 0], dtype=F64)
    )
    # last: the widest translation step, negative, along LiDAR z
    D = geo.transform_inverse(T) @ cands[-1]
    assert torch.allclose(D[:3, 3], torch.tensor([0, 0, -TRANSLATION_STEPS_M[-1]], dtype=F64))


def test_resolution_of_a_peaked_reward_is_finite_and_ordered():
    T = _true()
    res = resolve(_reward(probe(T), T), drop_fraction=0.005)
    # exp(-0.05 d) drops 0.5 % at d ≈ 0.1 deg; exp(-0.01 cm) at ≈ 0.5 cm
    assert all(0.05 < w < 0.25 for w in res.rotation_deg), res.rotation_deg
    assert all(0.003 < w < 0.01 for w in res.translation_m), res.translation_m
    assert res.better == []
    assert undetermined(res, 1.0, 0.05) == []


def test_flat_axis_is_named_and_off_optimum_is_flagged():
    T_true = _true()
    res = resolve(_reward(probe(T_true), T_true, flat_rot_axis=1))
    assert np.isinf(res.rotation_deg[1])
    names = undetermined(res, 1.0, 0.05)
    assert names == ["rotation about LiDAR y (resolution flat)"]
    # calibrated result 2 cm off along x: a probe step scores higher
    off = T_true.clone()
    off[:3, 3] += T_true[:3, :3] @ torch.tensor([0.02, 0, 0], dtype=F64)
    res = resolve(_reward(probe(off), T_true))
    assert res.better == ["translation along LiDAR x"]
    assert any("not converged" in n for n in undetermined(res, 1.0, 0.05))
