"""The calibration MDP as a TorchRL environment.

Single step, batched: one step scores K candidate extrinsics (the env's batch size ``[K]``).
The observation is a constant; the action of candidate ``k`` is
``[qx, qy, qz, qw, tx, ty, tz(, time_offset_s)]`` (``R_imu_lidar`` as a unit quaternion,
``t_imu_lidar`` in m); the reward is the paper's trajectory-alignment reward pooled over every
prepared segment (joint multi-sequence calibration), and every step ends the episode.

Also here: :func:`make_env` (a recipe's env, as worker processes and Ray actors build it) and
:func:`merge_shares` (a batch's rewards back in candidate order from the shares the workers or
actors scored; :func:`merge_block_shares` the same for the uncertainty's block costs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Composite, Unbounded
from torchrl.envs import EnvBase

from l2calib import geometry as geo
from l2calib.data import Segment
from l2calib.errors import TrainingError
from l2calib.interfaces import CandidateStatus, OdometryBackend, ReferenceTrajectory
from l2calib.recipe import Recipe, RewardConfig
from l2calib.reward import RewardBreakdown, aligned_errors, score

F64 = torch.float64
INFO_KEYS = ("mean_e_t", "mean_e_r", "status")


def action_to_extrinsic(action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``T_imu_lidar [K, 4, 4]`` and ``time_offset_s [K]`` (or None) from actions ``[K, 7|8]``."""
    T = geo.transform_from_quat(action[..., :4], action[..., 4:7])
    return T, (action[..., 7] if action.shape[-1] == 8 else None)


