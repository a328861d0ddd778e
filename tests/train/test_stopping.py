"""When PPO stops early: the reward plateau (with the coarse-to-fine data in mind)."""

from __future__ import annotations

from l2calib.recipe import TrainConfig
from l2calib.train.ppo import IterationRecord, _plateau


def _record(i: int, best: float, rot_sigma: float = 1.0, scans: int = 3200) -> IterationRecord:
    return IterationRecord(
        iteration=i, evaluations=32 * (i + 1), wall_s=float(i), reward_mean=best - 0.05,
        reward_max=best, mean_e_t_m=0.01, mean_e_r_deg=0.1, lost=0, diverged=0,
        translation_m=[0.1, 0.0, 0.0], rpy_deg=[0.0, 0.0, 0.0], time_offset_s=None,
        rotation_sigma_deg=[rot_sigma] * 3, translation_sigma_m=[0.05] * 3, loss_objective=0.0,
        loss_critic=0.0, loss_entropy=0.0, lr=1e-3, candidate_scans=scans,
    )  # fmt: skip


CFG = TrainConfig(stop_on_plateau=True, plateau_window=5)


def test_a_flat_best_reward_stops_once_the_rotation_is_narrow():
    flat = [_record(i, 0.9 + 0.0001 * (i % 2)) for i in range(10)]
    reason = _plateau(flat, CFG)
    assert reason is not None and reason.startswith("reward plateau after 10 iterations")
    assert _plateau(flat[:9], CFG) is None  # two full windows are needed
    assert _plateau(flat, TrainConfig(plateau_window=5, stop_on_plateau=False)) is None


def test_a_rising_reward_or_a_wide_rotation_keeps_training():
    rising = [_record(i, 0.8 + 0.01 * i) for i in range(10)]
    assert _plateau(rising, CFG) is None
    wide = [_record(i, 0.9, rot_sigma=5.0) for i in range(10)]
    assert _plateau(wide, CFG) is None


def test_rewards_on_different_parts_of_the_data_are_not_compared():
    """A coarse-to-fine step changes the data: a drop in reward there is not a plateau."""
    mixed = [_record(i, 0.95 if i < 5 else 0.9, scans=1600 if i < 5 else 3200) for i in range(10)]
    assert _plateau(mixed, CFG) is None
    same = [_record(i, 0.95 if i < 5 else 0.9) for i in range(10)]
    assert _plateau(same, CFG) is not None
    for r in same:
        r.data_fraction = 0.5  # the same part of the data, but not all of it
    assert _plateau(same, CFG) is None


def test_the_eta_is_the_budget_left_at_the_pace_so_far():
    from l2calib.cli.live import eta_text

    record = _record(9, 0.9)  # 10 iterations done in wall_s = 9 s
    assert eta_text(record, 100) == "≤ 1 min 21 s left"
    assert eta_text(record, 12) == "≤ 2 s left"
    assert eta_text(record, 10) == "≤ 0 s left"


def test_a_narrow_policy_hands_over_to_the_refinement():
    from l2calib.train.ppo import _narrow_enough

    cfg = TrainConfig(handover_rotation_sigma_deg=1.5, handover_translation_sigma_m=0.10)
    narrow = _record(40, 0.9, rot_sigma=1.0)  # translation σ 5 cm
    reason = _narrow_enough([narrow], cfg)
    assert reason is not None and reason.startswith("narrow enough for the refinement after 1")
    assert _narrow_enough([_record(40, 0.9, rot_sigma=2.0)], cfg) is None
    wide_t = TrainConfig(handover_rotation_sigma_deg=1.5, handover_translation_sigma_m=0.04)
    assert _narrow_enough([narrow], wide_t) is None
    assert _narrow_enough([narrow], TrainConfig(handover_rotation_sigma_deg=None)) is None


def test_the_hand_over_can_wait_for_the_time_offset():
    """Born narrow in rotation and translation, the policy still samples its start's 20 ms of
    time offset; with ``handover_time_offset_sigma_s`` it hands over only once that is narrow."""
    from l2calib.train.ppo import _narrow_enough

    gated = TrainConfig(handover_time_offset_sigma_s=0.005)
    wide = _record(0, 0.9)  # rotation σ 1°, translation σ 5 cm: narrow
    wide.time_offset_sigma_s = 0.02
    assert _narrow_enough([wide], TrainConfig()) is not None  # the offset is not checked
    assert _narrow_enough([wide], gated) is None
    narrow = _record(1, 0.9)
    narrow.time_offset_sigma_s = 0.004
    reason = _narrow_enough([wide, narrow], gated)
    assert reason is not None and reason.endswith("/ 5 ms)") and "after 2 iterations" in reason
    unestimated = _record(0, 0.9)  # time offset not estimated (σ None): the gate does not apply
    assert _narrow_enough([unestimated], gated) is not None


def test_a_signal_inside_a_held_block_is_raised_as_the_block_ends():
    """The PPO update runs inside ``held()``: a Ctrl-C there must surface as ``Interrupted``
    after the update, not as whatever a library turns it into mid-way."""
    import os
    import signal

    import pytest

    from l2calib.interrupt import Interrupted, handling, held

    done = []
    with pytest.raises(Interrupted) as info, handling(), held():
        os.kill(os.getpid(), signal.SIGINT)
        done.append("the rest of the block ran")
    assert done and info.value.signum == signal.SIGINT
