from __future__ import annotations

import math

import torch
from fakes import T_TRUE, FakeBackend, reference
from torchrl.envs.utils import check_env_specs

from l2calib import geometry as geo
from l2calib.interfaces import ReferenceTrajectory
from l2calib.reward import paper_reward
from l2calib.train.env import CalibrationEnv, action_to_extrinsic


def _env(refs, K=8, **kw):
    backend = FakeBackend()
    backend.prepare([None] * len(refs), refs)
    return CalibrationEnv(backend, refs, K, **kw)


def _action(T):
    q = geo.matrix_to_quat(T[..., :3, :3])
    return torch.cat([q, T[..., :3, 3]], -1)


def test_specs_and_rollout():
    env = _env([reference("a")])
    check_env_specs(env)
    td = env.rand_step(env.reset())
    assert td["next", "done"].all() and td["next", "reward"].shape == (8, 1)
    assert env.evaluations >= 8


def test_truth_scores_highest_and_rewards_pool_segments():
    refs = [reference("a"), reference("b", n=30, seed=1)]
    env = _env(refs, K=3)
    wrong = T_TRUE @ geo.se3_exp(torch.tensor([[0, 0, 0, 0.05, 0, 0], [0.1, 0, 0, 0, 0, 0.0]]))
    T = torch.cat([T_TRUE[None], wrong])
    td = env.reset()
    td["action"] = _action(T)
    out = env.step(td)["next"]
    r = out["reward"][:, 0]
    assert abs(float(r[0]) - 1.0) < 1e-7 and r[1] < r[0] and r[2] < r[0]  # sqrt of round-off
    # Pooling: the reward over both segments equals the formula over all their poses.
    e_t, e_r = [], []
    for ref in refs:
        T_ref = ref.trajectory.matrices()[1:]
        est = T_ref @ (torch.linalg.inv(T_TRUE) @ wrong[0])
        e_t.append((est[:, :3, 3] - T_ref[:, :3, 3]).norm(dim=-1))
        e_r.append(geo.rotation_angle(est[:, :3, :3] @ T_ref[:, :3, :3].transpose(1, 2)))
    manual = paper_reward(torch.cat(e_t)[None], torch.cat(e_r)[None])
    assert math.isclose(float(r[1]), float(manual[0]), rel_tol=1e-12)


def test_position_only_reference_drops_rotation_term():
    ref = reference("a")
    pos_ref = ReferenceTrajectory("a", ref.trajectory, constrains="position")
    env = _env([pos_ref], K=2)
    # With the fake backend a pure rotation about the LiDAR origin leaves every LiDAR position
    # unchanged: with the rotation term dropped, it must score exactly like the truth.
    rot_only = T_TRUE @ geo.se3_exp(torch.tensor([[0, 0, 0, 0.0, 0.0, 0.3]]))
    shifted = T_TRUE @ geo.se3_exp(torch.tensor([[0.05, 0, 0, 0.0, 0.0, 0.0]]))
    T = torch.cat([T_TRUE[None], rot_only, shifted])
    breakdown, _ = env.score_candidates(T)
    assert torch.isnan(breakdown.mean_e_r).all()
    assert abs(float(breakdown.reward[1] - breakdown.reward[0])) < 1e-9
    assert breakdown.reward[2] < breakdown.reward[0]


def test_action_to_extrinsic_normalises_and_reads_time_offset():
    a = torch.tensor([[0.0, 0.0, 0.0, 2.0, 1.0, 2.0, 3.0, 0.01]])
    T, off = action_to_extrinsic(a)
    assert torch.allclose(T[0, :3, :3], torch.eye(3, dtype=T.dtype))
    assert torch.allclose(off, torch.tensor([0.01], dtype=off.dtype))
