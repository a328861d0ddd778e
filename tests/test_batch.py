"""``l2calib batch``: jobs run (locally or on Ray), a bad job fails alone, summary.csv.

Three jobs on real simulated bags: a short calibration (tiny budget), a 1 s recording that stops
before training, and a job whose bag does not exist.
"""

from __future__ import annotations

import csv
import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from l2calib.cli.app import app
from l2calib.errors import ConfigError

TINY = [
    "reference.name=gt-file",
    "train.max_iterations=2",
    "train.candidates_per_iteration=8",
    "train.refine_rounds=1",
    "train.restarts=0",
    "train.estimate_time_offset=false",
    "selection.enabled=false",
]


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """A 4 s and a 1 s simulated hand-held bag with their ground-truth LiDAR trajectories."""
    from l2calib.sim import SimConfig, simulate, write_run

    out = {}
    for seconds in (4.0, 1.0):
        cfg = {"duration_s": seconds, "seed": 0, "motion": {"profile": "handheld"}}
        run = simulate(SimConfig.model_validate(cfg))
        files = write_run(run, tmp_path_factory.mktemp(f"sim{seconds:g}"))
        out[seconds] = (Path(files["bag"]), Path(files["gt_lidar"]))
    return out


def _manifest(folder: Path, bags, executor: str) -> Path:
    (bag4, gt4), (bag1, gt1) = bags[4.0], bags[1.0]
    jobs = [
        {"name": "short", "recipe": "simulator", "bags": [str(bag4)],
         "set": [*TINY, f"reference.options.path={gt4}"], "out": "out/short"},
        {"name": "one-second", "recipe": "simulator", "bags": [str(bag1)],
         "set": [*TINY, f"reference.options.path={gt1}"], "out": "out/one-second"},
        {"name": "no-bag", "recipe": "simulator", "bags": ["missing.bag"], "out": "out/no-bag"},
    ]  # fmt: skip
    path = folder / "batch.yaml"
    path.write_text(yaml.safe_dump({"executor": executor, "jobs": jobs}))
    return path


def _summary(path: Path) -> dict[str, dict[str, str]]:
    with path.open() as f:
        return {row["job"]: row for row in csv.DictReader(f)}


def _check(result, folder: Path) -> dict[str, dict[str, str]]:
    assert result.exit_code == 1, result.output  # a job failed
    rows = _summary(folder / "summary.csv")
    assert rows["short"]["state"] == "done" and rows["short"]["status"] in {
        "calibrated", "unreliable"
    }  # fmt: skip
    assert all(rows["short"][k] for k in ("tx_m", "roll_deg", "yaw_deg"))
    assert (folder / "out/short/calibration.yaml").is_file()
    assert rows["one-second"]["state"] == "done"
    assert rows["one-second"]["status"] == "not-calibrated" and not rows["one-second"]["tx_m"]
    assert rows["no-bag"]["state"] == "failed" and "missing.bag" in rows["no-bag"]["error"]
    return rows


@pytest.fixture(scope="module")
def local_batch(bags, tmp_path_factory):
    """The three jobs run locally once: ``(folder, CLI result)`` (the Ray test compares)."""
    folder = tmp_path_factory.mktemp("local")
    return folder, CliRunner().invoke(app, ["batch", str(_manifest(folder, bags, "local"))])


def test_local_batch_runs_every_job_and_a_bad_one_fails_alone(local_batch):
    folder, result = local_batch
    rows = _check(result, folder)
    assert "batch summary" in result.output and "missing.bag" in result.output
    # --resume keeps the finished jobs as they are (nothing is run again)
    before = (folder / "out/short/calibration.yaml").stat().st_mtime_ns
    again = CliRunner().invoke(app, ["batch", str(folder / "batch.yaml"), "--resume"])
    assert (folder / "out/short/calibration.yaml").stat().st_mtime_ns == before
    assert _summary(folder / "summary.csv")["short"]["tx_m"] == rows["short"]["tx_m"]
    assert again.exit_code == 1  # the missing bag is still missing


@pytest.mark.skipif(
    os.environ.get("L2CALIB_REQUIRE_RAY") != "1" and importlib.util.find_spec("ray") is None,
    reason="the optional extra: pip install 'l2calib[ray]'",
)
def test_ray_batch_gives_the_local_results(bags, local_batch, tmp_path):
    """The same jobs as Ray tasks on a local Ray instance: the same extrinsics as locally."""
    local, _ = local_batch
    result = CliRunner().invoke(app, ["batch", str(_manifest(tmp_path, bags, "ray"))])
    _check(result, tmp_path)
    a, b = _summary(local / "summary.csv")["short"], _summary(tmp_path / "summary.csv")["short"]
    keys = ("tx_m", "ty_m", "tz_m", "roll_deg", "pitch_deg", "yaw_deg")
    np.testing.assert_array_equal([a[k] for k in keys], [b[k] for k in keys])


def test_a_bad_manifest_names_the_file_and_field(tmp_path):
    path = tmp_path / "batch.yaml"
    path.write_text(yaml.safe_dump({"jobs": [{"name": "a", "recipe": "simulator", "out": "o"}]}))
    result = CliRunner().invoke(app, ["batch", str(path)])
    assert isinstance(result.exception, ConfigError)  # printed as "error: ... — fix: ..."
    assert "batch.yaml: jobs.0.bags: Field required" in str(result.exception)
