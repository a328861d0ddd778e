"""One GTSAM factor graph per filter: preintegrated IMU between scans, registered scan poses.

State ``i`` of a graph is the IMU at the end of the ``i``-th scan of its window: pose
``X(i)`` (``T_world_imu``, :class:`gtsam.Pose3`), velocity ``V(i)`` (world, m/s) and IMU bias
``B(i)`` (:class:`gtsam.imuBias.ConstantBias`, accel then gyro). Factors:

* priors on ``X(0)``, ``V(0)``, ``B(0)`` — the start state taken from the reference;
* a :class:`gtsam.CombinedImuFactor` between consecutive states, built from
  :class:`gtsam.PreintegratedCombinedMeasurements` (it also carries the bias random walk);
* a :class:`gtsam.PriorFactorPose3` on ``X(i)`` per scan whose registration succeeded, with the
  registration's information (see :mod:`l2calib_backends.registration`).

iSAM2 is used rather than a fixed-lag smoother: with the default re-anchoring every 10 scans a
graph never holds more than 11 states, and a chain of states stays cheap for iSAM2 over a
whole segment (``window_scans: 0``), so marginalisation would buy nothing. Gravity is not a
state: each candidate's gravity vector (estimated from the data at the start, as for the IEKF)
goes into its own :class:`gtsam.PreintegrationCombinedParams`.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import torch
from gtsam.symbol_shorthand import B, V, X
from torch import Tensor

from l2calib import geometry as geo
from l2calib_backends.propagation import ImuNoise, ImuTensors


@dataclass(frozen=True)
class GraphSettings:
    """Settings shared by every graph.

    Attributes:
        init_sigmas: Prior standard deviations of the start state: ``rot`` (rad), ``pos`` (m),
            ``vel`` (m/s), ``bg`` (rad/s), ``ba`` (m/s²).
        relinearize_threshold: iSAM2 relinearisation threshold (tangent-space units).
        extra_iterations: Additional ``ISAM2.update()`` calls after each scan.
        huber_k: Huber threshold (in sigmas) on the registered-pose factors; 0: plain Gaussian.
    """

    init_sigmas: dict[str, float]
    relinearize_threshold: float = 0.05
    extra_iterations: int = 0
    huber_k: float = 0.0


def imu_params(gravity: np.ndarray, noise: ImuNoise) -> gtsam.PreintegrationCombinedParams:
    """Preintegration parameters for one candidate's world gravity ``[3]`` (m/s²)."""
    params = gtsam.PreintegrationCombinedParams(np.asarray(gravity, dtype=np.float64))
    eye = np.eye(3)
    # GTSAM takes continuous-time densities squared and discretises them itself.
    params.setGyroscopeCovariance(noise.gyro**2 * eye)
    params.setAccelerometerCovariance(noise.accel**2 * eye)
    params.setBiasOmegaCovariance(noise.gyro_bias**2 * eye)
    params.setBiasAccCovariance(noise.accel_bias**2 * eye)
    params.setIntegrationCovariance(1e-8 * eye)
    return params


