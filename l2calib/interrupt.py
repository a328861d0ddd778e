"""Ctrl-C and SIGTERM during a calibration: stop at once, keep the checkpoint, say how to resume.

While :func:`handling` is active, SIGINT and SIGTERM raise :class:`Interrupted` in the main
process (a ``KeyboardInterrupt``, so no ``except Exception`` swallows it). Worker processes
forked meanwhile (the odometry workers of ``train.workers``) ignore SIGINT — a Ctrl-C reaches the
whole process group, and the parent stops them itself — and die on SIGTERM as usual. The trainer
saves the last completed iteration before the exception leaves it; the CLI prints
``interrupted at iteration N — resume with: …`` and exits with ``128 + signal``
(130 for SIGINT, 143 for SIGTERM). A second signal while cleaning up exits at once.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """A calibration stopped by SIGINT or SIGTERM.

    Attributes:
        signum: The signal received.
        iteration: PPO iterations kept in the checkpoint (``None``: training had not started).
        attempt: The PPO attempt interrupted (0: the first run, k: restart k).
        checkpoint: The checkpoint a ``--resume`` continues from (``None``: none written yet).
        report: The line to print (filled in by :func:`handling` on the way out).
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.iteration: int | None = None
        self.attempt = 0
        self.checkpoint: Path | None = None
        self.report: str | None = None  # the line for the user (set by :func:`handling`)

    @property
    def exit_status(self) -> int:
        """The shell convention: ``128 + signal`` (130 for SIGINT, 143 for SIGTERM)."""
        return 128 + self.signum


@dataclass
class InterruptContext:
    """What the CLI knows to tell the user when a run is interrupted.

    Attributes:
        resume_command: The command line that continues the run (set by the command once it
            knows it; the demo sets it after simulating).
        restart_command: The command line that starts the run again (no checkpoint yet).
    """

    resume_command: str | None = None
    restart_command: str | None = None
    main_pid: int = field(default_factory=os.getpid)

    def message(self, exc: Interrupted) -> str:
        """The line printed on interruption."""
        name = signal.Signals(exc.signum).name
        if exc.checkpoint is None or exc.iteration is None:
            again = f" — run again: {self.restart_command}" if self.restart_command else ""
            return f"interrupted ({name}) before the first checkpoint: nothing to resume{again}"
        where = f"iteration {exc.iteration}"
        if exc.attempt:
            where += f" of restart {exc.attempt}"
        hint = f" — resume with: {self.resume_command}" if self.resume_command else ""
        return f"interrupted at {where} ({name}; {exc.checkpoint} kept){hint}"


_ACTIVE: InterruptContext | None = None
_HELD: list[int] | None = None  # signals received inside held(), raised as it ends


def _in_child() -> None:
    """In a process forked while handling is active: ignore Ctrl-C, die on SIGTERM."""
    if _ACTIVE is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


os.register_at_fork(after_in_child=_in_child)


def _handler(signum: int, _frame) -> None:
    ctx = _ACTIVE
    if ctx is None or os.getpid() != ctx.main_pid:  # a child forked before the hook took effect
        if signum == signal.SIGTERM:
            os._exit(128 + signum)
        return
    if _HELD is not None:  # inside held(): raised as the block ends
        _HELD.append(signum)
        return
    for s in _SIGNALS:  # a second signal while cleaning up: leave at once
        signal.signal(s, _force_exit)
    raise Interrupted(signum)


@contextmanager
def held() -> Iterator[None]:
    """Holds SIGINT / SIGTERM back during a short computation, raising them as it ends.

    For code that must not be torn mid-way: an exception raised inside a library's context
    manager can come out as another one (TorchRL's PPO loss turned an :class:`Interrupted` into
    a ``RuntimeError``, so the run ended with a traceback instead of its checkpoint and resume
    line). Only for blocks of well under a second (a PPO update), so Ctrl-C stays prompt.
    """
    global _HELD
    if _HELD is not None:  # nested: the outer block raises
        yield
        return
    _HELD = []
    try:
        yield
    finally:
        pending, _HELD = _HELD, None
    if pending:
        for s in _SIGNALS:  # a second signal while cleaning up: leave at once
            signal.signal(s, _force_exit)
        raise Interrupted(pending[0])


