from __future__ import annotations

import dataclasses
import math
import shutil

import numpy as np
import pytest
import torch
from fakes import reference, tiny_sequence

from l2calib.assess.sensitivity import probe
from l2calib.assess.time_offset_probe import probe_evaluations
from l2calib.errors import ConfigError, TrainingError
from l2calib.pipeline import PreparedData
from l2calib.recipe import Recipe
from l2calib.training import train_policy


def _data():
    seqs = [tiny_sequence("s")]
    return PreparedData(seqs, [seqs[0].segment()], [reference("s:0.0-4.9")])


def _recipe(**train):
    base = {"candidates_per_iteration": 8, "max_iterations": 3, "seed": 5, "restarts": 0}
    return Recipe.model_validate(
        {
            "backend": {"name": "fake-lio"},
            "train": {**base, **train},
        }
    )


def _run(recipe, out=None, resume=False, progress=None):
    data = _data()
    ref = data.references[0]
    data.references = [type(ref)(data.segments[0].name, ref.trajectory)]
    run = train_policy(recipe, data, out, resume=resume, progress=progress)
    return run.result, run.outcome


def test_training_runs_and_counts_evaluations(fake_backend_env, tmp_path):
    result, outcome = _run(_recipe(), tmp_path)
    assert len(outcome.history) == 3
    assert outcome.evaluations == 3 * 8
    refined = result.extra["refine"]  # the policy's mode, refined on the reward
    assert refined["refined_reward"] >= refined["policy_mode_reward"]
    n_refine = refined["evaluations"]
    assert result.time_offset_s is not None  # estimated by default: a 7th refined axis
    assert 1 + 12 * 14 <= n_refine <= 1 + 12 * 15  # default 12 rounds
    n_probes = len(probe(result.T_imu_lidar)) + probe_evaluations()  # + the offset's probe
    n_bounds = result.axis_uncertainty.evaluations  # the uncertainty's stencil, with the offset
    assert n_bounds == 99
    assert result.evaluations == 3 * 8 + n_refine + n_probes + n_bounds
    assert len(result.resolution.rotation_deg) == 3
    assert len(result.axis_uncertainty.bound95) == 7 and result.axis_uncertainty.blocks >= 2
    assert result.axis_uncertainty.caveats == []  # hand-held: nothing named beyond the bounds
    assert result.reference_agreement["translation_m"] >= 0  # odometry vs reference at the result
    assert (tmp_path / "checkpoint.pt").is_file()
    assert (tmp_path / "metrics" / "scalars" / "reward_mean.csv").is_file()


def test_worker_count_does_not_change_the_result(fake_backend_env):
    r1, _ = _run(_recipe(workers=1))
    r2, _ = _run(_recipe(workers=2))  # refinement and probe also run on the 2 workers
    assert torch.allclose(torch.as_tensor(r1.T_imu_lidar), torch.as_tensor(r2.T_imu_lidar))
    assert r1.final_reward == pytest.approx(r2.final_reward, abs=1e-12)
    assert r1.reference_agreement == r2.reference_agreement


def test_the_reports_trajectories_come_from_the_open_training_env(fake_backend_env):
    runs = []
    for workers in (1, 2):  # 2: "before" runs on one worker, "after" on the other
        data = _data()
        ref = data.references[0]
        data.references = [type(ref)(data.segments[0].name, ref.trajectory)]
        runs.append(train_policy(_recipe(workers=workers), data, None))
    for run in runs:
        assert run.problems == [] and [t["name"] for t in run.trajectories] == ["s:0.0-4.9"]
        traj = run.trajectories[0]
        n = len(traj["reference"])
        assert n > 10 and traj["before"].shape == traj["after"].shape == (n, 3)
    one, two = (r.trajectories[0] for r in runs)
    for key in ("reference", "before", "after"):  # the shares merge back in candidate order
        assert torch.allclose(torch.as_tensor(one[key]), torch.as_tensor(two[key]), equal_nan=True)
    assert not torch.allclose(torch.as_tensor(one["before"]), torch.as_tensor(one["after"]))


def _drifted(traj):
    """``traj`` with its positions drifting 1 cm/s along x."""
    from l2calib.trajectory import Trajectory

    dt = (traj.stamps_ns - traj.stamps_ns[0]) * 1e-9
    p = traj.t_world_body + np.outer(0.01 * dt, [1.0, 0.0, 0.0])
    return Trajectory(traj.stamps_ns, p, traj.quat_xyzw, traj.body_frame, traj.world_frame)


