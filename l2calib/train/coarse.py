"""Coarse-to-fine training data: how much of the selected data an iteration scores on.

While the policy samples tens of degrees and centimetres wide, a part of the data already ranks
its candidates; the full data is needed only once the policy is narrow. The fraction follows the
policy's spread (not the iteration count), so a slow run stays coarse only while it is wide:

``u = clip(log(σ / σ_fine) / log(σ_coarse / σ_fine), 0, 1)`` per kind (rotation, translation),
the larger of the two decides, and the fraction is ``f_min + (1 - f_min)·(1 - u)``: all the data
once every σ is at or below its ``fine`` level, ``train.coarse_data_fraction`` at or above
``coarse``. Which part is used is the backend's choice, the same for every candidate of an
iteration (:meth:`~l2calib.interfaces.OdometryBackend.use_data_fraction`, sent to every worker
by :func:`l2calib.train.env_build.set_data_fraction`).
"""

from __future__ import annotations

import math

from l2calib.interfaces import PolicySpread
from l2calib.recipe import TrainConfig


def _coarseness(sigma: float, fine: float, coarse: float) -> float:
    """0 at or below ``fine``, 1 at or above ``coarse``, log-linear between."""
    if sigma <= fine:
        return 0.0
    return min(1.0, math.log(sigma / fine) / math.log(coarse / fine))


def data_fraction(spread: PolicySpread, cfg: TrainConfig) -> float:
    """The fraction (0–1] of the data to score the next iteration on (module docstring)."""
    if not cfg.coarse_to_fine:
        return 1.0
    u_r = _coarseness(
        float(spread.rotation_sigma_deg.max()),
        cfg.fine_rotation_sigma_deg,
        cfg.coarse_rotation_sigma_deg,
    )
    u_t = _coarseness(
        float(spread.translation_sigma_m.max()),
        cfg.fine_translation_sigma_m,
        cfg.coarse_translation_sigma_m,
    )
    f_min = cfg.coarse_data_fraction
    return f_min + (1.0 - f_min) * (1.0 - max(u_r, u_t))
