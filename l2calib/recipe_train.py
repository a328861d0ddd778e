"""The recipe's ``train`` section: PPO settings, budgets, stopping, refinement, executor."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from l2calib.config_base import StrictModel


class RayConfig(StrictModel):
    """Where ``train.executor: ray`` scores candidates (``docs/scaling.md``)."""

    address: str | None = Field(
        None,
        description="Ray cluster to join (e.g. ray://head:10001 or head:6379); null: the "
        "RAY_ADDRESS environment variable, else a Ray instance started on this machine",
    )
    actors: Annotated[int, Field(ge=1)] | Literal["auto"] = Field(
        "auto",
        description="scoring actors, each holding one prepared odometry backend; auto: the "
        "cluster's CPUs / threads_per_actor, at most candidates_per_iteration",
    )
    threads_per_actor: int = Field(1, ge=1, description="CPUs (torch threads) each actor uses")


class UncertaintyConfig(StrictModel):
    """After training: per-axis 95 % bounds on the error and when to call an axis undetermined.

    The bounds come from the data around the result (``l2calib.assess.uncertainty``,
    ``docs/design.md``); an axis whose bound exceeds its limit, or along which the reward is
    flat, is named as not determined by the data.
    """

    enabled: bool = Field(True, description="estimate the bounds (73-99 odometry runs)")
    block_s: float = Field(
        2.0, gt=0, description="length of the blocks of data the noise is measured on (s)"
    )
    rotation_limit_deg: float = Field(0.5, gt=0, description="undetermined beyond this bound")
    translation_limit_m: float = Field(0.02, gt=0, description="undetermined beyond this bound")
    time_offset_limit_ms: float = Field(
        5.0, gt=0, description="the time offset is undetermined beyond this bound (ms)"
    )


class TrainConfig(StrictModel):
    """PPO settings and budgets."""

    seed: int = 0
    candidates_per_iteration: int = Field(32, ge=2)
    max_iterations: int = Field(150, ge=1)
    max_evaluations: int = Field(5000, ge=1)
    estimate_time_offset: bool = True
    init_time_offset_s: float | None = Field(
        None,
        ge=-0.5,
        le=0.5,
        description="starting value of the LiDAR-IMU time offset when estimate_time_offset "
        "(s, t_imu = t_lidar + offset; `l2calib inspect` prints it); null: the reference's "
        "clock check, else 0",
    )
    time_offset_from_rates: Literal["hold", "start"] = Field(
        "hold",
        description="where the references' rotation rate pins the LiDAR-IMU offset (a sharp "
        "|ω| correlation with the gyro, hand-held data): hold = keep the offset there and search "
        "the extrinsic only; start = start the joint estimation there. Elsewhere (flat "
        "correlation: uav, ugv) the offset is estimated jointly either way (docs/time_offset.md)",
    )
    rotation_from_rates: Literal["start", "off"] = Field(
        "start",
        description="without policy.prior: start = PPO's first attempt starts its rotation at "
        "the references' body rates fitted to the gyro (SVD), with a spread per axis from the "
        "fit (l2calib.train.rotation_start); off = from a uniform rotation. Restarts always "
        "start from no guess",
    )
    translation_from_accelerations: Literal["start", "off"] = Field(
        "start",
        description="without policy.prior, once the rotation starts from the rates: start = "
        "PPO's first attempt starts its translation at the lever arm fitted to the references' "
        "accelerations against the accelerometer (linear least squares, gravity and a bias per "
        "segment), with a spread per axis from the fit (l2calib.train.lever_start); off = at "
        "zero with policy.options.init_translation_sigma_m",
    )
    known_time_offset_s: float | None = Field(
        None,
        ge=-0.5,
        le=0.5,
        description="a LiDAR-IMU time offset that is known and held fixed, not estimated (s, "
        "t_imu = t_lidar + offset); needs estimate_time_offset: false",
    )
    lr: float = Field(3e-2, gt=0, description="Adam rate of the spreads and the value head")
    mean_step_scale: float = Field(
        0.3,
        ge=0,
        description="Adam rate of the rotation/translation means = this × their current σ "
        "(rad, m); 0: use lr for them too",
    )
    lr_schedule: Literal["constant", "cosine"] = "constant"
    ppo_epochs: int = Field(4, ge=1)
    clip_epsilon: float = Field(0.2, gt=0)
    entropy_coef: float = Field(1e-3, ge=0)
    max_grad_norm: float = Field(1.0, gt=0)
    workers: Annotated[int, Field(ge=1)] | Literal["auto"] = Field(
        "auto",
        description="processes that run the odometry (same result for any count); auto: the "
        "largest divisor of candidates_per_iteration not above the CPUs this process may use",
    )
    executor: Literal["local", "ray"] = Field(
        "local",
        description="what scores the candidates: local = this machine's worker processes "
        "(train.workers); ray = Ray actors on a cluster (train.ray; pip install 'l2calib[ray]'). "
        "The same seed gives the same result with either",
    )
    ray: RayConfig = Field(default_factory=RayConfig)
    checkpoint_every: int = Field(10, ge=1)
    stop_on_plateau: bool = Field(
        False,
        description="end PPO when the best reward stops rising once the rotation is narrow; "
        "the refinement finishes (l2calib.train.ppo). Off by default: it fired only on weakly "
        "excited data, and there PPO's reward was still short of the optimum (docs/design.md)",
    )
    plateau_window: int = Field(10, ge=2, description="iterations per plateau comparison")
    plateau_min_gain: float = Field(
        0.005, ge=0, description="best-reward gain per window below which PPO stops"
    )
    plateau_rotation_sigma_deg: float = Field(
        2.0, gt=0, description="largest rotation σ at which the plateau stop may fire"
    )
    handover_rotation_sigma_deg: float | None = Field(
        2.5,
        gt=0,
        description="end PPO once every rotation σ is at most this (deg) and every "
        "translation σ at most handover_translation_sigma_m; the refinement finishes; "
        "null: never",
    )
    handover_translation_sigma_m: float = Field(
        0.20, gt=0, description="translation σ (m) for handover_rotation_sigma_deg"
    )
    handover_time_offset_sigma_s: float | None = Field(
        None,
        gt=0,
        description="... and, where the time offset is estimated, its σ at most this (s); "
        "null: not checked (the policy then hands over with the offset as wide as it started); "
        "ground vehicles started at the rate rotation take 0.01 unless set "
        "(l2calib.train.vertical_hold.PLANAR_RATE_START)",
    )
    coarse_to_fine: bool = Field(
        True,
        description="score wide policies on a part of the data, all of it once narrow "
        "(l2calib.train.coarse)",
    )
    coarse_data_fraction: float = Field(
        0.25, gt=0, le=1, description="data fraction while the policy is at its widest"
    )
    coarse_min_data_s: float = Field(
        3.0,
        ge=0,
        description="the coarse part holds at least this much data (s): on an 8 s recording, "
        "2 s of it led PPO to a wrong rotation where 3 s did not",
    )
    coarse_rotation_sigma_deg: float = Field(
        20.0, gt=0, description="rotation σ at and above which the coarsest fraction is used"
    )
    fine_rotation_sigma_deg: float = Field(
        2.0, gt=0, description="rotation σ at and below which all the data is used"
    )
    coarse_translation_sigma_m: float = Field(
        0.3, gt=0, description="translation σ at and above which the coarsest fraction is used"
    )
    fine_translation_sigma_m: float = Field(
        0.03, gt=0, description="translation σ at and below which all the data is used"
    )
    convergence_window: int = Field(15, ge=2, description="iterations the mode must stay put")
    converged_step_deg: float = Field(0.1, gt=0, description="largest mode move in the window")
    converged_step_m: float = Field(0.005, gt=0, description="largest mode move in the window")
    converged_rotation_sigma_deg: float = Field(0.5, gt=0, description="largest rotation sigma")
    converged_translation_sigma_m: float = Field(0.05, gt=0, description="largest trans. sigma")
    refine_rounds: int = Field(
        12,
        ge=0,
        description="after PPO, climb the reward from the policy's mode with this many batched "
        "probe rounds (13 evaluations each, 15 with the time offset; l2calib.assess.refine); "
        "0: off",
    )
    polish_rounds: int = Field(
        0,
        ge=0,
        description="after the refinement, rounds of Newton steps on a quadratic model of the "
        "reward fitted from one batch of 73 candidates (99 with the time offset) plus 3 along "
        "the step, kept only where the reward rises; a round without gain halves the stencil "
        "(l2calib.assess.polish); follows coupled axes the per-axis refinement stops short on. "
        "0: off; on planar motion (a ground vehicle) 8 unless set here (l2calib.train."
        "vertical_hold.PLANAR_TRAIN)",
    )
    polish_first_scale: float = Field(
        1.0,
        gt=0,
        le=1,
        description="the polish's first stencil as a fraction of 0.5 deg / 2 cm / 1 ms; 0.25 "
        "continued the ground vehicle's stored calibrations to 0.07-0.74 cm (1 = 1.13-1.54 cm; "
        "docs/backends.md) and is the planar-motion default",
    )
    refine_rot_step_deg: float = Field(1.0, gt=0, description="first rotation step of refine")
    restarts: int = Field(
        1,
        ge=0,
        description="fresh PPO runs (other seeds) when the result fails the reference-agreement "
        "check, e.g. a run stuck in a local optimum; the highest reward is kept; 0: off",
    )
    refine_trans_step_m: float = Field(0.04, gt=0, description="first translation step of refine")
    refine_offset_step_s: float = Field(
        0.002, gt=0, description="first time-offset step of refine (s; with estimate_time_offset)"
    )
    hold_vertical_translation: Literal["auto", "on", "off"] = Field(
        "auto",
        description="hold the lever arm's vertical component (along the IMU's measured up) at "
        "policy.prior's value, else 0 m, instead of searching it: auto = when the data's "
        "rotation is planar (a ground vehicle; planar_min_yaw_share), where the data cannot "
        "determine it; the output names it as not estimated (l2calib.train.vertical_hold)",
    )
    planar_min_yaw_share: float = Field(
        0.97,
        gt=0,
        le=1,
        description="share of the rotation (sum of squared rates) about the vertical from which "
        "the motion counts as planar (l2calib.selection.planar); the simulator's ground vehicle "
        "gives 0.998, its drone 0.83-0.92, hand-held rigs 0.40-0.43",
    )

    uncertainty: UncertaintyConfig = Field(default_factory=UncertaintyConfig)

    @field_validator(
        "hold_vertical_translation",
        "rotation_from_rates",
        "translation_from_accelerations",
        mode="before",
    )
    @classmethod
    def _yaml_on_off(cls, value: object) -> object:
        """YAML 1.1 reads an unquoted ``on`` / ``off`` as a boolean: take it as meant."""
        return {True: "on", False: "off"}.get(value, value) if isinstance(value, bool) else value

    @model_validator(mode="after")
    def _known_offset_is_not_estimated(self) -> TrainConfig:
        if self.known_time_offset_s is not None and self.estimate_time_offset:
            raise ValueError(
                f"train.known_time_offset_s={self.known_time_offset_s} holds the time offset "
                "fixed, but train.estimate_time_offset is true: set it to false to hold the "
                "offset, or drop known_time_offset_s (init_time_offset_s starts an estimate)"
            )
        return self

    @model_validator(mode="after")
    def _coarse_above_fine(self) -> TrainConfig:
        for kind in ("rotation_sigma_deg", "translation_sigma_m"):
            fine, coarse = getattr(self, f"fine_{kind}"), getattr(self, f"coarse_{kind}")
            if fine >= coarse:
                raise ValueError(
                    f"train.fine_{kind}={fine} must be below train.coarse_{kind}={coarse}"
                )
        return self

    @property
    def iteration_budget(self) -> int:
        """PPO iterations at most: ``max_iterations``, capped by ``max_evaluations`` / K."""
        return max(
            1, min(self.max_iterations, self.max_evaluations // self.candidates_per_iteration)
        )