def imu_intervals(imu: ImuTensors, t0: Tensor, t1: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """IMU readings of B filters over their windows ``[t0[b], t1[b]]`` (s, segment-relative).

    Uses the same intervals as :func:`l2calib_backends.propagation.propagate`: the mean of the
    two samples around each IMU interval, the interval clipped to the window.

    Returns:
        ``accel [B, n, 3]`` (m/s²), ``gyro [B, n, 3]`` (rad/s) and ``dt [B, n]`` (s, 0 where a
        filter has no more interval).
    """
    ts = imu.t
    last = len(ts) - 2
    lo = (torch.searchsorted(ts, t0, right=True) - 1).clamp(0, last)
    hi = torch.searchsorted(ts, t1, right=False).clamp(1, last + 1)
    steps = max(int((hi - lo).max()), 1) if len(t0) else 1
    i = (lo[:, None] + torch.arange(steps)).clamp(max=last)  # [B, n]
    a_t = torch.minimum(torch.maximum(ts[i], t0[:, None]), t1[:, None])
    a_t[:, 0] = t0
    b_t = torch.minimum(torch.maximum(ts[i + 1], t0[:, None]), t1[:, None])
    b_t = torch.where(i + 1 >= hi[:, None], t1[:, None], b_t)  # last interval ends at t1
    # 0 past a filter's own last interval (as propagate: a window ending past the last IMU
    # sample would otherwise repeat the extrapolated stretch on every extra step).
    own = lo[:, None] + torch.arange(steps) < hi[:, None]
    dt = torch.where(own, (b_t - a_t).clamp_min(0.0), torch.zeros((), dtype=t0.dtype))
    gyro = 0.5 * (imu.gyro[i] + imu.gyro[i + 1])
    # GTSAM rotates an interval's specific force by the attitude at its start; the trapezoid of
    # the two samples, each in its own frame (as the IEKF's propagation does), removes the
    # first-order error of fast turns (0.2 mm per 0.1 s scan at 1 rad/s, 4x the factor's sigma).
    turn = geo.so3_exp(gyro * dt[..., None])
    accel = 0.5 * (imu.accel[i] + (turn @ imu.accel[i + 1][..., None])[..., 0])
    return accel, gyro, dt


def _pose(R: np.ndarray, p: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(R), np.asarray(p, dtype=np.float64))


class ScanGraph:
    """The iSAM2 smoother of one filter (one candidate over one window).

    Args:
        params: The candidate's preintegration parameters.
        R: ``[3, 3]`` start ``R_world_imu``.
        p: ``[3]`` start ``t_world_imu`` (m).
        v: ``[3]`` start velocity (world, m/s).
        settings: Prior sigmas and iSAM2 settings.
        bias: ``[6]`` start accelerometer bias (m/s²) then gyro bias (rad/s), IMU frame; zero
            if not given.
    """

    def __init__(
        self,
        params: gtsam.PreintegrationCombinedParams,
        R: np.ndarray,
        p: np.ndarray,
        v: np.ndarray,
        settings: GraphSettings,
        bias: np.ndarray | None = None,
    ) -> None:
        self.params = params
        self.settings = settings
        isam_params = gtsam.ISAM2Params()
        isam_params.setRelinearizeThreshold(settings.relinearize_threshold)
        isam_params.relinearizeSkip = 1
        self.isam = gtsam.ISAM2(isam_params)
        s = settings.init_sigmas
        pose = _pose(R, p)
        self.bias = (
            gtsam.imuBias.ConstantBias()
            if bias is None
            else gtsam.imuBias.ConstantBias(np.asarray(bias[:3]), np.asarray(bias[3:]))
        )
        self.nav = gtsam.NavState(pose, np.asarray(v, dtype=np.float64))
        self.index = 0
        graph = gtsam.NonlinearFactorGraph()
        pose_sigmas = np.array([s["rot"]] * 3 + [s["pos"]] * 3)
        bias_sigmas = np.array([s["ba"]] * 3 + [s["bg"]] * 3)
        graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(pose_sigmas)))
        graph.add(
            gtsam.PriorFactorVector(
                V(0), self.nav.velocity(), gtsam.noiseModel.Isotropic.Sigma(3, s["vel"])
            )
        )
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(0), self.bias, gtsam.noiseModel.Diagonal.Sigmas(bias_sigmas)
            )
        )
        values = gtsam.Values()
        values.insert(X(0), pose)
        values.insert(V(0), self.nav.velocity())
        values.insert(B(0), self.bias)
        self.isam.update(graph, values)

    def step(
        self,
        accel: np.ndarray,
        gyro: np.ndarray,
        dt: np.ndarray,
        pose: tuple[np.ndarray, np.ndarray] | None,
        information: np.ndarray | None,
    ) -> None:
        """Adds the next scan's state and updates the estimate (may raise on a bad system).

        Args:
            accel: ``[n, 3]`` specific force (m/s²) of the IMU intervals since the last scan.
            gyro: ``[n, 3]`` angular rate (rad/s).
            dt: ``[n]`` interval lengths (s); zero-length intervals are skipped.
            pose: Registered ``(R_world_imu [3, 3], t_world_imu [3])``, or ``None`` if the scan
                could not be registered (the state then rests on the IMU alone).
            information: ``[6, 6]`` information of ``pose`` in the ``Pose3`` tangent.
        """
        pim = gtsam.PreintegratedCombinedMeasurements(self.params, self.bias)
        for a, w, d in zip(accel, gyro, dt, strict=True):
            if d > 0.0:
                pim.integrateMeasurement(a, w, float(d))
        predicted = pim.predict(self.nav, self.bias)
        i, j = self.index, self.index + 1
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.CombinedImuFactor(X(i), V(i), X(j), V(j), B(i), B(j), pim))
        guess = predicted.pose()
        if pose is not None:
            guess = _pose(*pose)
            noise = gtsam.noiseModel.Gaussian.Information(information)
            if self.settings.huber_k > 0:
                huber = gtsam.noiseModel.mEstimator.Huber.Create(self.settings.huber_k)
                noise = gtsam.noiseModel.Robust.Create(huber, noise)
            graph.add(gtsam.PriorFactorPose3(X(j), guess, noise))
        values = gtsam.Values()
        values.insert(X(j), guess)
        values.insert(V(j), predicted.velocity())
        values.insert(B(j), self.bias)
        self.isam.update(graph, values)
        for _ in range(self.settings.extra_iterations):
            self.isam.update()
        self.index = j
        self.nav = gtsam.NavState(
            self.isam.calculateEstimatePose3(X(j)), self.isam.calculateEstimateVector(V(j))
        )
        self.bias = self.isam.calculateEstimateConstantBias(B(j))

    def latest(self) -> np.ndarray:
        """``[15]``: rotation matrix (row-major 9), position, velocity of the latest state."""
        pose = self.nav.pose()
        rot = pose.rotation().matrix().ravel()
        return np.concatenate([rot, pose.translation(), self.nav.velocity()])

    def biases(self) -> np.ndarray:
        """``[6]``: gyro bias (rad/s) then accel bias (m/s²) of the latest state."""
        return np.concatenate([self.bias.gyroscope(), self.bias.accelerometer()])

    def smoothed_poses(self) -> np.ndarray:
        """``[index, 4, 4]`` current estimates of ``T_world_imu`` at scans ``1..index``."""
        est = self.isam.calculateEstimate()
        return np.stack([est.atPose3(X(i)).matrix() for i in range(1, self.index + 1)])
