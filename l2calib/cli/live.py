"""Live display of a calibration: stages, then per-iteration training progress (rich)."""

from __future__ import annotations

from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table


def eta_text(record: Any, iterations: int) -> str:
    """``"≤ 1 min 20 s left"``: the budget's remaining iterations at the pace so far.

    "≤" because PPO usually stops before its budget (hand-over, plateau, convergence); the pace
    is an average, and coarse-to-fine iterations get slower as they use more of the data.
    """
    done = record.iteration + 1
    left = max(iterations - done, 0) * record.wall_s / max(done, 1)
    minutes, seconds = divmod(int(round(left)), 60)
    return f"≤ {minutes} min {seconds:02d} s left" if minutes else f"≤ {seconds} s left"


class CalibrationDisplay:
    """Shows what stage runs and, during training, iteration, reward, extrinsic and σ per axis."""

    def __init__(self, console: Console, iterations: int) -> None:
        self.console = console
        self.iterations = iterations
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TextColumn("{task.fields[eta]}"),
            console=console,
        )
        self.task = self.progress.add_task("training", total=iterations, eta="")
        self.table = Table.grid(padding=(0, 2))
        self.live = Live(Group(self.progress), console=console, refresh_per_second=4,
                         transient=False)  # fmt: skip

    def __enter__(self) -> CalibrationDisplay:
        if self.console.is_terminal:  # off a terminal, update() prints plain lines instead
            self.live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.console.is_terminal:
            self.live.__exit__(*exc)

    def stage(self, message: str) -> None:
        """Prints a pipeline stage line above the live area."""
        self.console.print(f"[cyan]•[/] {message}")

    def skip_training(self) -> None:
        """Hides the training bar: the run stops before training."""
        self.progress.update(self.task, visible=False)

    def update(self, record: Any) -> None:
        """Refreshes with one :class:`~l2calib.train.ppo.IterationRecord`."""
        if not self.console.is_terminal:  # a log file or CI: a plain line every 10 iterations
            if record.iteration % 10 == 0:
                t = ", ".join(f"{100 * v:+.1f}" for v in record.translation_m)
                rpy = ", ".join(f"{v:+.2f}" for v in record.rpy_deg)
                self.console.print(
                    f"  iteration {record.iteration + 1}: evaluations {record.evaluations}, "
                    f"reward mean {record.reward_mean:.4f} best {record.reward_max:.4f}, "
                    f"t [{t}] cm, rpy [{rpy}] deg, max σ {max(record.rotation_sigma_deg):.2f} deg "
                    f"{100 * max(record.translation_sigma_m):.1f} cm, "
                    f"data {100 * record.data_fraction:.0f} %, {eta_text(record, self.iterations)}",
                    highlight=False,
                )
            return
        t = [100 * v for v in record.translation_m]
        ts = [100 * v for v in record.translation_sigma_m]
        table = Table(box=None, show_header=True, header_style="bold")
        for col in ("", "x / roll", "y / pitch", "z / yaw"):
            table.add_column(col, justify="right")
        table.add_row("translation cm", *(f"{v:+.2f}" for v in t))
        table.add_row("  σ cm", *(f"{v:.2f}" for v in ts))
        table.add_row("rotation deg", *(f"{v:+.3f}" for v in record.rpy_deg))
        table.add_row("  σ deg", *(f"{v:.3f}" for v in record.rotation_sigma_deg))
        summary = (
            f"iteration {record.iteration + 1}  evaluations {record.evaluations}  "
            f"reward mean {record.reward_mean:.4f} best {record.reward_max:.4f}"
        )
        if record.time_offset_s is not None:
            summary += f"  time offset {1000 * record.time_offset_s:+.2f} ms"
        if record.data_fraction < 1.0:
            summary += f"  data {100 * record.data_fraction:.0f} %"
        if record.lost or record.diverged:
            summary += f"  lost {record.lost} diverged {record.diverged}"
        self.progress.update(
            self.task, completed=record.iteration + 1, eta=eta_text(record, self.iterations)
        )
        self.live.update(Group(self.progress, summary, table))
