"""Building the calibration environment, in this process or spread over worker processes.

With ``workers > 1`` the K candidates of an iteration are split over a TorchRL ``ParallelEnv``;
each worker holds its own prepared backend. The policy still samples all K actions in the main
process, so a fixed seed gives the same candidates — and the same result — whatever the number
of workers.
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
    """A :class:`~l2calib.train.env.CalibrationEnv` (top-level so worker processes can build it)."""
    from l2calib.train.env import CalibrationEnv

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
    )


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

    ``hold``: the vertical lever-arm hold every worker applies (:mod:`l2calib.train.
    vertical_hold`), or ``None``.
    """
    K = recipe.train.candidates_per_iteration
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
    from l2calib.train.env import CalibrationEnv

    if isinstance(env, CalibrationEnv):
        return env.use_data_fraction(fraction)
    if not hasattr(env, "num_workers"):  # another ScoringEnv: always all of its data
        return 0
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
    from dataclasses import fields

    from l2calib.reward import RewardBreakdown
    from l2calib.train.env import CalibrationEnv

    if isinstance(env, CalibrationEnv):
        return env.score_candidates(T_imu_lidar, time_offset_s)[0]
    n = env.num_workers
    parts = [breakdown for breakdown, _ in _started(env).score_share(T_imu_lidar, time_offset_s, n)]
    merged = {}
    for f in fields(RewardBreakdown):
        first = getattr(parts[0], f.name)
        full = torch.empty(T_imu_lidar.shape[0], dtype=first.dtype)
        for i, part in enumerate(parts):
            full[i::n] = getattr(part, f.name)
        merged[f.name] = full
    return RewardBreakdown(**merged)


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
    from l2calib.train.env import CalibrationEnv

    if isinstance(env, CalibrationEnv):
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
