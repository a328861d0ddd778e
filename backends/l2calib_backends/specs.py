"""Plugin specs of the built-in backends (light: pydantic options + lazy factories).

Options: :mod:`l2calib_backends.options`. ``evaluation`` (see :class:`~l2calib.plugins.PluginSpec`)
turns a LIO backend into the continuous odometry ``l2calib evaluate`` runs: each candidate
builds its own map from its own estimates (``map_mode: odometry``) over the whole recording
(``window_scans: 0``), as FAST-LIO would with that extrinsic.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict

from l2calib.plugins import PluginSpec
from l2calib_backends.options import GtsamOptions, IekfOptions

#: Options that make a LIO backend a continuous odometry with its own map (``evaluate``).
CONTINUOUS_ODOMETRY = {"map_mode": "odometry", "window_scans": 0}


def _make_iekf(config: IekfOptions, **context: Any) -> Any:
    from l2calib_backends.iekf_backend import IekfBackend

    return IekfBackend(config, **context)


IEKF = PluginSpec(
    name="iekf",
    group="l2calib.backends",
    config=IekfOptions,
    factory=_make_iekf,
    description="Batched FAST-LIO2-style iterated ESKF LIO (torch), K candidates per call",
    evaluation=CONTINUOUS_ODOMETRY,
)


def _make_gtsam(config: GtsamOptions, **context: Any) -> Any:
    from l2calib_backends.gtsam_backend import GtsamBackend

    return GtsamBackend(config, **context)


GTSAM = PluginSpec(
    name="gtsam",
    group="l2calib.backends",
    config=GtsamOptions,
    factory=_make_gtsam,
    description="GTSAM LIO: CombinedImuFactor preintegration + scan-to-map pose factors, iSAM2",
    evaluation=CONTINUOUS_ODOMETRY,
)


class VioOptions(BaseModel):
    """Options of the VIO slot (none yet: the backend is a documented placeholder)."""

    model_config = ConfigDict(extra="allow")


def _make_vio(config: VioOptions, **context: Any) -> Any:
    from l2calib.errors import NotImplementedPluginError

    raise NotImplementedPluginError(
        "the 'vio' backend is a placeholder: no visual-inertial odometry is implemented yet",
        fix="use backend.name: iekf or gtsam for LiDAR-IMU rigs; a VIO backend must implement "
        "l2calib.interfaces.OdometryBackend over camera measurements (see docs/backends.md)",
    )


VIO = PluginSpec(
    name="vio",
    group="l2calib.backends",
    config=VioOptions,
    factory=_make_vio,
    description="PLACEHOLDER slot for a visual-inertial backend: not implemented, fails if chosen",
)
