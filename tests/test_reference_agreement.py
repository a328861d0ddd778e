"""The warning for a reference that disagrees with the odometry even at the calibrated result."""

import yaml

from l2calib.assess.agreement import DISAGREEMENT_LIMITS, disagreement_warnings
from l2calib.assess.result import CalibrationResult
from l2calib.outputs.calibration_file import write_calibration


def test_agreement_within_limits_gives_no_warning():
    good = {"translation_m": 0.006, "rotation_deg": 0.04}  # ct-lidar on the simulator
    assert disagreement_warnings(good, ["ct-lidar"]) == []
    assert disagreement_warnings({"translation_m": 0.01, "rotation_deg": None}, ["rtk"]) == []


def test_a_wrong_reference_is_named_with_its_size():
    bad = {"translation_m": 1.03, "rotation_deg": 4.64}  # KISS-ICP on a hand-swung 16-beam rig
    (warning,) = disagreement_warnings(bad, ["kiss-icp"])
    assert "kiss-icp" in warning and "103.0 cm / 4.64 deg" in warning
    only_rot = {"translation_m": 0.01, "rotation_deg": DISAGREEMENT_LIMITS["rotation_deg"] * 2}
    assert len(disagreement_warnings(only_rot, ["gt-file"])) == 1
    (rtk,) = disagreement_warnings({"translation_m": 0.2, "rotation_deg": None}, ["rtk"])
    assert "20.0 cm on average" in rtk  # no rotation figure for a position-only reference


def test_calibration_file_carries_agreement_and_warnings(tmp_path):
    import numpy as np

    agreement = {"translation_m": 0.2, "rotation_deg": 1.0}
    result = CalibrationResult(
        np.eye(4),
        reference_agreement=agreement,
        warnings=disagreement_warnings(agreement, ["kiss-icp"]),
    )
    unc = yaml.safe_load(write_calibration(tmp_path / "c.yaml", result).read_text())["uncertainty"]
    assert unc["reference_agreement"] == agreement
    assert len(unc["warnings"]) == 1 and "kiss-icp" in unc["warnings"][0]
