"""Acceptance on simulated sequences: still segments are never selected; planar UGV motion
leaves roll and pitch weak."""

from __future__ import annotations

from l2calib.data import NS_PER_S
from l2calib.recipe import SelectionConfig
from l2calib.selection import select_windows
from l2calib.sim import SimConfig, simulate

LIGHT_LIDAR = {"model": "velodyne-vlp-16", "columns": 32}  # selection only needs the IMU


def run(profile, still=(), duration=60.0, seed=1):
    cfg = SimConfig.model_validate(
        {
            "duration_s": duration,
            "seed": seed,
            "lidar": LIGHT_LIDAR,
            "motion": {"profile": profile, "still_segments": [list(s) for s in still]},
        }
    )
    return simulate(cfg)


def test_still_segments_are_never_selected_on_a_handheld_run():
    still = [(15.0, 25.0), (38.0, 46.0)]
    r = run("handheld", still)
    seq = r.sequence()
    t0 = (r.t0_ns - seq.start_ns) / NS_PER_S  # sequence start vs the simulator's τ = 0
    periods = [(0.0, r.config.motion.still_start_s), *still]
    sel = select_windows([seq], SelectionConfig(budget_s=30.0))
    assert sel.total_s == 30.0 and sel.weak_axes == []
    for c in sel.chosen:
        a = (c.start_ns - seq.start_ns) / NS_PER_S - t0
        b = (c.end_ns - seq.start_ns) / NS_PER_S - t0
        for lo, hi in periods:
            assert min(b, hi) - max(a, lo) <= 0.0, (a, b, lo, hi)


def test_ugv_selection_names_roll_and_pitch_weak():
    seq = run("ugv", seed=2).sequence()
    sel = select_windows([seq], SelectionConfig(budget_s=30.0))
    assert sel.total_s == 30.0
    assert sel.weak_axes[:2] == ["rotation about x", "rotation about y"]
    assert "rotation about z" not in sel.weak_axes


def test_a_simulated_drive_is_selected_whole_and_the_user_told_why():
    from l2calib.pipeline import select_data
    from l2calib.recipe import load_recipe

    drive, hand = run("ugv", seed=2), run("handheld", duration=40.0)
    recipe = load_recipe("simulator", [])  # a hand-held budget: 10 s in 5 s windows
    data = select_data(recipe, sequences=[drive.sequence()])
    # Most of the 60 s drive (disjoint 10 s windows leave the gaps between them) instead of
    # the recipe's 10 s.
    assert data.selection.total_s >= 40.0 and data.selection.config.budget_s == 60.0
    assert {c.end_ns - c.start_ns for c in data.selection.chosen} == {10 * NS_PER_S}
    assert len(data.notes) == 1 and "planar, yaw-dominant motion" in data.notes[0]
    held = select_data(recipe, sequences=[hand.sequence()])
    assert held.selection.total_s == 10.0 and held.notes == []
