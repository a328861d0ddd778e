"""``l2calib batch MANIFEST.yaml``: many calibrations, one after another or on a Ray cluster."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import typer


class BatchDisplay:
    """A live table of the jobs (stage, iteration, reward, ETA); plain lines off a terminal."""

    def __init__(self, console, names: list[str]) -> None:
        from rich.live import Live

        from l2calib.batch.jobs import JobState

        self.console = console
        self.jobs = {name: JobState(name) for name in names}
        self.live = Live(self._table(), console=console, refresh_per_second=2)

    def __enter__(self) -> BatchDisplay:
        if self.console.is_terminal:
            self.live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.console.is_terminal:
            self.live.__exit__(*exc)

    def report(self, name: str, fields: dict[str, Any]) -> None:
        """Takes a job's changed fields and redraws."""
        job = self.jobs[name]
        before = job.state
        for key, value in fields.items():
            if hasattr(job, key):
                setattr(job, key, value)
        if self.console.is_terminal:
            self.live.update(self._table())
        elif job.state != before:  # a log: one line per job state change
            extra = f": {job.error}" if job.error else f" {job.status}" if job.status else ""
            self.console.print(f"• job {name}: {job.state}{extra}", highlight=False)

    def _table(self):
        from rich.table import Table

        from l2calib.cli.live import eta_text

        table = Table(title="l2calib batch")
        for col in ("job", "state", "stage", "iteration", "reward", "ETA"):
            table.add_column(col)
        for job in self.jobs.values():
            it = f"{job.iteration}/{job.budget}" if job.budget else "-"
            reward = "-" if job.reward is None else f"{job.reward:.4f}"
            eta = "-"
            if job.state == "running" and job.iteration:
                record = SimpleNamespace(iteration=job.iteration - 1, wall_s=job.elapsed_s)
                eta = eta_text(record, job.budget)
            stage = job.stage if len(job.stage) < 60 else job.stage[:57] + "..."
            table.add_row(job.name, job.state, stage, it, reward, eta)
        return table


def batch(
    manifest: Path = typer.Argument(..., help="Batch manifest YAML (see below)."),
    summary: Path = typer.Option(
        None, "--summary", help="Where summary.csv goes (default: beside the manifest)."
    ),
    resume: bool = typer.Option(
        False, "--resume", help="Keep finished jobs, resume killed ones, start the others."
    ),
    force: bool = typer.Option(False, "--force", help="Move existing out folders aside first."),
) -> None:
    """Run many calibrations (each: recipe, bags, --set, out folder) and summarise them.

    With executor ray the jobs run concurrently on the cluster (ray.address or RAY_ADDRESS,
    else a local Ray instance; bags and out folders on paths every node sees); with local, one
    after another. A job that fails fails alone with its error. Writes summary.csv and prints a
    table. Exit status: 0 when every job ran (see each job's status), 1 when a job failed.

    Manifest (paths relative to its folder):

        executor: ray                 # or local (default)
        ray:
          address: null               # null: RAY_ADDRESS, else a local Ray instance
          cpus_per_job: 2
        jobs:
          - name: van-07
            recipe: velodyne-vlp16-xsens      # a built-in recipe's name, or a file
            bags:
              - van-07/drive.bag
            set:
              - train.seed=1
            out: results/van-07
    """
    import sys

    from rich.console import Console

    from l2calib import interrupt
    from l2calib.batch.jobs import run_local, run_on_ray
    from l2calib.batch.manifest import load_manifest
    from l2calib.batch.summary import table, write_csv

    console = Console()
    plan = load_manifest(manifest)
    run = run_on_ray if plan.executor == "ray" else run_local
    argv = sys.argv[1:]
    again = interrupt.command_line(argv, add="--resume", drop=("--force",))
    # Ctrl-C / SIGTERM: the running jobs keep their checkpoints; --resume continues the batch
    with interrupt.handling(again, again, exit_process=True):
        with BatchDisplay(console, [job.name for job in plan.jobs]) as display:
            jobs = run(plan, display.report, resume=resume, force=force)
    path = write_csv(jobs, summary or manifest.resolve().parent / "summary.csv")
    console.print(table(jobs))
    console.print(f"summary in [bold]{path}[/]")
    if any(job.state == "failed" for job in jobs):
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("batch")(batch)
