"""Ground-truth files, scenario.json, config validation, reproducibility and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml

from l2calib import geometry as geo
from l2calib.cli.app import main
from l2calib.errors import ConfigError
from l2calib.io.trajectory_files import read_tum
from l2calib.sim import SimConfig, simulate, write_run
from l2calib.sim.config import sim_config_from_dict

SMALL = {"duration_s": 1.0, "lidar": {"columns": 64}, "motion": {"still_start_s": 0.2}}


@pytest.fixture(scope="module")
def run():
    cfg = SimConfig.model_validate(
        {
            **SMALL,
            "seed": 9,
            "rig": {"preset": "paper-handheld", "time_offset_s": 0.03},
            "lidar": {"model": "ouster-os1-16", "columns": 64},
        }
    )
    return simulate(cfg)


def test_ground_truth_files_agree_with_the_run(run, tmp_path):
    files = write_run(run, tmp_path, write_bag_file=False)
    gt = yaml.safe_load(open(files["extrinsic"]))
    T = np.array(gt["T_imu_lidar"])
    assert np.allclose(T, run.T_imu_lidar) and np.allclose(T[:3, 3], [0.65, -0.372, -0.016])
    R = torch.tensor(T[:3, :3])
    assert np.allclose(geo.quat_to_matrix(torch.tensor(gt["quat_xyzw"])).numpy(), T[:3, :3])
    rpy = torch.tensor(np.radians(gt["rpy_deg"]))
    assert np.allclose(geo.euler_rpy_to_matrix(rpy).numpy(), R.numpy(), atol=1e-9)
    assert gt["time_offset_s"] == 0.03 and "t_imu = t_lidar" in gt["conventions"]["time_offset_s"]
    gi, gl = read_tum(files["gt_imu"], "imu"), read_tum(files["gt_lidar"], "lidar")
    assert np.array_equal(gi.stamps_ns, run.gt_imu.stamps_ns)
    assert np.allclose(gl.t_world_body, run.gt_lidar.t_world_body, atol=1e-8)
    # gt_lidar is on the LiDAR clock: at the same stamp it is 30 ms *later* in true time.
    s = gl.stamps_ns[10:12]
    assert np.allclose(run.lidar_poses(s), gl.matrices().numpy()[10:12], atol=1e-8)
    assert np.allclose(
        run.imu_poses(s + 30_000_000) @ run.T_imu_lidar, gl.matrices().numpy()[10:12], atol=1e-8
    )
    sc = json.load(open(files["scenario"]))
    assert sc["seed"] == 9 and sc["mean_abs_omega_rad_s"] == run.stats["mean_abs_omega_rad_s"]
    assert SimConfig.model_validate(sc["config"]) == run.config
    assert "t_imu = t_lidar + time_offset_s" in sc["clocks"]["relation"]


def test_existing_outputs_are_not_overwritten_silently(run, tmp_path):
    write_run(run, tmp_path, write_bag_file=False)
    with pytest.raises(ConfigError, match="already exists"):
        write_run(run, tmp_path, write_bag_file=False)
    write_run(run, tmp_path, write_bag_file=False, overwrite=True)


def test_same_seed_same_data_other_seed_other_data():
    a = simulate(SimConfig.model_validate({**SMALL, "seed": 1}))
    b = simulate(SimConfig.model_validate({**SMALL, "seed": 1}))
    c = simulate(SimConfig.model_validate({**SMALL, "seed": 2}))
    assert np.array_equal(a.imu.gyro_rad_s, b.imu.gyro_rad_s)
    assert np.array_equal(a.scans[3].points_lidar, b.scans[3].points_lidar)
    assert not np.array_equal(a.imu.gyro_rad_s, c.imu.gyro_rad_s)


def test_sequence_view_of_a_run(run):
    seq = run.sequence()
    seg = seq.segment()
    assert len(seg.scans) == len(run.scans) and seq.meta["source"] == "l2calib.sim"
    assert seg.imu.stamps_ns[0] <= seg.scans[0].stamp_ns


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"world": {"name": "mars"}}, "world.name: unknown world 'mars'; choose one of: urban"),
        ({"lidar": {"model": "os2"}}, "unknown LiDAR model 'os2'"),
        ({"imu": {"rate_hz": 10}}, "imu.rate_hz"),
        ({"durtion_s": 3}, "durtion_s: unknown key"),
        ({"rig": {"preset": None}}, "without a preset, give both translation_m and rpy_deg"),
    ],
)
def test_bad_settings_name_the_field(data, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        sim_config_from_dict(data)


def test_rig_that_does_not_fit_the_world_is_refused():
    cfg = SimConfig.model_validate(
        {
            **SMALL,
            "world": {"name": "corridor"},
            "rig": {"preset": None, "translation_m": (1.5, 0, 0), "rpy_deg": (0, 0, 0)},
        }
    )
    with pytest.raises(ConfigError, match="lever arm"):
        simulate(cfg)


def test_cli_simulate_writes_a_bag_and_ground_truth(tmp_path, capsys):
    out = tmp_path / "run"
    main(
        [
            "simulate",
            "--world",
            "hall",
            "--profile",
            "uav",
            "--lidar",
            "velodyne-vlp-16",
            "--imu",
            "bmi088",
            "--duration",
            "1.0",
            "--seed",
            "3",
            "--columns",
            "90",
            "--format",
            "ros2-mcap",
            "--gyro-unit",
            "deg/s",
            "--set",
            "imu.rate_hz=400",
            "--out",
            str(out),
        ]
    )
    assert (out / "sim" / "metadata.yaml").is_file()
    sc = json.load(open(out / "scenario.json"))
    assert sc["config"]["imu"]["rate_hz"] == 400 and sc["bag"]["imu"]["gyro_unit"] == "deg/s"
    assert sc["bag"]["lidar"]["stamp_position"] == "end"  # the Velodyne driver's habit
    assert sc["bag"]["imu"]["count"] == 401


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--world", "mars"], "error: simulate options: world.name: unknown world 'mars'"),
        (["--format", "ros3"], "error: bag options: format"),
        (["--stamp", "end"], "error: Ouster clouds cannot be stamped at the scan end"),
    ],
)
def test_cli_bad_options_give_one_line(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--duration", "1", "--columns", "64", "--out", str(tmp_path), *args])
    assert exc.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message)
