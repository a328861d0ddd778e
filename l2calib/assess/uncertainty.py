"""Per-axis uncertainty of the calibrated extrinsic: a 95 % bound per LiDAR axis, from the data.

The resolution probe (:mod:`l2calib.assess.sensitivity`) says how far one must move along an
axis before the reward drops by a fixed fraction; that is a property of the reward's shape, not
of the error, and it was 5–10× wider than the true errors (issue 25). This module estimates the
error itself. Around the result ``θ̂`` the odometry runs on the Newton polish's stencil (centre,
± each axis, ±± each pair: 73 candidates, 99 with the time offset; :func:`l2calib.assess.polish.
stencil`), and the reward's pose errors are summed per scan into a cost
``C(θ) = Σ_k c_k(θ)``, ``c_k = e_t,k / 4 + e_r,k / π²`` (m, rad: the paper reward's terms before
their means and square roots), and per block of :data:`BLOCK_S` seconds of each segment. With
the Hessian ``H`` of ``C`` and each block's gradient ``g_b`` (central differences), the bound
on axis ``i`` is

    bound95_i = |step_i| + sqrt( (t₉₇.₅,B−1 · σ_noise,i)² + σ_misfit,i² + r_i² )

* ``σ_noise``: the data's noise, a block sandwich ``H⁻¹ M H⁻¹`` with
  ``M = B/(B−1) Σ (g_b − ḡ)(g_b − ḡ)ᵀ`` — how far the minimum would move on other data like
  these, with the errors' correlation within a block kept (a Student-t quantile: few blocks);
* ``step``: the Newton step ``−H⁻¹ Σ g_b`` — how far the cost's own minimum lies from the result
  (where the search stopped). It is a known displacement, not a random one, so it adds to the
  rest rather than in quadrature;
* ``σ_misfit``: ``sqrt(2 C(θ̂)/S · τ · (H⁻¹)_ii)`` over ``S`` scans — the standard error of a
  least-squares fit whose per-scan residuals ``sqrt(c_k)`` have the size observed and the
  integrated autocorrelation time ``τ`` (scans) measured at the result
  (:func:`correlation_time`): ``S/τ`` independent residuals. A bias every block shares (the
  odometry's own model error, a reference's drift) moves the minimum of every block alike,
  which the sandwich cannot see; this term grows with how badly the best extrinsic still fits
  and with how slowly its misfit varies (a drift: τ 4.3–9.7 scans on the simulated ground
  vehicle and UAV, 1.0–4.2 on hand-held runs; ~21 where a search was trapped off the truth;
  ``benchmarks/results/uncertainty.json``).

* ``r``: the reference's own error, where the reference brings a second estimate of itself
  (:attr:`~l2calib.interfaces.ReferenceTrajectory.alternative`; ``ct-lidar``'s backward pass:
  the forward pass alone). The cost's minimum is found again against the alternative, from
  the same odometry runs (``shift = −H⁻¹ Σ (g_alt,b − g_b)``), and ``r = z₉₇.₅ · |shift|``.
  Were the two passes' errors independent and alike, the forward pass would differ from their
  average by as much as the average differs from the truth, so ``shift`` is one draw of the
  reference error's effect on the result, taken as its standard deviation. An error both passes
  share is not seen. 0 where there is no alternative (hand-held runs, exact references).

Directions along which ``C`` does not curve up (relative eigenvalue of ``H`` in stencil units
below :data:`FLAT_RTOL`, or negative) carry no information: an axis that lies mostly in them is
**flat** and gets an infinite bound. Measured against the true error on every stored benchmark
calibration by ``python -m benchmarks.bench_uncertainty`` (``docs/design.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from l2calib.assess.polish import STEPS, derivatives, moved, stencil
from l2calib.selection.planar import ONE_WAY_SHARE

__all__ = [
    "BLOCK_S", "AxisUncertainty", "block_index", "candidates", "correlation_time", "estimate",
    "reference_caveats", "undetermined",
]  # fmt: skip

#: Length of the blocks whose gradients measure the data's noise (s).
BLOCK_S = 2.0
#: Relative eigenvalue of the stencil-scaled Hessian below which a direction counts as flat.
FLAT_RTOL = 1e-4
#: Axis names in the order of the stencil's axes.
AXIS_NAMES = (
    "rotation about LiDAR x", "rotation about LiDAR y", "rotation about LiDAR z",
    "translation along LiDAR x", "translation along LiDAR y", "translation along LiDAR z",
    "time offset",
)  # fmt: skip
#: What motion determines each axis (rotations of the rig about the LiDAR's axes).
REMEDY = (
    "turns about the LiDAR's y and z axes", "turns about the LiDAR's x and z axes",
    "turns about the LiDAR's x and y axes", "rotation about the LiDAR's y and z axes",
    "rotation about the LiDAR's x and z axes", "rotation about the LiDAR's x and y axes",
    "faster rotations (a quick swing or turn)",
)  # fmt: skip


@dataclass
class AxisUncertainty:
    """Per-axis 95 % bounds on the error of the calibration (``inf``: flat, not determined).

    Axes: rotation about LiDAR x, y, z (rad), translation along LiDAR x, y, z (m), and the time
    offset (s) when it was estimated. Every array is ``[n]`` in that order and those units.

    Attributes:
        bound95: The 95 % bound (module docstring).
        noise95: Its data-noise part (``t · σ_noise``).
        step: Distance to the cost's own minimum along each axis (signed).
        misfit: Its model-misfit part (``σ_misfit``).
        reference95: Its reference-error part (``r``; zeros without an alternative reference).
        flat: Axes along which the cost does not curve up.
        blocks: Blocks of data the noise was measured on; ``scans``: scans in the cost.
        cost: ``C(θ̂)``, the summed pose cost at the result.
        tau: The residuals' integrated autocorrelation time at the result (scans).
        evaluations: Odometry runs it took (set by the caller).
        limits: Rotation (deg), translation (m) and time-offset (s) bounds beyond which an
            axis is undetermined, as the caller judged it (``train.uncertainty``), or ``None``.
        held: The translation axis held rather than estimated (the ground vehicle's vertical
            lever arm): left out of the fit, ``inf`` bound, not judged by :func:`undetermined`.
        caveats: What the bounds are known not to cover on this data (set by the caller:
            :func:`reference_caveats`).
    """

    bound95: np.ndarray
    noise95: np.ndarray
    step: np.ndarray
    misfit: np.ndarray
    flat: np.ndarray
    blocks: int
    scans: int
    cost: float
    held: list[int] = field(default_factory=list)
    tau: float = 1.0
    reference95: np.ndarray | None = None
    evaluations: int = 0
    limits: tuple[float, float, float] | None = None
    caveats: list[str] = field(default_factory=list)

    @property
    def rotation_deg(self) -> list[float]:
        """Bounds about LiDAR x, y, z (deg)."""
        return [math.degrees(float(v)) for v in self.bound95[:3]]

    @property
    def translation_m(self) -> list[float]:
        """Bounds along LiDAR x, y, z (m)."""
        return [float(v) for v in self.bound95[3:6]]

    @property
    def time_offset_s(self) -> float | None:
        """Bound on the time offset (s), ``None`` when it was not estimated."""
        return float(self.bound95[6]) if len(self.bound95) > 6 else None


def candidates(
    T_imu_lidar: torch.Tensor, time_offset_s: float | None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The stencil around the result: ``[P, 4, 4]`` extrinsics and ``[P]`` offsets (s) or None.

    Six axes, or seven with the time offset when ``time_offset_s`` is not ``None``.
    """
    n = 6 if time_offset_s is None else 7
    d = stencil(n)
    T = moved(torch.as_tensor(T_imu_lidar, dtype=torch.float64), d)
    if time_offset_s is None:
        return T, None
    return T, torch.as_tensor(time_offset_s + d[:, 6], dtype=torch.float64)


