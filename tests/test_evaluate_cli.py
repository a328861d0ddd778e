"""``l2calib evaluate``: odometry APE with a given extrinsic, before/after."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml
from typer.testing import CliRunner

from l2calib.calibration import Calibration
from l2calib.cli.app import app
from l2calib.interfaces import Extrinsic
from l2calib.recipe import load_recipe


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    from l2calib.sim import SimConfig, simulate, write_run

    cfg = SimConfig.model_validate(
        {
            "duration_s": 4.0,
            "seed": 3,
            "motion": {"profile": "handheld"},
            "lidar": {"model": "ouster-os1-16", "columns": 256},
            "imu": {"model": "vn100"},
        }
    )
    run = simulate(cfg)
    return run, write_run(run, tmp_path_factory.mktemp("sim"))


def _off(T: np.ndarray, deg: float, cm: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    out = T.copy()
    out[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", deg, degrees=True).as_matrix()
    out[:3, 3] += [cm / 100, 0.0, 0.0]
    return out


def test_true_extrinsic_beats_a_wrong_one(sim_bag):
    from l2calib.io.sequences import open_sequences

    run, files = sim_bag
    recipe = load_recipe(
        "simulator", ["reference.name=gt-file", f"reference.options.path={files['gt_lidar']}"]
    )
    sequences = open_sequences([files["bag"]], recipe.data, auto_topics=False)
    extrinsics = {
        "true": Extrinsic(torch.from_numpy(run.T_imu_lidar)),
        "off": Extrinsic(torch.from_numpy(_off(run.T_imu_lidar, 5, 10))),
    }
    rows = Calibration(recipe).evaluate(extrinsics, sequences=sequences)
    ape = {row.label: row.ape.rmse_t for row in rows}
    assert ape["true"] < 0.05
    assert ape["off"] > 2 * ape["true"]


def test_cli_prints_both_extrinsics(sim_bag, tmp_path):
    run, files = sim_bag
    wrong = tmp_path / "wrong.yaml"
    T = _off(run.T_imu_lidar, 5, 10)
    wrong.write_text(yaml.safe_dump({"T_imu_lidar": T.tolist()}))
    res = CliRunner(env={"COLUMNS": "160"}).invoke(
        app,
        [
            "evaluate",
            "--extrinsic", str(files["extrinsic"]),
            "--compare", str(wrong),
            "--bag", str(files["bag"]),
            "--recipe", "simulator",
            "--reference", str(files["gt_lidar"]),
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "extrinsic_gt.yaml" in res.output and "wrong.yaml" in res.output
    assert "APE" in res.output


def test_cli_names_a_missing_extrinsic_file(sim_bag, tmp_path):
    import subprocess
    import sys

    _run, files = sim_bag
    missing = tmp_path / "nope.yaml"
    out = subprocess.run(
        [sys.executable, "-m", "l2calib.cli.app", "evaluate", "--extrinsic", str(missing),
         "--bag", str(files["bag"])],
        capture_output=True,
        text=True,
    )  # fmt: skip
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "nope.yaml" in lines[0]
