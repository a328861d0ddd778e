"""The ``l2calib`` command: one typer app; each command lives in its own module.

Known errors (:class:`l2calib.errors.L2CalibError`) print one line
``error: <what> — fix: <how>`` and exit with status 1; an interrupted run
(:mod:`l2calib.interrupt`) says where to resume and exits with 130 (SIGINT) or 143 (SIGTERM).
``calibrate`` exits with 3 when the data could not calibrate (:mod:`l2calib.assess.status`).
"""

from __future__ import annotations

import sys

import typer

from l2calib import __version__
from l2calib.errors import L2CalibError

app = typer.Typer(
    name="l2calib",
    help="Target-free IMU-LiDAR extrinsic calibration by reinforcement learning on SE(3).",
    no_args_is_help=True,
    rich_markup_mode="rich",
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"l2calib {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Target-free IMU-LiDAR extrinsic calibration by reinforcement learning on SE(3)."""


# Command modules register themselves on ``app``; add new commands here (one line each).
from l2calib.cli import (  # noqa: E402
    cmd_batch,
    cmd_calibrate,
    cmd_demo,
    cmd_evaluate,
    cmd_inspect,
    cmd_plugins,
    cmd_recipe,
    cmd_reference,
    cmd_select,
    cmd_simulate,
)

for _module in (
    cmd_demo,
    cmd_calibrate,
    cmd_batch,
    cmd_evaluate,
    cmd_simulate,
    cmd_inspect,
    cmd_select,
    cmd_reference,
    cmd_plugins,
    cmd_recipe,
):
    _module.register(app)


def format_error(exc: L2CalibError) -> str:
    """One-line rendering of a known error: ``error: <what> — fix: <how>``."""
    return f"error: {exc}"


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``l2calib`` console script."""
    try:
        status = app(args=argv, standalone_mode=False)  # typer returns Exit codes here
        if isinstance(status, int) and status:
            sys.exit(status)
    except L2CalibError as exc:
        typer.echo(format_error(exc), err=True)
        sys.exit(1)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(130)
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)
    except Exception as exc:  # click usage errors
        # Typer >= 0.2x raises its own copy of click's exceptions (typer._click), which
        # click.ClickException does not catch: recognise both by what they offer.
        show, code = getattr(exc, "show", None), getattr(exc, "exit_code", None)
        if callable(show) and isinstance(code, int):
            show()
            sys.exit(code)
        raise


if __name__ == "__main__":
    main()
