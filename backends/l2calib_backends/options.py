"""Options of the built-in LiDAR-inertial backends (``iekf``, ``gtsam``): pydantic models.

Light (no torch): the plugin specs (:mod:`l2calib_backends.specs`) validate recipes with them,
the backends (:mod:`l2calib_backends.lio_backend` and its two subclasses) read them.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

AUTO_WINDOW_SCANS = 10  # window_scans "auto" on well-excited data
# init sigmas "auto" (accel bias, gravity; m/s²): (weakly excited, well excited)
AUTO_ACCEL_BIAS_SIGMA = (0.01, 0.1)
AUTO_GRAVITY_SIGMA = (0.01, 0.1)
Sigma = Annotated[float, Field(gt=0)] | Literal["auto"]


def _auto(value: float | str, choices: tuple[float, float], weak: bool) -> float:
    """A sigma option: the number given, or for ``auto`` ``choices[0 if weak else 1]``."""
    return float(choices[0] if weak else choices[1]) if value == "auto" else float(value)


class LioOptions(BaseModel):
    """Options shared by the LiDAR-inertial backends (``iekf``, ``gtsam``)."""

    model_config = ConfigDict(extra="forbid")

    map_mode: Literal["shared-map", "odometry"] = Field(
        "shared-map",
        description="shared-map: one map built once from the reference trajectory, queried by "
        "all candidates; odometry: each candidate builds its own map from its estimates, as "
        "FAST-LIO does",
    )
    window_scans: Annotated[int, Field(ge=0)] | Literal["auto"] = Field(
        "auto",
        description="re-anchor the filters on the reference every this many scans (windows run "
        "in parallel as extra batch entries); 0: one continuous run per segment, as FAST-LIO; "
        f"auto: 0 on weakly excited data (mean gyro norm below weak_excitation_rate_rad_s), "
        f"else {AUTO_WINDOW_SCANS}",
    )
    weak_excitation_rate_rad_s: float = Field(
        0.5,
        gt=0,
        description="the 'auto' settings treat data whose mean |ω| (rad/s) is below this as "
        "weakly excited",
    )
    map_voxel_m: float = Field(0.5, gt=0, description="voxel edge of the plane map (m)")
    scan_voxel_m: float = Field(0.5, gt=0, description="downsampling voxel of scan points (m)")
    voxel_point: Literal["random", "earliest", "centroid"] = Field(
        "random",
        description="what each voxel of the downsampling keeps (scans and the shared map): a "
        "random point (seeded by seed); the earliest fired (before 2026-12-07: which side of "
        "a voxel is kept then follows the sweep's direction and biased ground vehicles' "
        "lateral lever arm by up to 2 cm); or the centroid of its points at their mean time "
        "(PCL's VoxelGrid, as FAST-LIO; off the surface where a voxel holds a corner)",
    )
    map_points_per_scan: int = Field(1500, ge=10, description="points inserted per scan (odometry)")
    min_range_m: float = Field(1.0, ge=0)
    max_range_m: float = Field(100.0, gt=0)
    point_sigma_m: float = Field(0.05, gt=0, description="point-to-plane noise (m)")
    plane_thickness_m: float = Field(0.05, gt=0, description="thickest voxel accepted as plane")
    max_skipped_scans: int = Field(
        3, ge=1, description="scans without update before a candidate counts as lost"
    )
    max_speed_m_s: float = Field(
        1000.0, gt=0, description="faster than this counts as divergence (the run stops)"
    )
    init_sigma_rot_rad: float = Field(0.02, gt=0)
    init_sigma_pos_m: float = Field(0.02, gt=0)
    init_sigma_vel_m_s: float = Field(0.2, gt=0)
    init_sigma_gyro_bias_rad_s: float = Field(0.01, gt=0)
    init_sigma_accel_bias_m_s2: Sigma = Field(
        "auto",
        description=f"start-state accel-bias prior (m/s²); auto: {AUTO_ACCEL_BIAS_SIGMA[0]} on "
        "weakly excited data, where the whole-segment gravity estimate absorbs the bias (the "
        f"attitude barely changes), else {AUTO_ACCEL_BIAS_SIGMA[1]}",
    )
    start_biases: Literal["auto", "estimate", "gyro", "zero"] = Field(
        "auto",
        description="IMU biases at a filter's start: estimate (least squares of the segment's "
        "IMU against the reference motion, per candidate), gyro (the gyro bias only), zero; "
        "auto: estimate on well-excited data, zero on weakly excited data (there a candidate's "
        "own biases take up its rotation error and the search loses its way)",
    )
    threads: int = Field(0, ge=0, description="torch threads (0: leave torch's default)")
    seed: int = 0

    def start_bias_mode(self, weak_excitation: bool) -> str:
        """``start_biases`` with ``auto`` resolved for the data's excitation."""
        if self.start_biases != "auto":
            return self.start_biases
        return "zero" if weak_excitation else "estimate"

    def init_sigmas(self, weak_excitation: bool = False) -> dict[str, float]:
        """Prior standard deviations of each window's start state, by state block."""
        return {
            "rot": self.init_sigma_rot_rad,
            "pos": self.init_sigma_pos_m,
            "vel": self.init_sigma_vel_m_s,
            "bg": self.init_sigma_gyro_bias_rad_s,
            "ba": _auto(self.init_sigma_accel_bias_m_s2, AUTO_ACCEL_BIAS_SIGMA, weak_excitation),
        }


class IekfOptions(LioOptions):
    """Options of the batched FAST-LIO2-style IEKF backend."""

    points_per_scan: int = Field(250, ge=10, description="update points kept per scan")
    max_iterations: int = Field(3, ge=1, le=10, description="iterated-update steps per scan")
    min_correspondences: int = Field(20, ge=3)
    init_sigma_gravity_m_s2: Sigma = Field(
        "auto",
        description=f"start-state gravity prior (m/s²); auto: {AUTO_GRAVITY_SIGMA[0]} on weakly "
        f"excited data, else {AUTO_GRAVITY_SIGMA[1]}",
    )

    def init_sigmas(self, weak_excitation: bool = False) -> dict[str, float]:
        """Prior standard deviations of the start state, gravity included."""
        grav = _auto(self.init_sigma_gravity_m_s2, AUTO_GRAVITY_SIGMA, weak_excitation)
        return dict(super().init_sigmas(weak_excitation), grav=grav)


class GtsamOptions(LioOptions):
    """Options of the GTSAM IMU-preintegration LIO backend (iSAM2 graph per candidate)."""

    points_per_scan: int = Field(400, ge=10, description="registered points kept per scan")
    max_iterations: int = Field(4, ge=1, le=10, description="Gauss-Newton steps of a registration")
    registration_info_scale: float = Field(
        1.0,
        gt=0,
        le=1,
        description="scales the registration's information HᵀWH (< 1 inflates its covariance)",
    )
    min_correspondences: int = Field(20, ge=6)
    relinearize_threshold: float = Field(0.05, gt=0, description="iSAM2 relinearisation threshold")
    extra_iterations: int = Field(0, ge=0, le=5, description="extra iSAM2 updates per scan")
    pose_huber_k: float = Field(
        0.0, ge=0, description="Huber threshold (sigmas) on registered-pose factors; 0: off"
    )
    smoothed_output: bool = Field(
        False,
        description="report each window's final smoothed poses instead of the estimate of each "
        "scan when it arrived (filtered, as the IEKF and the paper's LIO)",
    )
