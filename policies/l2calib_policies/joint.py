"""Joint action distributions over the flat extrinsic action ``[qx, qy, qz, qw, tx, ty, tz(, dt)]``.

Why one custom distribution instead of tensordict's ``CompositeDistribution``: the environment
contract is a single action tensor ``"action"`` ``[..., 7|8]`` whose quaternion is unit-norm. A
``CompositeDistribution`` writes one key per component (``rotation``, ``translation``) and
per-component log-probs, so the environment would need to re-assemble the action and
``ClipPPOLoss`` would run its multi-head code path. A product distribution with event shape
``[7|8]`` keeps TorchRL's default single-head path: ``ProbabilisticActor(out_keys=["action"],
return_log_prob=True)`` writes ``"action_log_prob"`` and ``ClipPPOLoss`` picks that key up from
``actor.log_prob_keys``; the entropy bonus uses :meth:`ExtrinsicDistribution.entropy`.

``log_prob(a) = log p_rot(a[..., :4]) + Σ log N(a[..., 4:]; loc, scale)`` — rotation and
translation (and time offset) are independent given the parameters.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.distributions import Distribution, Independent, Normal, constraints

from l2calib_policies.bingham import Bingham
from l2calib_policies.gaussian import ProjectedNormal


class _ExtrinsicAction(constraints.Constraint):
    """``[..., 4 + k]`` vectors whose first four entries are a unit quaternion."""

    event_dim = 1

    def check(self, value: Tensor) -> Tensor:
        unit = (value[..., :4].norm(dim=-1) - 1).abs() < 1e-6
        return unit & torch.isfinite(value[..., 4:]).all(-1)


class ExtrinsicDistribution(Distribution):
    """Product of a rotation distribution on S³ and a diagonal Gaussian on translation (+ dt).

    Args:
        rotation: Distribution of unit xyzw quaternions (event shape ``[4]``).
        loc: Translation mean ``[..., k]`` (m; a 4th entry is the time offset in s).
        scale: Translation standard deviations ``[..., k]`` (> 0).
        validate_args: As in :class:`torch.distributions.Distribution`.
        mirrored: Draw candidates in groups that share their random numbers: ``(δ, ε)``,
            ``(δ⁻¹, ε)``, ``(δ, -ε)``, ``(δ⁻¹, -ε)`` where ``δ`` is the rotation relative to
            the rotation law's symmetry axis and ``ε`` the translation deviation (mirrored
            sampling, a standard variance reduction of evolution strategies; a rotation law
            without a known symmetry, the projected normal, gets ``(q, ±ε)`` pairs). Every
            candidate still follows this distribution exactly (the reflections are symmetries
            of the densities), so PPO's likelihood ratios are unchanged; but in the policy
            gradient the rotation's effect on the reward cancels between ``±ε`` and the
            translation's between ``δ^±1``. Applies when the batch holds a multiple of four
            distributions with equal parameters (what the calibration actor produces).
    """

    arg_constraints: dict = {}
    support = _ExtrinsicAction()

    def __init__(
        self,
        rotation: Distribution,
        loc: Tensor,
        scale: Tensor,
        validate_args: bool | None = None,
        mirrored: bool = False,
    ) -> None:
        self.mirrored = mirrored
        batch = torch.broadcast_shapes(rotation.batch_shape, loc.shape[:-1], scale.shape[:-1])
        k = loc.shape[-1]
        self.rotation = rotation.expand(batch) if rotation.batch_shape != batch else rotation
        self.loc = loc.to(torch.float64).expand(*batch, k)
        self.scale = scale.to(torch.float64).expand(*batch, k)
        self.translation = Independent(Normal(self.loc, self.scale, validate_args), 1)
        super().__init__(batch, torch.Size([4 + k]), validate_args=validate_args)

    @property
    def has_rsample(self) -> bool:  # type: ignore[override]
        """Reparameterisable iff the rotation part is (Gaussian yes, Bingham no)."""
        return self.rotation.has_rsample

    def sample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        """Actions ``[*sample_shape, *batch, 4 + k]`` (unit quaternion first)."""
        with torch.no_grad():
            if self.mirrored and self._can_mirror(sample_shape):
                return self._mirrored_sample()
            return torch.cat(
                [self.rotation.sample(sample_shape), self.translation.sample(sample_shape)], -1
            )

    def _can_mirror(self, sample_shape) -> bool:
        n = self.batch_shape.numel()
        if tuple(sample_shape) or n < 4 or n % 4:
            return False
        flat = self.loc.reshape(n, -1)
        return bool((flat == flat[:1]).all())

    def _mirrored_sample(self) -> Tensor:
        n = self.batch_shape.numel()
        g = n // 4
        rot = self.rotation.sample().reshape(n, 4)
        t = self.translation.sample().reshape(n, -1)[: 2 * g]
        t_m = 2.0 * self.loc.reshape(n, -1)[0] - t
        if hasattr(self.rotation, "symmetry_axis"):
            q = rot[:g]
            axis = self.rotation.symmetry_axis.reshape(n, 4)[0]
            q = torch.cat([q, 2.0 * (q @ axis)[:, None] * axis - q])  # δ and δ⁻¹
            t = torch.cat([t[:g], t[:g]])
            t_m = torch.cat([t_m[:g], t_m[:g]])
        else:  # no known symmetry of the rotation law: mirror the translation only
            q = rot[: 2 * g]
        out = torch.cat([torch.cat([q, t], -1), torch.cat([q, t_m], -1)])
        return out.reshape(*self.batch_shape, -1)

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> Tensor:
        """Reparameterised actions (only when the rotation part supports it)."""
        if not self.rotation.has_rsample:
            raise NotImplementedError(
                f"{type(self.rotation).__name__} samples by rejection and has no rsample"
            )
        return torch.cat(
            [self.rotation.rsample(sample_shape), self.translation.rsample(sample_shape)], -1
        )

    def log_prob(self, value: Tensor) -> Tensor:
        """Joint log-density ``[sample, batch]`` (rotation w.r.t. the surface measure of S³)."""
        if self._validate_args:
            self._validate_sample(value)
        return self.rotation.log_prob(value[..., :4]) + self.translation.log_prob(value[..., 4:])

    def entropy(self) -> Tensor:
        """Joint entropy ``[batch]`` (nats): rotation entropy + Gaussian entropy."""
        return self.rotation.entropy() + self.translation.entropy()

    @property
    def mode(self) -> Tensor:
        """Deterministic action ``[batch, 4 + k]``: rotation mode and translation mean."""
        return torch.cat([self.rotation.mode, self.loc], -1)

    @property
    def deterministic_sample(self) -> Tensor:
        """What TorchRL returns in deterministic mode (:attr:`mode`)."""
        return self.mode

    def rotation_sigma_rad(self) -> Tensor:
        """Per-body-axis rotation σ ``[batch, 3]`` (rad), see the rotation distribution."""
        return self.rotation.rotation_sigma_rad()


class BinghamExtrinsic(ExtrinsicDistribution):
    """Bingham rotation (L2Calib) × Gaussian translation; keyword names match the actor keys."""

    def __init__(
        self,
        rotation_quat_xyzw: Tensor,
        rotation_concentration: Tensor,
        translation_loc: Tensor,
        translation_scale: Tensor,
        validate_args: bool | None = None,
        mirrored: bool = False,
    ) -> None:
        rot = Bingham(rotation_quat_xyzw, rotation_concentration, validate_args)
        super().__init__(rot, translation_loc, translation_scale, validate_args, mirrored)


class GaussianExtrinsic(ExtrinsicDistribution):
    """Projected-normal rotation (L2Calib-g) × Gaussian translation."""

    def __init__(
        self,
        rotation_loc: Tensor,
        rotation_scale: Tensor,
        translation_loc: Tensor,
        translation_scale: Tensor,
        validate_args: bool | None = None,
        mirrored: bool = False,
    ) -> None:
        rot = ProjectedNormal(rotation_loc, rotation_scale, validate_args)
        super().__init__(rot, translation_loc, translation_scale, validate_args, mirrored)
