"""The actuator limits every controller shares: duty clamp and duty rate limit."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True, eq=False)
class Limits:
    """Duty limits per candidate.

    Attributes
    ----------
    duty_min_pct, duty_max_pct : ndarray, shape (B,)
        Output clamp, % (the valve takes 0-100 %).
    rate_pct_per_s : ndarray, shape (B,)
        Largest duty change per second, %/s (``inf`` for none). Spares the
        coil and the plunger the full-scale jumps a noisy derivative or a
        reference step would ask for.
    """

    duty_min_pct: np.ndarray
    duty_max_pct: np.ndarray
    rate_pct_per_s: np.ndarray

    @classmethod
    def make(cls, batch: int = 1, duty_min_pct=0.0, duty_max_pct=100.0, rate_pct_per_s=np.inf) -> "Limits":
        def col(v):
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (batch,)).copy()

        return cls(col(duty_min_pct), col(duty_max_pct), col(rate_pct_per_s))


@njit(cache=True, inline="always")
def maximum(a, b):
    """``np.maximum`` of two floats: NaN propagates, a tie keeps ``a``."""
    return a if (a >= b or a != a) else b


@njit(cache=True, inline="always")
def minimum(a, b):
    """``np.minimum`` of two floats: NaN propagates, a tie keeps ``a``."""
    return a if (a <= b or a != a) else b


@njit(cache=True, inline="always")
def limit(u_pct, u_prev_pct, dt_s, duty_min_pct, duty_max_pct, rate_pct_per_s):
    """One candidate: rate limit against the previous duty, then clamp to [min, max] (the clamp wins)."""
    step = rate_pct_per_s * dt_s
    u = minimum(maximum(u_pct, u_prev_pct - step), u_prev_pct + step)
    return minimum(maximum(u, duty_min_pct), duty_max_pct)


@njit(cache=True)
def _apply(u_pct, u_prev_pct, dt_s, lo, hi, rate, out):
    for b in range(out.shape[0]):
        out[b] = limit(u_pct[b], u_prev_pct[b], dt_s, lo[b], hi[b], rate[b])


def apply(lim: Limits, u_pct: np.ndarray, u_prev_pct: np.ndarray, dt_s: float) -> np.ndarray:
    """:func:`limit` for every candidate (arrays of shape (B,))."""
    b = lim.duty_min_pct.shape
    out = np.empty(b)
    _apply(*(np.broadcast_to(np.asarray(v, dtype=np.float64), b) for v in (u_pct, u_prev_pct)), float(dt_s),
           lim.duty_min_pct, lim.duty_max_pct, lim.rate_pct_per_s, out)
    return out
