"""TorchRL actors and value module for the single-step extrinsic-calibration MDP.

TensorDict keys (float64 throughout):

* in: ``"observation"`` ``[..., 1]`` (a constant; the parameters are free and only broadcast to
  its batch shape);
* distribution parameters (written by the parameter module, read by the actor):
  Bingham: ``"rotation_quat_xyzw"`` ``[..., 4]``, ``"rotation_concentration"`` ``[..., 3]``;
  Gaussian: ``"rotation_loc"``, ``"rotation_scale"`` ``[..., 4]``; both:
  ``"translation_loc"``, ``"translation_scale"`` ``[..., 3|4]`` (4th = time offset, s);
* out: ``"action"`` ``[..., 7|8]`` = ``[qx, qy, qz, qw, tx, ty, tz(, dt)]`` (unit quaternion of
  ``R_imu_lidar``, ``t_imu_lidar`` in m, ``time_offset_s``), ``"action_log_prob"`` ``[...]``
  (TorchRL's default key for a single ``"action"`` out key; ``ClipPPOLoss`` reads it from
  ``actor.log_prob_keys``), and ``"state_value"`` ``[..., 1]`` from :attr:`ExtrinsicPolicy.value`.

Sample with ``set_exploration_type(ExplorationType.RANDOM)`` (what TorchRL collectors do);
the default (deterministic) interaction returns the mode.

Unconstrained parameters: a free 4-vector (normalised) for the Bingham reference ``q0``, one
``ρ`` per body axis with ``z = -2 sinh(2ρ)`` (``ρ = 0``: ``z = 0`` exactly, the uniform "no idea"
start, with a non-zero gradient; ``ρ ≫ 0``: ``σ ≈ √2 e^{-ρ}``, so ``ρ`` moves like ``-log σ``;
``|ρ|`` is softly bounded by ``tanh`` at the minimum σ), the translation mean (optionally
``bound·tanh(raw/bound)``) and its ``log σ`` (own soft floor). Rotation and translation have
separate floors and bounds.

Why ``z`` may become positive (default, ``allow_positive_concentration``): with ``z ≤ 0`` the
mode ``q0`` only receives gradient in proportion to ``z``. On the toy problem PPO sometimes
concentrates one axis early (the good samples share a rotation axis) while ``q0`` is still far
away; the two free axes would need ``z > 0`` to follow the rewards and the run stalls 150° off
(1 of 3 seeds). Letting ``z`` cross 0 moves the mode to ``q0 ⊗ e_i`` smoothly. With the option
off, ``z = -2 e^{-2s}`` (``s = log σ``) as in the paper.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.data import Unbounded
from torchrl.modules import ProbabilisticActor, ValueOperator

from l2calib.errors import ConfigError
from l2calib.geometry import (
    euler_rpy_to_matrix,
    matrix_to_quat,
    quat_normalize,
    transform_from_quat,
)
from l2calib.interfaces import CalibrationPolicy, Extrinsic, PolicySpread
from l2calib.recipe import ExtrinsicPrior
from l2calib_policies.joint import BinghamExtrinsic, GaussianExtrinsic

F64 = torch.float64
OBSERVATION_KEY = "observation"
ACTION_KEY = "action"
VALUE_KEY = "state_value"
#: Rotation σ (rad) of the "no idea" Bingham start when z must stay ≤ 0: z = -2/30² ≈ -2.2e-3,
#: i.e. the density varies by < 0.25 % over S³ (z = 0 exactly is unreachable with z = -2e^{-2s}).
NO_IDEA_ROTATION_SIGMA_RAD = 30.0
#: |μ| of the Gaussian baseline's "no idea" start (μ along identity, σ = 1 per component):
#: a broad law whose rotation spread (≈ 50–57° per axis) matches the uniform Bingham's 57°.
#: A truly uniform start (μ → 0) learned markedly worse on the toy problem (scale-free
#: parameters must first grow |μ| from ~0), so the baseline is not handicapped by it.
NO_IDEA_GAUSSIAN_MEAN_NORM = 1.0


def _soft_floor(s: Tensor, lo: Tensor) -> Tensor:
    """Smooth ``max(s, lo)`` (``lo + softplus(s - lo)``); keeps a gradient everywhere."""
    return lo + nn.functional.softplus(s - lo)


def _inv_soft_floor(target: Tensor, lo: Tensor) -> Tensor:
    return lo + torch.log(torch.expm1(target - lo))


def _t(x: Any) -> Tensor:
    return torch.as_tensor(x, dtype=F64)


class TranslationParams(nn.Module):
    """Free mean and ``log σ`` of the translation (and time offset), ``k`` = 3 or 4 entries.

    The time offset's mean is its own parameter (``offset_raw``), so that the trainer can give
    it its own step size: Adam moves a parameter by about its learning rate per step, and a rate
    scaled by the translation's σ (metres) moved the offset by ~150 ms per step.
    """

    def __init__(self, loc0: Tensor, sigma0: Tensor, sigma_min: Tensor, bound: Tensor) -> None:
        super().__init__()
        self.register_buffer("bounded", torch.isfinite(bound))
        self.register_buffer("bound", torch.where(self.bounded, bound, torch.ones_like(bound)))
        self.register_buffer("log_sigma_min", sigma_min.log())
        if bool(((loc0.abs() >= self.bound) & self.bounded).any()):
            raise ConfigError(
                f"initial translation/time offset {loc0.tolist()} is outside the bound "
                f"{bound.tolist()}",
                fix="raise policy.options.translation_bound_m / time_offset_bound_s or fix the "
                "prior",
            )
        raw = torch.where(self.bounded, self.bound * torch.atanh(loc0 / self.bound), loc0)
        self.loc_raw = nn.Parameter(raw[:3].clone())
        self.offset_raw = nn.Parameter(raw[3:].clone()) if raw.shape[0] > 3 else None
        self.log_sigma_raw = nn.Parameter(_inv_soft_floor(sigma0.log(), self.log_sigma_min))

    def forward(self) -> tuple[Tensor, Tensor]:
        """Mean ``[k]`` and σ ``[k]``."""
        b = self.bound
        raw = self.loc_raw
        if self.offset_raw is not None:
            raw = torch.cat([raw, self.offset_raw])
        loc = torch.where(self.bounded, b * torch.tanh(raw / b), raw)
        return loc, _soft_floor(self.log_sigma_raw, self.log_sigma_min).exp()


class BinghamParams(nn.Module):
    """Free parameters of the Bingham policy, broadcast to the observation's batch shape.

    Args:
        q0: Initial reference quaternion ``[4]``.
        sigma_rot_rad: Initial σ per body axis ``[3]`` (rad); ``None``: uniform (z = 0).
        sigma_rot_min_rad: Smallest σ (largest |z| = 2/σ²).
        trans: Translation parameters.
        allow_positive: ``z = -2 sinh(2ρ)`` (any sign) instead of ``z = -2 e^{-2s}`` (≤ 0).
    """

    def __init__(
        self,
        q0: Tensor,
        sigma_rot_rad: Tensor | None,
        sigma_rot_min_rad: float,
        trans: TranslationParams,
        allow_positive: bool = True,
    ) -> None:
        super().__init__()
        self.allow_positive = allow_positive
        z_max = 2.0 / sigma_rot_min_rad**2
        self.rho_max = 0.5 * math.asinh(z_max / 2)
        self.register_buffer("log_sigma_min", _t(math.log(sigma_rot_min_rad)))
        self.quat_raw = nn.Parameter(q0.clone())
        if allow_positive:
            rho = (
                torch.zeros(3, dtype=F64)
                if sigma_rot_rad is None
                else 0.5 * torch.asinh(sigma_rot_rad**-2)
            )
            self.conc_raw = nn.Parameter(self.rho_max * torch.atanh(rho / self.rho_max))
        else:
            sigma = (
                sigma_rot_rad
                if sigma_rot_rad is not None
                else torch.full((3,), NO_IDEA_ROTATION_SIGMA_RAD, dtype=F64)
            )
            self.conc_raw = nn.Parameter(_inv_soft_floor(sigma.log(), self.log_sigma_min))
        self.translation = trans

    def concentration(self) -> Tensor:
        """``z`` ``[3]`` from the unconstrained parameters."""
        if self.allow_positive:
            rho = self.rho_max * torch.tanh(self.conc_raw / self.rho_max)
            return -2.0 * torch.sinh(2.0 * rho)
        return -2.0 * torch.exp(-2.0 * _soft_floor(self.conc_raw, self.log_sigma_min))

    def forward(self, observation: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``(q0 [..., 4], z [..., 3], loc [..., k], scale [..., k])`` for ``observation``."""
        batch = observation.shape[:-1]
        loc, scale = self.translation()
        q = quat_normalize(self.quat_raw)
        z = self.concentration()
        return tuple(p.expand(*batch, p.shape[-1]) for p in (q, z, loc, scale))  # type: ignore


