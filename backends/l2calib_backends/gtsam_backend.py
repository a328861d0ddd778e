"""``gtsam`` backend: GTSAM IMU-preintegration LIO scoring K candidate extrinsics per call.

A factor-graph counterpart of the ``iekf`` backend with the same interface and outputs: each
candidate × window runs its own iSAM2 graph of ``CombinedImuFactor`` preintegrated IMU factors
between scans and scan-to-map pose factors (:mod:`l2calib_backends.gtsam_lio`). Preparation
(downsampled scans, reference start states, the shared plane map built from the reference) is
the shared LIO base's (:mod:`l2calib_backends.lio_backend`), so both backends see the same data.

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

from dataclasses import replace

from l2calib.recipe import ImuInput
from l2calib_backends.gtsam_graph import GraphSettings
from l2calib_backends.gtsam_lio import GtsamRunSettings, run_segment_gtsam
from l2calib_backends.iekf import RunResult
from l2calib_backends.lio_backend import LioBackend
from l2calib_backends.options import GtsamOptions
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.registration import RegistrationSettings


class GtsamBackend(LioBackend):
    """Batched GTSAM LIO (see :mod:`l2calib_backends.gtsam_lio`).

    Args:
        config: Backend options.
        imu: IMU noise densities from the recipe (defaults of :class:`ImuInput` if ``None``).
    """

    def __init__(self, config: GtsamOptions, imu: ImuInput | None = None, **_: object) -> None:
        super().__init__(config)
        c = config
        self.settings = GtsamRunSettings(
            registration=RegistrationSettings(
                max_iterations=c.max_iterations,
                point_sigma_m=c.point_sigma_m,
                info_scale=c.registration_info_scale,
                min_correspondences=c.min_correspondences,
            ),
            graph=GraphSettings(
                init_sigmas=self.init_sigmas,
                relinearize_threshold=c.relinearize_threshold,
                extra_iterations=c.extra_iterations,
                huber_k=c.pose_huber_k,
            ),
            noise=ImuNoise.from_recipe(imu),
            max_skipped_scans=c.max_skipped_scans,
            max_speed_m_s=c.max_speed_m_s,
            map_voxel_m=c.map_voxel_m,
            plane_thickness_m=c.plane_thickness_m,
            smoothed_output=c.smoothed_output,
        )

    def _use_init_sigmas(self, sigmas: dict[str, float]) -> None:
        """Start-state priors resolved at ``prepare`` (gravity is fixed here, not a state)."""
        self.init_sigmas = sigmas
        self.settings = replace(
            self.settings, graph=replace(self.settings.graph, init_sigmas=sigmas)
        )

    def _run_segment(  # noqa: ANN001
        self, seg, motion, starts, T, off, seeds, ends=None, shared_map=None
    ) -> RunResult:
        """One prepared segment for all candidates, with the GTSAM loop."""
        return run_segment_gtsam(
            seg, motion, starts, T, off, self.settings, shared_map, seeds, ends
        )
