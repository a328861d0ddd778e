"""The batch manifest: which calibrations to run, and where.

Example (paths are relative to the manifest's folder)::

    executor: ray            # local (default): one job after another on this machine
    ray: {address: null, cpus_per_job: 2}
    jobs:
      - name: van-07
        recipe: recipes/velodyne-vlp16-xsens.yaml   # a file or a built-in recipe's name
        bags: [van-07/2026-11-30.bag]
        set: [train.seed=1]
        out: results/van-07
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import Field, ValidationError, model_validator

from l2calib.config_base import StrictModel
from l2calib.errors import ConfigError


class BatchRay(StrictModel):
    """Where the jobs run with ``executor: ray``."""

    address: str | None = Field(
        None, description="Ray cluster to join; null: RAY_ADDRESS, else a local Ray instance"
    )
    cpus_per_job: int = Field(
        1, ge=1, description="CPUs each job reserves (its train.workers unless the job sets them)"
    )


class BatchJob(StrictModel):
    """One calibration: a recipe, its recordings, overrides and an output folder."""

    name: str = Field(min_length=1)
    recipe: str = Field(description="recipe file, or the name of a built-in recipe")
    bags: list[Path] = Field(min_length=1)
    set: list[str] = Field(default_factory=list, description="as calibrate's --set")
    out: Path


class BatchManifest(StrictModel):
    """A batch of calibrations (see the module docstring)."""

    executor: Literal["local", "ray"] = "local"
    ray: BatchRay = Field(default_factory=BatchRay)
    jobs: list[BatchJob] = Field(min_length=1)

    @model_validator(mode="after")
    def _distinct(self) -> BatchManifest:
        for what in ("name", "out"):
            seen: set = set()
            for job in self.jobs:
                value = getattr(job, what)
                if value in seen:
                    raise ValueError(f"two jobs have the same {what} {str(value)!r}")
                seen.add(value)
        return self


def load_manifest(path: Path) -> BatchManifest:
    """Reads and checks a manifest; relative paths are taken from the manifest's folder.

    Raises:
        ConfigError: naming the file and the field when the manifest is unusable.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such manifest", fix="pass the path of a batch YAML")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: a manifest is a YAML mapping with a 'jobs' list",
            fix="see `l2calib batch --help` for an example",
        )
    try:
        manifest = BatchManifest.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or '(top)'}: {e['msg']}" for e in exc.errors()
        )
        raise ConfigError(
            f"{path}: {problems}", fix="see `l2calib batch --help` for an example"
        ) from None
    base = path.resolve().parent
    for job in manifest.jobs:
        job.bags = [b if b.is_absolute() else base / b for b in job.bags]
        job.out = job.out if job.out.is_absolute() else base / job.out
        local = Path(job.recipe)
        if not local.is_absolute() and (base / local).is_file():
            job.recipe = str(base / local)  # else a built-in recipe's name (checked by the job)
    return manifest
