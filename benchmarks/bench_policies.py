"""Policies: normaliser accuracy, sampler throughput/acceptance, log_prob+backward, PPO toy curves.

Run: ``python -m benchmarks.bench_policies [--seeds 3] [--iterations 200]``; prints a table and
writes ``benchmarks/results/policies.json`` and ``benchmarks/results/policies_ppo_toy.png``
(rotation/translation error of the policy mode per PPO iteration, Bingham vs Gaussian).
Targets: log N within 1e-6 of scipy over z ∈ [-1e5, 0]³, sampling ≥ 100k samples/s, PPO toy
(Bingham) within 1° of the optimum. Timings are best-of-N on whatever CPU share is available.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import matplotlib
import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info
from l2calib.geometry import euler_rpy_to_matrix, matrix_to_quat, quat_normalize
from l2calib_policies.bingham import Bingham
from l2calib_policies.normaliser import bingham_log_normaliser
from l2calib_policies.toy import run_toy_ppo

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RESULTS = Path(__file__).parent / "results"
F64 = torch.float64
SAMPLER_CASES = [
    (0.0, 0.0, 0.0),
    (-1.0, -5.0, -20.0),
    (-100.0, -100.0, -1e4),
    (-1e5, -3.0, 0.0),
    (-1e5, -1e5, -1e5),
    (-6.6e3, -6.6e3, -6.6e3),
    (820.0, -3.0, -5.8),
]
#: PPO toy variants: label -> (plugin, options).
VARIANTS = {
    "bingham": ("bingham", {}),
    "bingham z<=0 (paper)": ("bingham", {"allow_positive_concentration": False}),
    "gaussian": ("gaussian", {}),
}


def _best_of(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def normaliser_accuracy() -> dict:
    import sys

    sys.path.insert(0, str(Path(__file__).parents[1] / "tests" / "policies"))
    from test_normaliser import scipy_log_normaliser  # the tests' scipy reference

    grid = [0.0, -1e-3, -0.1, -1.0, -10.0, -100.0, -1e3, -1e4, -1e5, -1e6]
    zs = list(itertools.combinations_with_replacement(grid, 3))
    rng = np.random.default_rng(0)
    zs += [tuple(r) for r in -(10.0 ** rng.uniform(-4, 5, size=(200, 3)))]
    ours = bingham_log_normaliser(torch.tensor(zs, dtype=F64)).numpy()
    ref = np.array([scipy_log_normaliser(z) for z in zs])
    rel = np.abs(np.expm1(ours - ref))
    # Gradient vs central finite differences (relative step).
    z = torch.tensor(-(10.0 ** rng.uniform(-2, 5, size=(50, 3))), dtype=F64, requires_grad=True)
    (grad,) = torch.autograd.grad(bingham_log_normaliser(z).sum(), z)
    fd = torch.zeros_like(grad)
    with torch.no_grad():
        for i in range(3):
            h = 1e-6 * z[:, i].abs().clamp_min(1.0)
            dz = torch.zeros_like(z)
            dz[:, i] = h
            fd[:, i] = (bingham_log_normaliser(z + dz) - bingham_log_normaliser(z - dz)) / (2 * h)
    grad_rel = ((grad - fd).abs() / grad.abs().clamp_min(1e-300)).max().item()
    zb = torch.tensor(-(10.0 ** rng.uniform(-3, 5, size=(1000, 3))), dtype=F64)
    t = _best_of(lambda: bingham_log_normaliser(zb), 5)
    return {
        "cases": len(zs),
        "max_rel_err_vs_scipy": float(rel.max()),
        "worst_z": list(zs[int(rel.argmax())]),
        "grad_max_rel_err_vs_fd": grad_rel,
        "time_batch1000_ms": 1e3 * t,
    }


def sampler() -> list[dict]:
    rows = []
    q0 = quat_normalize(torch.tensor([0.3, -0.2, 0.5, 0.8], dtype=F64))
    n = 200_000
    for z in SAMPLER_CASES:
        d = Bingham(q0, torch.tensor(z, dtype=F64))
        torch.manual_seed(0)
        t = _best_of(lambda d=d: d.sample((n,)))
        y = d.body_coordinates(d.sample((n,)))
        mom_err = ((y[:, :3] ** 2).mean(0) / d.second_moments() - 1).abs().max().item()
        rows.append(
            {
                "z": list(z),
                "samples_per_s": n / t,
                "acceptance": d.last_acceptance_rate,
                "moment_rel_err": mom_err,
            }
        )
    return rows


def log_prob_backward() -> dict:
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(1000, 4, dtype=F64, generator=gen).requires_grad_()
    raw = torch.randn(1000, 3, dtype=F64, generator=gen).requires_grad_()
    x = Bingham(q.detach(), -torch.exp(raw.detach())).sample()

    def lp_only():  # the metric: log_prob + backward, 1000 different distributions
        Bingham(q, -torch.exp(raw)).log_prob(x).sum().backward()

    def with_entropy():  # what a PPO step needs (log_prob and entropy bonus), worst case
        d = Bingham(q, -torch.exp(raw))
        (d.log_prob(x).sum() + d.entropy().sum()).backward()

    q1 = q[:1].detach().clone().requires_grad_()
    r1 = raw[:1].detach().clone().requires_grad_()

    def shared():  # one distribution broadcast over 1000 actions (what the actor produces)
        d = Bingham(q1.expand(1000, 4), (-torch.exp(r1)).expand(1000, 3))
        (d.log_prob(x).sum() + d.entropy().sum()).backward()

    return {
        "log_prob_backward_ms": 1e3 * _best_of(lp_only, 5),
        "log_prob_entropy_backward_ms": 1e3 * _best_of(with_entropy, 5),
        "shared_params_log_prob_entropy_backward_ms": 1e3 * _best_of(shared, 5),
    }


def ppo_curves(seeds: int, iterations: int) -> dict:
    q_star = matrix_to_quat(
        euler_rpy_to_matrix(torch.deg2rad(torch.tensor([180.0, 90.0, 0.0], dtype=F64)))
    )
    t_star = torch.tensor([0.650, -0.372, -0.016], dtype=F64)
    out = {}
    for name, (plugin, options) in VARIANTS.items():
        runs = []
        for seed in range(seeds):
            t = time.perf_counter()
            h = run_toy_ppo(
                plugin, q_star, t_star, iterations=iterations, seed=seed, options=options
            )
            runs.append(
                {
                    "seed": seed,
                    "seconds": time.perf_counter() - t,
                    "rotation_error_deg": h.rotation_error_deg,
                    "translation_error_m": h.translation_error_m,
                    "mean_reward": h.mean_reward,
                    "rotation_sigma_deg": h.rotation_sigma_deg,
                }
            )
        out[name] = runs
    return out


def plot(curves: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    colours = dict(zip(VARIANTS, ["tab:blue", "tab:green", "tab:orange"], strict=True))
    styles = dict(zip(VARIANTS, ["-", ":", "-"], strict=True))
    for name, runs in curves.items():
        for i, r in enumerate(runs):
            kw = {
                "color": colours[name],
                "ls": styles[name],
                "alpha": 0.8,
                "lw": 1.2,
                "label": name if i == 0 else None,
            }
            axes[0].semilogy(np.maximum(r["rotation_error_deg"], 1e-3), **kw)
            axes[1].semilogy(np.maximum(r["translation_error_m"], 1e-5), **kw)
            axes[2].plot(r["mean_reward"], **kw)
    axes[0].axhline(1.0, color="k", ls="--", lw=0.8)
    axes[0].set_ylabel("rotation error of the mode (deg)")
    axes[1].set_ylabel("translation error of the mode (m)")
    axes[2].set_ylabel("mean reward of the sampled candidates")
    for ax in axes:
        ax.set_xlabel("PPO iteration (32 candidates, 4 epochs)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(
        "PPO on a toy reward with known optimum (rpy 180°, 90°, 0°), from no initial guess"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch intra-op threads (1 is fastest for these small ops)",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    RESULTS.mkdir(parents=True, exist_ok=True)
    console = Console()

    acc = normaliser_accuracy()
    samp = sampler()
    lpb = log_prob_backward()
    curves = ppo_curves(args.seeds, args.iterations)
    png = RESULTS / "policies_ppo_toy.png"
    plot(curves, png)

    table = Table(title="l2calib-policies")
    table.add_column("metric")
    table.add_column("value", justify="right")
    table.add_column("target", justify="right")
    table.add_row(
        f"log N vs scipy, max rel. error ({acc['cases']} z, to -1e6)",
        f"{acc['max_rel_err_vs_scipy']:.1e}",
        "≤ 1e-6",
    )
    table.add_row("∂log N/∂z vs finite diff., max rel.", f"{acc['grad_max_rel_err_vs_fd']:.1e}", "")
    table.add_row("log N, batch 1000", f"{acc['time_batch1000_ms']:.1f} ms", "")
    for r in samp:
        table.add_row(
            f"sample z={tuple(r['z'])}",
            f"{r['samples_per_s'] / 1e3:.0f}k/s, acc {r['acceptance']:.2f}, "
            f"mom {100 * r['moment_rel_err']:.2f}%",
            "≥ 100k/s, ≤ 2%",
        )
    table.add_row(
        "log_prob+backward, batch 1000 (distinct params)",
        f"{lpb['log_prob_backward_ms']:.1f} ms",
        "",
    )
    table.add_row(
        "log_prob+entropy+backward, 1000 distinct",
        f"{lpb['log_prob_entropy_backward_ms']:.1f} ms",
        "",
    )
    table.add_row(
        "log_prob+entropy+backward, 1000 shared (actor)",
        f"{lpb['shared_params_log_prob_entropy_backward_ms']:.1f} ms",
        "",
    )
    for name, runs in curves.items():
        finals = [float(np.mean(r["rotation_error_deg"][-10:])) for r in runs]
        tfin = [float(np.mean(r["translation_error_m"][-10:])) for r in runs]
        first = [
            next((i for i, e in enumerate(r["rotation_error_deg"]) if e < 1.0), None) for r in runs
        ]
        secs = [r["seconds"] for r in runs]
        table.add_row(
            f"PPO toy {name}: rot err (last 10 it.)",
            ", ".join(f"{f:.2f}°" for f in finals),
            "< 1°" if name == "bingham" else "",
        )
        table.add_row(
            f"PPO toy {name}: trans err / 1st it. < 1° / time",
            ", ".join(
                f"{t * 100:.2f} cm/{i}/{s:.0f}s" for t, i, s in zip(tfin, first, secs, strict=True)
            ),
            "",
        )
    console.print(table)

    out = {
        "machine": machine_info(),
        "torch_threads": torch.get_num_threads(),
        "normaliser": acc,
        "sampler": samp,
        "log_prob_backward": lpb,
        "ppo_toy": curves,
        "plot": str(png.relative_to(Path(__file__).parents[1])),
    }
    (RESULTS / "policies.json").write_text(json.dumps(out, indent=1))
    console.print(f"wrote {RESULTS / 'policies.json'} and {png}")


if __name__ == "__main__":
    main()
