"""Inverse-PI feedforward, reference flow -> duty, over a batch of candidates.

A :class:`PIBank` is a Prandtl-Ishlinskii operator bank per candidate in
physical units: the forward model (duty -> flow, Eq. 1 and 4) or its
closed-form inverse (flow -> duty, Eq. 5-7), taken from a model file
(:func:`models.model.load_model`).

The model is only known on its identified ranges (the scalings' [-1, 1]).
The operators see the input clipped to that range, as the simulated valve's
do; below it the valve is taken as linear with the range's average gain
(flow half-range over duty half-range) down to no flow (never reverse
flow), and above it as saturated (the inverse never asks for more than the
top of the range). A reference of zero flow or less closes the valve (0 %). The feedforward is the inverse bank fed
with the reference flow; the Kalman feedback also runs the forward bank on the
applied duty to know what flow the model expects.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from models import play
from models.model import FittedModel


@dataclass(frozen=True, eq=False)
class PIBank:
    """A PI operator bank per candidate, physical units in and out.

    Attributes
    ----------
    r : ndarray, shape (B, n)
        Thresholds in normalized input units (Eq. 2 forward, Eq. 7 inverse).
    w : ndarray, shape (B, n)
        Weights (Eq. 4 forward, Eq. 7 inverse).
    offset : ndarray, shape (B,)
        Output offset of the forward model, normalized output units. The
        inverse subtracts it from its input first; the forward adds it.
    in_center, in_half : ndarray, shape (B,)
        Input scaling, ``u = (x - center) / half`` (duty % forward, L/min inverse).
    out_center, out_half : ndarray, shape (B,)
        Output scaling back to physical units.
    x0 : ndarray, shape (B, n)
        Operator memory before the first sample (``y_i0`` of Eq. 3, ``x_i'(0)`` of Eq. 7).
    inverse : bool
        True for the inverse bank (offset removed from the input).
    lo_gain : ndarray, shape (B,)
        Below the identified input range, output change per input change
        (the range's average gain; its reciprocal for the inverse).
    """

    r: np.ndarray
    w: np.ndarray
    offset: np.ndarray
    in_center: np.ndarray
    in_half: np.ndarray
    out_center: np.ndarray
    out_half: np.ndarray
    x0: np.ndarray
    inverse: bool
    lo_gain: np.ndarray

    @property
    def batch(self) -> int:
        return self.r.shape[0]


def _bank(core, in_scale, out_scale, x0, inverse: bool, batch: int) -> PIBank:
    def rows(v):
        return np.tile(np.asarray(v, dtype=np.float64), (batch, 1))

    def col(v):
        return np.full(batch, float(v))

    return PIBank(
        r=rows(core.r), w=rows(core.w), offset=col(core.offset),
        in_center=col(in_scale.center), in_half=col(in_scale.half_range),
        out_center=col(out_scale.center), out_half=col(out_scale.half_range),
        x0=rows(x0), inverse=inverse, lo_gain=col(out_scale.half_range / in_scale.half_range),
    )


def inverse_bank(model: FittedModel, batch: int = 1) -> PIBank:
    """The model's closed-form inverse PI (flow L/min -> duty %), repeated ``batch`` times."""
    if model.inverse is None:
        raise ValueError(f"model kind {model.kind!r} has no inverse; feedforward needs a PI model")
    inv = model.inverse
    return _bank(inv, model.y_scale, model.x_scale, inv.x0, True, batch)


def forward_bank(model: FittedModel, batch: int = 1) -> PIBank:
    """The model's forward PI (duty % -> flow L/min), repeated ``batch`` times."""
    return _bank(model.core, model.x_scale, model.y_scale, model.core.y0, False, batch)


def stack(banks: list[PIBank]) -> PIBank:
    """One bank holding the candidates of several (same number of operators)."""
    f = {k: np.concatenate([getattr(b, k) for b in banks]) for k in
         ("r", "w", "offset", "in_center", "in_half", "out_center", "out_half", "x0", "lo_gain")}
    return PIBank(**f, inverse=banks[0].inverse)


def _unit_input(bank: PIBank, x: np.ndarray) -> np.ndarray:
    u = np.minimum(np.maximum((x - bank.in_center) / bank.in_half, -1.0), 1.0)
    return u - bank.offset if bank.inverse else u


def _physical_output(bank: PIBank, s: np.ndarray, x: np.ndarray) -> np.ndarray:
    y = (bank.w * s).sum(axis=1)
    if not bank.inverse:
        y = y + bank.offset
    below = np.minimum(x - (bank.in_center - bank.in_half), 0.0)
    y = y * bank.out_half + bank.out_center + bank.lo_gain * below
    if bank.inverse:
        return np.where(x > 0.0, y, 0.0)  # no flow asked: the valve closed
    return np.maximum(y, 0.0)  # no reverse flow through a closed valve


def init(bank: PIBank, x0) -> np.ndarray:
    """Operator states at the first input ``x0`` (shape (B,) or scalar), Eq. (3)."""
    u = np.broadcast_to(_unit_input(bank, x0), (bank.batch,))
    return play.init(bank.r, u[:, None], bank.x0)


def step(bank: PIBank, state: np.ndarray, x) -> tuple[np.ndarray, np.ndarray]:
    """One sample for every candidate: Eq. (1)/(5) on the bank, then Eq. (4)/(6).

    Parameters
    ----------
    x : ndarray, shape (B,)
        Input in physical units (reference flow L/min for the inverse bank,
        duty % for the forward bank).

    Returns
    -------
    state : ndarray, shape (B, n)
    y : ndarray, shape (B,)
        Output in physical units (duty % from the inverse bank).
    """
    s = play.step(bank.r, state, _unit_input(bank, x)[:, None])
    return s, _physical_output(bank, s, x)



def inverse_state_from_forward(inv: PIBank, fwd: PIBank, fwd_state: np.ndarray) -> np.ndarray:
    """Inverse operator memory consistent with the forward bank's memory, Eq. (7) last line.

    ``x_i' = sum_{j<i} w_j y_i + sum_{j>=i} w_j y_j`` per candidate (axis 1),
    with ``w`` the forward weights and ``y`` the forward operator outputs. With
    it ``forward(inverse(y)) == y`` from the next sample on, whatever duty the
    limits actually let through before.
    """
    w = fwd.w
    head = np.cumsum(w, axis=1) - w  # sum_{j<i} w_j
    tail = np.cumsum((w * fwd_state)[:, ::-1], axis=1)[:, ::-1]  # sum_{j>=i} w_j y_j
    return head * fwd_state + tail


@dataclass(frozen=True, eq=False)
class LeadParams:
    """Inversion of the valve's first-order lag for the feedforward, per candidate.

    ``F(s) = (lead_s s + 1) / (lag_s s + 1)`` on the flow reference before the
    inverse PI: the valve is a static hysteresis followed by a lag
    ``1 / (tau s + 1)`` (a Hammerstein model), so ``lead_s = tau`` cancels
    the lag and ``lag_s`` (a few ms) keeps the inversion proper and bounds
    its gain on steps to ``lead_s / lag_s``. ``lead_s = 0`` and ``lag_s = 0``
    is the identity.

    Attributes
    ----------
    lead_s, lag_s : ndarray, shape (B,)
        Time constants, s.
    """

    lead_s: np.ndarray
    lag_s: np.ndarray

    @classmethod
    def make(cls, batch: int = 1, lead_s=0.0, lag_s=0.0) -> "LeadParams":
        def col(v):
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (batch,)).copy()

        return cls(col(lead_s), col(lag_s))


class LeadState(NamedTuple):
    ref_prev_lpm: np.ndarray
    out_prev_lpm: np.ndarray


def lead_init(p: LeadParams, ref0_lpm) -> LeadState:
    """At rest at ``ref0_lpm``."""
    r = np.broadcast_to(np.asarray(ref0_lpm, dtype=np.float64), p.lead_s.shape).copy()
    return LeadState(r, r.copy())


def lead_step(p: LeadParams, s: LeadState, ref_lpm: np.ndarray, dt_s: float) -> tuple[LeadState, np.ndarray]:
    """One period of ``F(s)`` by backward Euler: ``lag (y - y') / dt + y = lead (r - r') / dt + r``."""
    y = (p.lag_s * s.out_prev_lpm + p.lead_s * (ref_lpm - s.ref_prev_lpm) + dt_s * ref_lpm) / (p.lag_s + dt_s)
    return LeadState(ref_lpm, y), y
