"""PPO's translation start from the references' accelerations against the accelerometer.

:mod:`l2calib.train.lever_start` (issue 23: PPO's wide phase was the translation's).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from l2calib.data import ImuSamples
from l2calib.interfaces import ReferenceTrajectory
from l2calib.recipe import recipe_from_dict
from l2calib.train.lever_start import (
    CAP_M,
    FLOOR_M,
    HALF_WIDTH_S,
    WIDER_HALF_WIDTHS_S,
    _d2,
    lever_arm_from_accelerations,
    lever_start,
    widening_fit,
)
from l2calib.train.rotation_start import rotation_start
from l2calib.trajectory import Trajectory


def test_the_second_divided_difference_is_the_kernel_average_of_the_second_derivative():
    t = np.array([0.0, 0.3, 0.5, 0.9, 1.4])  # uneven knots
    x = np.stack([t**2, t**3, np.ones_like(t)], axis=1)
    # the hat kernel over (0.3, 0.5, 0.9) averages x'' = (2, 6t, 0): its mean of t is (a+b+c)/3
    got = _d2(x, (1, 2, 3), t)
    assert got == pytest.approx([2.0, 6.0 * (0.3 + 0.5 + 0.9) / 3, 0.0])


def test_the_simulators_hand_held_lever_arm_comes_within_a_few_millimetres(hand_held):
    run, data = hand_held
    notes: list[str] = []
    rot = rotation_start(recipe_from_dict({}), data, notes.append)
    start = lever_start(recipe_from_dict({}), data, rot, 0.0, notes.append)
    assert start is not None and "accelerations" in notes[-1] and data.notes == notes
    err = np.abs(np.array(start.translation_m) - run.T_imu_lidar[:3, 3])
    assert err.max() < 0.005  # m; the simulated IMU has white noise and bias walk
    assert all(FLOOR_M <= s <= CAP_M for s in start.sigma_m)
    assert start.relative_residual < 0.2
    # no start without the rotation, with the user's prior, or turned off (YAML 1.1's `off`)
    assert lever_start(recipe_from_dict({}), data, None, 0.0, notes.append) is None
    prior = recipe_from_dict({"policy": {"prior": {"rpy_deg": [0, 0, 0]}}})
    assert lever_start(prior, data, rot, 0.0, notes.append) is None
    off = recipe_from_dict({"train": {"translation_from_accelerations": False}})
    assert off.train.translation_from_accelerations == "off"
    assert lever_start(off, data, rot, 0.0, notes.append) is None


def test_an_accelerometer_that_does_not_follow_the_reference_gives_no_start(hand_held):
    run, data = hand_held
    seq = data.sequences[0]
    rng = np.random.default_rng(3)
    imu = seq.imu
    noise = ImuSamples(
        imu.stamps_ns, imu.gyro_rad_s, rng.normal(scale=5.0, size=imu.gyro_rad_s.shape)
    )
    R = run.T_imu_lidar[:3, :3]
    bad = SimpleNamespace(name=seq.name, imu=noise)
    assert lever_arm_from_accelerations(data.references, data.segments, [bad], R, 0.0) is None


@pytest.mark.parametrize("kind", ["bingham", "gaussian"])
def test_the_policy_starts_at_the_lever_arm_with_its_spread(kind, hand_held):
    from l2calib.plugins import get_plugin

    _, data = hand_held
    rot = rotation_start(recipe_from_dict({}), data, lambda _m: None)
    start = lever_start(recipe_from_dict({}), data, rot, 0.0, lambda _m: None)
    spec = get_plugin("l2calib.policies", kind)
    policy = spec.build(
        spec.config.model_validate({}), rotation_start=rot, translation_start=start, seed=0
    )
    t = policy.mode().T_imu_lidar[:3, 3]
    assert torch.allclose(t, torch.tensor(start.translation_m, dtype=t.dtype), atol=1e-9)
    sigma = policy.uncertainty().translation_sigma_m.numpy()
    assert sigma == pytest.approx(start.sigma_m, rel=0.05)  # not the 0.5 m of no guess


def test_a_noisy_reference_widens_the_kernel_until_the_fit_is_accepted(hand_held):
    """1 cm of white noise on the reference's positions (a 16-beam ``ct-lidar`` reference is of
    that order): the ±0.25 s kernel's second differences drown in it and are rejected; the
    ±0.5 s kernel averages the noise 6× further down and is taken, its σ covering its error."""
    run, data = hand_held
    ref = data.references[0]
    traj = ref.trajectory
    rng = np.random.default_rng(0)
    noisy = Trajectory(
        traj.stamps_ns, traj.t_world_body + rng.normal(scale=0.01, size=traj.t_world_body.shape),
        traj.quat_xyzw,
    )  # fmt: skip
    refs = [ReferenceTrajectory(ref.segment, noisy, "pose", "gt")]
    R = run.T_imu_lidar[:3, :3]
    args = (refs, data.segments, data.sequences, R, 0.0)
    assert lever_arm_from_accelerations(*args) is None  # at HALF_WIDTH_S
    start = widening_fit(*args)
    assert start is not None and start.half_width_s == WIDER_HALF_WIDTHS_S[0]
    assert start.half_width_s > HALF_WIDTH_S and start.relative_residual <= 0.5
    err = np.abs(np.array(start.translation_m) - run.T_imu_lidar[:3, 3])
    assert np.all(err < np.array(start.sigma_m)) and err.max() < 0.02  # m
    assert "±0.5 s" in start.describe() and start.to_dict()["half_width_s"] == 0.5
