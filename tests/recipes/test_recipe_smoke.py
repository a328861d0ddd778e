"""Every built-in recipe is smoke-trained for 2 iterations on simulated data of its layout.

The simulator writes a bag with the recipe's own topics and the matching LiDAR/IMU models, and
the real pipeline runs on it: bag reading, selection, the recipe's reference and backend, PPO.
"""

from __future__ import annotations

import pytest
import yaml

from l2calib.assess.polish import stencil
from l2calib.assess.sensitivity import probe
from l2calib.assess.time_offset_probe import probe_evaluations
from l2calib.recipe import builtin_recipes, load_recipe

#: recipe -> (simulated LiDAR model, IMU model, motion profile)
LAYOUTS = {
    "simulator": ("ouster-os1-16", "vn100", "handheld"),
    "ntu-viral-os1-16-vn100": ("ouster-os1-16", "vn100", "uav"),
    "mcd-ouster-vn200": ("ouster-os1-64", "vn200", "handheld"),
    "livox-mid360-mti300": ("livox-mid360", "mti-300", "handheld"),
    "velodyne-vlp16-xsens": ("velodyne-vlp-16", "mti-300", "handheld"),
    "hesai-bmi088": ("hesai-pandar-xt32", "bmi088", "handheld"),
}

SMOKE = [
    "train.max_iterations=2",
    "train.candidates_per_iteration=8",
    "selection.window_s=3",
    "selection.step_s=1",
    "selection.budget_s=3",
    "train.refine_rounds=1",
    "train.restarts=0",  # 2 iterations end far off; restarts are tested in tests/train
]


def test_every_builtin_recipe_has_a_layout():
    assert set(builtin_recipes()) == set(LAYOUTS)


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_recipe_trains_two_iterations(name, tmp_path):
    from rich.console import Console

    from l2calib.cli.cmd_calibrate import run_calibration
    from l2calib.sim import SimConfig, simulate, write_run

    lidar, imu, profile = LAYOUTS[name]
    recipe = load_recipe(name, SMOKE)
    lidar_cfg = {"model": lidar}
    if lidar != "livox-mid360":
        lidar_cfg["columns"] = 256
    run = simulate(
        SimConfig.model_validate(
            {
                "duration_s": 7.0,
                "seed": 4,
                "motion": {"profile": profile},
                "lidar": lidar_cfg,
                "imu": {"model": imu},
            }
        )
    )
    files = write_run(
        run,
        tmp_path / "sim",
        lidar_topic=recipe.data.lidar.topic,
        imu_topic=recipe.data.imu.topic,
    )
    result = run_calibration(
        recipe,
        tmp_path / "out",
        bags=[files["bag"]],
        truth=run.T_imu_lidar,
        console=Console(quiet=True),
    )
    assert result.iterations == 2
    n_probe = len(probe(result.T_imu_lidar))  # the per-axis resolution probe after training
    out = yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())
    n_refine = out["refine"]["evaluations"]  # the refinement from the policy's mode
    timed = recipe.train.estimate_time_offset  # the offset's probe runs, held or estimated
    # estimated jointly, the offset is a 7th refined axis; held at the rates' correlation, not
    held = timed and out["time_offset"]["method"].startswith("held")
    axes = 7 if timed and not held else 6
    assert 1 + 2 * axes <= n_refine <= 2 + 2 * axes
    n_bounds = len(stencil(axes))  # the per-axis uncertainty's stencil (73, 99 with the offset)
    assert result.axis_uncertainty.evaluations == n_bounds
    n_probe += n_bounds + (probe_evaluations() if timed else 0)
    assert result.evaluations == 2 * 8 + n_refine + n_probe
    assert out["refine"]["refined_reward"] >= out["refine"]["policy_mode_reward"]
    assert len(out["uncertainty"]["resolution_rotation_deg"]) == 3
    assert len(out["T_imu_lidar"]) == 4
    # 2 iterations may leave most axes flat: then no paste-ready block is written
    # (l2calib.assess.status)
    if out["status"] == "not-calibrated":
        assert "fast_lio" not in out and out["status_reasons"]
    else:
        assert "extrinsic_T" in out["fast_lio"]
    # the recipe's own reference (ct-lidar for the MID-360) tracked: no fallback was needed
    assert out["reference"]["sources"] == [recipe.reference.name]
    # the only notes: where the offset is held or its estimation starts, when the rates tell,
    # where the rotation starts (l2calib.train.rotation_start; always one of the two) and,
    # from a rotation start, where the translation starts (l2calib.train.lever_start)
    offset_notes = [
        n for n in out["reference"]["notes"]
        if "the offset's estimation starts there" in n or "the offset is held there" in n
    ]  # fmt: skip
    start_notes = [n for n in out["reference"]["notes"] if "rotation rates" in n]
    lever_notes = [n for n in out["reference"]["notes"] if "accelerations" in n]
    assert len(start_notes) == 1
    rotated = "start at" in start_notes[0]  # a start was found: calibration.yaml records it
    assert len(lever_notes) == (1 if rotated else 0)
    assert len(offset_notes) + 1 + len(lever_notes) == len(out["reference"]["notes"])
    assert len(offset_notes) <= (1 if timed else 0)
    if rotated:
        assert len(out["rotation_start"]["sigma_deg"]) == 3
    if lever_notes and "start at" in lever_notes[0]:
        assert len(out["translation_start"]["sigma_m"]) == 3
    assert (tmp_path / "out" / "report.png").stat().st_size > 10_000