def _force_exit(signum: int, _frame) -> None:
    os._exit(128 + signum)


@contextmanager
def handling(
    resume_command: str | None = None,
    restart_command: str | None = None,
    exit_process: bool = False,
) -> Iterator[InterruptContext]:
    """Turns SIGINT / SIGTERM into :class:`Interrupted` for the duration of the block.

    Only from the main thread (signal handlers cannot be set elsewhere); in other threads the
    block runs with the signals as they were.

    Args:
        resume_command: The command line that continues the run from its checkpoint.
        restart_command: The command line that starts it again (no checkpoint yet).
        exit_process: Print the report to stderr and exit with ``128 + signal`` (the CLI; the
            command-line framework would otherwise turn the interruption into its own status)
            instead of re-raising :class:`Interrupted`.

    Yields:
        The :class:`InterruptContext` whose commands the block may fill in.
    """
    global _ACTIVE
    import threading

    ctx = InterruptContext(resume_command, restart_command)
    if threading.current_thread() is not threading.main_thread():
        yield ctx
        return
    previous = {s: signal.getsignal(s) for s in _SIGNALS}
    _ACTIVE = ctx
    for s in _SIGNALS:
        signal.signal(s, _handler)
    try:
        yield ctx
    except Interrupted as exc:
        exc.report = ctx.message(exc)
        if not exit_process:
            raise
        print(exc.report, file=sys.stderr, flush=True)
        raise SystemExit(exc.exit_status) from None
    finally:
        _ACTIVE = None
        for s, h in previous.items():
            signal.signal(s, h)


def stop_workers(env, timeout_s: float = 2.0) -> None:
    """Terminates an interrupted training env's worker processes without talking to them.

    A ``ParallelEnv``'s own ``close`` sends each worker a message and waits for its answer; a
    worker in the middle of an odometry batch answers only when done (seconds to minutes). Its
    processes are terminated instead (SIGTERM, then SIGKILL after ``timeout_s``). Ray actors
    (``train.executor: ray``) are killed.
    """
    terminate = getattr(type(env), "terminate", None)  # RayScoringEnv
    if terminate is not None:
        terminate(env)
        return
    workers = getattr(env, "_workers", None) or []
    _quiet_fd_sharing()
    for proc in workers:
        if proc.is_alive():
            proc.terminate()
    for proc in workers:
        proc.join(timeout_s)
        if proc.is_alive():
            proc.kill()
            proc.join(1.0)


def _quiet_fd_sharing() -> None:
    """Keeps multiprocessing's descriptor-sharing thread quiet about workers killed mid-transfer.

    Tensors passed between the workers and this process travel as file descriptors, served by a
    thread of :mod:`multiprocessing.resource_sharer`; a worker terminated while fetching one
    leaves that thread an error which it prints through ``sys.excepthook`` as a traceback (seen
    once in the suite, under load) after the run has already stopped cleanly. Only errors
    raised in that module are dropped.
    """
    import traceback

    previous = sys.excepthook

    def hook(exc_type, exc, tb) -> None:
        frames = traceback.extract_tb(tb)
        if not any(f.filename.endswith("resource_sharer.py") for f in frames):
            previous(exc_type, exc, tb)

    sys.excepthook = hook


def command_line(argv: list[str], add: str | None = None, drop: tuple[str, ...] = ()) -> str:
    """``l2calib`` with ``argv`` (shell-quoted), without the flags in ``drop``, plus ``add``."""
    import shlex

    args = [a for a in argv if a not in drop]
    if add is not None and add not in args:
        args.append(add)
    return shlex.join(["l2calib", *args])
