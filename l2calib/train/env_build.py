"""Building the training environment: in this process, over worker processes, or on Ray.

With ``workers > 1`` the K candidates of an iteration are split over a TorchRL ``ParallelEnv``;
each worker holds its own prepared backend. With ``train.executor: ray`` they are split over Ray
actors instead (:mod:`l2calib.train.ray_executor`). The policy still samples all K actions in
the main process, so a fixed seed gives the same candidates — and the same result — whatever
the number of workers or actors.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from l2calib.data import Segment
from l2calib.errors import ConfigError
from l2calib.interfaces import ReferenceTrajectory
from l2calib.recipe import Recipe
from l2calib.train.env import BlockCosts, make_env, merge_block_shares, merge_shares


def resolve_workers(candidates: int, workers: int | str) -> int:
    """``train.workers`` as a process count.

    ``"auto"`` is the largest divisor of ``candidates`` not above the CPUs this process may run
    on; an explicit count is returned as is.
    """
    if workers != "auto":
        return int(workers)
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(d for d in range(1, min(candidates, cpus or 1) + 1) if candidates % d == 0)


def make_training_env(
    recipe: Recipe,
    segments: Sequence[Segment],
    references: Sequence[ReferenceTrajectory],
    hold: Any | None = None,
):
    """One environment scoring ``train.candidates_per_iteration`` candidates per step.

    ``train.executor: local`` (default): in this process, or on a ``ParallelEnv`` of
    ``train.workers`` processes; ``ray``: on Ray actors (:mod:`l2calib.train.ray_executor`).
    ``hold``: the vertical lever-arm hold every worker applies (:mod:`l2calib.train.
    vertical_hold`), or ``None``.
    """
    K = recipe.train.candidates_per_iteration
    if recipe.train.executor == "ray":
        from l2calib.train.ray_executor import RayScoringEnv

        return RayScoringEnv(recipe, segments, references, hold=hold)
    workers = resolve_workers(K, recipe.train.workers)
    data = recipe.model_dump(mode="json")
    if workers == 1:
        return make_env(data, segments, references, K, hold=hold)
    if K % workers:
        raise ConfigError(
            f"train.candidates_per_iteration={K} is not divisible by train.workers={workers}",
            fix="choose a multiple of the number of workers",
        )
    from torchrl.envs import ParallelEnv

    creator = functools.partial(
        make_env,
        recipe_data=data,
        segments=list(segments),
        references=list(references),
        num_candidates=K // workers,
        threads=1,
        hold=hold,
    )
    # A plain callable, not TorchRL's EnvCreator: that one also runs a random step in this
    # process (seconds of odometry on one core) just to learn the specs, and cannot give each
    # worker its own ``worker_index``.
    # use_buffers=False: with shared-memory buffers the parent spin-polls for the workers and
    # takes a third of 2 cores from them while they run the odometry (one step lasts seconds,
    # so passing the small result tensordicts through the pipes costs nothing).
    return ParallelEnv(
        workers,
        creator,
        create_env_kwargs=[{"worker_index": i} for i in range(workers)],
        num_threads=1,
        mp_start_method="fork",
        use_buffers=False,
    )


def _started(env):
    """An open ``ParallelEnv``: one built but not yet used is started (workers start lazily)."""
    if env.is_closed:
        env.start()
    return env


def set_data_fraction(env, fraction: float) -> int:
    """Tells a training env (one ``CalibrationEnv`` or a ``ParallelEnv`` of them) the fraction.

    Coarse-to-fine training (:mod:`l2calib.train.coarse`): every worker's backend evaluates on
    the same part of the data from now on.

    Returns:
        Scans each candidate is now estimated on (0 for an env that does not subsample, e.g.
        the policies' toy problem).
    """
    from l2calib.train.env import ScoringEnv

    if isinstance(env, ScoringEnv):  # in this process (or the driver of Ray actors)
        use = getattr(env, "use_data_fraction", None)
        return use(fraction) if use is not None else 0  # e.g. the toy: always all of its data
    counts = _started(env).use_data_fraction(fraction)  # the same call in every worker
    return int(counts[0])


def score_batch(env, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None):
    """Scores ``N`` candidates of any ``N`` on a training env, spread over its workers.

    After training, the refinement and the resolution probe score batches whose size differs
    from the training batch; a ``ParallelEnv``'s ``step`` only takes the training size, so every
    worker is sent the whole batch and scores its share (:meth:`CalibrationEnv.score_share`).

    Args:
        env: A :class:`~l2calib.train.env.CalibrationEnv` or an open ``ParallelEnv`` of them.
        T_imu_lidar: ``[N, 4, 4]`` candidates.
        time_offset_s: ``[N]`` time offsets (s) or ``None``.

    Returns:
        The :class:`~l2calib.reward.RewardBreakdown` of the ``N`` candidates, in their order.
    """
    from l2calib.train.env import ScoringEnv

    if isinstance(env, ScoringEnv):  # in this process (or the driver of Ray actors)
        return env.score_candidates(T_imu_lidar, time_offset_s)[0]
    n = env.num_workers
    parts = [breakdown for breakdown, _ in _started(env).score_share(T_imu_lidar, time_offset_s, n)]
    return merge_shares(parts, T_imu_lidar.shape[0])


def block_costs(
    env, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None, block_s: float
) -> BlockCosts:
    """The pose cost of ``N`` candidates per block of data, spread over the env's workers.

    See :meth:`~l2calib.train.env.CalibrationEnv.block_cost_share`; costs in candidate order.
    """
    from l2calib.train.env import ScoringEnv

    if isinstance(env, ScoringEnv):  # in this process (or the driver of Ray actors)
        return env.block_cost_share(T_imu_lidar, time_offset_s, 1, block_s)
    n = env.num_workers
    shares = _started(env).block_cost_share(T_imu_lidar, time_offset_s, n, block_s)
    return merge_block_shares(shares, T_imu_lidar.shape[0])


def trajectory_previews(
    env, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
) -> list[dict[str, np.ndarray | str]]:
    """LiDAR trajectories of ``N`` candidates on every segment from an open training env.

    Spread over the workers like :func:`score_batch` (see
    :meth:`~l2calib.train.env.CalibrationEnv.trajectory_share`).

    Returns:
        Per segment ``{"name", "reference": [M,3], "positions": [N,M,3]}`` (m), candidates in
        their order.
    """
    from l2calib.train.env import ScoringEnv

    if isinstance(env, ScoringEnv):  # in this process (or the driver of Ray actors)
        return env.trajectory_share(T_imu_lidar, time_offset_s, 1)
    n = env.num_workers
    shares = _started(env).trajectory_share(T_imu_lidar, time_offset_s, n)
    merged = []
    for j, first in enumerate(shares[0]):
        positions = np.empty((T_imu_lidar.shape[0], *first["positions"].shape[1:]))
        for i, share in enumerate(shares):
            if share:
                positions[i::n] = share[j]["positions"]
        merged.append(
            {"name": first["name"], "reference": first["reference"], "positions": positions}
        )
    return merged