def block_index(stamps_s: np.ndarray, block_s: float = BLOCK_S) -> np.ndarray:
    """Block of each scan of one segment (``[N]`` ints from 0): ``block_s`` from the first scan.

    A short last block (under half the first's scans) joins the one before; blocks a gap in
    the scans left empty are not counted (the numbers stay consecutive).
    """
    t = np.asarray(stamps_s, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=int)
    b = np.unique(np.floor((t - t[0]) / block_s).astype(int), return_inverse=True)[1].ravel()
    last = int(b.max())
    if last > 0 and (b == last).sum() < (b == 0).sum() / 2:
        b[b == last] = last - 1
    return b


def correlation_time(series: list[np.ndarray], window: float = 5.0) -> float:
    """Integrated autocorrelation time ``τ`` (scans) of the residuals ``sqrt(c_k)`` at the result.

    ``τ = 1 + 2 Σ_{l=1..M} ρ_l`` per segment, with Sokal's automatic window (the smallest ``M``
    with ``M ≥ window · τ(M)``), averaged over the segments weighted by their scans; at least 1.
    Written here (an FFT autocorrelation) because the libraries at hand (scipy, statsmodels is
    not a dependency) give the autocorrelation, not the windowed sum.

    Args:
        series: Per segment, ``[S_i]`` per-scan costs ``c_k`` in time order.
        window: Sokal's window factor (5: the usual choice for a positive autocorrelation).
    """
    taus, weights = [], []
    for c in series:
        r = np.sqrt(np.clip(np.asarray(c, dtype=np.float64), 0, None))
        n = len(r)
        r = r - r.mean() if n else r
        if n < 4 or not np.any(r):
            continue
        f = np.fft.rfft(r, 2 * n)
        rho = np.fft.irfft(f * np.conj(f))[:n]
        tau_m = 1.0 + 2.0 * np.cumsum(rho[1:] / rho[0])  # τ with the window at m = 1, 2, …
        inside = np.flatnonzero(np.arange(1, n) >= window * tau_m)
        tau = float(tau_m[inside[0]] if inside.size else tau_m[-1])
        taus.append(max(tau, 1.0))
        weights.append(n)
    return float(np.average(taus, weights=weights)) if taus else 1.0


