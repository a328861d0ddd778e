"""Running a batch's jobs: one after another here, or concurrently as Ray tasks.

Each job is a whole :class:`~l2calib.calibration.Calibration` (``calibrate`` with the job's
recipe, bags, ``--set`` and out folder). A job that fails — a bad recipe, a missing bag, an
error in the odometry, even a crashed Ray worker — fails alone: its state holds the error and
the other jobs go on. Jobs report their progress through ``report(name, fields)``; on Ray the
reports go to a small :class:`JobBoard` actor the driver reads for its live table (Ray's own
object store and actor calls, no other channel).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from l2calib.batch.manifest import BatchJob, BatchManifest

Report = Callable[[str, dict[str, Any]], None]


@dataclass
class JobState:
    """Where one job stands, and what it produced.

    Attributes:
        name: The job's name in the manifest.
        state: ``waiting``, ``running``, ``done`` or ``failed``.
        stage: The latest stage line (reading, reference, training, ...).
        iteration: PPO iterations done; ``budget`` the most it may run.
        reward: Best reward of the latest iteration.
        elapsed_s: Training time so far (s), for the ETA.
        status: ``calibrated``, ``unreliable`` or ``not-calibrated`` once done.
        T_imu_lidar: The result ``[4][4]`` (LiDAR → IMU, m), or ``None``.
        time_offset_s: The LiDAR–IMU time offset (``t_imu = t_lidar + offset``), or ``None``.
        warnings: The result's warnings and undetermined axes.
        error: Why the job failed.
        wall_s: The job's wall time (s).
        out: Its output folder.
    """

    name: str
    state: str = "waiting"
    stage: str = ""
    iteration: int = 0
    budget: int = 0
    reward: float | None = None
    elapsed_s: float = 0.0
    status: str = ""
    T_imu_lidar: list[list[float]] | None = None
    time_offset_s: float | None = None
    warnings: list[str] = field(default_factory=list)
    error: str = ""
    wall_s: float = 0.0
    out: str = ""


def run_job(
    job: BatchJob, report: Report, resume: bool = False, force: bool = False,
    defaults: list[str] | None = None,
) -> JobState:  # fmt: skip
    """Runs one calibration; never raises for the job's own failure (see the module docstring).

    Args:
        job: The job.
        report: Called with ``(job.name, changed fields)`` as the job progresses.
        resume: Continue the job's killed run from its out folder's checkpoint; a job whose
            ``calibration.yaml`` is already there is kept as it is; one killed before its first
            checkpoint starts again (its folder moved aside).
        force: Move a non-empty out folder aside first.
        defaults: ``--set`` items applied before the job's own (e.g. ``train.workers``).
    """
    from l2calib.calibration import Calibration, RunHooks
    from l2calib.errors import L2CalibError
    from l2calib.recipe import load_recipe
    from l2calib.train.checkpoint import CHECKPOINT_NAME

    state = JobState(job.name, state="running", out=str(job.out))
    t0 = time.monotonic()
    report(job.name, {"state": "running", "out": state.out})
    try:
        if resume and (job.out / "calibration.yaml").is_file():
            return _finished_earlier(job, state, report)
        recipe = load_recipe(job.recipe, [*(defaults or []), *job.set])
        budget = recipe.train.iteration_budget

        def progress(record: Any) -> None:
            report(job.name, {"iteration": record.iteration + 1, "budget": budget,
                              "reward": record.reward_max, "elapsed_s": record.wall_s,
                              "stage": "training"})  # fmt: skip

        hooks = RunHooks(stage=lambda msg: report(job.name, {"stage": msg}), progress=progress)
        # --resume: a killed job continues from its checkpoint; one killed before its first
        # checkpoint starts again, its folder moved aside (never deleted)
        again = resume and (job.out / CHECKPOINT_NAME).is_file()
        aside = force or (resume and not again)  # ignored when resuming
        run = Calibration(recipe, job.out, resume=again, force=aside, hooks=hooks)
        result = run.run(bags=job.bags)
        state.state, state.status = "done", result.status
        if result.T_imu_lidar is not None:
            state.T_imu_lidar = [[float(v) for v in row] for row in result.T_imu_lidar]
        state.time_offset_s = result.time_offset_s
        state.warnings = [*result.warnings, *result.undetermined]
    except L2CalibError as exc:
        state.state, state.error = "failed", str(exc)
    except Exception as exc:  # a bug or a crash in one job must not end the others
        state.state, state.error = "failed", f"{type(exc).__name__}: {exc}"
    state.wall_s = time.monotonic() - t0
    report(job.name, {**asdict(state), "stage": state.state})
    return state


def _finished_earlier(job: BatchJob, state: JobState, report: Report) -> JobState:
    """A job whose out folder already holds its calibration.yaml (``--resume``)."""
    from l2calib.errors import NotCalibratedError
    from l2calib.outputs.calibration_read import read_extrinsic, read_status

    path = job.out / "calibration.yaml"
    state.state, state.stage = "done", f"kept: {path} was already written"
    state.status = f"{read_status(path)} (earlier run)"
    try:
        extrinsic = read_extrinsic(path)
        state.T_imu_lidar = extrinsic.T_imu_lidar.tolist()
        state.time_offset_s = extrinsic.time_offset_s
    except NotCalibratedError:  # no extrinsic in it
        pass
    report(job.name, asdict(state))
    return state


def run_local(
    manifest: BatchManifest, report: Report, resume: bool = False, force: bool = False
) -> list[JobState]:
    """The jobs one after another in this process (each with its recipe's own workers)."""
    return [run_job(job, report, resume, force) for job in manifest.jobs]


class JobBoard:
    """Where Ray jobs post their progress and the driver reads it (a Ray actor)."""

    def __init__(self) -> None:
        self.fields: dict[str, dict[str, Any]] = {}

    def update(self, name: str, fields: dict[str, Any]) -> None:
        """Merges a job's changed fields."""
        self.fields.setdefault(name, {}).update(fields)

    def snapshot(self) -> dict[str, dict[str, Any]]:
        """Every job's fields so far."""
        return self.fields


def _ray_job(job_data: dict, board, resume: bool, force: bool, defaults: list[str]) -> dict:
    """One job on a Ray worker (a remote function: module-level so Ray can ship it)."""
    job = BatchJob.model_validate(job_data)

    def report(name: str, fields: dict[str, Any]) -> None:
        board.update.remote(name, fields)

    return asdict(run_job(job, report, resume, force, defaults))


def run_on_ray(
    manifest: BatchManifest,
    report: Report,
    resume: bool = False,
    force: bool = False,
    poll_s: float = 0.5,
) -> list[JobState]:
    """All jobs at once as Ray tasks, ``ray.cpus_per_job`` CPUs each; Ray queues the rest.

    Bags and out folders must be paths every node sees (a shared file system); the driver
    reads the progress from the board every ``poll_s`` and passes it to ``report``.
    """
    from l2calib.recipe_train import RayConfig
    from l2calib.train.ray_executor import connect, import_ray

    ray = import_ray()
    owns = connect(RayConfig(address=manifest.ray.address))
    cpus = manifest.ray.cpus_per_job
    try:
        board = ray.remote(num_cpus=0)(JobBoard).remote()
        task = ray.remote(num_cpus=cpus, max_retries=0)(_ray_job)
        defaults = [f"train.workers={cpus}"]
        pending = {
            task.remote(job.model_dump(mode="json"), board, resume, force, defaults): job.name
            for job in manifest.jobs
        }
        states: dict[str, JobState] = {}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=len(pending), timeout=poll_s)
            for name, fields in ray.get(board.snapshot.remote()).items():
                if name not in states:  # a finished job's own result is newer than the board
                    report(name, fields)
            for ref in done:
                name = pending.pop(ref)
                try:
                    states[name] = JobState(**ray.get(ref))
                except Exception as exc:  # the worker died (out of memory, node lost, ...)
                    states[name] = JobState(name, "failed", error=f"{type(exc).__name__}: {exc}")
                report(name, {**asdict(states[name]), "stage": states[name].state})
        return [states[job.name] for job in manifest.jobs]
    finally:
        if owns:
            ray.shutdown()
