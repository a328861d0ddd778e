"""Smooth continuous-time rig trajectories with analytic derivatives.

A trajectory moves a *base* frame whose orientation is the LiDAR's nominal mounting (x forward,
z up) and whose origin is the IMU. Everything is a function of the motion clock ``u(t)``
(:class:`~l2calib.sim.signals.ActivityWindow`), so ``d/dt = W d/du`` and
``d²/dt² = W² d²/du² + W' d/du``:

* position: the route's centre line ``C(s(u))`` (a periodic quintic B-spline in arc length,
  travelled at a curvature-limited speed) plus bounded sinusoidal offsets;
* orientation: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` with yaw = route heading + sinusoids and
  sinusoidal roll/pitch; the body rate follows from the Euler rates in closed form.

So gyro and accelerometer readings are exact derivatives of the poses (before noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.ndimage import gaussian_filter1d, minimum_filter1d

from l2calib.sim.signals import ActivityWindow, Sines
from l2calib.sim.world import Route


def _rpy_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` ``Rz(yaw) Ry(pitch) Rx(roll)``.

    Written out because it runs on every firing time (~10^6 per minute of Livox data) and
    scipy's ``Rotation.from_euler`` is ~20x slower here.
    """
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    R = np.empty((len(roll), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp, cp * sr, cp * cr
    return R


@dataclass(frozen=True)
class MotionState:
    """Rig state at ``N`` times (world frame z up; base = LiDAR orientation, IMU origin).

    Attributes:
        R_world_base: ``[N, 3, 3]`` orientation of the base (LiDAR-aligned) frame.
        t_world_imu: ``[N, 3]`` IMU origin (m).
        v_world_imu: ``[N, 3]`` IMU velocity (m/s) or ``None``.
        a_world_imu: ``[N, 3]`` IMU acceleration (m/s², without gravity) or ``None``.
        omega_base: ``[N, 3]`` angular velocity of the base in the base frame (rad/s) or ``None``.
    """

    R_world_base: np.ndarray
    t_world_imu: np.ndarray
    v_world_imu: np.ndarray | None = None
    a_world_imu: np.ndarray | None = None
    omega_base: np.ndarray | None = None


class RouteCurve:
    """The route's closed centre line as a periodic quintic spline ``C(s)`` in arc length.

    The rounded rectangle is first smoothed along its length (circular Gaussian, σ up to 2 m) so
    curvature builds up gradually into a corner, like a steered vehicle (clothoid-like), instead
    of jumping to ``1 / radius``. ``shift_m`` is how far that moved the line (it eats into the
    free half width).
    """

    def __init__(self, route: Route, spacing_m: float = 0.25) -> None:
        raw = route.polyline(spacing_m)
        sigma_m = min(2.0, 0.5 * route.corner_radius_m)
        pts = gaussian_filter1d(raw, sigma=sigma_m / spacing_m, axis=0, mode="wrap")
        self.shift_m = float(np.linalg.norm(pts - raw, axis=1).max())
        seg = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(s[-1])
        self.spline: BSpline = make_interp_spline(
            s, np.vstack([pts, pts[:1]]), k=5, bc_type="periodic"
        )
        self._d1 = self.spline.derivative(1)
        self._d2 = self.spline.derivative(2)

    def __call__(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        """``[N, 2]`` point (order 0) or derivative (1, 2) at arc length ``s`` (wrapped)."""
        sw = np.mod(s, self.length)
        return (self.spline, self._d1, self._d2)[order](sw)

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Signed curvature ``dψ/ds`` of the heading ``ψ = atan2(y', x')``."""
        d1, d2 = self(s, 1), self(s, 2)
        return (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.sum(d1 * d1, axis=1)


@dataclass(frozen=True)
class MotionParams:
    """Numbers that shape one motion profile (see :mod:`l2calib.sim.profiles`)."""

    speed_m_s: float
    speed_var: float
    lat_accel_max_m_s2: float
    height_m: float
    xy_amp_m: float
    xy_freq_hz: tuple[float, float]
    z_amp_m: float
    z_freq_hz: tuple[float, float]
    yaw_amp_rad: float
    roll_amp_rad: float
    pitch_amp_rad: float
    rot_freq_hz: tuple[float, float]
    follow_heading: bool = True
    ramp_s: float = 1.0


class Motion:
    """A rig trajectory: route progress, offsets and attitude, all functions of ``u(t)``.

    Args:
        route: The world's route (centre line and free space).
        params: Profile numbers.
        window: Activity window (still periods).
        horizon_s: Latest time the trajectory must cover (s since the start).
        rng: Random generator for the sinusoids and speed variations.
        height_m: IMU height to use (already fitted to the world's free heights).
        xy_amp_m: Lateral amplitude to use (already reduced by the lever arm).
        curve: The route's centre line (built from ``route`` if ``None``).
    """

    def __init__(
        self,
        route: Route,
        params: MotionParams,
        window: ActivityWindow,
        horizon_s: float,
        rng: np.random.Generator,
        height_m: float,
        xy_amp_m: float,
        curve: RouteCurve | None = None,
    ) -> None:
        self.params, self.window, self.height_m = params, window, height_m
        self.curve = curve or RouteCurve(route)
        p = params
        self.off = [Sines.random(rng, xy_amp_m / np.sqrt(2), p.xy_freq_hz) for _ in range(2)]
        self.off.append(Sines.random(rng, p.z_amp_m, p.z_freq_hz))
        self.yaw = Sines.random(rng, p.yaw_amp_rad, p.rot_freq_hz)
        self.pitch = Sines.random(rng, p.pitch_amp_rad, p.rot_freq_hz)
        self.roll = Sines.random(rng, p.roll_amp_rad, p.rot_freq_hz)
        self.progress = self._progress(rng, float(window.clock(np.array([horizon_s]))[0]) + 2.0)

    def _progress(self, rng: np.random.Generator, u_max: float) -> BSpline:
        """Arc length ``s(u)``: speed limited by curvature, randomly modulated, then splined."""
        p, curve = self.params, self.curve
        grid = np.linspace(0.0, curve.length, max(int(curve.length / 0.1), 64), endpoint=False)
        v_curve = np.sqrt(p.lat_accel_max_m_s2 / np.maximum(np.abs(curve.curvature(grid)), 1e-6))
        # Brake before curves: spread each curve's speed limit over the braking distance at
        # the lateral acceleration limit, then smooth (so the speed stays under the limit).
        step = curve.length / len(grid)
        brake = max(int(p.speed_m_s**2 / (2 * p.lat_accel_max_m_s2) / step), 1)
        v_min = minimum_filter1d(np.minimum(p.speed_m_s, v_curve), size=2 * brake + 1, mode="wrap")
        v_s = gaussian_filter1d(v_min, sigma=brake / 2, mode="wrap")
        mod = Sines.random(rng, p.speed_var, (0.02, 0.1))
        du = 0.01
        u = np.arange(0.0, u_max + 1.0, du)
        gain = du * (1.0 + mod(u))
        s = np.zeros_like(u)
        for i in range(1, len(u)):  # forward Euler on a fine grid; the spline below is the truth
            v = np.interp(s[i - 1] % curve.length, grid, v_s, period=curve.length)
            s[i] = s[i - 1] + gain[i - 1] * v
        keep = slice(None, None, 10)  # knots every 0.1 s of motion
        return make_interp_spline(u[keep], s[keep], k=5)

    def state(self, t: np.ndarray, order: int = 2) -> MotionState:
        """Rig state at times ``t`` (s since the start, ``[N]``), derivatives up to ``order``."""
        t = np.asarray(t, dtype=np.float64)
        u = self.window.clock(t)
        s = self.progress(u)
        c0 = self.curve(s, 0)
        off = [f(u) for f in self.off]
        pos = np.column_stack([c0[:, 0] + off[0], c0[:, 1] + off[1], self.height_m + off[2]])
        d1 = self.curve(s, 1)
        heading = np.arctan2(d1[:, 1], d1[:, 0]) if self.params.follow_heading else 0.0 * s
        yaw, pitch, roll = heading + self.yaw(u), self.pitch(u), self.roll(u)
        R = _rpy_matrix(roll, pitch, yaw)
        if order == 0:
            return MotionState(R, pos)
        w, dw = self.window(t), self.window(t, 1)
        s_u, s_uu = self.progress(u, 1), self.progress(u, 2)
        d2 = self.curve(s, 2)
        p_u = np.column_stack(
            [
                d1 * s_u[:, None] + np.column_stack([f(u, 1) for f in self.off[:2]]),
                self.off[2](u, 1),
            ]
        )
        p_uu = np.column_stack(
            [
                d2 * (s_u**2)[:, None]
                + d1 * s_uu[:, None]
                + np.column_stack([f(u, 2) for f in self.off[:2]]),
                self.off[2](u, 2),
            ]
        )
        vel = p_u * w[:, None]
        acc = p_uu * (w**2)[:, None] + p_u * dw[:, None]
        k = self.curve.curvature(s) if self.params.follow_heading else 0.0 * s
        yaw_t = (k * s_u + self.yaw(u, 1)) * w
        pitch_t, roll_t = self.pitch(u, 1) * w, self.roll(u, 1) * w
        # Body rates of R = Rz(yaw) Ry(pitch) Rx(roll) from the Euler rates.
        sp, cp, sr, cr = np.sin(pitch), np.cos(pitch), np.sin(roll), np.cos(roll)
        omega = np.column_stack(
            [
                roll_t - yaw_t * sp,
                pitch_t * cr + yaw_t * cp * sr,
                -pitch_t * sr + yaw_t * cp * cr,
            ]
        )
        return MotionState(R, pos, vel, acc if order >= 2 else None, omega)