@pytest.mark.parametrize("n", [1, 5, 12])
def test_batches_of_any_size_score_alike_on_workers(fake_backend_env, n):
    from l2calib import geometry as geo
    from l2calib.train.env_build import block_costs, make_training_env, score_batch

    data = _data()
    # a second estimate of each reference (a drift of 1 cm/s along x): its costs merge alike
    data.references = [
        dataclasses.replace(r, alternative=_drifted(r.trajectory)) for r in data.references
    ]
    recipe = _recipe(workers=2)
    T = probe(torch.eye(4, dtype=torch.float64))[:n]
    T[:, :3, :3] = geo.so3_exp(0.1 * torch.randn(n, 3, dtype=torch.float64)) @ T[:, :3, :3]
    local = make_training_env(_recipe(workers=1), data.segments, data.references)
    workers = make_training_env(recipe, data.segments, data.references)
    try:
        expected = score_batch(local, T)
        got = score_batch(workers, T)  # split over 2 processes, any n (fewer than workers too)
        costs, scans, centre, alt = block_costs(workers, T, None, 2.0)  # the uncertainty's
        costs_local, scans_local, centre_local, alt_local = block_costs(local, T, None, 2.0)
    finally:
        workers.close()
    # per-block costs: the same candidates in the same order, summing to the reward's errors
    assert costs.shape == costs_local.shape and costs.shape[0] == n and costs.shape[1] >= 2
    np.testing.assert_allclose(costs, costs_local)
    assert scans == scans_local
    np.testing.assert_allclose(alt, alt_local)  # against the alternatives: merged alike
    assert alt.shape == costs.shape and not np.allclose(alt, costs)
    # the first candidate's per-scan costs, per segment: the same series, summing to its blocks
    assert len(centre) == len(centre_local) == len(data.segments)
    for a, b in zip(centre, centre_local, strict=True):
        np.testing.assert_allclose(a, b)
    np.testing.assert_allclose(sum(c.sum() for c in centre), costs[0].sum())
    pooled = got.num_poses * (got.mean_e_t / 4 + got.mean_e_r / math.pi**2)
    np.testing.assert_allclose(costs.sum(1), pooled.numpy(), rtol=1e-9)
    assert got.reward.shape == (n,)
    assert torch.allclose(got.reward, expected.reward)
    assert torch.allclose(got.mean_e_t, expected.mean_e_t)
    assert torch.equal(got.num_poses, expected.num_poses)


def test_restart_when_the_result_disagrees_keeps_the_best(fake_backend_env, tmp_path):
    from l2calib.training import RESTART_SEED_STRIDE

    single, _ = _run(_recipe())
    assert single.warnings  # 3 iterations end far from the truth: the agreement check fails
    result, outcome = _run(_recipe(restarts=1), tmp_path)
    first, second = result.extra["attempts"]
    assert (first["seed"], second["seed"]) == (5, 5 + RESTART_SEED_STRIDE)
    assert first["final_reward"] == pytest.approx(single.final_reward)  # attempt 1 as before
    kept = max((first, second), key=lambda a: a["final_reward"])
    assert kept["kept"] and result.final_reward == pytest.approx(kept["final_reward"])
    assert result.evaluations > single.evaluations  # every attempt is charged
    assert len(outcome.history) == 3
    assert (tmp_path / "restart-1" / "checkpoint.pt").is_file()
    resumed, _ = _run(_recipe(restarts=1), tmp_path, resume=True)  # both attempts resume
    assert torch.equal(torch.as_tensor(resumed.T_imu_lidar), torch.as_tensor(result.T_imu_lidar))
    shutil.rmtree(tmp_path / "restart-1")  # killed before the restart began: it starts afresh
    again, _ = _run(_recipe(restarts=1), tmp_path, resume=True)
    assert torch.equal(torch.as_tensor(again.T_imu_lidar), torch.as_tensor(result.T_imu_lidar))


def test_resume_without_an_out_dir_is_a_clear_error(fake_backend_env):
    with pytest.raises(TrainingError, match="resume needs the output directory"):
        _run(_recipe(), None, resume=True)


def test_resume_continues_to_the_same_result(fake_backend_env, tmp_path):
    recipe = _recipe(max_iterations=5, checkpoint_every=2)
    full, _ = _run(recipe)

    def kill_after_third(record):
        if record.iteration == 2:  # iterations 0-1 are checkpointed, iteration 2 is lost
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(recipe, tmp_path, progress=kill_after_third)
    state = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert len(state["outcome"].history) == 2
    resumed, outcome = _run(recipe, tmp_path, resume=True)
    assert len(outcome.history) == 5
    assert torch.equal(torch.as_tensor(full.T_imu_lidar), torch.as_tensor(resumed.T_imu_lidar))


