"""The production trainer on the real IEKF backend: the reward rises, the mode nears the truth.

The other trainer tests use a fake backend to check counts, files, resume and restarts; this one
checks that :class:`~l2calib.train.ppo.PpoTrainer` actually learns on the real odometry
(TorchRL collector, ``ClipPPOLoss``, IEKF scoring each candidate against the simulated LiDAR
trajectory). It starts from a rough prior (about 11° and 7 cm off) so that a few iterations
show the trend; learning from no initial guess to the truth is ``tests/e2e``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.interfaces import ReferenceTrajectory
from l2calib.plugins import get_plugin
from l2calib.recipe import load_recipe
from l2calib.sim import SimConfig, simulate
from l2calib.train.env_build import make_training_env
from l2calib.train.ppo import PpoTrainer

#: The demo rig: LiDAR upside down and turned 90°, 12 cm off the IMU (far from identity).
RIG = {"preset": None, "translation_m": (0.12, -0.05, 0.08), "rpy_deg": (180.0, 0.0, 90.0)}
BUDGET = ["train.candidates_per_iteration=16", "train.max_iterations=20", "train.workers=1"]
PRIOR = [
    "policy.prior.translation_m=[0.16,-0.09,0.12]",
    "policy.prior.rpy_deg=[172,6,95]",
    "policy.prior.sigma_rotation_deg=10",
    "policy.prior.sigma_translation_m=0.1",
]


def _mode_errors(record, T_true: np.ndarray) -> tuple[float, float]:
    """Rotation (deg) and translation (m) error of an iteration's policy mode."""
    R = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor(record.rpy_deg, dtype=torch.float64)))
    angle = geo.rotation_angle(torch.from_numpy(T_true[:3, :3]).T @ R)
    return math.degrees(float(angle)), float(np.linalg.norm(record.translation_m - T_true[:3, 3]))


@pytest.mark.slow
def test_reward_rises_and_the_mode_moves_towards_the_truth():
    """Catches a trainer that does not learn: a stuck optimiser, a sign error between reward
    and advantage (the mode would run away from the truth), a policy update that ignores the
    batch, or a collector that feeds stale actions."""
    run = simulate(
        SimConfig.model_validate(
            {
                "duration_s": 5.0,
                "seed": 7,
                "motion": {"profile": "handheld"},
                "lidar": {"model": "ouster-os1-16", "columns": 512},
                "imu": {"model": "vn100"},
                "rig": RIG,
            }
        )
    )
    seq = run.sequence()
    seg = seq.segment(seq.start_ns + 1_000_000_000, seq.end_ns)
    refs = [ReferenceTrajectory(seg.name, run.gt_lidar, source="gt")]
    recipe = load_recipe("simulator", [*BUDGET, *PRIOR])
    policy = get_plugin("l2calib.policies", "bingham").build(
        {}, action_dim=7, prior=recipe.policy.prior, seed=3
    )
    env = make_training_env(recipe, [seg], refs)
    try:
        outcome = PpoTrainer(policy, env, recipe.train, None, "test").run()
    finally:
        env.close()
    hist = outcome.history
    assert len(hist) == 20 and outcome.evaluations == 20 * 16
    # Per-iteration figures are noisy (16 candidates, and the mode still jumps by degrees from one
    # iteration to the next): compare averages of the last five with the start.
    first = np.mean([r.reward_mean for r in hist[:5]])
    last = np.mean([r.reward_mean for r in hist[-5:]])
    assert last > first + 0.03, (first, last)  # the candidates got better, not just the mode
    prior = recipe.policy.prior.T_imu_lidar()
    rot_prior, _ = _mode_errors(_Record(prior), run.T_imu_lidar)  # 11.1°
    rot = np.mean([_mode_errors(r, run.T_imu_lidar)[0] for r in hist[-5:]])
    # Measured on AMD EPYC, policy seeds 3 / 4 / 5: 3.1 / 1.5 / 1.1° (an Intel Xeon gave 0.9°
    # for seed 3: floating-point order differs between CPUs and a 20-iteration run amplifies
    # it). Translation is not asserted: after 20 iterations it is still within the prior's
    # spread (3-11 cm against 6.9 cm at the prior); the e2e tests check it to the end.
    assert rot < 0.5 * rot_prior, (rot_prior, rot)


class _Record:
    """The fields of an iteration record that :func:`_mode_errors` reads, for a transform."""

    def __init__(self, T: np.ndarray):
        self.translation_m = T[:3, 3]
        self.rpy_deg = torch.rad2deg(geo.matrix_to_euler_rpy(torch.from_numpy(T[:3, :3]))).tolist()
