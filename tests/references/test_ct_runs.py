"""ct-lidar runs: segments near each other or near their recording's start share one odometry."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from test_ct_lidar_source import build

from l2calib.alignment import ape
from l2calib.errors import ReferenceLostTrackError
from l2calib.references import ct_lidar_source
from l2calib.references.ct_runs import plan_runs

S = 1_000_000_000


@dataclass
class Seq:
    """Stand-in for a Sequence: plan_runs reads its name and start only."""

    name: str
    start_ns: int = 0


@dataclass
class Seg:
    """Stand-in for a Segment: plan_runs reads its name, sequence and window only."""

    name: str
    sequence: str
    start_ns: int
    end_ns: int


def test_segments_near_the_start_and_each_other_share_one_run_from_the_start():
    seqs = {"a": Seq("a")}
    segs = [Seg("late", "a", 22 * S, 27 * S), Seg("early", "a", 8 * S, 13 * S),
            Seg("mid", "a", 15 * S, 20 * S)]  # fmt: skip
    runs, alone = plan_runs(segs, seqs, from_start_s=60, chain_gap_s=10, margin_s=1)
    assert alone == [] and len(runs) == 1
    assert runs[0].start_ns == 0 and [s.name for s in runs[0].segments] == ["early", "mid", "late"]


def test_far_segments_run_apart_and_a_lone_far_segment_keeps_the_per_segment_path():
    seqs = {"a": Seq("a", 100 * S)}
    segs = [Seg("near", "a", 110 * S, 115 * S), Seg("far1", "a", 300 * S, 305 * S),
            Seg("far2", "a", 310 * S, 315 * S), Seg("lone", "a", 500 * S, 505 * S),
            Seg("other", "unknown", 0, 5 * S)]  # fmt: skip
    runs, alone = plan_runs(segs, seqs, from_start_s=60, chain_gap_s=10, margin_s=1)
    assert [(r.start_ns, [s.name for s in r.segments]) for r in runs] == [
        (100 * S, ["near"]),  # from the recording's start, 10 s before the segment
        (299 * S, ["far1", "far2"]),  # margin_s before the first of the chain
    ]
    assert sorted(s.name for s in alone) == ["lone", "other"]
    runs, alone = plan_runs(segs, seqs, from_start_s=0, chain_gap_s=0, margin_s=1)
    assert [[s.name for s in r.segments] for r in runs] == [] and len(alone) == 5


@pytest.fixture(scope="module")
def two(swing):
    """Two segments of the swing's recording, 1.0-2.0 s and 2.2-3.4 s."""
    st = swing.sequence.scans.stamps_ns
    return [swing.sequence.segment(int(st[a]), int(st[b])) for a, b in ((10, 20), (22, 34))]


def test_segments_cut_from_one_run_cover_their_points_and_are_cached(
    swing, two, tmp_path, monkeypatch
):
    refs = build(tmp_path, [swing.sequence]).compute(two)
    for seg, ref in zip(two, refs, strict=True):
        tr = ref.trajectory
        assert ref.segment == seg.name and tr.world_frame == refs[0].trajectory.world_frame
        assert tr.stamps_ns[0] == seg.scans[0].stamp_ns
        assert tr.stamps_ns[-1] >= seg.scans[-1].end_stamp_ns
        assert tr.stamps_ns[-2] < seg.scans[-1].end_stamp_ns  # no pose beyond the one needed
        points = np.unique(np.concatenate([s.point_stamps_ns for s in seg.scans]))
        assert tr.sample(points, max_gap_s=0.05)[1].all()
        # measured 1.13 / 0.45 cm (each segment on its own, 1 s warm-up: 1.22 / 0.82 cm); the
        # recording starts mid-swing here, so this checks the cut, not the gain from rest
        assert ape(swing.run.gt_lidar, tr).rmse_t < 0.02

    def boom(*_, **__):
        raise AssertionError("recomputed although cached")

    monkeypatch.setattr(ct_lidar_source, "_run", boom)
    again = build(tmp_path, [swing.sequence]).compute(two)
    assert all(
        np.array_equal(a.trajectory.t_world_body, b.trajectory.t_world_body)
        for a, b in zip(again, refs, strict=True)
    )


def test_a_run_whose_backward_pass_loses_track_has_no_alternative(swing, two, tmp_path):
    """Cold at the end of a hand-held swing, the backward pass loses track: one estimate only."""
    refs = build(tmp_path, [swing.sequence], backward_pass=True).compute(two)
    forward = build(tmp_path, [swing.sequence]).compute(two)  # the same run, one pass
    for ref, fwd in zip(refs, forward, strict=True):
        assert ref.alternative is None
        np.testing.assert_allclose(ref.trajectory.t_world_body, fwd.trajectory.t_world_body)


def test_a_run_that_loses_track_leaves_each_segment_to_its_own_start(
    swing, two, tmp_path, monkeypatch
):
    def lost(*_, **__):
        raise ReferenceLostTrackError("ct-lidar lost track 1.0 s into the run")

    calls = []
    real = ct_lidar_source.run_segment_passes

    def per_segment(scans, warmup, *a, **k):
        calls.append(len(warmup))
        return real(scans, warmup, *a, **k)

    monkeypatch.setattr(ct_lidar_source.CtLidarReference, "_compute_run", lost)
    monkeypatch.setattr(ct_lidar_source, "run_segment_passes", per_segment)
    refs = build(tmp_path, [swing.sequence], cache=False).compute(two)
    assert [r.segment for r in refs] == [s.name for s in two]
    assert len(calls) == 2 and all(n > 0 for n in calls)  # each with its warm-up scans
