"""``report.html``: a self-contained page with the status, the CLI's table and the figures.

The browser test renders the page in headless Chromium (Debian's ``chromium``; ``.ci/run``
installs it and sets ``L2CALIB_REQUIRE_BROWSER=1`` so that CI fails instead of skipping).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from l2calib import geometry as geo
from l2calib.assess.result import CalibrationResult
from l2calib.assess.sensitivity import AxisResolution
from l2calib.outputs.report import write_html
from l2calib.outputs.report_figures import plot_report, plot_trajectories, rotation_errors_deg
from l2calib.train.ppo import IterationRecord

RPY_DEG = np.array([179.5, -0.4, 90.2])  # near ±180° roll: roll/pitch/yaw would wrap


def _T() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor(RPY_DEG))).numpy()
    T[:3, 3] = [0.1234, -0.0567, 0.0891]
    return T


def _history(n: int = 12) -> list[IterationRecord]:
    rows = []
    for i in range(n):
        roll = 178.0 + 3.0 * (i % 2)  # jumps across ±180° as roll/pitch/yaw
        rows.append(
            IterationRecord(
                iteration=i, evaluations=16 * (i + 1), wall_s=float(i), reward_mean=0.1 + 0.05 * i,
                reward_max=0.2 + 0.05 * i, mean_e_t_m=0.1, mean_e_r_deg=1.0, lost=0, diverged=0,
                translation_m=[0.1, -0.05, 0.09], rpy_deg=[roll if roll <= 180 else roll - 360,
                                                          -0.4, 90.2],
                time_offset_s=None, rotation_sigma_deg=[1.0] * 3, translation_sigma_m=[0.01] * 3,
                loss_objective=0.0, loss_critic=0.0, loss_entropy=0.0, lr=1e-3,
            )
        )  # fmt: skip
    return rows


def _result() -> CalibrationResult:
    res = AxisResolution([0.2, math.inf, 0.1], [0.004, 0.011, 0.09], 0.93)
    return CalibrationResult(
        _T(),
        resolution=res,
        rotation_sigma_deg=[0.1] * 3,
        translation_sigma_m=[0.002] * 3,
        final_reward=0.93,
        evaluations=192,
        iterations=12,
        wall_time_s=12.0,
        stop_reason="budget",
        undetermined=["rotation about LiDAR y (flat reward)"],
        warnings=["the odometry and the reference disagree by 4.1 cm"],
        status="unreliable",
        status_reasons=["reference agreement 4.1 cm > 3 cm"],
    )


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    result = _result()
    plot_report(out / "report.png", _history(), result, truth=_T())
    t = np.linspace(0, 6, 50)
    ref = np.stack([np.cos(t), np.sin(t), 0 * t], axis=1)
    plot_trajectories(
        out / "trajectories.png",
        [{"name": f"seq0:{k}", "reference": ref, "before": ref * 3, "after": ref + 0.01}
         for k in range(2)],
    )  # fmt: skip
    (out / "calibration.yaml").write_text("status: unreliable\n")
    figures = [(out / "report.png", "training"), (out / "trajectories.png", "segments"),
               (out / "selection.png", "absent: skipped")]  # fmt: skip
    return write_html(out / "report.html", result, figures, out / "calibration.yaml", truth=_T())


def test_rotation_is_plotted_as_the_error_to_the_final_estimate_without_wrapping():
    rpy = np.array([[179.9, 0.0, 0.0], [-179.9, 0.0, 0.0]])  # 0.2° apart, 359.8° as roll
    R_final = geo.euler_rpy_to_matrix(torch.deg2rad(torch.tensor([180.0, 0.0, 0.0]))).numpy()
    err = rotation_errors_deg(rpy, R_final)
    np.testing.assert_allclose(np.abs(err[:, 0]), [0.1, 0.1], atol=1e-9)
    np.testing.assert_allclose(err[:, 1:], 0.0, atol=1e-9)


def test_the_page_is_self_contained_and_leads_with_the_status_and_what_is_missing(page):
    text = page.read_text()
    assert not re.search(r'src="(?!data:image/png;base64,)', text)  # nothing loaded from outside
    assert text.count("data:image/png;base64,") == 2  # report, trajectories; selection absent
    marks = ('id="status"', 'id="undetermined"', 'id="warnings"', "T_imu_lidar (LiDAR",
             'id="report"', 'id="trajectories"')  # fmt: skip
    order = [text.index(m) for m in marks]
    assert order == sorted(order)
    assert "status: unreliable" in text and "#e37400" in text  # the status's colour
    assert "rotation about LiDAR y (flat reward)" in text and "disagree by 4.1 cm" in text
    # The CLI's table, numbers as calibrate prints them, with the error against the truth
    for number in ("+0.1234", "-0.0567", "+0.0891", "+90.200", "flat", "0.40", "|error|"):
        assert number in text, number
    assert "<details><summary>calibration.yaml</summary>" in text


def _chromium() -> str | None:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None and os.environ.get("L2CALIB_REQUIRE_BROWSER") == "1":
        pytest.fail("chromium is not installed: apt-get install chromium (see .ci/run)")
    return found


def test_the_page_renders_in_a_headless_browser(page, tmp_path):
    browser = _chromium()
    if browser is None:
        pytest.skip("no chromium on this machine (CI installs it: apt-get install chromium)")
    flags = [
        browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars",
    ]  # fmt: skip
    shot = tmp_path / "shot.png"
    subprocess.run(
        [*flags, f"--screenshot={shot}", "--window-size=1280,1600", page.as_uri()],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    dom = subprocess.run(
        [*flags, "--dump-dom", page.as_uri()],
        check=True, capture_output=True, text=True, timeout=120,
    ).stdout  # fmt: skip
    assert "status: unreliable" in dom and "+0.1234" in dom and "flat reward" in dom
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.shape[:2] == (1600, 1280)
    # The status box's orange border (#e37400) is drawn, and the figures put ink on the page.
    orange = np.all(np.abs(pixels - np.array([0xE3, 0x74, 0x00]) / 255) < 0.03, axis=-1)
    assert orange.sum() > 100
    assert (pixels.mean(axis=-1) < 0.5).mean() > 0.01
