"""The time offset is held (or its estimation starts) where the references' |ω| follows the gyro.

Issue 21; :mod:`l2calib.train.offset_hold`.
"""

from __future__ import annotations

import pytest

from l2calib.interfaces import ReferenceTrajectory
from l2calib.pipeline import PreparedData
from l2calib.recipe import recipe_from_dict
from l2calib.sim import SimConfig, simulate
from l2calib.time_offset_estimate import offset_from_references
from l2calib.train.env import CalibrationEnv
from l2calib.train.offset_hold import offset_from_rates


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


def test_a_sharp_correlation_holds_the_offset_and_ppo_searches_the_extrinsic_only(lagging):
    notes = []
    data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
    recipe = recipe_from_dict({"train": {"estimate_time_offset": True}})
    held, method = offset_from_rates(recipe, data, notes.append)
    assert not held.train.estimate_time_offset
    assert held.train.known_time_offset_s == pytest.approx(0.03, abs=0.002)
    assert method.startswith("held at the references' rotation-rate correlation")
    assert "held there" in notes[0] and data.notes == notes
    assert data.rate_offset_s is None  # nothing left to start
    assert recipe.train.estimate_time_offset  # the caller's recipe is not changed


def test_start_mode_starts_the_joint_estimation_there_unless_the_recipe_says_where(lagging):
    notes = []
    on = recipe_from_dict({"train": {"time_offset_from_rates": "start"}})
    data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
    same, method = offset_from_rates(on, data, notes.append)
    assert same is on and "jointly" in method
    assert data.time_offset_hint_s == pytest.approx(0.03, abs=0.002)
    assert "+30." in notes[0] and data.notes == notes
    given = recipe_from_dict({"train": {"estimate_time_offset": True, "init_time_offset_s": 0.0}})
    off = recipe_from_dict({"train": {"estimate_time_offset": False}})
    for recipe in (given, off):
        data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
        assert offset_from_rates(recipe, data, notes.append)[0] is recipe
        assert data.rate_offset_s is None


def test_a_known_offset_must_not_also_be_estimated():
    with pytest.raises(Exception, match="estimate_time_offset is true"):
        recipe_from_dict({"train": {"known_time_offset_s": 0.01}})
    ok = recipe_from_dict({"train": {"known_time_offset_s": 0.01, "estimate_time_offset": False}})
    assert ok.train.known_time_offset_s == 0.01


class _Asked(Exception):
    pass


class _Backend:
    """Records the offsets it is asked to score with, then stops (unit isolation of the env)."""

    outputs_in_reference_frame = False

    def __init__(self):
        self.seen = []

    def evaluate(self, T, offsets=None):
        self.seen.append(offsets)
        raise _Asked


def test_the_env_scores_every_candidate_at_the_held_offset_unless_told_otherwise():
    import torch

    backend = _Backend()
    env = CalibrationEnv(backend, [], 2, fixed_time_offset_s=0.03)
    T = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    with pytest.raises(_Asked):
        env.score_candidates(T)
    assert backend.seen[-1].tolist() == [0.03, 0.03]
    with pytest.raises(_Asked):  # the offset probe's own offsets
        env.score_candidates(T, torch.tensor([0.0, 0.01], dtype=torch.float64))
    assert backend.seen[-1].tolist() == [0.0, 0.01]
    assert env.action_spec.shape[-1] == 7
    with pytest.raises(Exception, match="fixed time offset and an estimated one"):
        CalibrationEnv(backend, [], 2, time_offset=True, fixed_time_offset_s=0.03)


def test_a_given_start_is_held_when_the_rates_agree_and_estimated_from_when_not(lagging):
    agree = recipe_from_dict({"train": {"init_time_offset_s": 0.0305}})  # `inspect`'s 30.5 ms
    data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
    held, method = offset_from_rates(agree, data, lambda _m: None)
    assert held.train.known_time_offset_s == pytest.approx(0.03, abs=0.002)
    assert method.startswith("held")
    notes = []
    disagree = recipe_from_dict({"train": {"init_time_offset_s": 0.02}})
    data = PreparedData(lagging.sequences, lagging.segments, lagging.references)
    same, method = offset_from_rates(disagree, data, notes.append)
    assert same is disagree and method.endswith("from the recipe's train.init_time_offset_s")
    assert "+20.00 ms" in notes[0] and "estimated jointly from the latter" in notes[0]
