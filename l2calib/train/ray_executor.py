"""Scoring candidates on Ray actors (``train.executor: ray``).

Plain Ray actors behind the batch-scoring path the local workers use, not TorchRL's Ray
collector: the policy samples all K candidates of an iteration in the driver (so a seed gives
the same ``T_imu_lidar`` with any executor and any number of actors), and only the scoring —
seconds to minutes of odometry per candidate — is spread. TorchRL's ``RayCollector`` would run
whole collectors, each with its own copy of the policy, on the remote nodes: the candidates
would then depend on how many there are, and the refinement and the resolution probe (batches
of other sizes, outside any collector) would need a second path. See ``docs/scaling.md``.

Each actor holds one prepared odometry backend, built once from the selected segments and their
references, which are put into Ray's object store once and fetched by every node that runs an
actor: no path needs to be shared between the nodes, but every node needs l2calib (and the
backend plugin) installed. An actor that dies (node lost, out of memory, killed) is restarted by
Ray and its call retried (``max_restarts`` / ``max_task_retries``); the data fraction travels
with every call, so a restarted actor scores on the same part of the data and the run ends with
the same result.

Ray is an optional dependency: this module imports it only when an executor is built.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch

from l2calib.errors import ConfigError
from l2calib.recipe import Recipe
from l2calib.recipe_train import RayConfig
from l2calib.train.env import ScoringEnv, merge_block_shares, merge_shares

#: How often Ray restarts a dead actor, and retries the call it was running, before giving up.
ACTOR_RESTARTS = 4


def import_ray():
    """The ``ray`` module, or a :class:`ConfigError` saying how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise ConfigError(
            "train.executor=ray needs Ray, which is not installed",
            fix="pip install 'l2calib[ray]' (or set train.executor=local)",
        ) from exc
    return ray


