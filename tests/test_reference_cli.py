"""``l2calib reference``: writes the reference of a bag as TUM and compares it with a file."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from l2calib.cli.app import app
from l2calib.io.trajectory_files import read_tum


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    from l2calib.sim import SimConfig, simulate, write_run

    run = simulate(
        SimConfig.model_validate(
            {
                "duration_s": 5.0,
                "seed": 2,
                "motion": {"profile": "handheld"},
                "lidar": {"model": "ouster-os1-16", "columns": 512},
                "imu": {"model": "vn100"},
            }
        )
    )
    return write_run(run, tmp_path_factory.mktemp("sim"))


def _invoke(*args: str):
    return CliRunner(env={"COLUMNS": "200"}).invoke(app, ["reference", "simulator", *args])


def test_whole_bag_with_kiss_icp_is_written_and_compared(small_bag, tmp_path):
    out = tmp_path / "ref" / "traj.tum"
    res = _invoke(
        "--bag", str(small_bag["bag"]), "--out", str(out), "--all",
        "--set", "reference.name=kiss-icp", "--compare", str(small_bag["gt_lidar"]),
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    traj = read_tum(out)
    assert len(traj.stamps_ns) > 30  # 10 Hz over ~4 s after the warm-up
    assert "APE RMSE" in res.output and "kiss-icp" in res.output
    again = _invoke("--bag", str(small_bag["bag"]), "--out", str(out), "--all")
    assert again.exit_code == 1 and "already exist" in str(again.exception)  # not overwritten


def test_several_segments_get_one_file_each(small_bag, tmp_path):
    out = tmp_path / "traj.tum"
    gt = str(small_bag["gt_lidar"])
    bag = str(small_bag["bag"])
    res = _invoke(
        "--bag", bag, "--bag", bag, "--all", "--out", str(out), "--compare", gt,
        "--set", "reference.name=gt-file", "--set", f"reference.options.path={gt}",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    files = sorted(tmp_path.glob("traj-*.tum"))
    assert [f.name for f in files] == ["traj-01.tum", "traj-02.tum"]  # one per bag
    assert not out.exists()
    assert len(read_tum(files[1]).stamps_ns) > 30
    assert "0.00" in res.output  # the ground truth compared with itself


def test_a_missing_compare_file_is_a_clear_error(small_bag, tmp_path, capsys):
    from l2calib.cli.app import main

    with pytest.raises(SystemExit) as exc:
        main(
            ["reference", "simulator", "--bag", str(small_bag["bag"]),
             "--out", str(tmp_path / "t.tum"), "--compare", str(tmp_path / "nope.tum")]
        )  # fmt: skip
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert "nope.tum" in err and "no such file" in err


def test_a_usage_error_is_a_message_not_a_traceback(tmp_path, capsys):
    """``--set`` takes one field per flag; extra arguments get click's usage message, exit 2."""
    from l2calib.cli.app import main

    with pytest.raises(SystemExit) as exc:
        main(
            ["calibrate", "simulator", "--bag", str(tmp_path / "a.bag"), "--out",
             str(tmp_path / "o"), "--set", "train.seed=1", "selection.budget_s=60"]
        )  # fmt: skip
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unexpected extra argument" in err and "selection.budget_s=60" in err
    assert "Traceback" not in err
