"""The filters' start: gravity reads the accelerometer at each candidate's own time offset."""

from __future__ import annotations

from dataclasses import replace

import torch

from l2calib import geometry as geo
from l2calib_backends.initialise import ReferenceMotion, _shifted, initial_states


def _motion(n: int = 200, rate_hz: float = 100.0) -> ReferenceMotion:
    g = torch.Generator().manual_seed(0)
    t = torch.arange(n, dtype=torch.float64) / rate_hz
    accel = torch.randn(n, 3, generator=g, dtype=torch.float64) + torch.tensor([0, 0, 9.81])
    inside = slice(20, n - 20)  # the segment's margins lie outside the LiDAR span
    eye = torch.eye(3, dtype=torch.float64)
    yaw = torch.zeros(n, 3, dtype=torch.float64)
    yaw[:, 2] = 0.01 * torch.arange(n)
    rot = geo.so3_exp(yaw)  # a slow yaw, so that a time shift changes the rotated force
    zeros = torch.zeros(3, dtype=torch.float64)
    return ReferenceMotion(
        R0=eye[None], p0=zeros[None], v0=zeros[None], w0=zeros[None],
        R_imu=rot[inside], accel=accel[inside], imu_t=t[inside], all_t=t, all_accel=accel,
        R_a=eye, v_a=zeros, w_a=zeros, R_b=eye, v_b=zeros, w_b=zeros, span_s=1.6,
        start_biases="zero",
        all_gyro=torch.zeros(n, 3, dtype=torch.float64), bounds=torch.tensor([0, n - 41]),
        R_B=eye[None].repeat(2, 1, 1), v_B=zeros[None].repeat(2, 1), dR_B=eye[None].repeat(2, 1, 1),
    )  # fmt: skip


def test_a_whole_sample_shift_reads_the_sample_that_far_away():
    motion = _motion()
    offsets = torch.tensor([0.0, 0.03, -0.05], dtype=torch.float64)
    shifted = _shifted(motion, motion.all_accel, offsets)
    assert torch.allclose(shifted[0], motion.accel)  # no offset: the paired samples
    assert torch.allclose(shifted[1], motion.all_accel[23:183])  # +30 ms = 3 samples later
    assert torch.allclose(shifted[2], motion.all_accel[15:175])  # −50 ms = 5 samples earlier


def test_zero_offsets_give_the_unshifted_start_and_an_offset_changes_gravity():
    motion = _motion()
    T = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    sigmas = dict.fromkeys(("rot", "pos", "vel", "bg", "ba", "grav"), 0.1)
    none = initial_states(motion, T, sigmas)
    zero = initial_states(motion, T, sigmas, torch.zeros(2, dtype=torch.float64))
    assert torch.equal(none.g, zero.g)
    late = initial_states(motion, T, sigmas, torch.tensor([0.0, 0.05], dtype=torch.float64))
    assert torch.equal(late.g[0], none.g[0]) and not torch.allclose(late.g[1], none.g[1])
    # the late candidate's gravity is what the same motion gives with the accelerometer
    # re-read 5 samples later
    moved = replace(motion, accel=motion.all_accel[25:185])
    assert torch.allclose(late.g[1], initial_states(moved, T[:1], sigmas).g[0])
