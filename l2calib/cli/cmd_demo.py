"""``l2calib demo``: the whole product on the built-in simulator.

Simulates a handheld recording, calibrates it from no initial guess and compares the result with
the ground truth.
"""

from __future__ import annotations

from pathlib import Path

import typer

#: The demo rig: an Ouster OS1-16 mounted upside down and turned 90° on a VN100-class IMU,
#: 12 cm away — far from identity, so "no initial guess" means something.
DEMO_RIG = {"translation_m": (0.12, -0.05, 0.08), "rpy_deg": (180.0, 0.0, 90.0)}


DEMO_BUDGET = ("train.max_iterations=100", "train.max_evaluations=3200")
#: The reference the demo uses unless ``--reference`` says otherwise: LiDAR-only, as a user
#: without motion capture or RTK calibrates.
DEFAULT_REFERENCE = "ct-lidar"


def demo(
    out: Path = typer.Option(Path("l2calib-demo"), "--out", "-o", help="Output directory."),
    seed: int = typer.Option(1, "--seed", help="Seed of the simulation and of the training."),
    duration: float = typer.Option(20.0, "--duration", help="Simulated seconds."),
    set_: list[str] = typer.Option([], "--set", help="Override a field of the demo recipe."),
    force: bool = typer.Option(False, "--force", help="Move an existing --out aside first."),
    reference: str = typer.Option(
        DEFAULT_REFERENCE,
        "--reference",
        help="ct-lidar: the continuous-time LiDAR-only odometry, no ground truth used (the "
        "built-in recipes' default); gt-file: the simulated LiDAR trajectory as a ground-truth "
        "file (as from motion capture); kiss-icp: LiDAR-only odometry (not accurate enough on "
        "this aggressive 16-beam motion: see docs/references.md).",
    ),
) -> None:
    """Simulate a handheld LiDAR+IMU bag, calibrate it from no initial guess, show the error."""
    import sys

    from l2calib import interrupt

    with interrupt.handling(
        restart_command=interrupt.command_line(sys.argv[1:], add="--force"), exit_process=True
    ) as ctx:
        _demo(out, seed, duration, set_, force, reference, ctx)


def _demo(out, seed, duration, set_, force, reference, ctx) -> None:
    """The body of :func:`demo`; ``ctx`` learns the resume command once it is known."""
    import time

    from rich.console import Console

    from l2calib.cli.cmd_calibrate import run_calibration
    from l2calib.errors import ConfigError
    from l2calib.outputs.writer import prepare_out_dir
    from l2calib.recipe import load_recipe
    from l2calib.sim import SimConfig, simulate, write_run

    t0 = time.monotonic()
    console = Console()
    if reference not in ("ct-lidar", "gt-file", "kiss-icp"):
        raise ConfigError(
            f"--reference {reference}: unknown", fix="use ct-lidar, gt-file or kiss-icp"
        )
    # A demo budget: 100 PPO iterations (3,200 candidates) reach ~2 cm / 0.4 deg on this rig and
    # the refinement after them the last millimetres; the full 4,800 take 6.5 min on 2 cores.
    overrides = [f"train.seed={seed}", *DEMO_BUDGET, *set_]
    load_recipe("simulator", overrides)  # fail on a bad --set before simulating
    out = prepare_out_dir(out, resume=False, force=force)
    cfg = SimConfig.model_validate(
        {
            "duration_s": duration,
            "seed": seed,
            "world": {"name": "urban"},
            "motion": {"profile": "handheld"},
            "lidar": {"model": "ouster-os1-16"},
            "imu": {"model": "vn100"},
            "rig": {"preset": None, **DEMO_RIG},
        }
    )
    console.print(f"[cyan]•[/] simulating {duration:.0f} s of handheld motion (urban world)")
    run = simulate(cfg, progress=console.is_terminal)
    sim_dir = out / "simulated"
    files = write_run(run, sim_dir, progress=console.is_terminal)
    console.print(f"[cyan]•[/] wrote {files['bag']} and its ground truth")
    if reference != "gt-file":
        overrides = [f"reference.name={reference}", *overrides]
        console.print(
            f"[cyan]•[/] reference: {reference} (LiDAR-only odometry; no ground truth is used)"
        )
    else:
        overrides = [
            "reference.name=gt-file",
            f"reference.options.path={files['gt_lidar']}",
            *overrides,
        ]
        console.print(
            f"[cyan]•[/] reference: {files['gt_lidar']} (the LiDAR's own trajectory, as a "
            "motion-capture file would give it; the extrinsic is still learnt from IMU + LiDAR)"
        )
    recipe = load_recipe("simulator", overrides)
    # the demo has no --resume of its own: its calibration continues as a plain `calibrate`
    calib_args = ["calibrate", "simulator", "--bag", str(files["bag"])]
    calib_args += ["--out", str(out / "calibration")]
    ctx.resume_command = interrupt_cmd(calib_args, overrides)
    run_calibration(
        recipe,
        out / "calibration",
        bags=[Path(files["bag"])],
        truth=run.T_imu_lidar,
        console=console,
    )
    console.print(f"demo finished in {time.monotonic() - t0:.0f} s")


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("demo")(demo)


def interrupt_cmd(args: list[str], overrides: list[str]) -> str:
    """The ``l2calib calibrate … --resume`` line that continues the demo's calibration."""
    from l2calib.interrupt import command_line

    for item in overrides:
        args += ["--set", item]
    return command_line(args, add="--resume")
