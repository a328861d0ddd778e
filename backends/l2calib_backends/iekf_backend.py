"""``iekf`` backend: batched FAST-LIO2-style LIO scoring K candidate extrinsics per call.

Preparation and the candidate loop are the shared LIO base's (:mod:`l2calib_backends.lio_backend`);
this module supplies the iterated-ESKF run of one segment (:mod:`l2calib_backends.iekf`).
"""

from __future__ import annotations

from dataclasses import replace

from l2calib.recipe import ImuInput
from l2calib_backends.iekf import RunResult, RunSettings, run_segment
from l2calib_backends.lio_backend import LioBackend
from l2calib_backends.options import IekfOptions
from l2calib_backends.propagation import ImuNoise
from l2calib_backends.update import UpdateSettings


class IekfBackend(LioBackend):
    """Batched iterated ESKF LIO (see :mod:`l2calib_backends.iekf`).

    Args:
        config: Backend options.
        imu: IMU noise densities from the recipe (defaults of :class:`ImuInput` if ``None``).
    """

    def __init__(self, config: IekfOptions, imu: ImuInput | None = None, **_: object) -> None:
        super().__init__(config)
        c = config
        self.settings = RunSettings(
            update=UpdateSettings(
                max_iterations=c.max_iterations,
                point_sigma_m=c.point_sigma_m,
                min_correspondences=c.min_correspondences,
            ),
            noise=ImuNoise.from_recipe(imu),
            init_sigmas=self.init_sigmas,
            max_skipped_scans=c.max_skipped_scans,
            max_speed_m_s=c.max_speed_m_s,
            map_voxel_m=c.map_voxel_m,
            plane_thickness_m=c.plane_thickness_m,
        )

    def _use_init_sigmas(self, sigmas: dict[str, float]) -> None:
        """Start-state priors resolved at :meth:`prepare` (``auto`` depends on the data)."""
        self.init_sigmas = sigmas
        self.settings = replace(self.settings, init_sigmas=sigmas)

    def _run_segment(  # noqa: ANN001
        self, seg, motion, starts, T, off, seeds, ends=None, shared_map=None
    ) -> RunResult:
        """One prepared segment for all candidates, with the IEKF loop."""
        return run_segment(seg, motion, starts, T, off, self.settings, shared_map, seeds, ends)
