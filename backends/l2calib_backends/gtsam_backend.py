"""``gtsam`` backend: GTSAM IMU-preintegration LIO scoring K candidate extrinsics per call.

A factor-graph counterpart of the ``iekf`` backend with the same interface and outputs: each
candidate × window runs its own iSAM2 graph of ``CombinedImuFactor`` preintegrated IMU factors
between scans and scan-to-map pose factors (:mod:`l2calib_backends.gtsam_lio`). Preparation
(downsampled scans, reference start states, the shared plane map built from the reference) is
the IEKF backend's, inherited unchanged, so both backends see the same data.

Design choices:

* LiDAR constraint = registered pose + its information ``HᵀWH``
  (:mod:`l2calib_backends.registration`) rather than one GTSAM factor per point: at the
  Gauss–Newton solution both give the graph the same quadratic, and the registration of all
  K×W filters runs as one batched torch computation against the shared plane map, while
  per-point custom factors would run in Python, one filter at a time.
* Output = each scan's estimate when it arrived (filtered), as the IEKF and the paper's LIO:
  the IMU pulling against the scan is what grades a wrong extrinsic. ``smoothed_output`` reports
  the final smoothed window instead (slightly more accurate, less sensitive to translation).
* iSAM2 without marginalisation (graphs are short, see :mod:`l2calib_backends.gtsam_graph`);
  gravity is fixed per candidate (the IEKF's data-driven start value), not a state.
* Both map modes work. ``odometry`` with ``window_scans > 0`` starts each window's own map from a
  single reference-placed scan, which has few plane voxels for a 16-beam LiDAR: candidates then
  lose track (as with the IEKF); use ``window_scans: 0`` with ``odometry``.
"""

from __future__ import annotations

import torch

from l2calib.errors import BackendError
from l2calib.interfaces import CandidateTrajectories
from l2calib.recipe import ImuInput
from l2calib_backends.gtsam_graph import GraphSettings
from l2calib_backends.gtsam_lio import GtsamRunSettings, run_segment_gtsam
from l2calib_backends.iekf_backend import IekfBackend
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.registration import RegistrationSettings
from l2calib_backends.specs import GtsamOptions


class GtsamBackend(IekfBackend):
    """Batched GTSAM LIO (see :mod:`l2calib_backends.gtsam_lio`).

    Args:
        config: Backend options (the fields shared with ``IekfOptions`` drive :meth:`prepare`).
        imu: IMU noise densities from the recipe (defaults of :class:`ImuInput` if ``None``).
    """

    outputs_in_reference_frame = True  # every graph starts from the reference pose

    def __init__(self, config: GtsamOptions, imu: ImuInput | None = None, **_: object) -> None:
        self.config = config
        imu = imu or ImuInput()
        c = config
        self.settings = GtsamRunSettings(
            registration=RegistrationSettings(
                max_iterations=c.max_iterations,
                point_sigma_m=c.point_sigma_m,
                info_scale=c.registration_info_scale,
                min_correspondences=c.min_correspondences,
            ),
            graph=GraphSettings(
                init_sigmas={
                    "rot": c.init_sigma_rot_rad,
                    "pos": c.init_sigma_pos_m,
                    "vel": c.init_sigma_vel_m_s,
                    "bg": c.init_sigma_gyro_bias_rad_s,
                    "ba": c.init_sigma_accel_bias_m_s2,
                },
                relinearize_threshold=c.relinearize_threshold,
                extra_iterations=c.extra_iterations,
                huber_k=c.pose_huber_k,
            ),
            noise=ImuNoise(
                imu.gyro_noise_density,
                imu.accel_noise_density,
                imu.gyro_bias_random_walk,
                imu.accel_bias_random_walk,
            ),
            max_skipped_scans=c.max_skipped_scans,
            max_speed_m_s=c.max_speed_m_s,
            map_voxel_m=c.map_voxel_m,
            plane_thickness_m=c.plane_thickness_m,
            smoothed_output=c.smoothed_output,
        )
        self._segments = []
        self._motions = []
        self._starts = []
        self._map = None
        if c.threads:
            torch.set_num_threads(c.threads)

    def evaluate(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ) -> list[CandidateTrajectories]:
        """Runs all candidates on every prepared segment (see :class:`OdometryBackend`)."""
        if not self._segments:
            raise BackendError("evaluate() called before prepare()", fix="call prepare() first")
        T = torch.as_tensor(T_imu_lidar, dtype=torch.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise BackendError(
                f"T_imu_lidar must be [K, 4, 4], got {tuple(T.shape)}",
                fix="stack the K candidate extrinsics into one [K, 4, 4] float64 tensor",
            )
        K = T.shape[0]
        off = (
            torch.zeros(K, dtype=torch.float64)
            if time_offset_s is None
            else torch.as_tensor(time_offset_s, dtype=torch.float64).reshape(K)
        )
        outputs = []
        with torch.no_grad():
            for seg, motion, starts, seeds in zip(
                self._segments, self._motions, self._starts, self._seeds, strict=True
            ):
                res = run_segment_gtsam(
                    seg, motion, starts, T, off, self.settings, self._map, seeds
                )
                outputs.append(
                    CandidateTrajectories(
                        segment=seg.name,
                        stamps_ns=seg.end_stamps_ns[1:],
                        T_world_lidar=res.T_world_lidar,
                        valid=res.valid,
                        status=res.status,
                    )
                )
        return outputs
