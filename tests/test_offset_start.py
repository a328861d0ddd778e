"""The time offset's estimation starts where the references' |ω| follows the gyro (issue 21)."""

from __future__ import annotations

import pytest

from l2calib.interfaces import ReferenceTrajectory
from l2calib.pipeline import PreparedData
from l2calib.recipe import recipe_from_dict
from l2calib.sim import SimConfig, simulate
from l2calib.time_offset_estimate import offset_from_references
from l2calib.training import _offset_from_rates


@pytest.fixture(scope="module")
def lagging():
    """8 s hand-held, the IMU stamping 30 ms after the LiDAR; two 3 s segments, exact poses."""
    run = simulate(
        SimConfig.model_validate(
            {"duration_s": 8.0, "seed": 4, "motion": {"profile": "handheld"},
             "lidar": {"model": "ouster-os1-16", "columns": 64},
             "rig": {"time_offset_s": 0.03}}
        )
    )  # fmt: skip
    seq = run.sequence()
    segs = [seq.segment(seq.start_ns + int(a * 1e9), seq.start_ns + int(b * 1e9))
            for a, b in ((1.0, 4.0), (4.5, 7.5))]  # fmt: skip
    refs = [ReferenceTrajectory(s.name, run.gt_lidar, "pose", "gt") for s in segs]
    return PreparedData([seq], segs, refs)


def test_the_references_rate_finds_the_offset(lagging):
    est = offset_from_references(lagging.references, lagging.segments, lagging.sequences, 0.1)
    assert est is not None and est.observable
    assert est.time_offset_s == pytest.approx(0.03, abs=0.002)


def test_kiss_icp_and_position_only_references_are_not_used(lagging):
    refs = [ReferenceTrajectory(r.segment, r.trajectory, "pose", "kiss-icp")
            for r in lagging.references]  # fmt: skip
    refs += [ReferenceTrajectory(r.segment, r.trajectory, "position", "rtk")
             for r in lagging.references]  # fmt: skip
    assert offset_from_references(refs, lagging.segments, lagging.sequences, 0.1) is None


def test_training_starts_the_offset_there_unless_the_recipe_says_where(lagging):
    notes = []
    on = recipe_from_dict({"train": {"estimate_time_offset": True}})
    data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
    _offset_from_rates(on, data, notes.append)
    assert data.time_offset_hint_s == pytest.approx(0.03, abs=0.002)
    assert "+30." in notes[0] and data.notes == notes
    given = recipe_from_dict({"train": {"estimate_time_offset": True, "init_time_offset_s": 0.0}})
    off = recipe_from_dict({"train": {"estimate_time_offset": False}})
    for recipe in (given, off):
        data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
        _offset_from_rates(recipe, data, notes.append)
        assert data.rate_offset_s is None
