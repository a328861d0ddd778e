"""Options of the built-in reference sources (light: pydantic only, no numpy/torch/kiss-icp).

These are the models behind ``reference.options`` in a recipe. ``l2calib recipe dump`` prints them
with their defaults; unknown keys are errors.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from l2calib.errors import ReferenceSourceError
from l2calib.recipe import StrictModel


class KissIcpOptions(StrictModel):
    """KISS-ICP settings (a flat view of its ``KISSConfig``)."""

    voxel_size: float | None = Field(None, gt=0, description="m; default: max_range_m / 100")
    max_range_m: float = Field(100.0, gt=0)
    min_range_m: float = Field(0.5, ge=0)
    deskew: bool = Field(True, description="motion-compensate with per-point times")
    max_points_per_voxel: int = Field(20, ge=1)
    initial_threshold: float = Field(2.0, gt=0, description="initial correspondence threshold (m)")
    min_motion_th: float = Field(0.1, ge=0)
    fixed_threshold: float | None = Field(None, gt=0)
    max_num_iterations: int = Field(500, ge=1)
    convergence_criterion: float = Field(1e-4, gt=0)
    max_num_threads: int = Field(0, ge=0, description="0: all cores")

    def kiss_config(self):  # noqa: ANN201 - kiss_icp.config.KISSConfig, imported lazily
        """The equivalent ``kiss_icp.config.KISSConfig``."""
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import (
            AdaptiveThresholdConfig,
            DataConfig,
            MappingConfig,
            RegistrationConfig,
        )

        if self.min_range_m >= self.max_range_m:
            raise ReferenceSourceError(
                f"kiss-icp: min_range_m ({self.min_range_m}) >= max_range_m ({self.max_range_m})",
                fix="make min_range_m smaller than max_range_m",
            )
        return KISSConfig(
            data=DataConfig(
                max_range=self.max_range_m, min_range=self.min_range_m, deskew=self.deskew
            ),
            mapping=MappingConfig(
                voxel_size=self.voxel_size or self.max_range_m / 100.0,
                max_points_per_voxel=self.max_points_per_voxel,
            ),
            registration=RegistrationConfig(
                max_num_iterations=self.max_num_iterations,
                convergence_criterion=self.convergence_criterion,
                max_num_threads=self.max_num_threads,
            ),
            adaptive_threshold=AdaptiveThresholdConfig(
                fixed_threshold=self.fixed_threshold,
                initial_threshold=self.initial_threshold,
                min_motion_th=self.min_motion_th,
            ),
        )


class CacheOptions(StrictModel):
    """Where computed references are cached (see :mod:`l2calib.references.cache`)."""

    cache: bool = Field(True, description="reuse references computed earlier for the same input")
    cache_dir: str | None = Field(
        None, description="default: $L2CALIB_CACHE/references or ~/.cache/l2calib/references"
    )


class KissIcpReferenceOptions(KissIcpOptions, CacheOptions):
    """``reference: {name: kiss-icp, options: ...}``: KISS-ICP settings plus how it is run."""

    deskew_iterations: int = Field(
        3,
        ge=1,
        le=5,
        description="1: stock KISS-ICP; more: deskew again with the motion just estimated for the "
        "scan and re-register (robust to fast, changing rotation such as a hand-swung rig)",
    )
    margin_s: float = Field(
        1.0,
        ge=0,
        description="warm-up: also run on this many seconds of scans before each segment (when "
        "the pipeline passes the sequences), then keep only the segment's poses",
    )


#: ``ct-lidar``'s process noise of the attitude (deg/√s) and of the body rate (rad/s/√s) where
#: ``auto``: in general (hand-held, UAV) and on planar, yaw-dominant motion (a ground vehicle).
#: With the general values the attitude may step 0.16° from scan to scan whatever the body
#: rate says, so the body rate is fixed only by each scan's own distortion, which a 16-beam
#: scan shows weakly: on a simulated 16-beam drive it wandered by 3-24 deg/s in roll and pitch
#: (truly ~0), and the forward pass tilted 1.6° by the last turn. The vehicle prior ties each
#: scan's attitude to the previous scan's rate and lets the rate change slowly, as a
#: vehicle's does: tilt within 0.23° over the 47 s, as with the true in-scan motion (0.22°).
#: Measured in docs/references.md ("The vehicle prior").
GENERAL_MOTION_NOISE = (0.5, 1.0)
VEHICLE_MOTION_NOISE = (0.05, 0.1)


class CtLidarOptions(CacheOptions):
    """``reference: {name: ct-lidar, options: ...}``: continuous-time LiDAR-only odometry.

    See :mod:`l2calib.references.ct_odometry`. Defaults suit 16–128-beam spinning LiDARs and
    Livox scanners at 10–20 Hz, indoors and outdoors.
    """

    min_range_m: float = Field(0.5, ge=0, description="points nearer than this are dropped (m)")
    max_range_m: float = Field(100.0, gt=0, description="points farther than this are dropped")
    isolated_ratio: float = Field(
        0.03,
        ge=0,
        description="a point whose nearest other return of the scan is farther than this times "
        "its range (and isolated_min_m) is dropped as spurious (0: keep all)",
    )
    isolated_min_m: float = Field(0.1, gt=0, description="... but never nearer than this (m)")
    insert_max_residual_m: float = Field(
        0.0,
        ge=0,
        description="a scan point farther than this from the map's plane there is not added to "
        "the map (m; 0: all are added; experimental: 0.1 lost a 16-beam hand-held run)",
    )
    scan_voxel_m: float = Field(0.4, gt=0, description="registration sample: 1 point per voxel")
    max_points: int = Field(3000, ge=100, description="registration points per scan at most")
    map_voxel_m: float = Field(0.2, gt=0, description="local map: 1 point per voxel (m)")
    map_radius_m: float = Field(60.0, gt=0, description="map points kept around the LiDAR (m)")
    neighbours: int = Field(12, ge=5, description="map points per plane fit")
    max_plane_rms_m: float = Field(0.05, gt=0, description="flatness a plane fit needs (m)")
    plane_radius_m: float = Field(
        1.0, gt=0, description="a plane needs all its neighbours this near its cell's centre (m)"
    )
    plane_cell_m: float = Field(
        0.2, gt=0, description="queries in one cell of this edge share one plane fit (m)"
    )
    line_match_m: float = Field(
        2.0,
        ge=0,
        description="a point with no map plane but a normal from its scan lines (ring field) "
        "is matched to the plane through the nearest map point this near with that normal "
        "(m; 0: off)",
    )
    line_neighbours: int = Field(6, ge=3, description="... whose this many nearest map points")
    line_flat_m: float = Field(0.05, gt=0, description="... lie this near the plane (m)")
    line_match_from: int = Field(0, ge=0, description="... from this association round on")
    line_gate_m: float = Field(0.3, gt=0, description="... within this of that plane (m)")
    min_spread_ratio: float = Field(
        0.2, gt=0, lt=1, description="rejects line-like neighbourhoods (2nd / 1st spread)"
    )
    max_correspondence_m: float = Field(1.0, gt=0, description="first association gate (m)")
    robust_scale_start_m: float = Field(0.3, gt=0, description="Geman-McClure scale, first (m)")
    robust_scale_m: float = Field(0.05, gt=0, description="Geman-McClure scale, last (m)")
    sigma_point_m: float = Field(0.03, gt=0, description="point-to-plane noise (m)")
    min_incidence_deg: float = Field(
        8.0,
        ge=0,
        lt=90,
        description="map planes fitted to one scan line and within this angle of the point's "
        "viewing ray are not used (deg; 0: all are); with one_line_planes='never' this holds "
        "for the drift check only",
    )
    one_line_planes: Literal["never", "facing"] = Field(
        "never",
        description="registration against map planes fitted to one scan line: 'never' (one "
        "line does not fix a plane: a ring over a ribbed wall fits the beam cone's tangent "
        "plane, a ring over a floor-wall corner a plane through the kink; such points take "
        "their scan-line normal instead) or 'facing' (those at min_incidence_deg or more from "
        "the viewing ray, engine 7)",
    )
    iterations: int = Field(6, ge=1, description="association rounds per scan")
    inner_steps: int = Field(2, ge=1, description="Levenberg-Marquardt steps per round")
    min_planes: int = Field(30, ge=18, description="fewest planes to solve a scan")
    noise_rot_deg: Annotated[float, Field(gt=0)] | Literal["auto"] = Field(
        "auto",
        description="process noise of the attitude at each scan's start (deg/√s); auto: "
        f"{GENERAL_MOTION_NOISE[0]}, or {VEHICLE_MOTION_NOISE[0]} on planar, yaw-dominant "
        "motion (a ground vehicle: the 'vehicle prior', docs/references.md)",
    )
    noise_pos_m: float = Field(0.01, gt=0, description="... of the position (m/√s)")
    noise_rate_rad_s: Annotated[float, Field(gt=0)] | Literal["auto"] = Field(
        "auto",
        description=f"... of the body rate (rad/s/√s); auto: {GENERAL_MOTION_NOISE[1]}, or "
        f"{VEHICLE_MOTION_NOISE[1]} on planar, yaw-dominant motion (the vehicle prior)",
    )
    noise_alpha_rad_s2: float = Field(
        8.0,
        gt=0,
        description="... of α (rad/s²/√s) at most, for the fastest swings; α is weakly seen in "
        "one scan, so its noise follows the recent angular acceleration (alpha_noise_gain)",
    )
    noise_alpha_min_rad_s2: float = Field(
        0.2,
        gt=0,
        description="... at least this where the body rate changes slowly (UAV, vehicle): α's "
        "noise follows the recent angular acceleration, between this and noise_alpha_rad_s2",
    )
    alpha_noise_gain: float = Field(
        0.5, gt=0, description="α's noise: this times the recent angular acceleration (rad/s²)"
    )
    alpha_noise_window_s: float = Field(1.0, gt=0, description="... over this long (s)")
    noise_velocity_m_s: float = Field(0.5, gt=0, description="... of the velocity (m/s/√s)")
    noise_accel_m_s2: float = Field(1.0, gt=0, description="... of a (m/s²/√s)")
    retry_inlier_drop: float = Field(
        0.9,
        gt=0,
        le=1,
        description="a scan whose share of points on a plane drops below this times the "
        "median of the last five is solved again with a wider motion prior",
    )
    retry_widen: float = Field(
        4.0, ge=1, description="... the body rate's and α's process noise times this (1: off)"
    )
    rollback_scans: int = Field(
        12,
        ge=0,
        description="where a scan is found lost (a poor fit or a drift, not an unverifiable "
        "scene), this many scans are undone, map points included, and solved again with "
        "a denser, freshly drawn sample (0: off)",
    )
    rollback_density: float = Field(
        2.0, ge=1, description="... that sample is this many times denser"
    )
    rollback_max: int = Field(
        3, ge=0, description="... at most this many roll-backs per run (0: off)"
    )
    initial_rate_rad_s: float = Field(
        3.0, gt=0, description="prior σ of the first scan's motion: body rate (rad/s)"
    )
    initial_alpha_rad_s2: float = Field(2.0, gt=0, description="... α (rad/s²)")
    initial_velocity_m_s: float = Field(2.0, gt=0, description="... velocity (m/s)")
    initial_accel_m_s2: float = Field(1.0, gt=0, description="... a (m/s²)")
    bootstrap_rounds: int = Field(
        4, ge=1, description="iterated deskew rounds of the first two scans (first scan's motion)"
    )
    lost_inlier_ratio: float = Field(
        0.15, ge=0, le=1, description="a scan with fewer of its points on map planes is poor"
    )
    lost_scans: int = Field(3, ge=1, description="this many poor scans in a row: lost (error)")
    lost_grace_scans: int = Field(
        10, ge=0, description="the first scans are poor only below lost_young_inlier_ratio"
    )
    lost_young_inlier_ratio: float = Field(
        0.05, ge=0, le=1, description="... (the map is young, much of each scan new)"
    )
    lost_map_age_s: float = Field(
        2.0, gt=0, description="drift check: each scan against the map points this old or older (s)"
    )
    lost_old_residual_m: float = Field(
        0.03,
        gt=0,
        description="drift check: a median distance to the old map's planes above this is poor (m)",
    )
    lost_old_points: int = Field(
        50, ge=10, description="drift check: fewest points on old planes for a verdict"
    )
    lost_old_info: float = Field(
        10.0,
        ge=0,
        description="drift check: old planes pinning the scan's weakest direction by fewer "
        "points leave a drift there unseen (unverified scan)",
    )
    lost_unverified_s: float = Field(
        3.0,
        gt=0,
        description="drift check: unverified for this long in a row means lost (s; 1 s stopped "
        "16-beam UAV flights tracking to 0.2 cm as they took off)",
    )
    max_rate_rad_s: float = Field(30.0, gt=0, description="a faster body rate means lost")
    max_speed_m_s: float = Field(40.0, gt=0, description="a higher speed means lost")
    poses_per_scan: int = Field(4, ge=1, description="reference poses written per scan")
    seed: int = Field(0, description="seed of the point sampling")
    margin_s: float = Field(
        1.0,
        ge=0,
        description="warm-up: also run on this many seconds of scans before each segment (when "
        "the pipeline passes the sequences), then keep only the segment's poses",
    )
    cold_starts: int = Field(
        4,
        ge=1,
        description="starts tried per segment: when the odometry loses track before "
        "cold_start_window_s into the segment (a start mid-swing, or a hard swing met with a "
        "young map), it starts again twice as far back before the segment (margin_s, 2 x, 4 x, "
        "...), as far as the sequence reaches",
    )
    cold_start_window_s: float = Field(
        5.0, gt=0, description="... a loss later than this into the segment is not retried (s)"
    )
    from_start_s: float = Field(
        60.0,
        ge=0,
        description="segments beginning within this many seconds of their recording's start "
        "are cut from one run that starts there, usually at rest (measured 0.19-0.22 cm where "
        "a start 1-6 s before the segment, mid-swing, gave 0.95-2.48 cm or lost track; 0: off)",
    )
    chain_gap_s: float = Field(
        10.0,
        ge=0,
        description="segments of one recording closer than this (s) are cut from one run",
    )
    backward_pass: bool | Literal["auto"] = Field(
        "auto",
        description="also run the odometry backwards in time and average the two passes "
        "(twice the time); auto (the default): only on planar, yaw-dominant motion (a ground "
        "vehicle): on simulated 16-beam drives the LiDAR-only calibration's lateral lever arm "
        "came out 3.5-4.9 cm off with the forward pass alone, 1.9-2.7 cm with both "
        "(docs/references.md, 'Backward pass'); experimental",
    )
    backward_leadout_s: float = Field(
        5.0,
        ge=0,
        description="... which starts this many seconds of scans after the segment (or run), "
        "cold and usually while moving: its first seconds are its worst (s)",
    )

    def motion_noise(self, planar: bool = False) -> tuple[float, float]:
        """The attitude's (deg/√s) and body rate's (rad/s/√s) process noise, ``auto`` resolved.

        Args:
            planar: The IMU says planar, yaw-dominant motion (a ground vehicle).
        """
        auto = VEHICLE_MOTION_NOISE if planar else GENERAL_MOTION_NOISE
        rot = auto[0] if self.noise_rot_deg == "auto" else self.noise_rot_deg
        rate = auto[1] if self.noise_rate_rad_s == "auto" else self.noise_rate_rad_s
        return float(rot), float(rate)

    @model_validator(mode="after")
    def _ranges(self) -> CtLidarOptions:
        if self.min_range_m >= self.max_range_m:
            raise ValueError(
                f"min_range_m ({self.min_range_m}) must be smaller than max_range_m "
                f"({self.max_range_m})"
            )
        return self


class TransformSpec(StrictModel):
    """A rigid transform as translation plus roll-pitch-yaw (degrees) or quaternion (xyzw)."""

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] | None = Field(
        None, description="R = Rz(yaw) Ry(pitch) Rx(roll)"
    )
    quat_xyzw: tuple[float, float, float, float] | None = None

    @model_validator(mode="after")
    def _one_rotation(self) -> TransformSpec:
        if self.rpy_deg is not None and self.quat_xyzw is not None:
            raise ValueError("give the rotation as rpy_deg or quat_xyzw, not both")
        if self.quat_xyzw is not None and abs(sum(q * q for q in self.quat_xyzw) - 1.0) > 1e-3:
            raise ValueError("quat_xyzw must be a unit quaternion in the order qx qy qz qw")
        return self


class GtFileOptions(StrictModel):
    """``reference: {name: gt-file, options: ...}``: a ground-truth trajectory file."""

    path: str = Field(..., description="trajectory file (TUM, KITTI poses or CSV)")
    format: Literal["auto", "tum", "kitti", "csv"] = Field(
        "auto", description="auto: from the extension (.tum/.txt, .kitti, .csv)"
    )
    times_path: str | None = Field(None, description="KITTI times file (seconds, one per line)")
    body_frame: Literal["lidar", "imu", "other"] = Field(
        "lidar",
        description="the frame the file's poses describe; imu/other need T_body_lidar (see docs)",
    )
    T_body_lidar: list[list[float]] | TransformSpec | None = Field(
        None, description="pose of the LiDAR in the file's body frame: 4x4 rows or a transform"
    )
    time_offset_s: float = Field(
        0.0, description="added to the file's stamps: t_lidar = t_file + time_offset_s"
    )
    constrains: Literal["auto", "pose", "position"] = Field(
        "auto", description="auto: position for body_frame imu (see docs), pose otherwise"
    )
    max_gap_s: float = Field(0.2, gt=0, description="largest gap between poses inside a segment")
    check_imu: bool = Field(
        True,
        description="compare the file's rotation rate with the IMU gyro (catches clock offsets "
        "and wrong quaternion order)",
    )

    @field_validator("T_body_lidar")
    @classmethod
    def _matrix_shape(cls, v: list[list[float]] | TransformSpec | None):  # noqa: ANN206
        if isinstance(v, list) and (len(v) != 4 or any(len(r) != 4 for r in v)):
            raise ValueError("a matrix T_body_lidar must be 4 rows of 4 numbers")
        return v

    @model_validator(mode="after")
    def _frames(self) -> GtFileOptions:
        if self.body_frame == "lidar" and self.T_body_lidar is not None:
            raise ValueError(
                "body_frame is lidar but T_body_lidar is given: set body_frame to imu or other, "
                "or drop T_body_lidar"
            )
        if self.body_frame != "lidar" and self.T_body_lidar is None:
            raise ValueError(
                f"body_frame {self.body_frame} needs T_body_lidar (the LiDAR pose in that frame)"
            )
        if self.format == "kitti" and self.times_path is None:
            raise ValueError("format kitti needs times_path (KITTI poses carry no stamps)")
        return self


class RtkOptions(CacheOptions):
    """``reference: {name: rtk, options: ...}``: GNSS/RTK fixes as a position-only reference."""

    topic: str | None = Field(None, description="NavSatFix topic; default: data.rtk_topic")
    bag_path: str | None = Field(
        None, description="read the fixes from this bag instead of the segment's own bag"
    )
    lever_arm_m: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="antenna phase centre in the LiDAR frame (t_lidar_antenna)"
    )
    orientation: Literal["kiss-icp", "ct-lidar", "none"] = Field(
        "kiss-icp",
        description="LiDAR attitude for the lever arm (and for backends that start from the "
        "reference): the rotations of a LiDAR-only odometry (kiss-icp or ct-lidar) aligned to "
        "the fixes; none: identity (zero lever arm)",
    )
    kiss_icp: KissIcpReferenceOptions = Field(
        default_factory=KissIcpReferenceOptions, description="settings of that KISS-ICP run"
    )
    ct_lidar: CtLidarOptions = Field(
        default_factory=CtLidarOptions, description="settings of that ct-lidar run"
    )
    min_status: Literal[0, 1, 2] = Field(
        0, description="lowest NavSatStatus accepted: 0 fix, 1 SBAS, 2 GBAS/RTK"
    )
    max_sigma_m: float = Field(
        0.1, gt=0, description="drop fixes whose reported standard deviation is larger (m)"
    )
    time_offset_s: float = Field(
        0.0, description="added to the fix stamps: t_lidar = t_fix + time_offset_s"
    )
    origin: tuple[float, float, float] | None = Field(
        None, description="ENU origin (lat deg, lon deg, ellipsoidal height m); default: first fix"
    )
    min_fixes: int = Field(10, ge=3, description="fewest usable fixes per segment")

    @model_validator(mode="after")
    def _lever(self) -> RtkOptions:
        if self.orientation == "none" and any(abs(v) > 0 for v in self.lever_arm_m):
            raise ValueError(
                "a non-zero lever_arm_m needs the LiDAR attitude: set orientation to kiss-icp "
                "or ct-lidar"
            )
        return self
