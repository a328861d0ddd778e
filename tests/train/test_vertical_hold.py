"""Planar-motion detection and the vertical lever-arm hold (ground vehicles, issue #27)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from fakes import T_TRUE, FakeBackend, reference
from imu_signals import imu_signal
from scipy.spatial.transform import Rotation

from l2calib.data import ImuSamples
from l2calib.recipe import ExtrinsicPrior, SelectionConfig, TrainConfig
from l2calib.selection.planar import planar_motion, planar_selection
from l2calib.train.env import CalibrationEnv
from l2calib.train.vertical_hold import decide_hold


def _imu(rot_amp, yaw_rate=0.0, mount=None, seed=0) -> ImuSamples:
    stamps, gyro, accel = imu_signal(
        30.0, rot_amp_rad=rot_amp, yaw_rate_rad_s=yaw_rate, acc_amp_m_s2=(0.5, 0.5, 0.1), seed=seed
    )
    if mount is not None:  # an IMU mounted turned: its readings are those of the rig, rotated
        R = Rotation.from_rotvec(mount).as_matrix().T
        gyro, accel = gyro @ R.T, accel @ R.T
    return ImuSamples(stamps, gyro, accel)


def test_planar_drive_is_found_and_its_up_axis_follows_the_mounting():
    car = planar_motion([_imu((0.004, 0.004, 0.6), yaw_rate=0.2)])
    assert car.yaw_share > 0.97 and car.planar(0.9)
    assert np.allclose(car.axis_imu, [0, 0, 1], atol=0.02)
    # The same drive with the IMU mounted 30 deg rolled: "up" is no longer the IMU's z.
    tilted = planar_motion([_imu((0.004, 0.004, 0.6), 0.2, mount=[np.radians(30), 0, 0])])
    assert tilted.planar(0.9)
    expect = Rotation.from_rotvec([np.radians(30), 0, 0]).as_matrix().T @ [0, 0, 1]
    assert np.allclose(tilted.axis_imu, expect, atol=0.02)


def test_a_loop_turns_one_way_and_a_figure_eight_both():
    t = np.arange(0.0, 60.0, 0.005)
    up = np.tile([0.0, 0.0, 9.81], (len(t), 1))

    def drive(yaw_rate):  # planar: rate about the vertical only
        return planar_motion(
            [ImuSamples((t * 1e9).astype(np.int64), np.c_[0 * t, 0 * t, yaw_rate], up)]
        )

    turns = np.where(np.sin(2 * np.pi * t / 15) > 0.5, 0.4, 0.0)  # a 0.4 rad/s turn every 15 s
    loop = drive(turns + 0.03 * np.sin(3 * t))  # left turns only, with sway
    eight = drive(turns * np.sign(np.sin(2 * np.pi * t / 30)) + 0.03 * np.sin(3 * t))
    assert loop.planar(0.9) and eight.planar(0.9)
    assert loop.one_way_share > 0.99
    assert eight.one_way_share < 0.2  # the turns alternate: left, right, left, ...


def test_hand_held_and_still_data_are_not_planar():
    hand = planar_motion([_imu((0.5, 0.5, 0.8))])
    assert hand.yaw_share < 0.6 and not hand.planar(0.9)
    still = planar_motion([_imu((0.0, 0.0, 0.0), seed=1)])
    assert not still.planar(0.9)  # noise alone turns too few samples to judge


def test_planar_drives_select_more_data_in_longer_windows_unless_turned_off():
    car, hand = [_imu((0.004, 0.004, 0.6), yaw_rate=0.2)], [_imu((0.5, 0.5, 0.8))]
    hand_held = SelectionConfig(window_s=5.0, budget_s=15.0)
    wide, note = planar_selection(hand_held, 0.97, car)
    assert (wide.budget_s, wide.window_s) == (60.0, 10.0)
    assert "planar" in note and "60 s in windows of 10 s" in note and "recipe: 15 s, 5 s" in note
    assert planar_selection(hand_held, 0.97, hand) == (hand_held, None)  # not a vehicle
    off = hand_held.model_copy(update={"planar_budget_s": None})
    assert planar_selection(off, 0.97, car) == (off, None)
    # A recipe that already asks for more keeps it (the budget and window only grow).
    more = SelectionConfig(window_s=12.0, budget_s=90.0)
    assert planar_selection(more, 0.97, car) == (more, None)


def test_hold_sets_only_the_vertical_component_and_projects_the_spread():
    drive = [_imu((0.004, 0.004, 0.6), yaw_rate=0.2)]
    hold = decide_hold(TrainConfig(), None, drive)
    assert hold is not None and hold.source == "none" and hold.value_m == 0.0
    T = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    T[:, :3, 3] = torch.tensor([[0.1, -0.2, 0.7], [0.0, 0.3, -1.5]], dtype=torch.float64)
    held = hold.apply(T)
    up = torch.tensor(hold.axis_imu, dtype=torch.float64)
    assert torch.allclose(held[:, :3, 3] @ up, torch.zeros(2), atol=1e-12)
    moved = held[:, :3, 3] - T[:, :3, 3]  # only along up
    off_axis = torch.linalg.cross(moved, up.expand_as(moved))
    assert torch.allclose(off_axis, torch.zeros(2, 3), atol=1e-9)
    assert torch.equal(held[:, :3, :3], T[:, :3, :3])
    sigma = hold.spread(torch.tensor([0.1, 0.2, 0.5], dtype=torch.float64))
    assert sigma[2] < 0.02
    assert abs(float(sigma[0]) - 0.1) < 1e-3 and abs(float(sigma[1]) - 0.2) < 2e-3
    text = hold.describe()
    assert "NOT a measurement" in text and "policy.prior" in text


def test_hold_follows_the_prior_and_the_setting():
    drive = [_imu((0.004, 0.004, 0.6), yaw_rate=0.2)]
    prior = ExtrinsicPrior(translation_m=(0.1, 0.0, 0.35))
    hold = decide_hold(TrainConfig(), prior, drive)
    assert hold.source == "prior" and hold.value_m == pytest.approx(0.35, abs=0.01)
    assert decide_hold(TrainConfig(hold_vertical_translation="off"), prior, drive) is None
    hand = [_imu((0.5, 0.5, 0.8))]
    assert decide_hold(TrainConfig(), None, hand) is None  # auto: not planar, searched
    forced = decide_hold(TrainConfig(hold_vertical_translation="on"), prior, hand)
    assert forced is not None and forced.source == "prior"


class _Recording(FakeBackend):
    def evaluate(self, T_imu_lidar, time_offset_s=None):
        self.seen = T_imu_lidar.clone()
        return super().evaluate(T_imu_lidar, time_offset_s)


def test_env_scores_candidates_with_the_held_vertical():
    hold = decide_hold(TrainConfig(), None, [_imu((0.004, 0.004, 0.6), yaw_rate=0.2)])
    refs = [reference("a")]
    backend = _Recording()
    backend.prepare([None], refs)
    env = CalibrationEnv(backend, refs, 2, hold=hold)
    T = T_TRUE.repeat(2, 1, 1).clone()
    T[1, 2, 3] += 0.8  # far off along the vertical only
    breakdown, _ = env.score_candidates(T)
    up = torch.tensor(hold.axis_imu, dtype=torch.float64)
    assert torch.allclose(backend.seen[:, :3, 3] @ up, torch.zeros(2, dtype=torch.float64))
    assert torch.allclose(breakdown.reward[0], breakdown.reward[1])  # the vertical no longer counts


def test_inspect_names_planar_motion_and_what_calibrate_does():
    from l2calib.data import Sequence
    from l2calib.preflight_motion import _planar_issue

    drive = _imu((0.004, 0.004, 0.6), yaw_rate=0.2)
    seq = Sequence("car", drive, _Stamps(drive.stamps_ns[::20]))
    share, issues = _planar_issue(drive, seq, "/points + /imu")
    assert share > 0.97 and len(issues) == 1 and issues[0].severity == "info"
    assert "vertical component" in issues[0].message and "policy.prior" in issues[0].fix
    hand = _imu((0.5, 0.5, 0.8))
    share, issues = _planar_issue(hand, Sequence("hand", hand, _Stamps(hand.stamps_ns[::20])), "x")
    assert share < 0.6 and issues == []


def test_inspect_says_when_every_turn_goes_the_same_way():
    from l2calib.data import Sequence
    from l2calib.preflight_motion import _planar_issue

    t = np.arange(0.0, 60.0, 0.005)
    turns = np.where(np.sin(2 * np.pi * t / 15) > 0.5, 0.4, 0.0)  # a 0.4 rad/s turn every 15 s
    for sign, one_way in ((np.sign(np.sin(2 * np.pi * t / 30)), False), (1.0, True)):
        rate = np.c_[0 * t, 0 * t, sign * turns + 0.03 * np.sin(3 * t)]
        imu = ImuSamples((t * 1e9).astype(np.int64), rate, np.tile([0.0, 0.0, 9.81], (len(t), 1)))
        seq = Sequence("car", imu, _Stamps(imu.stamps_ns[::20]))
        _, issues = _planar_issue(imu, seq, "/points + /imu")
        said = [i for i in issues if "turns all go one way (100 %" in i.message]
        assert len(issues) == 1 + one_way and len(said) == one_way  # a loop, not a figure-8
    assert "turns both ways" in said[0].fix and "ct-lidar" in said[0].fix


class _Stamps:
    def __init__(self, stamps_ns):
        self.stamps_ns = stamps_ns

    def load(self, start_ns, end_ns):
        return []


def test_planar_data_trains_with_the_weak_data_settings_unless_the_recipe_sets_them():
    from l2calib.train.vertical_hold import planar_train_settings

    cfg, changed = planar_train_settings(TrainConfig())  # PPO starts from no rotation guess
    assert cfg.handover_rotation_sigma_deg is None and cfg.refine_rounds == 6
    assert cfg.polish_rounds == 8 and cfg.polish_first_scale == 0.25
    assert set(changed) == {
        "handover_rotation_sigma_deg", "refine_rounds", "polish_rounds", "polish_first_scale"
    }  # fmt: skip
    mine = TrainConfig.model_validate({"refine_rounds": 9, "polish_rounds": 0})
    cfg, changed = planar_train_settings(mine)
    assert cfg.refine_rounds == 9 and cfg.handover_rotation_sigma_deg is None
    assert cfg.polish_rounds == 0  # the user's "off" stays off
    assert set(changed) == {"handover_rotation_sigma_deg", "polish_first_scale"}


def test_a_run_started_at_the_rate_rotation_keeps_the_hand_over_on_planar_data():
    from l2calib.train.vertical_hold import planar_train_settings

    default = TrainConfig()
    cfg, changed = planar_train_settings(default, rate_start=True)
    assert cfg.handover_rotation_sigma_deg == default.handover_rotation_sigma_deg is not None
    assert cfg.refine_rounds == default.refine_rounds
    assert cfg.handover_time_offset_sigma_s == 0.01  # the hand-over waits for the offset too
    assert set(changed) == {"polish_rounds", "polish_first_scale", "handover_time_offset_sigma_s"}
    mine = TrainConfig.model_validate({"handover_rotation_sigma_deg": None})
    assert planar_train_settings(mine, rate_start=True)[0].handover_rotation_sigma_deg is None
    mine = TrainConfig.model_validate({"handover_time_offset_sigma_s": None})  # "off", kept
    assert planar_train_settings(mine, rate_start=True)[0].handover_time_offset_sigma_s is None


@pytest.mark.parametrize("text, expected", [("off", "off"), ("on", "on"), ("auto", "auto")])
def test_unquoted_yaml_on_off_is_read_as_the_setting(tmp_path, text, expected):
    """YAML 1.1 turns an unquoted on / off into a boolean; the recipe and --set take it as meant."""
    from l2calib.recipe import load_recipe

    override = [f"train.hold_vertical_translation={text}"]
    assert load_recipe("simulator", override).train.hold_vertical_translation == expected
    path = tmp_path / "r.yaml"
    path.write_text(f"train:\n  hold_vertical_translation: {text}\n")
    assert load_recipe(path).train.hold_vertical_translation == expected
