"""ct-lidar's backward pass: mirrored scans, the fusion of two passes, and auto on a drive."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2calib.alignment import ape
from l2calib.data import LidarScan
from l2calib.plugins import get_plugin
from l2calib.references.ct_smoothing import fuse, reversed_scans


def _scans(rng, n=4):
    out = []
    for k in range(n):
        offsets = np.sort(rng.uniform(0.0, 0.1, 50))
        offsets[0] = 0.0  # the scan's stamp is its earliest point
        out.append(
            LidarScan(
                stamp_ns=1_000_000_000 + k * 100_000_000,
                points_lidar=rng.normal(size=(50, 3)).astype(np.float32),
                offset_s=offsets.astype(np.float32),
                intensity=rng.uniform(size=50).astype(np.float32),
                ring=rng.integers(0, 16, 50).astype(np.uint16),
            )
        )
    return out


def test_reversed_scans_mirror_every_point_time_and_reverse_twice_to_the_original(rng):
    scans = _scans(rng)
    rev, t0 = reversed_scans(scans)
    assert [s.stamp_ns for s in rev] == sorted(s.stamp_ns for s in rev)
    for s, r in zip(scans, reversed(rev), strict=True):
        # the same points, each at the mirrored time t0 - t (to the ns rounding of float32)
        order = np.argsort(s.point_stamps_ns)
        back = np.argsort(t0 - r.point_stamps_ns)
        np.testing.assert_allclose(t0 - r.point_stamps_ns[back], s.point_stamps_ns[order], atol=20)
        np.testing.assert_array_equal(np.sort(r.ring), np.sort(s.ring))
        assert np.all(r.offset_s >= 0) and np.all(np.diff(r.offset_s) >= 0)
    again, t1 = reversed_scans(rev)
    assert t1 == t0
    for s, a in zip(scans, again, strict=True):
        assert abs(a.stamp_ns - s.stamp_ns) <= 20
        np.testing.assert_allclose(np.sort(a.points_lidar, 0), np.sort(s.points_lidar, 0))


def _poses(t_ns, sign):
    """A drive's poses at ``t_ns`` with a lag-like error ``sign * e(t)`` (odd under reversal)."""
    t = t_ns * 1e-9
    p = np.stack([4 * t, 3 * np.sin(0.3 * t), 0.05 * np.sin(t)], 1)
    R = Rotation.from_euler("zyx", np.stack([0.6 * np.sin(0.3 * t), 0.01 * t, 0.02 * t], 1))
    e_rot = np.stack([0.002 * np.sin(t), 0.001 * np.cos(0.5 * t), 0 * t], 1)
    e_pos = np.stack([0.01 * np.sin(0.7 * t), 0.02 * np.cos(t), 0 * t], 1)
    return R, p, R * Rotation.from_rotvec(sign * e_rot), p + sign * e_pos


def test_the_average_of_two_passes_cancels_an_error_odd_in_time():
    t_ns = np.arange(400, dtype=np.int64) * 25_000_000
    R, p, R_f, p_f = _poses(t_ns, +1)
    # the backward pass: the opposite error, in its own frame, at other stamps, shorter
    tb = t_ns[20:-20] + 7_000_000
    _, _, R_b, p_b = _poses(tb, -1)
    A = Rotation.from_euler("xyz", [3, -2, 50], degrees=True)
    back = (tb, (A * R_b).as_matrix(), A.apply(p_b) + [10.0, -5.0, 1.0])
    R_out, p_out = fuse(t_ns, R_f.as_matrix(), p_f, back)
    inside = (t_ns >= tb[0]) & (t_ns <= tb[-1])
    # the truth up to the (common) frame the fusion settles in: compare after removing it
    err_R = (Rotation.from_matrix(R_out[inside]) * R[inside].inv()).as_rotvec()
    assert np.abs(err_R - err_R.mean(0)).max() < 1e-4  # forward: 2e-3
    err_p = p_out[inside] - p[inside]
    assert np.abs(err_p - err_p.mean(0)).max() < 1e-3  # forward: 2e-2
    # outside the backward span the forward poses are kept as they are
    np.testing.assert_array_equal(p_out[~inside], p_f[~inside])
    np.testing.assert_array_equal(R_out[~inside], R_f.as_matrix()[~inside])


def test_auto_runs_the_backward_pass_on_a_drive_only_and_it_tracks(drive, tmp_path):
    spec = get_plugin("l2calib.references", "ct-lidar")
    auto = {"cache_dir": str(tmp_path), "backward_pass": "auto"}
    on = spec.build(auto, planar_motion=True)
    off = spec.build(auto)
    default = spec.build({"cache_dir": str(tmp_path)}, planar_motion=True)
    assert default.options.backward_pass is True and default.notes  # auto is the default
    assert spec.build({"cache_dir": str(tmp_path)}).options.backward_pass is False
    assert on.options.backward_pass is True and on.notes
    assert off.options.backward_pass is False and not off.notes
    ref = on.compute([drive.segment])[0]
    both = ref.trajectory
    # the forward pass alone, with the vehicle prior a planar drive also gets (auto)
    alone = spec.build({**auto, "backward_pass": False}, planar_motion=True)
    alone = alone.compute([drive.segment])[0]
    fwd = alone.trajectory
    np.testing.assert_array_equal(both.stamps_ns, fwd.stamps_ns)
    assert not np.allclose(both.t_world_body, fwd.t_world_body)
    gt = drive.run.gt_lidar
    assert ape(gt, both).rmse_t < 0.015, ape(gt, both).rmse_t
    # the forward pass alone rides along as the reference's alternative (the uncertainty's
    # reference-error term), from the cache too; a single pass has none
    assert alone.alternative is None
    for r in (ref, spec.build(auto, planar_motion=True).compute([drive.segment])[0]):
        np.testing.assert_array_equal(r.alternative.stamps_ns, both.stamps_ns)
        np.testing.assert_allclose(r.alternative.t_world_body, fwd.t_world_body)


