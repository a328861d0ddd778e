"""Smooth scalar signals with analytic derivatives, the building blocks of the motion profiles.

* :class:`Sines` — sums of sinusoids (value, first and second derivative).
* :class:`ActivityWindow` — a C³ 0/1 window that is exactly 0 during still periods, and its
  closed-form integral, which serves as the *motion clock* ``u(t)``: every moving quantity is a
  function of ``u``, so the rig is exactly at rest whenever the window is 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l2calib.errors import ConfigError


@dataclass(frozen=True)
class Sines:
    """``f(u) = sum_k A_k sin(w_k u + phi_k)``.

    Attributes:
        amp: ``[K]`` amplitudes.
        omega: ``[K]`` angular frequencies (rad per unit of ``u``).
        phase: ``[K]`` phases (rad).
    """

    amp: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        peak: float,
        freq_hz: tuple[float, float],
        terms: int = 3,
    ) -> Sines:
        """Random sum of ``terms`` sinusoids with ``sum |A_k| == peak`` (a hard bound on |f|)."""
        if peak <= 0 or terms == 0:
            z = np.zeros(0)
            return cls(z, z, z)
        w = rng.uniform(0.6, 1.4, size=terms)
        amp = peak * w / w.sum()
        freq = np.exp(rng.uniform(np.log(freq_hz[0]), np.log(freq_hz[1]), size=terms))
        return cls(amp, 2 * np.pi * freq, rng.uniform(0, 2 * np.pi, size=terms))

    def __call__(self, u: np.ndarray, order: int = 0) -> np.ndarray:
        """``order``-th derivative (0, 1 or 2) at ``u`` (``[N]`` -> ``[N]``)."""
        u = np.asarray(u, dtype=np.float64)
        if self.amp.size == 0:
            return np.zeros_like(u)
        arg = u[:, None] * self.omega + self.phase
        if order == 0:
            return np.sin(arg) @ self.amp
        if order == 1:
            return np.cos(arg) @ (self.amp * self.omega)
        if order == 2:
            return -np.sin(arg) @ (self.amp * self.omega**2)
        raise ValueError(f"order must be 0, 1 or 2, got {order}")


# Septic smoothstep S(x) = 35x^4 - 84x^5 + 70x^6 - 20x^7: S(0)=0, S(1)=1, C^3 at both ends.
def _step(x: np.ndarray) -> np.ndarray:
    return x**4 * (35 - 84 * x + 70 * x**2 - 20 * x**3)


def _step_d(x: np.ndarray) -> np.ndarray:
    return 140 * x**3 * (1 - x) ** 3


def _step_int(x: np.ndarray) -> np.ndarray:
    """Integral of S from 0 to x (equals 1/2 at x = 1)."""
    return x**5 * (7 - 14 * x + 10 * x**2 - 2.5 * x**3)


class ActivityWindow:
    """``W(t)`` in ``[0, 1]``: 0 during still periods, 1 while moving, C³ ramps in between.

    Args:
        still: Still periods ``[(start_s, end_s), ...]`` (time since the run start).
        ramp_s: Length of each ramp; ramps lie inside the moving periods.

    Raises:
        ConfigError: if a moving period is too short to hold its two ramps.
    """

    def __init__(self, still: list[tuple[float, float]], ramp_s: float = 1.0) -> None:
        self.ramp_s = T = float(ramp_s)
        moving: list[tuple[float, float]] = []
        cursor: float | None = None  # end of the last still period; None: moving since t < 0
        for a, b in sorted(still):
            if b <= a:
                raise ConfigError(
                    f"still segment ({a}, {b}) s ends before it starts",
                    fix="give still segments as [start, end] with end > start",
                )
            if a <= 0:  # still from the start
                cursor = max(cursor or 0.0, b)
                continue
            start = -T if cursor is None else cursor  # moving at t = 0: ramp lies before 0
            if a > start:
                moving.append((start, a))
            cursor = max(start, b)
        moving.append((-T if cursor is None else cursor, np.inf))
        for a, b in moving:
            if np.isfinite(b) and b - a < 2 * T:
                raise ConfigError(
                    f"moving period ({max(a, 0.0):.2f}, {b:.2f}) s before a still segment is "
                    f"shorter than its {T} s ramps",
                    fix=f"leave at least {2 * T:g} s of motion before each still segment",
                )
        self.moving = moving

    def _parts(self, t: np.ndarray, a: float, b: float) -> tuple[np.ndarray, ...]:
        T = self.ramp_s
        rise = (t >= a) & (t < a + T)
        fall = (t >= b - T) & (t < b) if np.isfinite(b) else np.zeros(t.shape, bool)
        full = (t >= a + T) & (t < b - T)
        return rise, fall, full

    def __call__(self, t: np.ndarray, order: int = 0) -> np.ndarray:
        """``W`` (order 0) or ``dW/dt`` (order 1) at times ``t`` (s)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros_like(t)
        T = self.ramp_s
        for a, b in self.moving:
            rise, fall, full = self._parts(t, a, b)
            if order == 0:
                out[full] = 1.0
                out[rise] = _step((t[rise] - a) / T)
                out[fall] = _step((b - t[fall]) / T)
            else:
                out[rise] = _step_d((t[rise] - a) / T) / T
                out[fall] = -_step_d((b - t[fall]) / T) / T
        return out

    def clock(self, t: np.ndarray) -> np.ndarray:
        """Motion clock ``u(t) = integral of W from 0 to t`` (s of motion), closed form."""
        t = np.asarray(t, dtype=np.float64)
        return self._integral(t) - self._integral(np.zeros(1))[0]

    def _integral(self, t: np.ndarray) -> np.ndarray:
        T = self.ramp_s
        out = np.zeros_like(t)
        for a_eff, b in self.moving:
            rise, fall, full = self._parts(t, a_eff, b)
            after = t >= b if np.isfinite(b) else np.zeros(t.shape, bool)
            out[rise] += T * _step_int((t[rise] - a_eff) / T)
            out[full] += T / 2 + (t[full] - a_eff - T)
            if np.isfinite(b):
                out[fall] += (b - a_eff - 1.5 * T) + T * (0.5 - _step_int((b - t[fall]) / T))
                out[after] += b - a_eff - T
        return out
