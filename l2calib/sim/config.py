"""Simulator settings: one pydantic model with small nested sections.

Unknown keys and bad values fail with the dotted field path (:func:`sim_config_from_dict`).
Sensor models left unset follow the rig preset (``ntu-viral`` → Ouster OS1-16 + VN100).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, ValidationError, field_validator, model_validator

from l2calib.errors import ConfigError
from l2calib.recipe import StrictModel
from l2calib.sim.imu_model import IMU_NAMES
from l2calib.sim.lidar_models import LIDAR_NAMES
from l2calib.sim.profiles import PROFILE_NAMES
from l2calib.sim.rigs import RIG_NAMES, RIGS
from l2calib.sim.world import ROUTE_PATHS, WORLD_NAMES


def _one_of(value: str | None, names: tuple[str, ...], what: str) -> str | None:
    if value is not None and value not in names:
        raise ValueError(f"unknown {what} {value!r}; choose one of: {', '.join(names)}")
    return value


class WorldOptions(StrictModel):
    """Which procedural world to build."""

    name: str = Field("urban", description=f"one of: {', '.join(WORLD_NAMES)}")
    seed: int | None = Field(None, description="world seed (default: the run's seed)")
    route: str = Field(
        "loop",
        description="how the route is driven: loop (counter-clockwise, left turns only), loop-cw "
        "(clockwise) or figure-8 (urban only: both ways, through a cross street)",
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return _one_of(v, WORLD_NAMES, "world")

    @field_validator("route")
    @classmethod
    def _route(cls, v: str) -> str:
        return _one_of(v, ROUTE_PATHS, "route path")


class MotionOptions(StrictModel):
    """Motion profile and still periods."""

    profile: str = Field("handheld", description=f"one of: {', '.join(PROFILE_NAMES)}")
    still_start_s: float = Field(1.0, ge=0, description="still period at the start (IMU init)")
    still_segments: list[tuple[float, float]] = Field(
        default_factory=list, description="extra still periods [[start_s, end_s], ...]"
    )
    excitation: float = Field(1.0, gt=0, description="scale of the rotational sway")
    speed_scale: float = Field(1.0, gt=0, description="scale of the travel speed")

    @field_validator("profile")
    @classmethod
    def _profile(cls, v: str) -> str:
        return _one_of(v, PROFILE_NAMES, "motion profile")


class LidarOptions(StrictModel):
    """LiDAR model and overrides of its preset."""

    model: str | None = Field(None, description=f"one of: {', '.join(LIDAR_NAMES)}")
    columns: int | None = Field(None, ge=32, le=4096, description="azimuth steps (spinning)")
    rate_hz: float | None = Field(None, gt=0, le=40)
    range_noise_m: float | None = Field(None, ge=0)
    dropout_prob: float | None = Field(None, ge=0, lt=1)
    spurious_prob: float | None = Field(
        None, ge=0, lt=1, description="share of returns short of the surface (dust, mixed pixels)"
    )
    min_range_m: float | None = Field(None, ge=0)
    max_range_m: float | None = Field(None, gt=0)
    noise: bool = Field(True, description="range noise and random dropouts on/off")

    @field_validator("model")
    @classmethod
    def _model(cls, v: str | None) -> str | None:
        return _one_of(v, LIDAR_NAMES, "LiDAR model")


class ImuOptions(StrictModel):
    """IMU model and rate."""

    model: str | None = Field(None, description=f"one of: {', '.join(IMU_NAMES)}")
    rate_hz: float | None = Field(None, ge=50, le=2000)
    noise: bool = Field(True, description="white noise and biases on/off")

    @field_validator("model")
    @classmethod
    def _model(cls, v: str | None) -> str | None:
        return _one_of(v, IMU_NAMES, "IMU model")


class RigOptions(StrictModel):
    """Ground-truth extrinsic ``T_imu_lidar`` and LiDAR-IMU time offset."""

    preset: str | None = Field("ntu-viral", description=f"one of: {', '.join(RIG_NAMES)}")
    translation_m: tuple[float, float, float] | None = Field(
        None, description="t_imu_lidar (overrides the preset)"
    )
    rpy_deg: tuple[float, float, float] | None = Field(
        None, description="roll, pitch, yaw of R_imu_lidar in degrees (overrides the preset)"
    )
    time_offset_s: float = Field(
        0.0, ge=-0.5, le=0.5, description="t_imu = t_lidar + time_offset_s"
    )

    @field_validator("preset")
    @classmethod
    def _preset(cls, v: str | None) -> str | None:
        return _one_of(v, RIG_NAMES, "rig preset")

    @model_validator(mode="after")
    def _complete(self) -> RigOptions:
        if self.preset is None and (self.translation_m is None or self.rpy_deg is None):
            raise ValueError("without a preset, give both translation_m and rpy_deg")
        return self


class SimConfig(StrictModel):
    """Everything that defines a simulated run (same config and seed → same data)."""

    world: WorldOptions = Field(default_factory=WorldOptions)
    motion: MotionOptions = Field(default_factory=MotionOptions)
    lidar: LidarOptions = Field(default_factory=LidarOptions)
    imu: ImuOptions = Field(default_factory=ImuOptions)
    rig: RigOptions = Field(default_factory=RigOptions)
    duration_s: float = Field(20.0, gt=0, le=3600)
    seed: int = 0
    gravity_m_s2: float = Field(9.81, gt=0)
    gt_rate_hz: float = Field(100.0, gt=0, le=1000, description="rate of the GT trajectories")
    start_time_s: float = Field(
        1_700_000_000.0, ge=0, description="absolute time of the first IMU sample (epoch s)"
    )

    def resolved(self) -> SimConfig:
        """A copy with sensor models and extrinsic filled in from the rig preset."""
        data = self.model_dump()
        rig = RIGS[self.rig.preset] if self.rig.preset else None
        data["lidar"]["model"] = self.lidar.model or (rig.lidar if rig else "ouster-os1-16")
        data["imu"]["model"] = self.imu.model or (rig.imu if rig else "vn100")
        if rig is not None:
            data["rig"]["translation_m"] = self.rig.translation_m or rig.translation_m
            data["rig"]["rpy_deg"] = self.rig.rpy_deg or rig.rpy_deg
        if data["world"]["seed"] is None:
            data["world"]["seed"] = self.seed
        return SimConfig.model_validate(data)


def sim_config_from_dict(data: dict[str, Any], source: str = "simulator config") -> SimConfig:
    """Validates a nested dict into a :class:`SimConfig`; :class:`ConfigError` on bad fields."""
    try:
        return SimConfig.model_validate(data)
    except ValidationError as exc:
        parts = []
        for err in exc.errors():
            path = ".".join(str(p) for p in err["loc"])
            msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
            msg = msg.removeprefix("Value error, ")
            parts.append(f"{path}: {msg}")
        raise ConfigError(
            f"{source}: " + "; ".join(parts),
            fix="correct these fields (scenario.json of any run lists every key and its value)",
        ) from None
