"""Motion profiles (``handheld``, ``uav``, ``ugv``) and their fitting into a world.

Magnitudes follow the paper's platforms: a hand-swung rig (mean |ω| ≈ 2 rad/s, a few m/s²),
a slow UAV (≈ 0.15 rad/s) and a planar, yaw-dominant ground vehicle (small suspension roll,
pitch and bounce). Each profile is a :class:`~l2calib.sim.motion.MotionParams`; ``excitation``
scales the rotational sway and ``speed_scale`` the travel speed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from l2calib.errors import ConfigError
from l2calib.sim.motion import Motion, MotionParams, RouteCurve
from l2calib.sim.signals import ActivityWindow
from l2calib.sim.world import World

PROFILES: dict[str, MotionParams] = {
    "handheld": MotionParams(
        speed_m_s=1.2,
        speed_var=0.2,
        lat_accel_max_m_s2=1.5,
        height_m=1.3,
        xy_amp_m=0.15,
        xy_freq_hz=(0.3, 1.0),
        z_amp_m=0.06,
        z_freq_hz=(0.8, 2.0),
        yaw_amp_rad=1.0,
        roll_amp_rad=0.75,
        pitch_amp_rad=0.75,
        rot_freq_hz=(0.3, 0.9),
    ),
    "uav": MotionParams(
        speed_m_s=1.5,
        speed_var=0.2,
        lat_accel_max_m_s2=0.8,
        height_m=4.0,
        xy_amp_m=0.8,
        xy_freq_hz=(0.02, 0.08),
        z_amp_m=1.0,
        z_freq_hz=(0.02, 0.06),
        yaw_amp_rad=0.2,
        roll_amp_rad=0.06,
        pitch_amp_rad=0.06,
        rot_freq_hz=(0.08, 0.4),
        ramp_s=3.0,
    ),
    "ugv": MotionParams(
        speed_m_s=4.0,
        speed_var=0.25,
        lat_accel_max_m_s2=2.0,
        height_m=1.0,
        xy_amp_m=0.4,
        xy_freq_hz=(0.01, 0.04),
        z_amp_m=0.01,
        z_freq_hz=(1.0, 3.0),
        yaw_amp_rad=0.0,
        roll_amp_rad=0.004,
        pitch_amp_rad=0.004,
        rot_freq_hz=(0.5, 2.0),
        ramp_s=4.0,
    ),
}
PROFILE_NAMES = tuple(PROFILES)


def profile_params(name: str, excitation: float = 1.0, speed_scale: float = 1.0) -> MotionParams:
    """The named profile with sway scaled by ``excitation`` and speed by ``speed_scale``.

    Raises:
        ConfigError: for an unknown profile name.
    """
    if name not in PROFILES:
        raise ConfigError(
            f"unknown motion profile {name!r}", fix=f"choose one of: {', '.join(PROFILE_NAMES)}"
        )
    p = PROFILES[name]
    return dataclasses.replace(
        p,
        yaw_amp_rad=p.yaw_amp_rad * excitation,
        roll_amp_rad=p.roll_amp_rad * excitation,
        pitch_amp_rad=p.pitch_amp_rad * excitation,
        speed_m_s=p.speed_m_s * speed_scale,
    )


def build_motion(
    world: World,
    params: MotionParams,
    lever_m: float,
    horizon_s: float,
    still: list[tuple[float, float]],
    rng: np.random.Generator,
) -> Motion:
    """Fits a profile into ``world`` and returns the trajectory.

    Lateral and vertical amplitudes and the height are reduced so that both the IMU and the
    LiDAR (``lever_m`` away) stay within the route's free space.

    Raises:
        ConfigError: if the rig cannot fit (lever arm larger than the free space).
    """
    route, clear = world.route, world.clearance_m
    curve = RouteCurve(route)
    xy_amp = min(params.xy_amp_m, route.half_width_m - lever_m - curve.shift_m)
    if xy_amp < 0:
        raise ConfigError(
            f"the rig's lever arm ({lever_m:.2f} m) does not fit the {world.name} route's free "
            f"half width ({route.half_width_m:.2f} m)",
            fix="use a smaller IMU-LiDAR translation or another world",
        )
    zmin, zmax = route.z_range_m[0] + clear + lever_m, route.z_range_m[1] - clear - lever_m
    z_amp = min(params.z_amp_m, max((zmax - zmin) / 2, 0.0))
    if zmax - zmin < 0:
        raise ConfigError(
            f"the rig ({lever_m:.2f} m lever arm) does not fit between floor and ceiling of "
            f"the {world.name} world",
            fix="use a smaller IMU-LiDAR translation or another world",
        )
    height = float(np.clip(params.height_m, zmin + z_amp, zmax - z_amp))
    params = dataclasses.replace(params, z_amp_m=z_amp)
    window = ActivityWindow(still, ramp_s=params.ramp_s)
    return Motion(
        route, params, window, horizon_s, rng, height_m=height, xy_amp_m=xy_amp, curve=curve
    )
