"""l2calib.assess.status: when a finished run is calibrated, unreliable or not calibrated."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from l2calib.assess.result import CalibrationResult
from l2calib.assess.sensitivity import AxisResolution
from l2calib.assess.status import assess, before_training, flat_axes
from l2calib.recipe import SelectionConfig

CFG = SelectionConfig(window_s=5.0, budget_s=10.0)


def _data(seconds: float, gyro=(0.5, 0.5, 0.5), accel=(1.0, 1.0, 1.0)):
    selection = SimpleNamespace(gyro_rms_rad_s=np.array(gyro), accel_rms_m_s2=np.array(accel))
    return SimpleNamespace(segments=[SimpleNamespace(duration_s=seconds)], selection=selection)


def _result(flat: int = 0, warnings=()) -> CalibrationResult:
    values = [math.inf] * flat + [0.1] * (6 - flat)
    res = AxisResolution(values[:3], [v / 100 for v in values[3:]], 0.9)
    return CalibrationResult(np.eye(4), resolution=res, warnings=list(warnings))


def test_enough_data_and_sharp_axes_is_calibrated():
    status = assess(_result(flat=1), _data(10.0), CFG)
    assert status.status == "calibrated" and status.reasons == []


def test_four_flat_axes_are_not_calibrated():
    status = assess(_result(flat=4), _data(10.0), CFG)
    assert status.status == "not-calibrated"
    assert "flat along 4 of 6 axes" in status.reasons[0]
    assert flat_axes(_result(flat=4).resolution)[:3] == [
        "rotation about x", "rotation about y", "rotation about z",
    ]  # fmt: skip


def test_too_little_or_too_still_data_is_not_calibrated():
    short = assess(_result(), _data(0.9), CFG)
    assert short.status == "not-calibrated"
    assert short.reasons[0].startswith("only 0.9 s of usable data")
    still = assess(_result(), _data(10.0, gyro=(0.01,) * 3, accel=(0.02,) * 3), CFG)
    assert still.status == "not-calibrated" and "too still" in still.reasons[0]


def test_weak_but_real_motion_is_trained_on():
    # The simulated UAV flights: every axis under the selection's thresholds, yet they
    # calibrate to 2.9-3.2 cm (benchmarks/results/calibration.json, "uav all"). Stopping them
    # would refuse the weakly excited data l2calib is for.
    uav = _data(20.0, gyro=(0.04, 0.02, 0.15), accel=(0.12, 0.26, 0.03))
    assert before_training(uav, CFG).status == "calibrated"
    assert assess(_result(), uav, CFG).status == "calibrated"


def test_a_reference_disagreement_is_unreliable():
    status = assess(_result(warnings=["disagree by 63 cm"]), _data(10.0), CFG)
    assert status.status == "unreliable" and status.reasons == ["disagree by 63 cm"]


def test_before_training_stops_on_data_too_short_or_too_still():
    short = before_training(_data(0.9), CFG)
    assert short.status == "not-calibrated"
    assert short.reasons[0].startswith("only 0.9 s of usable data, far below one selection window")
    assert "record at least 5 s of motion" in short.reasons[0]
    still = before_training(_data(10.0, gyro=(0.01,) * 3, accel=(0.02,) * 3), CFG)
    assert still.status == "not-calibrated" and "swing the rig" in still.reasons[0]


def test_before_training_lets_enough_data_train():
    ok = before_training(_data(10.0), CFG)
    assert ok.status == "calibrated" and ok.reasons == []
    # with the selection disabled only the length is known, and judged
    no_selection = SimpleNamespace(segments=[SimpleNamespace(duration_s=0.9)], selection=None)
    assert before_training(no_selection, CFG).status == "not-calibrated"


def test_before_training_gives_the_same_reasons_as_after():
    data = _data(0.9, gyro=(0.01,) * 3, accel=(0.02,) * 3)
    assert before_training(data, CFG).reasons == assess(_result(), data, CFG).reasons
