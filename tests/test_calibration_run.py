"""The run object behind ``calibrate``, ``demo`` and the benchmarks (:mod:`l2calib.calibration`).

The full path (bag → PPO → files) is covered by the e2e tests through the CLI; here the object's
own contract: the stage order it enforces and a run the data stops before training.
"""

from __future__ import annotations

import pytest

from l2calib.assess.status import NOT_CALIBRATED
from l2calib.calibration import STOPPED_BEFORE_TRAINING, Calibration, RunHooks
from l2calib.errors import ConfigError
from l2calib.recipe import load_recipe
from l2calib.sim import SimConfig, simulate


@pytest.fixture(scope="module")
def one_second():
    """An in-memory 1 s hand-held sequence: far too short to calibrate."""
    cfg = SimConfig.model_validate(
        {"duration_s": 1.0, "seed": 0, "motion": {"profile": "handheld"}}
    )
    return simulate(cfg).sequence()


def test_train_before_prepare_is_refused():
    run = Calibration(load_recipe("simulator"))
    with pytest.raises(ConfigError, match="call prepare"):
        run.train()


def test_data_too_short_stops_before_the_reference_and_training(one_second, tmp_path):
    said, skipped = [], []
    refs_asked = []
    hooks = RunHooks(stage=said.append, skip_training=lambda: skipped.append(True))
    run = Calibration(load_recipe("simulator"), tmp_path / "out", hooks=hooks)
    run.prepare(sequences=[one_second], references=lambda segs: refs_asked.append(segs) or [])
    assert run.stopped and skipped == [True]
    assert refs_asked == [] and run.data.references == []  # no reference was computed
    assert said[-1].endswith("s of data")  # the last stage told is the selection's summary
    with pytest.raises(ConfigError, match="nothing to train on"):
        run.train()
    result = run.assess()
    assert result.T_imu_lidar is None and result.status == NOT_CALIBRATED
    assert result.stop_reason == STOPPED_BEFORE_TRAINING and result.status_reasons
    paths = run.write()
    assert set(paths) >= {"calibration", "recipe"}
    assert "not-calibrated" in paths["calibration"].read_text()


def test_a_run_without_out_writes_nothing(one_second, tmp_path):
    run = Calibration(load_recipe("simulator"))
    run.prepare(sequences=[one_second])
    run.assess()
    assert run.out is None and run.write() == {}