def connect(config: RayConfig) -> bool:
    """Joins ``config.address`` (else ``RAY_ADDRESS``, else starts Ray here) unless joined.

    Returns:
        Whether this call started the connection (the caller then shuts it down when done).
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    address = config.address or os.environ.get("RAY_ADDRESS") or None
    try:
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    except ConnectionError as exc:
        raise ConfigError(
            f"cannot reach the Ray cluster at {address!r}: {exc}",
            fix="start it (ray start --head) or correct train.ray.address / RAY_ADDRESS",
        ) from exc
    return True


def resolve_actors(config: RayConfig, candidates: int) -> int:
    """``train.ray.actors`` as a count: ``auto`` = the cluster's CPUs / threads per actor.

    Never more than ``candidates`` (an actor without a candidate would idle) and at least 1.
    """
    if config.actors != "auto":
        return int(config.actors)
    cpus = int(import_ray().cluster_resources().get("CPU", 1))
    return max(1, min(candidates, cpus // config.threads_per_actor))


class ScoringActor:
    """One prepared backend on a Ray worker (made a Ray actor by :class:`RayScoringEnv`).

    Args:
        recipe_data: The recipe as JSON-able data.
        segments: The selected segments (fetched from the object store).
        references: One reference per segment.
        threads: Torch threads of this actor.
        hold: The vertical lever-arm hold, or ``None``.
    """

    def __init__(self, recipe_data, segments, references, threads: int, hold=None) -> None:
        from l2calib.train.env import make_env

        self.env = make_env(recipe_data, segments, references, 1, threads=threads, hold=hold)
        self.fraction, self.scans = 1.0, self.env.use_data_fraction(1.0)

    def _use(self, fraction: float) -> int:
        if fraction != self.fraction:
            self.fraction, self.scans = fraction, self.env.use_data_fraction(fraction)
        return self.scans

    def use_data_fraction(self, fraction: float) -> int:
        """As :meth:`~l2calib.train.env.CalibrationEnv.use_data_fraction`."""
        return self._use(fraction)

    def score(self, T_imu_lidar, time_offset_s, fraction: float):
        """Scores ``[k,4,4]`` candidates on ``fraction`` of the data: (breakdown, status)."""
        self._use(fraction)
        return self.env.score_candidates(T_imu_lidar, time_offset_s)

    def trajectories(self, T_imu_lidar, time_offset_s, fraction: float):
        """LiDAR positions of the candidates per segment (the report's previews)."""
        self._use(fraction)
        return self.env.trajectory_share(T_imu_lidar, time_offset_s, 1)

    def block_costs(self, T_imu_lidar, time_offset_s, fraction: float, block_s: float):
        """Pose cost of the candidates per block of data (the uncertainty estimate)."""
        self._use(fraction)
        return self.env.block_cost_share(T_imu_lidar, time_offset_s, 1, block_s)

    def pid(self) -> int:
        """The actor's process id (tests kill it to check the restart)."""
        return os.getpid()


class RayScoringEnv(ScoringEnv):
    """The calibration environment with its candidates scored by Ray actors.

    The driver's side of :class:`ScoringActor`: to the trainer it is one environment of batch
    ``[K]`` like :class:`~l2calib.train.env.CalibrationEnv`; each step (and each refinement or
    probe batch, of any size) is split over the actors, every ``n``-th candidate to one actor,
    and merged back in candidate order.

    Args:
        recipe: The recipe (``train.ray`` says where and how many actors).
        segments: The selected segments.
        references: One reference per segment.
        hold: The vertical lever-arm hold every actor applies, or ``None``.
    """

    def __init__(
        self,
        recipe: Recipe,
        segments: Sequence[Any],
        references: Sequence[Any],
        hold: Any | None = None,
    ) -> None:
        train = recipe.train
        super().__init__(train.candidates_per_iteration, 8 if train.estimate_time_offset else 7)
        ray = import_ray()
        self._owns_ray = connect(train.ray)
        threads = train.ray.threads_per_actor
        self.num_actors = resolve_actors(train.ray, train.candidates_per_iteration)
        actor_class = ray.remote(
            num_cpus=threads, max_restarts=ACTOR_RESTARTS, max_task_retries=ACTOR_RESTARTS
        )(ScoringActor)
        data = recipe.model_dump(mode="json")
        # Held for the env's life: a restarted actor is built again from the same objects.
        self._objects = ray.put(list(segments)), ray.put(list(references))
        self.actors = [
            actor_class.remote(data, *self._objects, threads, hold) for _ in range(self.num_actors)
        ]
        self.fraction = 1.0

    def _get(self, futures: list) -> list:
        return import_ray().get(futures)

    def use_data_fraction(self, fraction: float) -> int:
        """Every actor scores on ``fraction`` of the data from now on (waits for them).

        Returns:
            Scans each candidate is now estimated on.
        """
        self.fraction = float(fraction)
        counts = self._get([a.use_data_fraction.remote(self.fraction) for a in self.actors])
        return int(counts[0])

    def score_candidates(
        self, T_imu_lidar: torch.Tensor, time_offset_s: torch.Tensor | None = None
    ):
        """Scores ``[N,4,4]`` candidates (any ``N``) on the actors; (breakdown, ``[N]`` status)."""
        n = min(self.num_actors, T_imu_lidar.shape[0])
        futures = []
        for i in range(n):
            offsets = None if time_offset_s is None else time_offset_s[i::n]
            futures.append(self.actors[i].score.remote(T_imu_lidar[i::n], offsets, self.fraction))
        parts = self._get(futures)
        self.evaluations += int(T_imu_lidar.shape[0])
        breakdown = merge_shares([p[0] for p in parts], T_imu_lidar.shape[0])
        status = torch.empty(T_imu_lidar.shape[0], dtype=torch.int64)
        for i, (_, s) in enumerate(parts):
            status[i::n] = s
        return breakdown, status

    def trajectory_share(self, T_imu_lidar, time_offset_s, num_workers: int = 1):
        """The report's trajectories of a few candidates, run on the first actor."""
        future = self.actors[0].trajectories.remote(T_imu_lidar, time_offset_s, self.fraction)
        return self._get([future])[0]

    def block_cost_share(self, T_imu_lidar, time_offset_s, num_workers: int, block_s: float):
        """Pose costs per block of data, the candidates split over the actors.

        A :class:`~l2calib.train.env.BlockCosts` (see
        :meth:`~l2calib.train.env.CalibrationEnv.block_cost_share`).
        """
        n = min(self.num_actors, T_imu_lidar.shape[0])
        futures = []
        for i in range(n):
            offsets = None if time_offset_s is None else time_offset_s[i::n]
            futures.append(
                self.actors[i].block_costs.remote(
                    T_imu_lidar[i::n], offsets, self.fraction, block_s
                )
            )
        return merge_block_shares(self._get(futures), T_imu_lidar.shape[0])

    def terminate(self) -> None:
        """Kills the actors at once (an interrupted run: they may be mid-batch)."""
        ray = import_ray()
        for actor in getattr(self, "actors", []):
            ray.kill(actor, no_restart=True)
        self.actors = []
        if self._owns_ray:
            ray.shutdown()
            self._owns_ray = False

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Ends the actors (and the Ray connection when this env started it)."""
        self.terminate()
        super().close(raise_if_closed=raise_if_closed)