def estimate(
    block_costs: np.ndarray,
    scans: int,
    held_axis: int | None = None,
    tau: float = 1.0,
    alternative_costs: np.ndarray | None = None,
) -> AxisUncertainty:
    """The per-axis bounds from the stencil's block costs (module docstring).

    Args:
        block_costs: ``[P, B]`` cost of each :func:`candidates` candidate on each block.
        scans: Scans that entered the cost (``S``).
        tau: The residuals' integrated autocorrelation time at the result (scans;
            :func:`correlation_time`), which divides ``S`` in the misfit term.
        held_axis: The translation axis (3, 4 or 5) held rather than estimated (the ground
            vehicle's vertical lever arm), or ``None``. It is left out of the fit (its moves are
            undone by the hold, up to a tilt's leak) and reported with an infinite bound, in
            ``held``, not judged.
        alternative_costs: ``[P, B]`` the same against the reference's alternative (the
            reference-error term ``r``), or ``None``.
    """
    from scipy import stats

    C = np.asarray(block_costs, dtype=np.float64)
    P, B = C.shape
    n = 6 if P == len(stencil(6)) else 7
    g_all, H_all = derivatives(C, n)
    keep_axes = [i for i in range(n) if i != held_axis]
    g, H = g_all[keep_axes], H_all[np.ix_(keep_axes, keep_axes)]
    h = np.array(STEPS[:n])[keep_axes]
    values, vectors = np.linalg.eigh(H * np.outer(h, h))  # stencil units: axes compare
    keep = values > FLAT_RTOL * max(float(values.max()), 1e-300)
    flat = (vectors[:, keep] ** 2).sum(1) < 0.5
    Hi = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T * np.outer(h, h)
    gc = g - g.mean(1, keepdims=True)
    noise_cov = Hi @ (B / max(B - 1, 1) * gc @ gc.T) @ Hi
    q = float(stats.t.ppf(0.975, max(B - 1, 1)))
    cost = float(C[0].sum())

    def full(sub: np.ndarray, fill: float) -> np.ndarray:
        out = np.full(n, fill, dtype=sub.dtype)
        out[keep_axes] = sub
        return out

    noise95 = full(q * np.sqrt(np.clip(np.diag(noise_cov), 0, None)), 0.0)
    step = full(-Hi @ g.sum(1), 0.0)
    tau = max(float(tau), 1.0)
    misfit = full(np.sqrt(2 * cost * tau / max(scans, 1) * np.clip(np.diag(Hi), 0, None)), 0.0)
    reference95 = np.zeros(n)
    if alternative_costs is not None:
        g_alt = derivatives(np.asarray(alternative_costs, dtype=np.float64), n)[0][keep_axes]
        shift = -Hi @ (g_alt - g).sum(1)
        reference95 = full(float(stats.norm.ppf(0.975)) * np.abs(shift), 0.0)
    flat = full(flat, True)
    bound = np.abs(step) + np.sqrt(noise95**2 + misfit**2 + reference95**2)
    bound[flat] = np.inf
    held = [] if held_axis is None else [held_axis]
    return AxisUncertainty(
        bound, noise95, step, misfit, flat, B, int(scans), cost, held, tau=tau,
        reference95=reference95,
    )  # fmt: skip


