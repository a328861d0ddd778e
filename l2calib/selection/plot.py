"""Timeline plot of a selection: window scores, still blocks, gaps and the chosen windows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from l2calib.data import NS_PER_S
from l2calib.selection.greedy import Selection


def plot_selection(selection: Selection, path: str | Path) -> Path:
    """Saves a PNG with one row per sequence.

    Each row shows, at window centres, ``√λ_min`` of the gyro (rad/s) and of the gravity-free
    acceleration (m/s²) divided by their thresholds (log scale; 1 = threshold), grey bands for
    still blocks, red bands for windows that contain gaps, and green bands for chosen windows
    (numbered in the order they were chosen).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = selection.config
    names = list(selection.windows)
    fig, axes = plt.subplots(
        max(len(names), 1), 1, figsize=(11, 2.4 * max(len(names), 1) + 0.6), squeeze=False
    )
    order = {(c.sequence, c.start_ns): i + 1 for i, c in enumerate(selection.chosen)}
    for ax, name in zip(axes[:, 0], names, strict=False):
        w = selection.windows[name]
        t0 = int(w.block_start_ns[0]) if len(w.block_start_ns) else 0
        step = cfg.step_s

        def rel(ns: np.ndarray | int, t0: int = t0) -> np.ndarray:
            return (np.asarray(ns, dtype=np.int64) - t0) / NS_PER_S

        if len(w):
            mid = rel((w.start_ns + w.end_ns) // 2)
            rg = np.sqrt(w.lambda_gyro) / cfg.min_gyro_rad_s
            ra = np.sqrt(w.lambda_accel) / cfg.min_accel_m_s2
            ax.semilogy(
                mid, np.clip(rg, 1e-3, None), label="rotation √λ_min / threshold", color="tab:blue"
            )
            ax.semilogy(
                mid,
                np.clip(ra, 1e-3, None),
                label="acceleration √λ_min / threshold",
                color="tab:orange",
            )
            for k in np.flatnonzero(w.gap):
                ax.axvspan(rel(w.start_ns[k]), rel(w.end_ns[k]), color="tab:red", alpha=0.04)
        for b in np.flatnonzero(w.block_still):
            x = rel(w.block_start_ns[b])
            ax.axvspan(x, x + step, color="0.6", alpha=0.5, lw=0)
        for c in selection.chosen:
            if c.sequence == name:
                ax.axvspan(rel(c.start_ns), rel(c.end_ns), color="tab:green", alpha=0.25)
                ax.text(
                    rel(c.start_ns),
                    1.02,
                    f"#{order[(c.sequence, c.start_ns)]}",
                    transform=ax.get_xaxis_transform(),
                    fontsize=8,
                    color="tab:green",
                )
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_title(name, fontsize=10, loc="left")
        ax.set_ylabel("excitation")
        ax.grid(True, which="both", alpha=0.2)
    axes[-1, 0].set_xlabel("time in sequence (s); grey: still, green: chosen, red: gap")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    weak = ", ".join(selection.weak_axes) or "none"
    fig.suptitle(
        f"selection {selection.total_s:.0f} s of {selection.budget_s:.0f} s; weak: {weak}",
        fontsize=10,
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
