"""Writes a simulated run to disk: the bag plus its ground truth.

``out_dir`` receives

* ``sim.bag`` (ROS1) or ``sim/`` (ROS2, sqlite3 or mcap) — see :mod:`l2calib.sim.bagwriter`;
* ``extrinsic_gt.yaml`` — ``T_imu_lidar`` (4×4), translation, quaternion xyzw, rpy in degrees,
  time offset, and which clock is which;
* ``gt_imu.tum`` (IMU clock) and ``gt_lidar.tum`` (LiDAR clock), world frame z up;
* ``scenario.json`` — every setting, the seed, motion statistics (mean |ω| ...), sensor models and
  the bag's topics, message types and conventions.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from l2calib import __version__
from l2calib.errors import ConfigError
from l2calib.io.trajectory_files import write_tum
from l2calib.sim import SIMULATOR_VERSION
from l2calib.sim.bagwriter import BagOptions, bag_path, write_bag
from l2calib.sim.rigs import describe_extrinsic

if TYPE_CHECKING:
    from l2calib.sim.scenario import SimRun

CLOCKS = {
    "imu": "true time; IMU stamps and gt_imu.tum",
    "lidar": "t_lidar = t_imu - time_offset_s; LiDAR header/point stamps and gt_lidar.tum",
    "relation": "t_imu = t_lidar + time_offset_s",
}


def extrinsic_document(run: SimRun) -> dict[str, Any]:
    """The content of ``extrinsic_gt.yaml``."""
    d = describe_extrinsic(run.T_imu_lidar)
    return {
        "T_imu_lidar": [[float(v) for v in row] for row in run.T_imu_lidar],
        "translation_m": d["translation_m"],
        "quat_xyzw": d["quat_xyzw"],
        "rpy_deg": d["rpy_deg"],
        "time_offset_s": float(run.time_offset_s),
        "conventions": {
            "T_imu_lidar": "maps LiDAR points into the IMU frame: p_imu = R p_lidar + t",
            "rpy_deg": "R = Rz(yaw) Ry(pitch) Rx(roll)",
            "time_offset_s": CLOCKS["relation"],
        },
        "clocks": CLOCKS,
    }


def scenario_document(run: SimRun, files: dict[str, str], bag: dict | None) -> dict[str, Any]:
    """The content of ``scenario.json``."""
    route = dataclasses.asdict(run.world.route)
    return {
        "generator": f"l2calib {__version__} simulator",
        "simulator_version": SIMULATOR_VERSION,
        "seed": run.config.seed,
        "config": run.config.model_dump(mode="json"),
        "stats": run.stats,
        "mean_abs_omega_rad_s": run.stats.get("mean_abs_omega_rad_s"),
        "ground_truth": extrinsic_document(run),
        "clocks": CLOCKS,
        "start_stamp_ns": run.t0_ns,
        "world": {
            "name": run.world.name,
            "seed": run.world.seed,
            "triangles": int(len(run.world.triangles)),
            "route": route,
            "frame": "z up, gravity along -z, ground top at z = 0",
        },
        "sensors": {
            "lidar": dataclasses.asdict(run.lidar_spec),
            "imu": dataclasses.asdict(run.imu_spec),
        },
        "files": files,
        "bag": bag,
    }


def bag_options(base: BagOptions | None = None, **overrides: Any) -> BagOptions:
    """Validated bag options: ``base`` (or defaults) with keyword ``overrides``.

    Raises:
        ConfigError: naming each bad option.
    """
    from pydantic import ValidationError

    try:
        return BagOptions.model_validate({**(base.model_dump() if base else {}), **overrides})
    except ValidationError as exc:
        msg = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise ConfigError(f"bag options: {msg}", fix="see `l2calib simulate --help`") from None


def output_files(out: Path, opts: BagOptions, write_bag_file: bool = True) -> dict[str, Path]:
    """The files :func:`write_run` writes into ``out``, by role."""
    files = {
        "extrinsic": out / "extrinsic_gt.yaml",
        "gt_imu": out / "gt_imu.tum",
        "gt_lidar": out / "gt_lidar.tum",
        "scenario": out / "scenario.json",
    }
    if write_bag_file:
        files["bag"] = bag_path(out, opts.format)
    return files


def check_outputs(files: dict[str, Path], overwrite: bool) -> list[Path]:
    """The outputs that exist already (to be replaced); an error if ``overwrite`` is false.

    ``l2calib simulate`` calls it before simulating, :func:`write_run` again before writing.

    Raises:
        ConfigError: naming the first existing output, unless ``overwrite``.
    """
    existing = [p for p in files.values() if p.exists()]
    if existing and not overwrite:
        raise ConfigError(
            f"{existing[0]} already exists",
            fix="choose another --out directory or pass --overwrite",
        )
    return existing


def write_run(
    run: SimRun,
    out_dir: str | Path,
    bag: BagOptions | None = None,
    overwrite: bool = False,
    progress: bool = False,
    write_bag_file: bool = True,
    **bag_overrides: Any,
) -> dict[str, str]:
    """Writes the bag and ground-truth files of ``run`` into ``out_dir``.

    Args:
        run: The simulated run.
        out_dir: Output directory (created if missing).
        bag: Bag options (defaults if ``None``).
        overwrite: Replace an existing bag and ground-truth files.
        progress: Show a rich progress bar while writing.
        write_bag_file: Set ``False`` to write only the ground truth and scenario.
        **bag_overrides: :class:`BagOptions` fields applied on top of ``bag``
            (``format="ros2-mcap"``, ``stamp_position="end"``, ``lidar_msg="pointcloud2"``...).

    Returns:
        Paths of the files written, by role (``bag``, ``extrinsic``, ``gt_imu``, ...).

    Raises:
        ConfigError: if the outputs exist and ``overwrite`` is false, or for bad bag options.
    """
    out = Path(out_dir)
    opts = bag_options(bag, **bag_overrides)
    opts.resolved(run.lidar_spec.vendor)  # vendor-specific checks before touching the disk
    files = output_files(out, opts, write_bag_file)
    existing = check_outputs(files, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    for p in existing:
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    summary = write_bag(run, files["bag"], opts, progress) if write_bag_file else None
    files["extrinsic"].write_text(
        "# l2calib simulator ground truth (see scenario.json for the full settings)\n"
        + yaml.safe_dump(extrinsic_document(run), sort_keys=False, default_flow_style=None)
    )
    write_tum(files["gt_imu"], run.gt_imu)
    write_tum(files["gt_lidar"], run.gt_lidar)
    names = {k: str(v) for k, v in files.items()}
    files["scenario"].write_text(
        json.dumps(scenario_document(run, names, summary), indent=2) + "\n"
    )
    return names
