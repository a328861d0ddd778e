from __future__ import annotations

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.errors import NotImplementedPluginError
from l2calib.interfaces import CandidateStatus, ReferenceTrajectory
from l2calib.plugins import get_plugin
from l2calib.reward import trajectory_reward
from l2calib_backends.propagation import ImuNoise, ImuTensors, propagate
from l2calib_backends.scan_loop import count_misses
from l2calib_backends.state import DIM, FilterState


def _backend(**options):
    return get_plugin("l2calib.backends", "iekf").build(options)


def _rewards(backend, segment, reference, T):
    out = backend.evaluate(T)[0]
    ref = reference.trajectory.interpolate(out.stamps_ns).matrices()
    failed = out.status == int(CandidateStatus.DIVERGED)
    return out, trajectory_reward(
        ref, out.T_world_lidar, out.valid, failed=failed, align="none"
    ).reward


def test_propagation_matches_noise_free_imu_integration(sim):
    run = sim(duration_s=5.0, imu={"noise": False}, lidar={"noise": False})
    imu = run.imu
    t_rel = (imu.stamps_ns - imu.stamps_ns[0]) * 1e-9
    tensors = ImuTensors(
        torch.from_numpy(t_rel), torch.from_numpy(imu.gyro_rad_s), torch.from_numpy(imu.accel_m_s2)
    )
    t0, t1 = 2.0, 3.0
    h = 1e-3
    stamps = imu.stamps_ns[0] + np.round(np.array([t0 - h, t0, t0 + h, t1]) * 1e9).astype(np.int64)
    gt = run.gt_imu.interpolate(stamps).matrices()
    v0 = (gt[2, :3, 3] - gt[0, :3, 3]) / (2 * h)
    state = FilterState(
        R=gt[1:2, :3, :3], p=gt[1:2, :3, 3], v=v0[None],
        bg=torch.zeros(1, 3), ba=torch.zeros(1, 3), g=torch.tensor([[0.0, 0.0, -9.81]]),
        P=torch.eye(DIM)[None] * 1e-4,
    )  # fmt: skip
    noise = ImuNoise(1e-3, 1e-2, 1e-5, 1e-4)
    out, track = propagate(state, tensors, torch.tensor([t0]), torch.tensor([t1]), noise)
    rot_err = float(geo.rotation_angle(gt[3, :3, :3].T @ out.R[0]))
    pos_err = float((gt[3, :3, 3] - out.p[0]).norm())
    assert np.degrees(rot_err) < 0.05, np.degrees(rot_err)
    assert pos_err < 0.01, pos_err
    assert torch.all(torch.linalg.eigvalsh(out.P[0]) > 0)
    # The deskew track reproduces the propagated end pose.
    R_end, p_end = track.poses_at(torch.tensor([[t1]]))
    assert torch.allclose(R_end[0, 0], out.R[0], atol=1e-9)
    assert torch.allclose(p_end[0, 0], out.p[0], atol=1e-9)


def test_a_window_past_the_last_imu_sample_integrates_its_own_length_once():
    """Two filters in one batch, the second ending 55 ms past the IMU (a positive time offset
    at a segment's end): its rotation is the constant rate times its own 0.1 s, not the
    extrapolated stretch again for every step the first filter still takes."""
    t = torch.arange(200, dtype=torch.float64) * 0.005  # 0 ... 0.995 s
    gyro = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).repeat(200, 1)
    accel = torch.tensor([0.0, 0.0, 9.81], dtype=torch.float64).repeat(200, 1)
    state = FilterState(
        R=torch.eye(3).repeat(2, 1, 1).double(), p=torch.zeros(2, 3).double(),
        v=torch.zeros(2, 3).double(), bg=torch.zeros(2, 3).double(),
        ba=torch.zeros(2, 3).double(), g=torch.tensor([[0.0, 0.0, -9.81]]).repeat(2, 1).double(),
        P=torch.eye(DIM).repeat(2, 1, 1).double() * 1e-4,
    )  # fmt: skip
    t0 = torch.tensor([0.0, 0.95], dtype=torch.float64)
    t1 = torch.tensor([0.9, 1.05], dtype=torch.float64)
    out, _ = propagate(state, ImuTensors(t, gyro, accel), t0, t1, ImuNoise(1e-3, 1e-2, 1e-5, 1e-4))
    yaw = geo.so3_log(out.R)[:, 2]
    assert torch.allclose(yaw, torch.tensor([0.9, 0.1], dtype=torch.float64), atol=1e-9)
    assert torch.allclose(out.p, torch.zeros(2, 3, dtype=torch.float64), atol=1e-9)
    from l2calib_backends.gtsam_graph import imu_intervals  # the GTSAM backend's intervals

    _, _, dt = imu_intervals(ImuTensors(t, gyro, accel), t0, t1)
    assert torch.allclose(dt.sum(1), t1 - t0, atol=1e-12)


