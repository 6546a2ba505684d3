"""PID feedback on flow, over a batch of candidates.

``v = u_bias + kp e + I + D``, ``e = ref - meas`` (L/min), duty in %.

- Derivative on the measurement (no kick on reference steps), filtered by a
  first-order lag ``tf_s``: ``D(s) = -kd s / (tf_s s + 1) * meas``,
  discretized by backward Euler.
- Anti-windup by back-calculation: the integral moves by
  ``ki e dt + (dt / tt_s) (u - v)`` where ``u`` is the duty after clamp and
  rate limit; ``tt_s`` of one period is the clamped integral.
- ``u_bias`` is the feedforward duty (0 for PID alone); the limits act on the sum.
- Bumpless: :func:`transfer` sets the integral so that the law continues from
  the duty actually applied; :func:`resume` reseeds the derivative's memory
  with a fresh measurement (no derivative kick after a gap in the data).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from . import limits


@dataclass(frozen=True, eq=False)
class PIDParams:
    """Gains per candidate, all arrays of shape (B,).

    Attributes
    ----------
    kp : ndarray
        Proportional gain, % per L/min.
    ki : ndarray
        Integral gain, % per (L/min s).
    kd : ndarray
        Derivative gain, % s per L/min.
    tf_s : ndarray
        Derivative filter time constant, s (> 0).
    tt_s : ndarray
        Back-calculation tracking time constant, s (> 0).
    """

    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    tf_s: np.ndarray
    tt_s: np.ndarray

    @classmethod
    def make(cls, batch: int = 1, kp=0.0, ki=0.0, kd=0.0, tf_s=0.01, tt_s=0.05) -> "PIDParams":
        def col(v):
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (batch,)).copy()

        return cls(col(kp), col(ki), col(kd), col(tf_s), col(tt_s))


class PIDState(NamedTuple):
    """Integral term (%), filtered derivative term (%), previous measurement (L/min)."""

    integral_pct: np.ndarray
    deriv_pct: np.ndarray
    meas_prev_lpm: np.ndarray


def init(p: PIDParams, meas_lpm, integral_pct=0.0) -> PIDState:
    """State with the derivative memory at ``meas_lpm`` (no kick on the first step)."""
    b = p.kp.shape
    return PIDState(
        np.broadcast_to(np.asarray(integral_pct, dtype=np.float64), b).copy(),
        np.zeros(b),
        np.broadcast_to(np.asarray(meas_lpm, dtype=np.float64), b).copy(),
    )


@njit(cache=True, inline="always")
def update(kp, ki, kd, tf_s, tt_s, integral_pct, deriv_pct, meas_prev_lpm, ref_lpm, meas_lpm, dt_s, u_bias_pct,
           u_prev_pct, duty_min_pct, duty_max_pct, rate_pct_per_s):
    """One period of one candidate: ``(integral_pct, deriv_pct, u_pct)``, ``u`` after clamp and rate limit."""
    e = ref_lpm - meas_lpm
    d = (tf_s * deriv_pct - kd * (meas_lpm - meas_prev_lpm)) / (tf_s + dt_s)
    v = u_bias_pct + kp * e + integral_pct + d
    u = limits.limit(v, u_prev_pct, dt_s, duty_min_pct, duty_max_pct, rate_pct_per_s)
    # No integral action at all for ki = 0 (P, PD candidates), back-calculation otherwise.
    i = integral_pct + ki * e * dt_s + (dt_s / tt_s) * (u - v) if ki > 0 else 0.0
    return i, d, u


@njit(cache=True)
def _step(kp, ki, kd, tf, tt, i_in, d_in, m_in, ref, meas, dt_s, bias, u_prev, lo, hi, rate, i_out, d_out, u_out):
    for b in range(u_out.shape[0]):
        i_out[b], d_out[b], u_out[b] = update(kp[b], ki[b], kd[b], tf[b], tt[b], i_in[b], d_in[b], m_in[b], ref[b],
                                              meas[b], dt_s, bias[b], u_prev[b], lo[b], hi[b], rate[b])


def step(
    p: PIDParams,
    s: PIDState,
    ref_lpm: np.ndarray,
    meas_lpm: np.ndarray,
    dt_s: float,
    u_bias_pct: np.ndarray,
    u_prev_pct: np.ndarray,
    lim: limits.Limits,
) -> tuple[PIDState, np.ndarray]:
    """:func:`update` for every candidate (arrays of shape (B,)); returns the new state and the applied duty."""
    b = p.kp.shape

    def col(v):
        return np.broadcast_to(np.asarray(v, dtype=np.float64), b)

    new = PIDState(np.empty(b), np.empty(b), col(meas_lpm).copy())
    u = np.empty(b)
    _step(p.kp, p.ki, p.kd, p.tf_s, p.tt_s, *s, col(ref_lpm), col(meas_lpm), float(dt_s), col(u_bias_pct),
          col(u_prev_pct), lim.duty_min_pct, lim.duty_max_pct, lim.rate_pct_per_s, new.integral_pct, new.deriv_pct, u)
    return new, u


def output(p: PIDParams, s_before: PIDState, s_after: PIDState, ref_lpm, meas_lpm) -> np.ndarray:
    """The law's own output of the step from ``s_before`` to ``s_after``: ``kp e + I + D``, % (before the limits)."""
    return p.kp * (ref_lpm - meas_lpm) + s_before.integral_pct + s_after.deriv_pct


def transfer(p: PIDParams, s: PIDState, ref_lpm, meas_lpm, u_bias_pct, u_applied_pct) -> PIDState:
    """Bumpless switch into this law: the integral absorbs what P, D and the bias do not give."""
    e = np.asarray(ref_lpm, dtype=np.float64) - meas_lpm
    i = np.where(p.ki > 0, u_applied_pct - u_bias_pct - p.kp * e - s.deriv_pct, 0.0)
    return PIDState(i, s.deriv_pct, np.broadcast_to(meas_lpm, p.kp.shape).astype(np.float64))


def resume(s: PIDState, meas_lpm) -> PIDState:
    """After a gap in the measurements: integral held, derivative memory reseeded."""
    return PIDState(s.integral_pct, np.zeros_like(s.deriv_pct),
                    np.broadcast_to(meas_lpm, s.deriv_pct.shape).astype(np.float64))