class ScoringEnv(EnvBase):
    """A single-step, batched environment whose reward scores K candidate extrinsics.

    Holds what every calibration MDP shares — the specs, the one-step episode, the mapping from
    actions to extrinsics — so the trainer sees the same environment whatever scores the
    candidates. Subclasses implement :meth:`score_candidates`: :class:`CalibrationEnv` runs an
    odometry backend; the policies' toy problem (``l2calib_policies.toy``) a closed-form reward.

    Args:
        num_candidates: K, the batch size.
        action_dim: 7 (quaternion xyzw + translation m) or 8 (+ time offset s).
    """

    def __init__(self, num_candidates: int, action_dim: int = 7) -> None:
        super().__init__(batch_size=torch.Size([num_candidates]), device="cpu")
        self.action_dim = action_dim
        self.evaluations = 0
        self._make_spec()

    def score_candidates(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ) -> tuple[RewardBreakdown, torch.Tensor]:
        """Scores ``T_imu_lidar [K, 4, 4]``; returns the breakdown and ``[K]`` status codes."""
        raise NotImplementedError

    def _make_spec(self) -> None:
        K = self.batch_size[0]
        self.observation_spec = Composite(
            observation=Unbounded((K, 1), dtype=F64),
            mean_e_t=Unbounded((K, 1), dtype=F64),
            mean_e_r=Unbounded((K, 1), dtype=F64),
            status=Unbounded((K, 1), dtype=torch.int64),
            shape=(K,),
        )
        self.action_spec = Unbounded((K, self.action_dim), dtype=F64)
        self.reward_spec = Unbounded((K, 1), dtype=F64)
        self.done_spec = Composite(
            done=Binary(1, (K, 1), dtype=torch.bool),
            terminated=Binary(1, (K, 1), dtype=torch.bool),
            truncated=Binary(1, (K, 1), dtype=torch.bool),
            shape=(K,),
        )

    def _blank(self) -> TensorDict:
        K = self.batch_size[0]
        return TensorDict(
            {
                "observation": torch.zeros(K, 1, dtype=F64),
                "mean_e_t": torch.zeros(K, 1, dtype=F64),
                "mean_e_r": torch.zeros(K, 1, dtype=F64),
                "status": torch.zeros(K, 1, dtype=torch.int64),
            },
            batch_size=self.batch_size,
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        out = self._blank()
        false = torch.zeros(self.batch_size[0], 1, dtype=torch.bool)
        out.update({"done": false, "terminated": false.clone(), "truncated": false.clone()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"].to(F64)
        T, offset = action_to_extrinsic(action)
        breakdown, status = self.score_candidates(T, offset)
        out = self._blank()
        out["mean_e_t"] = breakdown.mean_e_t[:, None]
        out["mean_e_r"] = torch.nan_to_num(breakdown.mean_e_r, nan=-1.0)[:, None]
        out["status"] = status[:, None]
        true = torch.ones(self.batch_size[0], 1, dtype=torch.bool)
        out.update(
            {
                "reward": breakdown.reward[:, None],
                "done": true,
                "terminated": true.clone(),
                "truncated": torch.zeros_like(true),
            }
        )
        return out

    def _set_seed(self, seed: int | None) -> None:
        # The environment is deterministic: all randomness lives in the policy.
        self._seed = seed


class CalibrationEnv(ScoringEnv):
    """Scores K candidate extrinsics per step with an odometry backend against references.

    Args:
        backend: A prepared :class:`OdometryBackend`.
        references: One reference per prepared segment, in the backend's segment order.
        num_candidates: K, the batch size.
        reward: Reward settings (kind, alignment, maximum interpolation gap).
        time_offset: Whether actions carry a LiDAR–IMU time offset (8-dim actions).
        worker_index: This env's place among the worker processes of a ``ParallelEnv`` (which
            share of a batch :meth:`score_share` scores).
        hold: Holds every candidate's vertical lever arm before the odometry runs
            (:class:`~l2calib.train.vertical_hold.VerticalHold`), or ``None``.
        fixed_time_offset_s: A LiDAR–IMU offset (s) every candidate is scored with when the
            caller gives none (``train.known_time_offset_s``; 7-dim actions), or ``None``.
    """

    def __init__(
        self,
        backend: OdometryBackend,
        references: Sequence[ReferenceTrajectory],
        num_candidates: int,
        reward: RewardConfig | None = None,
        time_offset: bool = False,
        worker_index: int = 0,
        hold: Any | None = None,
        fixed_time_offset_s: float | None = None,
    ) -> None:
        super().__init__(num_candidates, 8 if time_offset else 7)
        if time_offset and fixed_time_offset_s is not None:
            raise TrainingError(
                "a fixed time offset and an estimated one were both asked for",
                fix="set train.estimate_time_offset: false with train.known_time_offset_s",
            )
        self.backend = backend
        self.hold = hold
        self.fixed_time_offset_s = fixed_time_offset_s
        self.worker_index = worker_index
        self.references = list(references)
        self.reward_config = reward or RewardConfig()
        align = self.reward_config.align
        if align == "auto":
            align = "none" if backend.outputs_in_reference_frame else "se3"
        self.align = align
        self._ref_cache: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        self._alt_cache: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}  # alternatives

    def _reference_at(self, index: int, segment: str, stamps_ns: np.ndarray):
        if segment not in self._ref_cache:
            self._ref_cache[segment] = self._sampled(self.references[index].trajectory, stamps_ns)
        return self._ref_cache[segment]

    def _sampled(self, trajectory, stamps_ns: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """``trajectory``'s poses ``[N, 4, 4]`` at ``stamps_ns`` (zeros where none) and the mask."""
        sampled, ok = trajectory.sample(stamps_ns, self.reward_config.max_gap_s)
        T = torch.zeros(len(stamps_ns), 4, 4, dtype=F64)
        T[torch.from_numpy(ok)] = sampled.matrices()
        return T, torch.from_numpy(ok)

    def score_candidates(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ):
        """Runs the backend and pools the errors of every segment into one reward per candidate.

        Returns:
            A :class:`l2calib.reward.RewardBreakdown` and the ``[K]`` candidate status codes.
        """
        if self.hold is not None:
            T_imu_lidar = self.hold.apply(T_imu_lidar)
        outputs = self.backend.evaluate(T_imu_lidar, self._offsets(T_imu_lidar, time_offset_s))
        if len(outputs) != len(self.references):
            raise TrainingError(
                f"the backend returned {len(outputs)} segments for {len(self.references)} "
                "references",
                fix="prepare the backend with the same segments as the environment",
            )
        e_t, e_r, valid, valid_r = [], [], [], []
        status = torch.zeros(T_imu_lidar.shape[0], dtype=torch.int64)
        for i, out in enumerate(outputs):
            T_ref, ok = self._reference_at(i, out.segment, out.stamps_ns)
            v = out.valid & ok[None]
            et, er = aligned_errors(T_ref, out.T_world_lidar, v, self.align)
            e_t.append(et)
            e_r.append(er)
            valid.append(v)
            rotation = self.references[i].constrains == "pose"
            valid_r.append(v if rotation else torch.zeros_like(v))
            status = torch.maximum(status, out.status)
        failed = status == int(CandidateStatus.DIVERGED)
        breakdown = score(
            torch.cat(e_t, 1),
            torch.cat(e_r, 1),
            torch.cat(valid, 1),
            self.reward_config.kind,
            torch.cat(valid_r, 1),
            failed,
        )
        self.evaluations += int(T_imu_lidar.shape[0])
        return breakdown, status

    def _offsets(self, T_imu_lidar: torch.Tensor, given: torch.Tensor | None):
        """``given`` offsets ``[K]`` (s), else the fixed offset for every candidate, else None."""
        if given is not None or self.fixed_time_offset_s is None:
            return given
        return torch.full((T_imu_lidar.shape[0],), self.fixed_time_offset_s, dtype=F64)

    def use_data_fraction(self, fraction: float) -> int:
        """Scores the following steps on about ``fraction`` of the data (coarse-to-fine).

        Every candidate of a step sees the same part (the backend's
        :meth:`~l2calib.interfaces.OdometryBackend.use_data_fraction`); ``1.0`` restores all.

        Returns:
            Scans each candidate is now estimated on (0 when the backend does not say).
        """
        return int(self.backend.use_data_fraction(float(fraction)))

    def score_share(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None, num_workers: int
    ):
        """Scores this worker's share ``[worker_index::num_workers]`` of a batch.

        A ``ParallelEnv`` sends the same call to every worker; each scores every
        ``num_workers``-th candidate, so a batch of any size is split evenly over the processes
        (its ``step`` only takes batches of the fixed training size). See
        :func:`l2calib.train.env_build.score_batch`.

        Returns:
            As :meth:`score_candidates`, for the share.
        """
        share = slice(self.worker_index, None, num_workers)
        T, offsets = T_imu_lidar[share], None if time_offset_s is None else time_offset_s[share]
        if T.shape[0] == 0:  # fewer candidates than workers: nothing here
            none = torch.zeros(0, dtype=F64)
            count = torch.zeros(0, dtype=torch.int64)
            return RewardBreakdown(none, none.clone(), none.clone(), count), count.clone()
        return self.score_candidates(T, offsets)

    def block_cost_share(
        self,
        T_imu_lidar: torch.Tensor,
        time_offset_s: torch.Tensor | None,
        num_workers: int,
        block_s: float,
    ) -> BlockCosts:
        """The reward's pose cost per block of data for this worker's share of the candidates.

        The cost of a scan is ``e_t / 4 + e_r / π²`` (m, rad: the paper reward's terms before
        their means and square roots; the rotation term only against pose references), summed
        over blocks of ``block_s`` seconds of each segment
        (:func:`l2calib.assess.uncertainty.block_index`). For the uncertainty estimate; where
        any reference has an :attr:`~l2calib.interfaces.ReferenceTrajectory.alternative`, the
        same cost against it too (from the same odometry runs).
        """
        from l2calib.assess.uncertainty import block_index

        share = slice(self.worker_index, None, num_workers)
        T, offsets = T_imu_lidar[share], None if time_offset_s is None else time_offset_s[share]
        if self.hold is not None:
            T = self.hold.apply(T)
        has_alt = any(r.alternative is not None for r in self.references)
        blocks, alt_blocks, scans, first = [], [], 0, []
        outputs = self.backend.evaluate(T, self._offsets(T, offsets)) if T.shape[0] else []
        for i, o in enumerate(outputs):
            T_ref, ok = self._reference_at(i, o.segment, o.stamps_ns)
            valid = o.valid & ok[None]
            cost = self._pose_cost(i, T_ref, o.T_world_lidar, valid)
            b = block_index(o.stamps_ns * 1e-9, block_s)
            per_block = [b == j for j in range(int(b.max(initial=-1)) + 1)]
            blocks += [cost[:, m].sum(1) for m in per_block]
            if has_alt:  # a segment without one counts its main cost (no shift there)
                alt = self._alternative_at(i, o.segment, o.stamps_ns)
                alt_cost = (
                    cost
                    if alt is None
                    else self._pose_cost(i, alt[0], o.T_world_lidar, valid & alt[1])
                )
                alt_blocks += [alt_cost[:, m].sum(1) for m in per_block]
            scans += int(ok.sum())
            first.append(cost[0, valid[0].numpy()])
        if not blocks:
            return BlockCosts(np.zeros((T.shape[0], 0)), scans, first, None)
        alternative = np.stack(alt_blocks, 1) if has_alt else None
        return BlockCosts(np.stack(blocks, 1), scans, first, alternative)

    def _pose_cost(self, i: int, T_ref: torch.Tensor, T_est: torch.Tensor, valid: torch.Tensor):
        """``[k, N]`` per-scan costs ``e_t / 4 + e_r / π²`` on segment ``i`` (0 where invalid)."""
        e_t, e_r = aligned_errors(T_ref, T_est, valid, self.align)
        use_r = float(self.references[i].constrains == "pose")
        return torch.where(valid, e_t / 4 + use_r * e_r / math.pi**2, 0.0).numpy()

    def _alternative_at(self, index: int, segment: str, stamps_ns: np.ndarray):
        """The reference's alternative ``[N, 4, 4]`` and ``[N]`` mask at ``stamps_ns``, or None."""
        alternative = self.references[index].alternative
        if alternative is None:
            return None
        if segment not in self._alt_cache:
            self._alt_cache[segment] = self._sampled(alternative, stamps_ns)
        return self._alt_cache[segment]

    def trajectory_share(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None, num_workers: int
    ) -> list[dict[str, np.ndarray | str]]:
        """LiDAR positions of this worker's share of the candidates, for the report.

        The same share as :meth:`score_share` (every ``num_workers``-th candidate), run on the
        backend that is already prepared: the report needs no second odometry preparation.
        Estimates are shown in the reference's frame (aligned as the reward aligns them).

        Returns:
            Per segment ``{"name": str, "reference": [N,3], "positions": [k,N,3]}`` (m) at the
            odometry's stamps where the reference has a pose (``k`` candidates of the share);
            empty when the share is.
        """
        from l2calib.alignment import umeyama

        share = slice(self.worker_index, None, num_workers)
        T, offsets = T_imu_lidar[share], None if time_offset_s is None else time_offset_s[share]
        if T.shape[0] == 0:
            return []
        if self.hold is not None:
            T = self.hold.apply(T)
        out = []
        for i, o in enumerate(self.backend.evaluate(T, self._offsets(T, offsets))):
            T_ref, ok = self._reference_at(i, o.segment, o.stamps_ns)
            ref = T_ref[ok][:, :3, 3]
            pos = o.T_world_lidar[:, ok][..., :3, 3]
            valid = o.valid[:, ok] & torch.isfinite(pos).all(-1)
            if self.align != "none":
                R, t, s = umeyama(
                    torch.nan_to_num(pos), ref.expand_as(pos), valid.to(F64), self.align == "sim3"
                )
                pos = s[:, None, None] * pos @ R.transpose(-1, -2) + t[:, None, :]
            pos = torch.where(valid[..., None], pos, torch.nan)  # lost poses: gaps in the plot
            out.append({"name": o.segment, "reference": ref.numpy(), "positions": pos.numpy()})
        return out


def build_backend(recipe: Recipe, segments: Sequence[Segment], references, threads: int = 0):
    """The recipe's backend plugin, prepared on ``segments`` with their ``references``."""
    from l2calib.plugins import get_plugin

    if threads:
        torch.set_num_threads(threads)
    backend = get_plugin("l2calib.backends", recipe.backend.name).build(
        recipe.backend.options, imu=recipe.data.imu
    )
    backend.prepare(list(segments), list(references))
    return backend


def make_env(
    recipe_data: dict[str, Any],
    segments: Sequence[Segment],
    references: Sequence[ReferenceTrajectory],
    num_candidates: int,
    threads: int = 0,
    worker_index: int = 0,
    hold: Any | None = None,
):
    """A :class:`CalibrationEnv` (top-level so worker processes and Ray actors can build it)."""
    recipe = Recipe.model_validate(recipe_data)
    backend = build_backend(recipe, segments, references, threads)
    return CalibrationEnv(
        backend,
        references,
        num_candidates,
        recipe.reward,
        time_offset=recipe.train.estimate_time_offset,
        worker_index=worker_index,
        hold=hold,
        fixed_time_offset_s=recipe.train.known_time_offset_s,
    )


class BlockCosts(NamedTuple):
    """The pose cost of candidates per block of data (the uncertainty estimate's input).

    Attributes:
        costs: ``[k, B]`` costs (``B`` blocks over all segments, in order).
        scans: The scans counted.
        centre: Per segment, the per-scan costs of the first candidate (its valid scans, in
            time order: the residuals' correlation; empty for an empty share).
        alternative: ``[k, B]`` the same costs against the references' alternatives (the main
            reference's where a segment has none), or ``None`` when no reference has one.
    """

    costs: np.ndarray
    scans: int
    centre: list[np.ndarray]
    alternative: np.ndarray | None


def merge_block_shares(parts: Sequence[BlockCosts], total: int) -> BlockCosts:
    """One :class:`BlockCosts` of ``total`` candidates from shares split as in :func:`merge_shares`.

    Share 0 holds candidate 0, whose per-scan costs are kept; empty shares are skipped.
    """
    n = len(parts)
    width = max(p.costs.shape[1] for p in parts)
    costs = np.zeros((total, width))
    has_alt = any(p.alternative is not None for p in parts)
    alternative = np.zeros((total, width)) if has_alt else None
    for i, p in enumerate(parts):
        if p.costs.shape[0]:
            costs[i::n] = p.costs
            if alternative is not None:
                alternative[i::n] = p.alternative
    return BlockCosts(costs, max(p.scans for p in parts), parts[0].centre, alternative)


def merge_shares(parts: Sequence[Any], total: int):
    """One :class:`~l2calib.reward.RewardBreakdown` of ``total`` candidates from its shares.

    Share ``i`` of ``n`` holds candidates ``i, i + n, ...`` (how the workers and the Ray actors
    split a batch); shares may be empty when there are fewer candidates than workers.
    """
    from dataclasses import fields

    from l2calib.reward import RewardBreakdown

    n, merged = len(parts), {}
    for f in fields(RewardBreakdown):
        full = torch.empty(total, dtype=getattr(parts[0], f.name).dtype)
        for i, part in enumerate(parts):
            full[i::n] = getattr(part, f.name)
        merged[f.name] = full
    return RewardBreakdown(**merged)