def test_interruption_checkpoints_the_last_iteration_and_resumes_to_the_same_result(
    fake_backend_env, tmp_path
):
    from l2calib.interrupt import Interrupted

    recipe = _recipe(max_iterations=5, checkpoint_every=100)  # no periodic checkpoint
    full, _ = _run(recipe)

    def signal_after_third(record):
        if record.iteration == 2:
            raise Interrupted(2)  # what the SIGINT handler raises in the main process

    with pytest.raises(Interrupted) as info:
        _run(recipe, tmp_path, progress=signal_after_third)
    assert info.value.iteration == 3 and info.value.attempt == 0
    assert info.value.checkpoint == tmp_path / "checkpoint.pt" and info.value.exit_status == 130
    resumed, outcome = _run(recipe, tmp_path, resume=True)
    assert len(outcome.history) == 5
    assert torch.equal(torch.as_tensor(full.T_imu_lidar), torch.as_tensor(resumed.T_imu_lidar))


def test_resume_refuses_another_recipe(fake_backend_env, tmp_path):
    _run(_recipe(max_iterations=1), tmp_path)
    with pytest.raises(TrainingError, match="another recipe or other input data"):
        _run(_recipe(max_iterations=2, lr=0.1), tmp_path, resume=True)


def test_workers_must_divide_the_batch(fake_backend_env):
    with pytest.raises(ConfigError, match="not divisible by train.workers=3"):
        _run(_recipe(workers=3))


def test_auto_workers_divide_the_batch(monkeypatch):
    from l2calib.train import env_build

    monkeypatch.setattr(env_build.os, "sched_getaffinity", lambda _pid: set(range(6)))
    assert env_build.resolve_workers(32, "auto") == 4  # 6 CPUs: the largest divisor of 32 below 6
    assert env_build.resolve_workers(30, "auto") == 6
    assert env_build.resolve_workers(7, "auto") == 1
    assert env_build.resolve_workers(32, 3) == 3  # explicit counts are checked by make_training_env
    monkeypatch.setattr(env_build.os, "sched_getaffinity", lambda _pid: {0})
    assert env_build.resolve_workers(32, "auto") == 1
    assert Recipe.model_validate({}).train.workers == "auto"


def test_the_recorded_data_share_is_what_the_backend_scored(fake_backend_env, monkeypatch):
    """A backend that keeps all its data when asked for less (a continuous odometry run) is
    recorded at 100 %, so the plateau stop, which waits for all the data, may end such a run."""
    from fakes import FakeBackend

    asked = []

    def use_data_fraction(self, fraction):
        asked.append(fraction)
        return 40  # all of it, whatever the fraction

    monkeypatch.setattr(FakeBackend, "use_data_fraction", use_data_fraction, raising=False)
    _, outcome = _run(_recipe(coarse_to_fine=True, max_iterations=2, workers=1))
    assert any(f < 1.0 for f in asked)  # the trainer asked for a part (the policy is wide)
    assert [r.data_fraction for r in outcome.history] == [1.0, 1.0]
    assert [r.candidate_scans for r in outcome.history] == [8 * 40, 8 * 40]


def test_the_newton_polish_runs_after_the_refinement_and_is_counted(fake_backend_env):
    result, outcome = _run(_recipe(polish_rounds=2))
    polished = result.extra["polish"]
    assert polished["polished_reward"] >= polished["start_reward"]
    assert polished["start_reward"] >= result.extra["refine"]["refined_reward"] - 1e-12
    assert polished["evaluations"] == 2 * 102  # 99 stencil candidates + 3 along the step, per round
    n_probes = len(probe(result.T_imu_lidar)) + probe_evaluations()
    n_probes += result.axis_uncertainty.evaluations
    n_refine = result.extra["refine"]["evaluations"]
    assert result.evaluations == 3 * 8 + n_refine + polished["evaluations"] + n_probes


def test_the_polish_starts_at_the_recipes_stencil_width(fake_backend_env, monkeypatch):
    import l2calib.assess.polish as polish_module

    seen, real = [], polish_module.polish

    def spy(*args, **kwargs):
        seen.append(kwargs.get("first_scale"))
        return real(*args, **kwargs)

    monkeypatch.setattr(polish_module, "polish", spy)
    result, _ = _run(_recipe(polish_rounds=2, polish_first_scale=0.25))
    assert seen == [0.25]
    assert result.extra["polish"]["evaluations"] == 2 * 102