#: Own-map IEKF on the simulator's Ouster beam azimuth offsets (simulator v2): 10 cm APE RMSE
#: with the true extrinsic (1-3 cm without the offsets), and 2° rotations score above the truth.
#: Strict: the test fails once the mode is fixed, so the marker is removed then.
OWN_MAP_AZIMUTHS = pytest.mark.xfail(
    strict=True, reason="own-map IEKF loses accuracy with Ouster beam azimuth offsets (sim v2)"
)


@pytest.mark.parametrize(
    ("map_mode", "window"),
    [("shared-map", 10), pytest.param("odometry", 0, marks=OWN_MAP_AZIMUTHS)],
)
def test_perturbed_extrinsics_lower_the_reward(handheld_run, handheld_segment, map_mode, window):
    seg, ref = handheld_segment
    backend = _backend(map_mode=map_mode, window_scans=window)
    backend.prepare([seg], [ref])
    T_true = torch.from_numpy(handheld_run.T_imu_lidar)
    xis = torch.zeros(7, 6)
    xis[1, 3], xis[2, 4], xis[3, 5] = (np.radians(2.0),) * 3
    xis[4, 0], xis[5, 1], xis[6, 2] = (0.05,) * 3
    out, reward = _rewards(backend, seg, ref, T_true @ geo.se3_exp(xis))
    assert torch.all(out.status == int(CandidateStatus.OK))
    # Own-map odometry drifts by centimetres over a few seconds of 16-beam data, which hides
    # 5 cm translation errors (see benchmarks/results/backends.md); rotations still show.
    checked = slice(1, 7) if map_mode == "shared-map" else slice(1, 4)
    assert torch.all(reward[checked] < reward[0]), reward
    assert torch.isfinite(out.T_world_lidar).all()


@OWN_MAP_AZIMUTHS
def test_odometry_mode_tracks_with_the_true_extrinsic(handheld_run, handheld_segment):
    seg, ref = handheld_segment
    backend = _backend(map_mode="odometry", window_scans=0)
    backend.prepare([seg], [ref])
    out = backend.evaluate(torch.from_numpy(handheld_run.T_imu_lidar)[None])[0]
    gt = handheld_run.gt_lidar.interpolate(out.stamps_ns).matrices()
    err = (out.T_world_lidar[0, :, :3, 3] - gt[:, :3, 3]).norm(dim=-1)
    assert out.valid.all() and int(out.status[0]) == int(CandidateStatus.OK)
    assert float(err.pow(2).mean().sqrt()) < 0.05, err  # APE RMSE, as FAST-LIO is judged
    assert float(err.max()) < 0.15, err


def test_lost_track_counts_consecutive_misses_only():
    misses = torch.zeros(3, dtype=torch.int64)
    active = torch.tensor([True, True, False])
    for updated in ([False, False, False], [True, False, False], [False, False, False]):
        misses = count_misses(misses, torch.tensor(updated), active)
    assert misses.tolist() == [1, 3, 0]  # reset by an update; inactive filters do not count


def test_wildly_wrong_extrinsic_is_reported_not_crashed(handheld_run, handheld_segment):
    seg, ref = handheld_segment
    backend = _backend(points_per_scan=150)
    backend.prepare([seg], [ref])
    wrong = geo.se3_exp(torch.tensor([[2.0, -1.5, 1.0, 2.0, 1.0, -0.5]]))
    T = torch.cat([torch.from_numpy(handheld_run.T_imu_lidar)[None], wrong])
    out, reward = _rewards(backend, seg, ref, T)
    assert int(out.status[0]) == int(CandidateStatus.OK)
    assert int(out.status[1]) != int(CandidateStatus.OK)
    assert torch.isfinite(out.T_world_lidar).all()
    assert float(reward[1]) < 0.5 * float(reward[0])


def test_time_offset_candidates(sim):
    run = sim(rig={"time_offset_s": 0.02})
    seq = run.sequence()
    seg = seq.segment(seq.start_ns + 1_500_000_000, seq.end_ns)
    from l2calib.interfaces import ReferenceTrajectory

    ref = ReferenceTrajectory(seg.name, run.gt_lidar)
    backend = _backend(points_per_scan=200)
    backend.prepare([seg], [ref])
    T = torch.from_numpy(run.T_imu_lidar)[None].expand(3, 4, 4)
    out = backend.evaluate(T, torch.tensor([0.02, 0.0, 0.05]))[0]
    gt = ref.trajectory.interpolate(out.stamps_ns).matrices()
    reward = trajectory_reward(gt, out.T_world_lidar, out.valid, align="none").reward
    assert reward[0] > reward[1] and reward[0] > reward[2], reward