def test_the_pipeline_turns_it_on_for_a_drive_says_so_and_starts_it_after_the_segment(
    drive, monkeypatch
):
    from l2calib.pipeline import compute_references
    from l2calib.recipe import recipe_from_dict
    from l2calib.references import ct_lidar_source

    runs = []
    real = ct_lidar_source._run

    def spy(odo, scans, world, progress):  # noqa: ANN001, ANN202
        runs.append((world, len(scans)))
        return real(odo, scans, world, progress)

    monkeypatch.setattr(ct_lidar_source, "_run", spy)
    notes: list[str] = []
    options = {"cache": False}  # backward_pass: auto, the default
    recipe = recipe_from_dict({"reference": {"name": "ct-lidar", "options": options}})
    ref = compute_references(recipe, [drive.segment], [drive.sequence], notes.append)[0]
    assert any("backwards in time" in n for n in notes)
    (fwd, n_fwd), (bwd, n_bwd) = runs
    assert "backward" in bwd and "backward" not in fwd
    # the backward pass also runs on the scans after the segment (backward_leadout_s: 5 s)
    last = drive.segment.scans[-1].stamp_ns
    after = list(drive.sequence.scans.load(last + 1, last + 5_000_000_000))
    assert len(after) == 4 and n_bwd == n_fwd + len(after)  # the recording ends 0.4 s later
    assert ref.trajectory.stamps_ns[0] == drive.segment.scans[0].stamp_ns


def test_the_cache_key_names_the_backward_pass_only_when_it_runs(tmp_path):
    spec = get_plugin("l2calib.references", "ct-lidar")
    off = spec.build({"cache_dir": str(tmp_path)}).key_options()
    on = spec.build({"cache_dir": str(tmp_path), "backward_pass": True}).key_options()
    assert "backward_pass" not in off  # references cached before the option keep their keys
    assert on.pop("backward_pass") is True and on.pop("alternative") == "forward pass"
    assert on == off


def test_a_segment_cut_from_a_run_with_both_passes_carries_the_forward_pass(drive, tmp_path):
    """The shared-run path (the recording's start): its cut of the forward pass rides along."""
    spec = get_plugin("l2calib.references", "ct-lidar")
    seqs = [drive.sequence]
    both = spec.build({"cache_dir": str(tmp_path), "backward_pass": True}, sequences=seqs)
    one = spec.build({"cache_dir": str(tmp_path)}, sequences=seqs)
    ref, fwd = both.compute([drive.segment])[0], one.compute([drive.segment])[0]
    assert "@" in ref.trajectory.world_frame  # cut from a run (ct_runs), not the segment's own
    np.testing.assert_array_equal(ref.alternative.stamps_ns, ref.trajectory.stamps_ns)
    np.testing.assert_allclose(ref.alternative.t_world_body, fwd.trajectory.t_world_body)
    assert not np.allclose(ref.alternative.t_world_body, ref.trajectory.t_world_body)
    cached = spec.build({"cache_dir": str(tmp_path), "backward_pass": True}, sequences=seqs)
    again = cached.compute([drive.segment])[0]
    np.testing.assert_array_equal(again.alternative.t_world_body, ref.alternative.t_world_body)


def test_the_vehicle_prior_is_resolved_by_the_planar_check_and_keys_the_cache(tmp_path):
    from l2calib.references.ct_odometry import CtLidarOdometry
    from l2calib.references.options import (
        GENERAL_MOTION_NOISE,
        VEHICLE_MOTION_NOISE,
        CtLidarOptions,
    )

    spec = get_plugin("l2calib.references", "ct-lidar")
    base = {"cache_dir": str(tmp_path)}
    general = spec.build(base)
    vehicle = spec.build(base, planar_motion=True)
    given = spec.build({**base, "noise_rot_deg": 0.3, "noise_rate_rad_s": 2.0}, planar_motion=True)
    pick = ("noise_rot_deg", "noise_rate_rad_s")
    assert tuple(general.key_options()[k] for k in pick) == GENERAL_MOTION_NOISE
    assert tuple(vehicle.key_options()[k] for k in pick) == VEHICLE_MOTION_NOISE
    assert tuple(given.key_options()[k] for k in pick) == (0.3, 2.0)  # given numbers win
    assert any("vehicle prior" in n for n in vehicle.notes)
    assert not any("vehicle prior" in n for n in general.notes + given.notes)
    # a general key is the options' dump with the numbers the option had before ``auto``:
    # references cached before it keep their keys
    before = CtLidarOptions(noise_rot_deg=0.5, noise_rate_rad_s=1.0, backward_pass=False)
    dropped = {"cache", "cache_dir", "backward_pass"}
    assert general.key_options() == before.model_dump(exclude=dropped)
    # the odometry on its own (not through the source) takes the general numbers
    q = CtLidarOdometry(CtLidarOptions()).q_density
    np.testing.assert_allclose(q[[0, 6]], [np.radians(0.5) ** 2, 1.0])
    q = CtLidarOdometry(vehicle.options).q_density
    np.testing.assert_allclose(q[[0, 6]], [np.radians(0.05) ** 2, 0.1**2])
    with pytest.raises(ValueError, match="noise_rot_deg"):
        CtLidarOptions(noise_rot_deg=-1.0)
