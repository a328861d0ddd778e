"""kiss-icp reference: stamps, coverage of every point, warm-up, accuracy and the disk cache."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch
from ref_helpers import rpe

from l2calib import geometry as geo
from l2calib.alignment import ape
from l2calib.data import Segment
from l2calib.errors import ReferenceSourceError
from l2calib.plugins import get_plugin
from l2calib.references import kiss_icp_source
from l2calib.references.kiss_icp_source import extrapolate_start
from l2calib.trajectory import Trajectory

OPTS = {"max_range_m": 60.0}


def build(cache_dir, sequences=None, **extra):
    spec = get_plugin("l2calib.references", "kiss-icp")
    return spec.build({**OPTS, "cache_dir": str(cache_dir), **extra}, sequences=sequences)


@pytest.fixture(scope="module")
def refs(drive, cache_dir):
    warm = build(cache_dir, [drive.sequence]).compute([drive.segment])[0]
    cold = build(cache_dir).compute([drive.segment])[0]
    return warm, cold


def test_stamps_are_scan_ends_and_cover_every_point(drive, refs):
    scans = drive.segment.scans
    for ref in refs:
        tr = ref.trajectory
        assert ref.constrains == "pose" and ref.source == "kiss-icp" and tr.body_frame == "lidar"
        assert tr.stamps_ns.dtype == np.int64 and np.all(np.diff(tr.stamps_ns) > 0)
        assert tr.world_frame == f"kiss-icp:{drive.segment.name}"
        ends = np.array([s.end_stamp_ns for s in scans])
        assert np.array_equal(tr.stamps_ns[-len(scans) :], ends)
        assert tr.stamps_ns[0] <= scans[0].stamp_ns < tr.stamps_ns[1]
        points = np.unique(np.concatenate([s.point_stamps_ns for s in scans]))
        _, ok = tr.sample(points, max_gap_s=0.2)
        assert ok.all()


def test_warm_up_keeps_the_scan_end_before_the_segment(drive, refs):
    warm, cold = refs
    seq_stamps = drive.sequence.scans.stamps_ns
    i = int(np.searchsorted(seq_stamps, drive.segment.scans[0].stamp_ns))
    previous = drive.run.scans[i - 1]
    assert warm.trajectory.stamps_ns[0] == previous.end_stamp_ns
    assert cold.trajectory.stamps_ns[0] == drive.segment.scans[0].stamp_ns  # extrapolated


def test_reference_matches_ground_truth(drive, refs):
    path = float(np.linalg.norm(np.diff(refs[0].trajectory.t_world_body, axis=0), axis=1).sum())
    assert path > 5.0
    for ref in refs:
        res = ape(drive.run.gt_lidar, ref.trajectory)
        rot_deg, trans_m = rpe(drive.run.gt_lidar, ref.trajectory, 1.0)
        # 16-beam LiDAR in a hall: KISS-ICP drifts ~0.7 deg and ~2 % per second here
        assert res.rmse_t < 0.02 * path, res.rmse_t
        assert np.median(rot_deg) < 1.5 and np.median(trans_m) < 0.04 * 4.0, (rot_deg, trans_m)


def test_extrapolation_is_exact_for_constant_velocity():
    xi = torch.tensor([0.8, -0.2, 0.1, 0.3, -0.1, 0.5])
    stamps = np.array([1_000_000_000, 1_100_000_000, 1_200_000_000], dtype=np.int64)
    T = geo.se3_exp(torch.tensor([0.0, 1.0, 2.0])[:, None] * xi)
    tr = extrapolate_start(Trajectory.from_matrices(stamps, T, "lidar"), 950_000_000)
    expected = geo.se3_exp(-0.5 * xi)
    assert tr.stamps_ns[0] == 950_000_000
    assert torch.allclose(tr.matrices()[0], expected, atol=1e-9)


def test_cache_hit_and_invalidation(drive, cache_dir, refs, monkeypatch):
    def boom(*_, **__):
        raise AssertionError("recomputed although cached")

    monkeypatch.setattr(kiss_icp_source, "run_segment", boom)
    again = build(cache_dir, [drive.sequence]).compute([drive.segment])[0]
    assert np.array_equal(again.trajectory.t_world_body, refs[0].trajectory.t_world_body)
    with pytest.raises(AssertionError, match="recomputed"):  # another setting: another key
        build(cache_dir, [drive.sequence], min_range_m=1.0).compute([drive.segment])
    seg = drive.segment
    scans = list(seg.scans)
    moved = type(scans[3])(
        scans[3].stamp_ns, scans[3].points_lidar + np.float32(0.01), scans[3].offset_s
    )
    changed = Segment(
        seg.name,
        seg.sequence,
        seg.start_ns,
        seg.end_ns,
        seg.imu,
        scans[:3] + [moved] + scans[4:],
        seg.meta,
    )
    with pytest.raises(AssertionError, match="recomputed"):  # other data: another key
        build(cache_dir, [drive.sequence]).compute([changed])


@pytest.mark.parametrize("damage", ["truncate-npz", "garbage-header", "flip-byte"])
def test_corrupted_cache_is_reported_deleted_and_recomputed(drive, tmp_path, caplog, damage):
    seg = Segment(
        drive.segment.name,
        drive.segment.sequence,
        drive.segment.start_ns,
        drive.segment.end_ns,
        drive.segment.imu,
        drive.segment.scans[:8],
        drive.segment.meta,
    )
    src = build(tmp_path)
    first = src.compute([seg])[0]
    npz, header = src.cache.paths(src.key(seg, []))
    assert npz.exists() and header.exists()
    if damage == "truncate-npz":
        npz.write_bytes(npz.read_bytes()[:50])
    elif damage == "garbage-header":
        header.write_text("{not json")
    else:
        blob = bytearray(npz.read_bytes())
        blob[len(blob) // 2] ^= 0xFF
        npz.write_bytes(bytes(blob))
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        again = build(tmp_path).compute([seg])[0]
    assert "corrupted" in caplog.text and "recomputing" in caplog.text
    assert np.allclose(again.trajectory.t_world_body, first.trajectory.t_world_body, atol=1e-6)
    assert header.exists() and npz.exists()  # rewritten
    assert build(tmp_path).cache.load(src.key(seg, [])) is not None


def test_too_short_segment_is_an_error(drive, tmp_path):
    seg = drive.segment
    one = Segment(seg.name, seg.sequence, seg.start_ns, seg.end_ns, seg.imu, seg.scans[:1])
    with pytest.raises(ReferenceSourceError, match="at least 2 scans.*selection.window_s"):
        build(tmp_path, cache=False).compute([one])


def test_segment_from_a_bag_with_warm_up(drive, tmp_path):
    from l2calib.io.sequences import open_sequences
    from l2calib.recipe import DataConfig
    from l2calib.sim import write_run

    files = write_run(drive.run, tmp_path / "run")
    data = DataConfig()
    data.lidar.topic, data.imu.topic = "/ouster/points", "/imu/data"
    data.lidar.min_range_m = 0.5
    (seq,) = open_sequences([files["bag"]], data)
    assert seq.meta["path"] == files["bag"] and seq.meta["lidar_topic"] == "/ouster/points"
    st = seq.scans.stamps_ns
    i = int(np.searchsorted(st, drive.segment.scans[0].stamp_ns))
    seg = seq.segment(int(st[i]), int(st[i + 25]))
    ref = build(tmp_path / "cache", [seq]).compute([seg])[0]
    assert ref.trajectory.stamps_ns[0] < seg.scans[0].stamp_ns  # a warm-up pose from the bag
    assert ref.trajectory.stamps_ns[-1] == seg.scans[-1].end_stamp_ns
    assert ape(drive.run.gt_lidar, ref.trajectory).rmse_t < 0.15
