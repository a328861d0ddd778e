"""``l2calib simulate``: write a simulated LiDAR-IMU bag with its ground truth."""

from __future__ import annotations

from pathlib import Path

import typer

_SIM = "Simulation"
_BAG = "Bag"


def simulate(
    out: Path = typer.Option(..., "--out", "-o", help="Output directory.", rich_help_panel=_BAG),
    world: str = typer.Option(
        "urban", help="urban, hall, corridor or open-field.", rich_help_panel=_SIM
    ),
    profile: str = typer.Option("handheld", help="handheld, uav or ugv.", rich_help_panel=_SIM),
    lidar: str | None = typer.Option(
        None,
        help="ouster-os1-16, ouster-os1-64, velodyne-vlp-16, velodyne-vlp-32c, "
        "hesai-pandar-xt32, livox-mid360 (default: the rig's).",
        rich_help_panel=_SIM,
    ),
    imu: str | None = typer.Option(
        None,
        help="vn100, vn200, mti-300, bmi088, ideal (default: the rig's).",
        rich_help_panel=_SIM,
    ),
    rig: str = typer.Option(
        "ntu-viral", help="Extrinsic preset: ntu-viral, mcd, paper-handheld.", rich_help_panel=_SIM
    ),
    duration: float = typer.Option(20.0, help="Seconds.", rich_help_panel=_SIM),
    seed: int = typer.Option(0, help="Random seed (world, motion, noise).", rich_help_panel=_SIM),
    columns: int | None = typer.Option(
        None, help="Azimuth steps of a spinning LiDAR.", rich_help_panel=_SIM
    ),
    time_offset: float = typer.Option(
        0.0, help="t_imu = t_lidar + offset (s).", rich_help_panel=_SIM
    ),
    no_noise: bool = typer.Option(
        False, "--no-noise", help="Exact IMU and ranges.", rich_help_panel=_SIM
    ),
    set_: list[str] = typer.Option(
        [],
        "--set",
        help="Override any setting, e.g. --set imu.rate_hz=400 (see scenario.json).",
        rich_help_panel=_SIM,
    ),
    fmt: str = typer.Option(
        "ros1", "--format", help="ros1, ros2-sqlite3 or ros2-mcap.", rich_help_panel=_BAG
    ),
    stamp: str = typer.Option(
        "driver",
        help="Header stamp at the scan start or end; driver: as the vendor does.",
        rich_help_panel=_BAG,
    ),
    lidar_msg: str = typer.Option(
        "auto",
        help="pointcloud2 or livox-custom (auto: CustomMsg for Livox).",
        rich_help_panel=_BAG,
    ),
    gyro_unit: str = typer.Option("rad/s", help="rad/s or deg/s.", rich_help_panel=_BAG),
    accel_unit: str = typer.Option("m/s^2", help="m/s^2 or g.", rich_help_panel=_BAG),
    no_bag: bool = typer.Option(
        False, "--no-bag", help="Only ground truth and scenario.json.", rich_help_panel=_BAG
    ),
    overwrite: bool = typer.Option(False, help="Replace existing outputs.", rich_help_panel=_BAG),
) -> None:
    """Simulate a LiDAR-IMU recording and write it as a bag with its ground truth."""
    from rich.console import Console

    from l2calib.outputs.writable import check_writable
    from l2calib.recipe import apply_overrides
    from l2calib.sim.config import sim_config_from_dict
    from l2calib.sim.lidar_models import get_lidar
    from l2calib.sim.outputs import bag_options, check_outputs, output_files, write_run
    from l2calib.sim.scenario import simulate as run_simulation

    data = {
        "world": {"name": world},
        "motion": {"profile": profile},
        "lidar": {"model": lidar, "columns": columns, "noise": not no_noise},
        "imu": {"model": imu, "noise": not no_noise},
        "rig": {"preset": rig, "time_offset_s": time_offset},
        "duration_s": duration,
        "seed": seed,
    }
    config = sim_config_from_dict(apply_overrides(data, list(set_)), "simulate options")
    bag = bag_options(
        format=fmt,
        stamp_position=stamp,
        lidar_msg=lidar_msg,
        gyro_unit=gyro_unit,
        accel_unit=accel_unit,
    )  # fail before simulating
    bag.resolved(get_lidar(config.resolved().lidar.model).vendor)
    check_writable(out, "--out")
    check_outputs(output_files(out, bag, not no_bag), overwrite)  # before the sweep, not after
    console = Console(stderr=True)
    run = run_simulation(config, progress=True)
    files = write_run(run, out, bag, overwrite=overwrite, progress=True, write_bag_file=not no_bag)
    s = run.stats
    console.print(
        f"[bold]{len(run.scans)}[/] scans, {s['points']} points, {len(run.imu)} IMU samples; "
        f"mean |ω| {s['mean_abs_omega_rad_s']:.2f} rad/s, path {s['path_length_m']:.1f} m"
    )
    for role, path in files.items():
        console.print(f"  {role:<10} {path}")


def register(app: typer.Typer) -> None:
    """Adds the ``simulate`` command to ``app``."""
    app.command("simulate")(simulate)
