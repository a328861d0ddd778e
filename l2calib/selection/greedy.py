"""Choosing windows across sequences up to a time budget, filling the axes that lack excitation.

Greedy D-optimal design: the selection's information is the time-weighted sum of its windows'
second-moment matrices, normalised by the thresholds and the budget,
``I_r = Σ M_r·d / (min_gyro_rad_s² · budget_s)`` (likewise ``I_t``), and each step adds the
eligible window that most increases ``log det(I_r + εI) + log det(I_t + εI)`` (ε = 0.01). The log
determinant rewards adding excitation along weak directions far more than along strong ones,
so a window that turns about a missing axis beats a stronger one about an axis already covered.
Windows of the same sequence never overlap. Adjacent chosen windows merge into one span.

The final per-axis excitation is the RMS rate (rad/s) and acceleration (m/s²) per IMU axis over
the whole selection; an axis below the thresholds is *weak*, and so is the weakest eigen-direction
when it is not aligned with an axis.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass, field

import numpy as np

from l2calib.data import NS_PER_S, Segment, Sequence
from l2calib.recipe import SelectionConfig
from l2calib.selection.excitation import WindowStats, window_excitation
from l2calib.selection.gaps import gap_notes, no_window_reason

EPS = 0.01
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ChosenWindow:
    """One selected window.

    Attributes:
        sequence: Sequence name.
        start_ns, end_ns: Window bounds (ns).
        score: Normalised score (≥ 1: all axes above the thresholds).
        lambda_gyro: Min eigenvalue of the window's mean ω ωᵀ ((rad/s)²).
        lambda_accel: Min eigenvalue of its mean a aᵀ ((m/s²)²).
        gain: Increase of the selection objective when it was added.
    """

    sequence: str
    start_ns: int
    end_ns: int
    score: float
    lambda_gyro: float
    lambda_accel: float
    gain: float

    @property
    def duration_s(self) -> float:
        """Length (s)."""
        return (self.end_ns - self.start_ns) / NS_PER_S


@dataclass
class Selection:
    """Result of :func:`select_windows`.

    Attributes:
        chosen: Windows in the order they were chosen.
        windows: Per sequence, the excitation of every candidate window.
        gyro_rms_rad_s: ``[3]`` RMS angular rate per IMU axis over the selection.
        accel_rms_m_s2: ``[3]`` RMS gravity-free acceleration per IMU axis.
        gyro_weakest: ``(rms, [3] direction)`` of the weakest rotation direction.
        accel_weakest: ``(rms, [3] direction)`` of the weakest acceleration direction.
        weak_axes: Human-readable names of the weak axes/directions (empty: all excited).
        budget_s: Requested budget (s).
        notes: Things the user should know (budget not reached, shortened windows, ...).
    """

    chosen: list[ChosenWindow]
    windows: dict[str, WindowStats]
    gyro_rms_rad_s: np.ndarray
    accel_rms_m_s2: np.ndarray
    gyro_weakest: tuple[float, np.ndarray]
    accel_weakest: tuple[float, np.ndarray]
    weak_axes: list[str]
    budget_s: float
    config: SelectionConfig
    notes: list[str] = field(default_factory=list)

    @property
    def total_s(self) -> float:
        """Selected time (s)."""
        return float(sum(c.duration_s for c in self.chosen))

    def spans(self) -> list[tuple[str, int, int]]:
        """``(sequence, start_ns, end_ns)`` with adjacent/overlapping windows merged, sorted."""
        out: list[list] = []
        for c in sorted(self.chosen, key=lambda c: (c.sequence, c.start_ns)):
            if out and out[-1][0] == c.sequence and c.start_ns <= out[-1][2]:
                out[-1][2] = max(out[-1][2], c.end_ns)
            else:
                out.append([c.sequence, c.start_ns, c.end_ns])
        return [tuple(s) for s in out]

    def segments(self, sequences: Seq[Sequence]) -> list[Segment]:
        """Cuts the merged spans out of ``sequences`` (loads their scans)."""
        by_name = {s.name: s for s in sequences}
        return [by_name[name].segment(a, b) for name, a, b in self.spans()]

    def as_dict(self) -> dict:
        """JSON-serialisable summary."""
        return {
            "budget_s": self.budget_s,
            "total_s": self.total_s,
            "chosen": [
                {
                    "sequence": c.sequence,
                    "start_ns": c.start_ns,
                    "end_ns": c.end_ns,
                    "score": c.score,
                    "lambda_gyro": c.lambda_gyro,
                    "lambda_accel": c.lambda_accel,
                    "gain": c.gain,
                }
                for c in self.chosen
            ],
            "spans": [list(s) for s in self.spans()],
            "gyro_rms_rad_s": self.gyro_rms_rad_s.tolist(),
            "accel_rms_m_s2": self.accel_rms_m_s2.tolist(),
            "weak_axes": self.weak_axes,
            "notes": self.notes,
            "config": self.config.model_dump(),
        }


def _logdet(m: np.ndarray) -> np.ndarray:
    ev = np.linalg.eigvalsh(m)
    return np.sum(np.log(np.clip(ev, 0, None) + EPS), axis=-1)


def _weak(moment: np.ndarray, thr: float, kind: str) -> tuple[list[str], tuple]:
    rms = np.sqrt(np.clip(np.diag(moment), 0, None))
    names = [f"{kind} {AXES[i]}" for i in range(3) if rms[i] < thr]
    ev, vec = np.linalg.eigh(moment)
    weakest = (
        float(np.sqrt(max(ev[0], 0.0))),
        vec[:, 0] * np.sign(vec[np.argmax(np.abs(vec[:, 0])), 0]),
    )
    if weakest[0] < thr and np.max(np.abs(weakest[1])) < 0.9:
        d = ", ".join(f"{x:+.2f}" for x in weakest[1])
        names.append(f"{kind} the direction [{d}] (IMU frame)")
    return names, weakest


def _summary(
    chosen: list[ChosenWindow], stats: dict[str, WindowStats], cfg: SelectionConfig
) -> tuple[np.ndarray, np.ndarray, float]:
    gm, am, total = np.zeros((3, 3)), np.zeros((3, 3)), 0.0
    for c in chosen:
        ws = stats[c.sequence]
        k = int(np.flatnonzero(ws.start_ns == c.start_ns)[0])
        gm += ws.gyro_moment[k] * c.duration_s
        am += ws.accel_moment[k] * c.duration_s
        total += c.duration_s
    return (gm / total, am / total, total) if total > 0 else (gm, am, 0.0)


def select_windows(sequences: Seq[Sequence], config: SelectionConfig | None = None) -> Selection:
    """Scores windows of all sequences and picks them greedily up to ``config.budget_s``.

    With ``config.enabled = False`` every sequence's whole LiDAR–IMU overlap is chosen (and
    still reported). Sequences need only IMU samples and scan stamps.
    """
    cfg = config or SelectionConfig()
    notes: list[str] = []
    if cfg.enabled and cfg.budget_s < cfg.window_s:
        notes.append(f"window shortened to the budget ({cfg.budget_s:g} s)")
        cfg = SelectionConfig(**{**cfg.model_dump(), "window_s": cfg.budget_s})
    stats = {s.name: window_excitation(s, cfg) for s in sequences}
    notes += gap_notes(sequences, stats)
    if not cfg.enabled:
        whole = SelectionConfig(**{**cfg.model_dump(), "window_s": 1e9})
        stats = {s.name: window_excitation(s, whole) for s in sequences}
        chosen = [
            ChosenWindow(
                n,
                int(w.start_ns[0]),
                int(w.end_ns[0]),
                float(w.score[0]),
                float(w.lambda_gyro[0]),
                float(w.lambda_accel[0]),
                0.0,
            )
            for n, w in stats.items()
            if len(w)
        ]
        notes.append("selection disabled: whole sequences are used")
        return _finish(chosen, stats, cfg, notes)
    cand = [(n, k) for n, w in stats.items() for k in np.flatnonzero(w.eligible)]
    if not cand:
        notes.append("no eligible window: " + no_window_reason(sequences, stats, cfg.window_s))
        return _finish([], stats, cfg, notes)
    gms = np.stack([stats[n].gyro_moment[k] for n, k in cand])
    ams = np.stack([stats[n].accel_moment[k] for n, k in cand])
    dur = np.array([(stats[n].end_ns[k] - stats[n].start_ns[k]) / NS_PER_S for n, k in cand])
    starts = np.array([stats[n].start_ns[k] for n, k in cand])
    ends = np.array([stats[n].end_ns[k] for n, k in cand])
    seq_idx = np.array([list(stats).index(n) for n, _ in cand])
    if all(s.end_ns - s.start_ns < cfg.window_s * NS_PER_S for s in sequences):
        notes.append(f"windows shortened to {dur.max():.1f} s (sequences are shorter)")
    scale_g = 1.0 / (cfg.min_gyro_rad_s**2 * cfg.budget_s)
    scale_a = 1.0 / (cfg.min_accel_m_s2**2 * cfg.budget_s)
    info_g, info_a = np.zeros((3, 3)), np.zeros((3, 3))
    available = np.ones(len(cand), bool)
    chosen: list[ChosenWindow] = []
    total = 0.0
    base = _logdet(info_g) + _logdet(info_a)
    while available.any():
        fits = available & (total + dur <= cfg.budget_s + 1e-6)
        if not fits.any():
            break
        ig = info_g + gms * (dur * scale_g)[:, None, None]
        ia = info_a + ams * (dur * scale_a)[:, None, None]
        obj = np.where(fits, _logdet(ig) + _logdet(ia), -np.inf)
        j = int(np.argmax(obj))
        n, k = cand[j]
        w = stats[n]
        chosen.append(
            ChosenWindow(
                n,
                int(w.start_ns[k]),
                int(w.end_ns[k]),
                float(w.score[k]),
                float(w.lambda_gyro[k]),
                float(w.lambda_accel[k]),
                float(obj[j] - base),
            )
        )
        base = float(obj[j])
        info_g, info_a = ig[j], ia[j]
        total += dur[j]
        available &= ~((seq_idx == seq_idx[j]) & (starts < ends[j]) & (ends > starts[j]))
    if total < cfg.budget_s - cfg.window_s + 1e-6:
        notes.append(
            f"budget not reached: {total:.1f} s of {cfg.budget_s:.1f} s (not enough "
            "moving, gap-free data)"
        )
    return _finish(chosen, stats, cfg, notes)


def _finish(
    chosen: list[ChosenWindow],
    stats: dict[str, WindowStats],
    cfg: SelectionConfig,
    notes: list[str],
) -> Selection:
    gm, am, _ = _summary(chosen, stats, cfg)
    weak_g, g_weakest = _weak(gm, cfg.min_gyro_rad_s, "rotation about")
    weak_a, a_weakest = _weak(am, cfg.min_accel_m_s2, "acceleration along")
    if not chosen:
        weak_g, weak_a = (
            [f"rotation about {a}" for a in AXES],
            [f"acceleration along {a}" for a in AXES],
        )
    return Selection(
        chosen,
        stats,
        np.sqrt(np.clip(np.diag(gm), 0, None)),
        np.sqrt(np.clip(np.diag(am), 0, None)),
        g_weakest,
        a_weakest,
        weak_g + weak_a,
        cfg.budget_s,
        cfg,
        notes,
    )
