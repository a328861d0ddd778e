from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def fake_backend_env(monkeypatch):
    """Registers the fake backend as plugin ``fake-lio`` for the duration of a test."""
    from l2calib.plugins import ENV_VAR

    monkeypatch.setenv(ENV_VAR, "l2calib.backends:fake-lio=fake_specs:FAKE")
    monkeypatch.syspath_prepend(str(Path(__file__).parent))


@pytest.fixture(scope="session")
def hand_held_run():
    """10 s hand-held from the simulator (OS1-16, 64 columns): the run, its sequence, one 8 s
    segment and the exact LiDAR poses as its reference (shared by the start tests)."""
    from l2calib.interfaces import ReferenceTrajectory
    from l2calib.sim import SimConfig, simulate

    run = simulate(
        SimConfig.model_validate(
            {"duration_s": 10.0, "seed": 7, "motion": {"profile": "handheld"},
             "lidar": {"model": "ouster-os1-16", "columns": 64}}
        )
    )  # fmt: skip
    seq = run.sequence()
    seg = seq.segment(seq.start_ns + 1_000_000_000, seq.start_ns + 9_000_000_000)
    return run, seq, seg, ReferenceTrajectory(seg.name, run.gt_lidar, "pose", "gt")


@pytest.fixture
def hand_held(hand_held_run):
    """``(run, PreparedData)`` of :func:`hand_held_run`, fresh per test (its notes start empty)."""
    from l2calib.pipeline import PreparedData

    run, seq, seg, ref = hand_held_run
    return run, PreparedData([seq], [seg], [ref])
