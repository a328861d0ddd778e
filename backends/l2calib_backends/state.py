"""Batched error-state of the IEKF: K candidate filters advanced in lock-step.

Nominal state per candidate: ``R_world_imu`` (3×3), ``p_world_imu``, ``v_world_imu`` (m/s), gyro
bias ``bg`` (rad/s), accel bias ``ba`` (m/s²) and gravity ``g_world`` (m/s²). The 18-dim error
state is ordered ``[δθ, δp, δv, δbg, δba, δg]``; rotation errors are right perturbations,
``R = R̂ Exp(δθ)``, as in FAST-LIO.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from l2calib import geometry as geo

DIM = 18
TH, POS, VEL, BG, BA, GRAV = (slice(i, i + 3) for i in range(0, 18, 3))


@dataclass
class FilterState:
    """Nominal states ``[K, ...]`` and covariances ``P [K, 18, 18]`` (float64)."""

    R: Tensor
    p: Tensor
    v: Tensor
    bg: Tensor
    ba: Tensor
    g: Tensor
    P: Tensor

    @property
    def num(self) -> int:
        """K, the number of candidates."""
        return int(self.R.shape[0])

    def boxplus(self, dx: Tensor) -> FilterState:
        """``x ⊞ dx`` for ``dx [K, 18]`` (covariance unchanged)."""
        return replace(
            self,
            R=self.R @ geo.so3_exp(dx[:, TH]),
            p=self.p + dx[:, POS],
            v=self.v + dx[:, VEL],
            bg=self.bg + dx[:, BG],
            ba=self.ba + dx[:, BA],
            g=self.g + dx[:, GRAV],
        )

    def boxminus(self, other: FilterState) -> Tensor:
        """``self ⊟ other`` as ``[K, 18]``."""
        return torch.cat(
            [
                geo.so3_log(other.R.transpose(-1, -2) @ self.R),
                self.p - other.p,
                self.v - other.v,
                self.bg - other.bg,
                self.ba - other.ba,
                self.g - other.g,
            ],
            dim=-1,
        )

    def where(self, mask: Tensor, other: FilterState) -> FilterState:
        """Per-candidate select: ``self`` where ``mask [K]`` is True, else ``other``."""
        out = {}
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            m = mask.view(-1, *([1] * (a.dim() - 1)))
            out[f.name] = torch.where(m, a, b)
        return FilterState(**out)

    def is_finite(self) -> Tensor:
        """``[K]`` True where every quantity is finite."""
        ok = torch.ones(self.num, dtype=torch.bool, device=self.R.device)
        for f in fields(self):
            x = getattr(self, f.name)
            ok &= torch.isfinite(x.reshape(self.num, -1)).all(dim=-1)
        return ok
