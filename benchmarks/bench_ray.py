"""Scoring on Ray actors: measured cost per batch and per iteration, and a scaling model (issue 24).

Run: ``python -m benchmarks.bench_ray [--case handheld] [--repeats 3]`` (``--render`` only
rewrites the markdown from the JSON).

Measured on this machine, on the :mod:`benchmarks.bench_calibration` case's selected data (all
of it, the exact LiDAR trajectory as reference):

* the cost of scoring a batch of ``k`` candidates in one process, ``k`` = 1 … K (the backend
  runs a batch as one vectorised filter bank, so the cost is ``a + b·k``, fitted);
* one training iteration's scoring (K candidates) locally in one process, and on 1 and 2 Ray
  actors of one thread each (a local Ray instance), and the actors' start (odometry preparation);
* from these, the Ray overhead per iteration ``o`` = Ray time − local time of the largest share.

The model — a model, extrapolated from 1–2 actors on 2 cores, not a measurement on a cluster —
is ``t_iter(n) = a + b·ceil(K/n) + o`` for ``n`` actors on ``n`` CPUs, printed for 1–64 actors.
Beyond ``n = K`` nothing more is gained (one candidate per actor). Results:
``benchmarks/results/ray.json`` and ``ray.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path
from typing import Any

import torch

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "ray.json"
MODEL_ACTORS = (1, 2, 4, 8, 16, 32, 64)


def _candidates(K: int, seed: int = 0) -> torch.Tensor:
    """``[K,4,4]`` perturbations of ~2° / 3 cm (applied to the truth: a late iteration)."""
    from l2calib import geometry as geo

    g = torch.Generator().manual_seed(seed)
    T = torch.eye(4, dtype=torch.float64).repeat(K, 1, 1)
    T[:, :3, :3] = geo.so3_exp(0.035 * torch.randn(K, 3, generator=g, dtype=torch.float64))
    T[:, :3, 3] = 0.03 * torch.randn(K, 3, generator=g, dtype=torch.float64)
    return T


def _time(fn, repeats: int) -> float:
    """Median wall time (s) of ``fn()`` over ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(case: str, repeats: int) -> dict[str, Any]:
    """The measurements of the module docstring."""
    import ray

    from benchmarks.bench_calibration import exact_reference_env
    from l2calib.train.env_build import score_batch
    from l2calib.train.ray_executor import RayScoringEnv

    torch.set_num_threads(1)
    env, runs, data, recipe = exact_reference_env(case)
    K = recipe.train.candidates_per_iteration
    T_true = torch.from_numpy(runs[0].T_imu_lidar)
    T = T_true[None] @ _candidates(K)
    sizes = sorted({1, 2, 4, 8, 16, K})
    score_batch(env, T[:2])  # warm-up: the first call fills caches (reference samples, maps)
    batch_s = {k: _time(lambda k=k: score_batch(env, T[:k]), repeats) for k in sizes}
    n = len(sizes)
    mean_k = sum(sizes) / n
    mean_t = sum(batch_s.values()) / n
    b = sum((k - mean_k) * (batch_s[k] - mean_t) for k in sizes) / sum(
        (k - mean_k) ** 2 for k in sizes
    )
    a = mean_t - b * mean_k
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    actors: dict[int, dict[str, float]] = {}
    try:
        for count in (1, 2):
            cfg = recipe.model_copy(deep=True)
            cfg.train.executor, cfg.train.ray.actors = "ray", count
            t0 = time.perf_counter()
            remote = RayScoringEnv(cfg, data.segments, data.references)
            remote.use_data_fraction(1.0)  # waits for every actor's preparation
            start_s = time.perf_counter() - t0
            score_batch(remote, T[: 2 * count])  # warm-up, as above
            iteration_s = _time(lambda r=remote: score_batch(r, T), repeats)
            share = batch_s.get(math.ceil(K / count)) or (a + b * math.ceil(K / count))
            actors[count] = {
                "start_s": start_s, "iteration_s": iteration_s, "overhead_s": iteration_s - share
            }  # fmt: skip
            remote.close()
    finally:
        ray.shutdown()
    overhead = max(0.0, statistics.mean(v["overhead_s"] for v in actors.values()))
    model = {m: a + b * math.ceil(K / m) + overhead for m in MODEL_ACTORS}
    return {
        "case": case,
        "candidates_per_iteration": K,
        "scans_per_candidate": int(env.use_data_fraction(1.0)),
        "batch_s": {str(k): v for k, v in batch_s.items()},
        "fit": {"a_s": a, "b_s_per_candidate": b},
        "local_iteration_s": batch_s[K],
        "ray": {str(k): v for k, v in actors.items()},
        "overhead_s": overhead,
        "model_iteration_s": {str(k): v for k, v in model.items()},
        "repeats": repeats,
        "machine": machine_info(),
    }


def render(r: dict[str, Any]) -> str:
    """The markdown of one result."""
    m, K = r["machine"], r["candidates_per_iteration"]
    lines = [
        "# Scoring on Ray (benchmarks/bench_ray.py)\n",
        f"Case `{r['case']}`: K = {K} candidates per iteration, {r['scans_per_candidate']} scans "
        f"each; {m['cores']} cores, {m['cpu']}, load {m['load'][0]:.1f}; medians of "
        f"{r['repeats']}.\n",
        "| measured | s |",
        "|---|---|",
    ]
    for k, v in r["batch_s"].items():
        lines.append(f"| one process, batch of {k} | {v:.2f} |")
    for k, v in r["ray"].items():
        lines.append(f"| {k} Ray actor(s): start (preparation) | {v['start_s']:.1f} |")
        lines.append(
            f"| {k} Ray actor(s): one iteration ({K} candidates) | {v['iteration_s']:.2f} |"
        )
    fit = r["fit"]
    lines += [
        f"\nFit: batch cost = {fit['a_s']:.2f} s + {fit['b_s_per_candidate']:.3f} s × k; Ray "
        f"overhead per iteration {r['overhead_s']:.2f} s.\n",
        "**Model** (extrapolated, not measured on a cluster): t_iter(n) = a + b·ceil(K/n) + o "
        "for n actors on n CPUs.\n",
        "| actors | model s / iteration | speed-up vs 1 |",
        "|---|---|---|",
    ]
    one = r["model_iteration_s"]["1"]
    for n, t in r["model_iteration_s"].items():
        lines.append(f"| {n} | {t:.2f} | {one / t:.1f}× |")
    return "\n".join(lines) + "\n"


def main() -> None:
    """Measures, writes JSON and markdown, prints the markdown."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="handheld")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--render", action="store_true")
    args = parser.parse_args()
    if args.render:
        args.out.with_suffix(".md").write_text(render(json.loads(args.out.read_text())))
        return
    torch.set_default_dtype(torch.float64)
    result = run(args.case, args.repeats)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    args.out.with_suffix(".md").write_text(render(result))
    print(render(result))


if __name__ == "__main__":
    main()