def reference_caveats(
    unc: AxisUncertainty, drives: int, one_way_share: float | None = None
) -> list[str]:
    """What the bounds miss on one drive from a LiDAR-only reference (issue 27), or nothing.

    On planar motion (a held vertical axis) the horizontal lever arm rests on the drive's few
    turns, and a LiDAR-only reference's drift over them moves the result in a way the data cannot
    tell from the lever arm. ``r`` (the reference's two passes) sees the part of that error the
    passes disagree on, not the part they share: on the simulator's one-drive runs the lateral
    error was outside its bound on all six 16-beam runs (1.9–2.4 cm against 1.5–1.6 cm), inside
    on the 32-beam and the three-drive runs (``benchmarks/results/uncertainty.json``).

    A drive whose turns all go one way (a loop) adds up any reference error that follows the
    turning, like a lateral lever arm: on the simulator's loops, driven the other way round,
    the LiDAR-only reference's share of the reward's lateral peak changed sign (+2.3 → −2.0 cm on
    the VLP-16 drive, +1.0 → −1.1 cm on the OS1-16 drive; docs/backends.md, "Not loop closure"),
    so the caveat then says so. On a figure-8 drive (the simulator's ``world.route=figure-8``,
    turning both ways and twice as much) the same LiDARs calibrated to within 1.4 cm along x
    and y on four drives (one-way loops: 1.6–3.0 cm off, either way round, with the general
    motion prior; with ``ct-lidar``'s vehicle prior since 2026-12-07 three of four within 1.3 cm
    and the OS1-16's counter-clockwise loop 2.3 cm off; docs/backends.md, "Both ways", and
    docs/references.md, "The vehicle prior").

    Args:
        unc: The bounds; the caveat needs a held axis and a reference term (``reference95``).
        drives: Recordings the segments come from.
        one_way_share: :attr:`~l2calib.selection.planar.PlanarMotion.one_way_share` of the
            selected data (``None``: unknown).
    """
    ref = unc.reference95
    if not unc.held or ref is None or not np.any(ref[3:6] > 0) or drives != 1:
        return []
    one_way = ""
    if one_way_share is not None and one_way_share >= ONE_WAY_SHARE:
        one_way = (
            f"; and the turns all go one way ({100 * one_way_share:.0f} % of the turning): a "
            "reference error that follows the turning adds up like a lateral lever arm (on "
            "simulated loops driven the other way round, the reference moved the reward's "
            "lateral peak the other way, by 1-2 cm), so a drive that also turns the other way "
            "helps (simulated 16-beam figure-8 drives: x and y within 1.4 cm on four drives, "
            "one-way loops up to 2.4 cm off; the figure-8s also turn twice as much)"
        )
    return [
        "one drive and a LiDAR-only reference: the horizontal lever arm rests on the drive's "
        "few turns and on the reference's drift over them, and the part of that drift both of "
        "the reference's passes share is not in these bounds (simulated 16-beam loops: lateral "
        "errors up to 2.4 cm against bounds of 1.2-1.6 cm; 32-beam drives and three 60 s drives "
        "together stayed inside); calibrate two or three drives together, or use an exact "
        f"reference (gt-file, rtk){one_way}"
    ]


def undetermined(
    unc: AxisUncertainty, rot_limit_deg: float, trans_limit_m: float, offset_limit_s: float
) -> list[str]:
    """Axes whose 95 % bound exceeds its limit or whose cost is flat, with the motion to fix it."""
    limits = [math.radians(rot_limit_deg)] * 3 + [trans_limit_m] * 3 + [offset_limit_s]
    out = []
    for i, b in enumerate(unc.bound95):
        if i in unc.held or not (unc.flat[i] or b > limits[i]):
            continue
        if unc.flat[i]:
            size = "the reward is flat along it"
        elif i < 3:
            size = f"±{math.degrees(b):.2f} deg at 95 % (limit {rot_limit_deg:g})"
        elif i < 6:
            size = f"±{100 * b:.1f} cm at 95 % (limit {100 * trans_limit_m:g})"
        else:
            size = f"±{1000 * b:.1f} ms at 95 % (limit {1000 * offset_limit_s:g})"
        out.append(f"{AXIS_NAMES[i]}: {size}; {REMEDY[i]} would determine it")
    return out
