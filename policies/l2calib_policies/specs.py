"""Plugin specs of the policies (light: pydantic options + lazy factories, no torch import).

Entry-point group ``l2calib.policies``: ``bingham`` (L2Calib) and ``gaussian`` (L2Calib-g).
``spec.build(options, action_dim=7|8, prior=ExtrinsicPrior|None, seed=int)`` (optionally
``init_time_offset_s=float``, ``rotation_start=RotationStart``,
``translation_start=LeverStart``) returns a
:class:`l2calib_policies.actors.ExtrinsicPolicy`.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from l2calib.plugins import PluginSpec


class _PolicyOptions(BaseModel):
    """Options shared by both policies (translation and time offset)."""

    model_config = ConfigDict(extra="forbid")

    init_translation_sigma_m: float = Field(
        0.5, gt=0, description="initial σ of each translation axis without a prior (m)"
    )
    min_translation_sigma_m: float = Field(
        1e-4, gt=0, description="soft floor of the translation σ (m)"
    )
    translation_bound_m: float | None = Field(
        None, gt=0, description="bound |t_i| of the translation mean (tanh); null: unbounded"
    )
    init_time_offset_sigma_s: float = Field(
        0.02, gt=0, description="initial σ of the time offset (s), when estimated"
    )
    min_time_offset_sigma_s: float = Field(1e-5, gt=0, description="soft floor (s)")
    time_offset_bound_s: float | None = Field(
        0.2, gt=0, description="bound of the time-offset mean (s, tanh); null: unbounded"
    )
    min_rotation_sigma_deg: float = Field(
        0.05, gt=0, description="soft floor of the rotation σ per axis (deg)"
    )
    mirrored_sampling: bool = Field(
        True,
        description="draw candidates in mirrored groups of four (δ^±1, ±ε) sharing random "
        "numbers: exact marginals, far less gradient noise (needs K divisible by 4)",
    )

    @model_validator(mode="after")
    def _floors_below_inits(self) -> _PolicyOptions:
        if self.min_translation_sigma_m >= self.init_translation_sigma_m:
            raise ValueError("min_translation_sigma_m must be below init_translation_sigma_m")
        if self.min_time_offset_sigma_s >= self.init_time_offset_sigma_s:
            raise ValueError("min_time_offset_sigma_s must be below init_time_offset_sigma_s")
        return self


class BinghamOptions(_PolicyOptions):
    """Options of the Bingham policy (rotation ~ Bingham with body-axis concentrations)."""

    init_rotation_sigma_deg: float | None = Field(
        None,
        gt=0,
        description="initial rotation σ per body axis without a prior (deg); null: uniform "
        "rotation (z = 0)",
    )
    allow_positive_concentration: bool = Field(
        True,
        description="let concentrations cross 0 (z = -2 sinh 2ρ) so the mode can flip to a body "
        "axis; false: z = -2 exp(-2 log σ) ≤ 0 as in the paper (no exact z = 0 start)",
    )


class GaussianOptions(_PolicyOptions):
    """Options of the Gaussian baseline (rotation = normalised 4-D Gaussian sample)."""

    init_rotation_sigma_deg: float | None = Field(
        None,
        gt=0,
        description="initial rotation σ without a prior (deg); null: a broad start "
        "(unit mean at identity, σ = 1 per quaternion component)",
    )


def _build(kind: str, config: BaseModel, **context: Any) -> Any:
    from l2calib_policies.actors import ExtrinsicPolicy

    return ExtrinsicPolicy(kind, config, **context)


def _build_bingham(config: BinghamOptions, **context: Any) -> Any:
    return _build("bingham", config, **context)


def _build_gaussian(config: GaussianOptions, **context: Any) -> Any:
    return _build("gaussian", config, **context)


BINGHAM = PluginSpec(
    name="bingham",
    group="l2calib.policies",
    config=BinghamOptions,
    factory=_build_bingham,
    description="Bingham rotation (exact normaliser) × Gaussian translation — L2Calib",
)

GAUSSIAN = PluginSpec(
    name="gaussian",
    group="l2calib.policies",
    config=GaussianOptions,
    factory=_build_gaussian,
    description="normalised 4-D Gaussian rotation × Gaussian translation — L2Calib-g baseline",
)