class GaussianParams(nn.Module):
    """Free parameters of the Gaussian baseline (4-D mean and σ per quaternion component)."""

    def __init__(
        self, mu0: Tensor, sigma0: Tensor, sigma_min: float, trans: TranslationParams
    ) -> None:
        super().__init__()
        self.register_buffer("log_sigma_min", _t(math.log(sigma_min)))
        self.quat_loc = nn.Parameter(mu0.clone())
        self.log_sigma_raw = nn.Parameter(_inv_soft_floor(sigma0.log(), self.log_sigma_min))
        self.translation = trans

    def forward(self, observation: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``(μ [..., 4], σ [..., 4], loc [..., k], scale [..., k])`` for ``observation``."""
        batch = observation.shape[:-1]
        sigma = _soft_floor(self.log_sigma_raw, self.log_sigma_min).exp()
        loc, scale = self.translation()
        return tuple(p.expand(*batch, p.shape[-1]) for p in (self.quat_loc, sigma, loc, scale))  # type: ignore


_KEYS = {
    "bingham": ["rotation_quat_xyzw", "rotation_concentration"],
    "gaussian": ["rotation_loc", "rotation_scale"],
}
_DISTRIBUTIONS = {"bingham": BinghamExtrinsic, "gaussian": GaussianExtrinsic}


class ExtrinsicPolicy(nn.Module, CalibrationPolicy):
    """Actor (``ProbabilisticActor``) and value module of one calibration run.

    The built-in implementation of :class:`l2calib.interfaces.CalibrationPolicy`.

    Args:
        kind: ``"bingham"`` or ``"gaussian"``.
        options: The plugin's options (:mod:`l2calib_policies.specs`).
        action_dim: 7 (rotation + translation) or 8 (+ time offset in s).
        prior: Initial guess of ``T_imu_lidar`` with σ; ``None`` = no idea (uniform rotation,
            zero translation with ``options.init_translation_sigma_m``).
        seed: Seeds the actor's own sampling generator (independent of the global RNG).
        init_time_offset_s: Starting mean of the time offset (s, ``t_imu = t_lidar + offset``;
            e.g. the reference's clock check), with ``action_dim`` 8.
        rotation_start: Without a prior, where the rotation starts: an object with
            ``quat_xyzw`` (4) and ``sigma_deg`` (3, per LiDAR axis), e.g.
            :class:`l2calib.train.rotation_start.RotationStart`; ``None``: uniform.
        translation_start: Without a prior, where the translation starts: an object with
            ``translation_m`` (3, ``t_imu_lidar``) and ``sigma_m`` (3, per IMU axis), e.g.
            :class:`l2calib.train.lever_start.LeverStart`; ``None``: zero with
            ``options.init_translation_sigma_m``.

    Attributes:
        actor: ``ProbabilisticActor`` reading ``"observation"``, writing ``"action"`` and
            ``"action_log_prob"`` (:attr:`log_prob_key`).
        value: ``ValueOperator`` writing ``"state_value"``.
    """

    def __init__(
        self,
        kind: str,
        options: Any,
        action_dim: int = 7,
        prior: ExtrinsicPrior | None = None,
        seed: int = 0,
        init_time_offset_s: float = 0.0,
        rotation_start: Any | None = None,
        translation_start: Any | None = None,
    ) -> None:
        super().__init__()
        if action_dim not in (7, 8):
            raise ConfigError(
                f"action_dim must be 7 or 8, got {action_dim}",
                fix="use 8 only when estimating the time offset (train.estimate_time_offset)",
            )
        if kind not in _KEYS:
            raise ConfigError(f"unknown policy kind {kind!r}", fix="use bingham or gaussian")
        self.kind, self.options, self.action_dim = kind, options, action_dim
        self.time_offset = action_dim == 8
        self.params_net = self._make_params(
            kind, options, prior, init_time_offset_s, None if prior else rotation_start,
            None if prior else translation_start,
        )  # fmt: skip
        keys = [*_KEYS[kind], "translation_loc", "translation_scale"]
        module = TensorDictModule(self.params_net, in_keys=[OBSERVATION_KEY], out_keys=keys)
        self.actor = ProbabilisticActor(
            module,
            in_keys=keys,
            out_keys=[ACTION_KEY],
            spec=Unbounded(shape=(action_dim,), dtype=F64),
            distribution_class=_DISTRIBUTIONS[kind],
            distribution_kwargs={"mirrored": bool(options.mirrored_sampling)},
            return_log_prob=True,
            generator=int(seed),
        )
        head = nn.Linear(1, 1, dtype=F64)
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)
        self.value = ValueOperator(head, in_keys=[OBSERVATION_KEY], out_keys=[VALUE_KEY])

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        """Parameters by role.

        ``rotation_mean``, ``translation_mean`` and, with a time offset, ``time_offset_mean``
        (whose natural step sizes scale with their current spread) and ``other`` (spreads,
        value head).
        """
        net = self.params_net
        rot = [net.quat_raw] if hasattr(net, "quat_raw") else [net.quat_loc]
        trans = [net.translation.loc_raw]
        offset = [] if net.translation.offset_raw is None else [net.translation.offset_raw]
        chosen = {id(p) for p in rot + trans + offset}
        other = [p for p in self.parameters() if id(p) not in chosen]
        groups = {"rotation_mean": rot, "translation_mean": trans, "other": other}
        return {**groups, "time_offset_mean": offset} if offset else groups

    # ------------------------------------------------------------------ construction
    def _make_params(
        self,
        kind: str,
        o: Any,
        prior: ExtrinsicPrior | None,
        offset0_s: float = 0.0,
        start: Any | None = None,
        t_start: Any | None = None,
    ) -> nn.Module:
        k = self.action_dim - 4
        loc0 = torch.zeros(k, dtype=F64)
        sigma0 = torch.full((k,), o.init_translation_sigma_m, dtype=F64)
        if t_start is not None:  # per-axis σ (IMU axes) from the acceleration fit
            loc0[:3] = _t(t_start.translation_m)
            sigma0[:3] = torch.clamp(_t(t_start.sigma_m), min=2 * o.min_translation_sigma_m)
        if prior is not None:
            loc0[:3] = _t(prior.translation_m)
            sigma0[:3] = prior.sigma_translation_m
            if prior.sigma_translation_m <= o.min_translation_sigma_m:
                raise ConfigError(
                    "policy.prior.sigma_translation_m must exceed the floor "
                    f"min_translation_sigma_m={o.min_translation_sigma_m}",
                    fix="raise the prior's σ or lower policy.options.min_translation_sigma_m",
                )
        sigma_min = torch.full((k,), o.min_translation_sigma_m, dtype=F64)
        inf = math.inf
        bound = torch.full((k,), o.translation_bound_m or inf, dtype=F64)
        if k == 4:
            sigma0[3], sigma_min[3] = o.init_time_offset_sigma_s, o.min_time_offset_sigma_s
            loc0[3] = offset0_s
            bound[3] = o.time_offset_bound_s or inf
        trans = TranslationParams(loc0, sigma0, sigma_min, bound)

        rot_min = math.radians(o.min_rotation_sigma_deg)
        if prior is not None:
            R = euler_rpy_to_matrix(torch.deg2rad(_t(prior.rpy_deg)))
            q0, sigma_rot = matrix_to_quat(R), math.radians(prior.sigma_rotation_deg)
        elif start is not None:  # per-axis σ (LiDAR axes) from the rate fit
            q0 = quat_normalize(_t(start.quat_xyzw))
            sigma_axes = torch.deg2rad(_t(start.sigma_deg))
            sigma_rot = float(sigma_axes.min())
        else:
            q0 = _t([0.0, 0.0, 0.0, 1.0])
            sigma_rot = (
                math.radians(o.init_rotation_sigma_deg) if o.init_rotation_sigma_deg else None
            )
        if sigma_rot is not None and sigma_rot <= rot_min:
            raise ConfigError(
                f"initial rotation σ {math.degrees(sigma_rot):g}° is not above the floor "
                f"min_rotation_sigma_deg={o.min_rotation_sigma_deg:g}",
                fix="raise the prior's sigma_rotation_deg or lower min_rotation_sigma_deg",
            )
        if kind == "bingham":
            sig = None if sigma_rot is None else torch.full((3,), sigma_rot, dtype=F64)
            if start is not None and prior is None:
                sig = sigma_axes
            return BinghamParams(q0, sig, rot_min, trans, o.allow_positive_concentration)
        if sigma_rot is None:  # broad start: unit mean at identity, unit σ
            mu0, comp = q0 * NO_IDEA_GAUSSIAN_MEAN_NORM, torch.ones(4, dtype=F64)
        else:  # φ = 2δq for a unit mean, so each component gets σ/2
            if start is not None and prior is None:  # one σ for all: the axes' RMS
                sigma_rot = float(sigma_axes.pow(2).mean().sqrt())
            mu0, comp = q0, torch.full((4,), sigma_rot / 2, dtype=F64)
        return GaussianParams(mu0, comp, rot_min / 2, trans)

    # ------------------------------------------------------------------ readouts
    @property
    def log_prob_key(self) -> str:
        """Key of the action log-probability (``"action_log_prob"``)."""
        return self.actor.log_prob_keys[0]

    def observation(self, batch_size: tuple[int, ...] = ()) -> TensorDict:
        """A TensorDict with the constant observation (zeros ``[*batch_size, 1]``)."""
        obs = torch.zeros(*batch_size, 1, dtype=F64)
        return TensorDict({OBSERVATION_KEY: obs}, batch_size=list(batch_size))

    def distribution(self) -> BinghamExtrinsic | GaussianExtrinsic:
        """The current action distribution (batch shape ``[]``)."""
        return self.actor.get_dist(self.observation())

    @torch.no_grad()
    def mode(self) -> Extrinsic:
        """Most likely extrinsic (the distribution's mode), with the time offset when estimated."""
        a = self.distribution().mode
        offset = float(a[7]) if self.time_offset else None
        return Extrinsic(transform_from_quat(a[:4], a[4:7]), offset)

    @torch.no_grad()
    def uncertainty(self) -> PolicySpread:
        """Per-axis spreads of the current policy (rotation about the mode's, i.e. LiDAR, axes)."""
        dist = self.distribution()
        offset = float(dist.scale[3]) if self.time_offset else None
        return PolicySpread(dist.rotation_sigma_rad(), dist.scale[:3].clone(), offset)