def test_vio_placeholder_fails_loudly():
    spec = get_plugin("l2calib.backends", "vio")
    assert "PLACEHOLDER" in spec.description
    with pytest.raises(NotImplementedPluginError, match="placeholder"):
        spec.build({})


@pytest.mark.parametrize(("rate", "expected"), [(2.0, 10), (0.15, 0)])
def test_auto_window_follows_rotation_rate(rate, expected):
    from types import SimpleNamespace

    from l2calib_backends.lio_backend import resolve_window_scans
    from l2calib_backends.options import IekfOptions

    gyro = torch.zeros(400, 3, dtype=torch.float64)
    gyro[:, 2] = rate
    segments = [SimpleNamespace(imu=SimpleNamespace(gyro=gyro))]
    assert resolve_window_scans(IekfOptions(), segments) == expected
    assert resolve_window_scans(IekfOptions(window_scans=7), segments) == 7


def test_auto_settings_on_simulated_motion(sim):
    # profile -> (window_scans, accel-bias and gravity start sigmas in m/s², start biases)
    reference = {"handheld": (10, 0.1, "estimate"), "uav": (0, 0.01, "zero")}
    for profile, (window, sigma, biases) in reference.items():
        run = sim(profile, duration_s=4.0)
        seq = run.sequence()
        seg = seq.segment(seq.start_ns + 1_000_000_000, seq.end_ns)
        for name in ("iekf", "gtsam"):
            backend = get_plugin("l2calib.backends", name).build({"threads": 1})
            backend.prepare([seg], [ReferenceTrajectory(seg.name, run.gt_lidar)])
            assert backend.window_scans == window, (name, profile)
            assert backend.init_sigmas["ba"] == sigma, (name, profile)
            assert backend.init_sigmas.get("grav", sigma) == sigma, (name, profile)
            assert backend.start_biases == biases, (name, profile)
    explicit = _backend(init_sigma_accel_bias_m_s2=0.3).config.init_sigmas(weak_excitation=True)
    assert explicit["ba"] == 0.3 and explicit["grav"] == 0.01
    assert _backend(start_biases="estimate").config.start_bias_mode(True) == "estimate"


def test_segments_in_different_world_frames_get_their_own_shared_map(handheld_run):
    """A LiDAR-only reference starts each run at its own origin; one map over such segments
    overlays scans that do not belong together (on the simulated ground vehicle the odometry at
    the true extrinsic then disagreed with the reference by 5.6 cm instead of 0.34 cm). Two
    segments of one recording, each expressed in the frame of its own first pose (as two
    LiDAR-only runs would be), continuous runs: each must follow its own reference.
    """
    from l2calib.interfaces import ReferenceTrajectory
    from l2calib.trajectory import Trajectory

    seq = handheld_run.sequence()
    s0 = seq.start_ns + 1_500_000_000
    segs = [
        seq.segment(s0, s0 + 2_500_000_000),
        seq.segment(s0 + 3_000_000_000, s0 + 5_500_000_000),
    ]
    gt = handheld_run.gt_lidar
    T = torch.from_numpy(handheld_run.T_imu_lidar)[None]

    def own_frame(seg, name):
        first = gt.interpolate(np.array([seg.start_ns])).matrices()[0]
        M = torch.linalg.inv(first)[None] @ gt.matrices()
        return ReferenceTrajectory(
            seg.name, Trajectory.from_matrices(gt.stamps_ns, M, "lidar", name)
        )

    def rms_errors(references):
        backend = _backend(window_scans=0)
        backend.prepare(segs, references)
        out = []
        for o, r in zip(backend.evaluate(T), references, strict=True):
            want = r.trajectory.interpolate(o.stamps_ns).matrices()[:, :3, 3]
            e = (o.T_world_lidar[0, :, :3, 3] - want).norm(dim=-1)[o.valid[0]]
            out.append(float(e.pow(2).mean().sqrt()))
        return out

    own = rms_errors([own_frame(segs[0], "run-a"), own_frame(segs[1], "run-b")])
    assert max(own) < 0.01, own
    # One map per world frame: what caught the bug (a single map over both frames; here the
    # hand-held windows hide most of its effect, which on the ground vehicle was 5.6 cm).
    from l2calib_backends.reference_map import build_reference_maps

    refs = [own_frame(segs[0], "run-a"), own_frame(segs[1], "run-b"), own_frame(segs[1], "run-a")]
    maps = build_reference_maps([*segs, segs[1]], refs, 0.5, 0.05, 1.0, 100.0)
    assert maps[0] is maps[2] and maps[0] is not maps[1]
