"""Plugin specs of the built-in reference sources (light: options + lazy factories).

Factories take the pipeline's context as keyword arguments and ignore what they do not use:

* ``sequences`` — the :class:`~l2calib.data.Sequence` objects the segments were cut from
  (``kiss-icp`` and ``rtk`` load warm-up scans before each segment from them);
* ``data`` — the recipe's :class:`~l2calib.recipe.DataConfig` (``rtk`` reads ``rtk_topic``);
* ``fixes`` — NavSatFix arrays in memory by sequence name (``rtk``, for data without a bag);
* ``progress`` — show progress bars;
* ``planar_motion`` — the IMU says planar, yaw-dominant motion (a ground vehicle): ``ct-lidar``
  adds its backward pass (``backward_pass: auto``, the default) and its vehicle prior
  (``noise_rot_deg`` / ``noise_rate_rad_s``: ``auto``).

Example:
    >>> spec = get_plugin("l2calib.references", recipe.reference.name)  # doctest: +SKIP
    >>> source = spec.build(recipe.reference.options, data=recipe.data, sequences=seqs)
    >>> references = source.compute(segments)  # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any

from l2calib.plugins import PluginSpec
from l2calib.references.options import (
    CtLidarOptions,
    GtFileOptions,
    KissIcpReferenceOptions,
    RtkOptions,
)

GROUP = "l2calib.references"


def _make_kiss_icp(config: KissIcpReferenceOptions, **context: Any) -> Any:
    from l2calib.references.kiss_icp_source import KissIcpReference

    return KissIcpReference(config, **context)


def _make_ct_lidar(config: CtLidarOptions, **context: Any) -> Any:
    from l2calib.references.ct_lidar_source import CtLidarReference

    return CtLidarReference(config, **context)


def _make_gt_file(config: GtFileOptions, **context: Any) -> Any:
    from l2calib.references.gt_file_source import GtFileReference

    return GtFileReference(config, **context)


def _make_rtk(config: RtkOptions, **context: Any) -> Any:
    from l2calib.references.rtk_source import RtkReference

    return RtkReference(config, **context)


KISS_ICP = PluginSpec(
    name="kiss-icp",
    group=GROUP,
    config=KissIcpReferenceOptions,
    factory=_make_kiss_icp,
    description="LiDAR-only odometry (KISS-ICP, iterated deskew) per segment; full pose; cached",
)
CT_LIDAR = PluginSpec(
    name="ct-lidar",
    group=GROUP,
    config=CtLidarOptions,
    factory=_make_ct_lidar,
    description="EXPERIMENTAL LiDAR-only continuous-time odometry per segment (aggressive "
    "motion; can lose track on 16-beam data, then errors); full pose; cached",
)
GT_FILE = PluginSpec(
    name="gt-file",
    group=GROUP,
    config=GtFileOptions,
    factory=_make_gt_file,
    description="Ground-truth file (TUM, KITTI + times, CSV) of the LiDAR, IMU or another body",
)
RTK = PluginSpec(
    name="rtk",
    group=GROUP,
    config=RtkOptions,
    factory=_make_rtk,
    description="GNSS/RTK NavSatFix in local ENU with lever arm; position only; cached",
)
