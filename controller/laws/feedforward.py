"""Model-inverse feedforward, reference flow -> duty, over a batch of candidates.

A :class:`ModelBank` holds, per candidate, an invertible hysteresis model in
physical units, taken from a model file (:func:`models.model.load_model`) of
any invertible kind: ``pi`` (Eq. 1-4 forward, Eq. 5-7 inverse), ``pi-asym``
(generalized play operators; inverse solved per sample to rounding,
:mod:`models.pi_asym`), ``pi-mod`` (either play operators, then a
dead-zone superposition inverted in closed form; the plays' inverse as
above, :mod:`models.pi_mod`) or ``preisach`` (relays; the input whose
switched relays give the level nearest the reference, found in O(relays)
per step, :func:`models.preisach.solve_input`). The PI family runs the one
play operator of :mod:`models.play` and the one inverse of
:func:`models.pi_mod.solve`.

Interface (what the control laws call; arrays of shape (B,)):

- :func:`init` ``(bank, duty0) -> memory``: the valve's operator memory at rest;
- :func:`step` ``(bank, memory, duty) -> (memory, flow)``: the forward model
  driven by the duty actually applied (the model flow the Kalman filter needs);
- :func:`invert` ``(bank, memory, ref) -> duty``: the feedforward, the duty
  that takes the model from its present memory to the reference flow, without
  changing the memory (so the duty clamp and rate limit leave no hysteresis
  mismatch behind: the memory only ever follows the applied duty).

The model is only known on its identified ranges (the scalings' [-1, 1]).
The operators see the duty clipped to that range, as the simulated valve's
do; below it the valve is taken as linear with the range's average gain
(flow half-range over duty half-range) down to no flow (never reverse
flow), and above it as saturated (the inverse never asks for more than the
top of the range).

No flow asked (a reference of 0 L/min or less): the feedforward returns the
*ready* duty, ``ready_margin_pct`` below the duty at which the model starts
to pass flow from its present memory (the cracking duty of the present
branch). The valve stays closed but ready, so the next breath does not wait
for the plunger to cross the dead zone; 0 % (valve closed, memory wiped) is
the loop's safe state, not the feedforward's answer.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from models import pi_asym, pi_mod, play, preisach
from models.model import FittedModel

#: Kinds the feedforward inverts, and how: closed form (Eq. 7 family), plays solved per sample
#: (a ``pi-mod`` with generalized plays, ``a > 0``, too) or Preisach relays.
INVERTIBLE = {"pi": 0, "pi-mod": 0, "pi-asym": 1, "preisach": 2}
#: Default gap between the ready duty and the cracking duty, %.
READY_MARGIN_PCT = 2.0


@dataclass(frozen=True, eq=False)
class ModelBank:
    """An invertible model per candidate, physical units in and out (normalized-unit arrays inside).

    Attributes
    ----------
    method : ndarray of int, shape (B,)
        0: closed-form inverse (``pi``, ``pi-mod`` with ``a = 0``); 1: solved per sample (``pi-asym``,
        ``pi-mod`` with ``a > 0``); 2: Preisach relays.
    r, w : ndarray, shape (B, n)
        Play thresholds and weights (Eq. 2, Eq. 4); for relays, their up-switching levels
        ``alpha`` and weights ``mu``.
    a, p : ndarray, shape (B,)
        Descending-threshold envelope of ``pi-asym`` and ``pi-mod`` (``a = 0``: Eq. 1).
    h, g : ndarray, shape (B, k)
        Dead-zone superposition on the play output (``pi-mod``; ``[0], [1]``: identity).
    offset, floor : ndarray, shape (B,)
        Output offset and the closed flow (``-inf`` when the kind has none), normalized.
    r_inv, w_inv : ndarray, shape (B, n)
        Eq. (7) inverse thresholds and weights (unused for method 1).
    h_inv, g_inv : ndarray, shape (B, k)
        Inverse dead-zone superposition.
    closed : ndarray, shape (B,)
        Normalized flow at or below which the model's valve is closed (``-inf``: none).
    x0 : ndarray, shape (B, n)
        Operator memory before the first sample (``y_i0`` of Eq. 3; NaN: at rest).
    duty_center, duty_half, flow_center, flow_half : ndarray, shape (B,)
        Scalings, ``u = (x - center) / half``.
    ready_margin_pct : ndarray, shape (B,)
        Ready duty below the cracking duty, % (see the module docstring).
    beta : ndarray, shape (B, n) or (B, 0)
        Relays' down-switching levels (method 2; none for the PI family).
    """

    method: np.ndarray
    r: np.ndarray
    w: np.ndarray
    a: np.ndarray
    p: np.ndarray
    h: np.ndarray
    g: np.ndarray
    offset: np.ndarray
    floor: np.ndarray
    r_inv: np.ndarray
    w_inv: np.ndarray
    h_inv: np.ndarray
    g_inv: np.ndarray
    closed: np.ndarray
    x0: np.ndarray
    duty_center: np.ndarray
    duty_half: np.ndarray
    flow_center: np.ndarray
    flow_half: np.ndarray
    ready_margin_pct: np.ndarray
    beta: np.ndarray

    @property
    def batch(self) -> int:
        return self.r.shape[0]

    @functools.cached_property
    def arrays(self) -> tuple:
        """The fields as one tuple, in field order: what the compiled kernels take."""
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self))


def bank(model: FittedModel, batch: int = 1, ready_margin_pct: float = READY_MARGIN_PCT) -> ModelBank:
    """The model (forward and inverse) of an invertible kind, repeated ``batch`` times."""
    if model.kind not in INVERTIBLE:
        raise ValueError(f"model kind {model.kind!r} has no inverse for feedforward "
                         f"(one of {', '.join(INVERTIBLE)})")
    core = model.core
    if model.kind == "preisach":  # relays: up-switching levels and weights where the plays keep theirs
        core.inverse()  # refused when a relay weight is negative
        r, w, beta = core.alpha, core.mu, core.beta
    else:
        r, w, beta = core.r, core.w, np.zeros(0)
    n = len(r)
    ident_h, ident_g = np.zeros(1), np.ones(1)
    a, p, floor, closed = 0.0, 1.0, -np.inf, -np.inf
    h, g, h_inv, g_inv = ident_h, ident_g, ident_h, ident_g
    r_inv, w_inv, x0 = np.zeros(n), np.zeros(n), np.full(n, np.nan)
    method = INVERTIBLE[model.kind]
    if model.kind == "pi-asym":
        a, p = core.a, core.p
    elif model.kind != "preisach":
        x0 = core.y0
        inv = model.inverse if model.inverse is not None else core.inverse()
        if model.kind == "pi":
            r_inv, w_inv = inv.r, inv.w
        else:
            r_inv, w_inv, h_inv, g_inv = inv.r_inv, inv.w_inv, inv.h_inv, inv.g_inv
            h, g, floor, closed, a, p = core.h, core.g, core.floor, inv.closed, core.a, core.p
            method = 0 if core.exact else 1

    def rows(v):
        return np.tile(np.asarray(v, dtype=np.float64), (batch, 1))

    def col(v):
        return np.full(batch, float(v))

    xs, ys = model.x_scale, model.y_scale
    return ModelBank(
        method=np.full(batch, method, dtype=np.int64), r=rows(r), w=rows(w),
        a=col(a), p=col(p), h=rows(h), g=rows(g), offset=col(core.offset), floor=col(floor),
        r_inv=rows(r_inv), w_inv=rows(w_inv), h_inv=rows(h_inv), g_inv=rows(g_inv), closed=col(closed),
        x0=rows(x0), duty_center=col(xs.center), duty_half=col(xs.half_range), flow_center=col(ys.center),
        flow_half=col(ys.half_range), ready_margin_pct=col(ready_margin_pct), beta=rows(beta),
    )


def stack(banks: list[ModelBank]) -> ModelBank:
    """One bank holding the candidates of several (same numbers of operators)."""
    return ModelBank(**{f.name: np.concatenate([getattr(b, f.name) for b in banks])
                        for f in dataclasses.fields(ModelBank)})


def init(bank: ModelBank, duty0_pct) -> np.ndarray:
    """Operator memory at the first duty (shape (B,) or scalar), Eq. (3); relays relaxed there."""
    d = np.broadcast_to(np.asarray(duty0_pct, dtype=np.float64), (bank.batch,))
    u = np.clip((d - bank.duty_center) / bank.duty_half, -1.0, 1.0)
    memory = play.init(bank.r, u[:, None], bank.x0)
    for j in np.flatnonzero(bank.method == 2):
        memory[j] = preisach.relaxed_state(bank.r[j], bank.beta[j], u[j])
    return memory


@njit(cache=True, inline="always")
def _forward(bk, j, state, d):
    """Model flow (L/min) of candidate j after duty ``d``; advances ``state`` (its operator memory)."""
    (method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0,
     dc, dh, fc, fh, margin, beta) = bk
    u = min(max((d - dc[j]) / dh[j], -1.0), 1.0)
    if method[j] == 2:
        preisach.switch(r[j], beta[j], state, u)
        acc = 0.0
        for i in range(state.shape[0]):
            acc += w[j, i] * state[i]
    else:
        acc = play.bank_step(r[j], w[j], pi_asym.down_scale(u, a[j], p[j]), state, u)
    y = max(pi_mod.dead_zone(h[j], g[j], acc) + offset[j], floor[j])
    below = min(d - (dc[j] - dh[j]), 0.0)
    return max(y * fh[j] + fc[j] + fh[j] / dh[j] * below, 0.0)  # no reverse flow through a closed valve


@njit(cache=True, inline="always")
def _solve(bk, j, state, work, q, closed):
    """Duty (%) that takes candidate j's model from ``state`` to flow ``q`` (L/min); ``state`` unchanged."""
    (method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, _, x0,
     dc, dh, fc, fh, margin, beta) = bk
    t = min(max((q - fc[j]) / fh[j], -1.0), 1.0)  # the model's flow range; above it: saturated
    if method[j] == 2:
        u = preisach.solve_input(r[j], beta[j], w[j], state, t - offset[j], -1.0, 1.0)
    else:
        u = pi_mod.solve(r[j], w[j], a[j], p[j], r_inv[j], w_inv[j], h_inv[j], g_inv[j], offset[j], closed, -1.0,
                         method[j] == 0, state, work, t)
    u = min(u, 1.0)
    below = min(q - (fc[j] - fh[j]), 0.0)  # below the flow range: the range's average gain
    return u * dh[j] + dc[j] + dh[j] / fh[j] * below


@njit(cache=True)
def _step(method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0, dc, dh, fc, fh, margin, beta,
          state, duty, out_state, flow):
    # the bank's arrays as separate arguments: the dispatcher types arrays fast, tuples slowly
    bk = (method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0, dc, dh, fc, fh, margin,
          beta)
    for j in range(duty.shape[0]):
        out_state[j] = state[j]
        flow[j] = _forward(bk, j, out_state[j], duty[j])


@njit(cache=True, inline="always")
def invert_one(bk, j, state, work, ref):
    """The feedforward duty (%) of candidate j for flow ``ref`` (L/min) from ``state``; ``work``: scratch (n,)."""
    closed, fc, fh, margin = bk[13], bk[17], bk[18], bk[19]
    if ref > 0.0:
        return _solve(bk, j, state, work, ref, closed[j])
    # no flow asked: ready, just below the flow's onset on the present branch
    onset = max(closed[j] * fh[j] + fc[j], 0.0)
    return _solve(bk, j, state, work, onset, -np.inf) - margin[j]


@njit(cache=True, inline="always")
def forward_one(bk, j, state, duty):
    """Model flow (L/min) of candidate j after duty ``duty`` (%); advances ``state`` in place."""
    return _forward(bk, j, state, duty)


@njit(cache=True)
def _invert(method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0, dc, dh, fc, fh, margin,
            beta, state, ref, out):
    bk = (method, r, w, a, p, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0, dc, dh, fc, fh, margin,
          beta)
    work = np.empty(state.shape[1])
    for j in range(ref.shape[0]):
        out[j] = invert_one(bk, j, state[j], work, ref[j])


def step(bank: ModelBank, state: np.ndarray, duty_pct) -> tuple[np.ndarray, np.ndarray]:
    """The forward model for every candidate: duty (%) in, ``(memory, flow L/min)`` out; pure."""
    duty = np.ascontiguousarray(np.broadcast_to(np.asarray(duty_pct, dtype=np.float64), (bank.batch,)))
    out, flow = np.empty_like(state), np.empty(bank.batch)
    _step(*bank.arrays, state, duty, out, flow)
    return out, flow


def invert(bank: ModelBank, state: np.ndarray, ref_lpm) -> np.ndarray:
    """The feedforward: duty (%) per candidate that takes the model from ``state`` to ``ref_lpm``.

    Exact for the closed-form kinds (``forward(invert(ref)) == ref`` within the model's
    ranges), to rounding for ``pi-asym``; a reference of no flow gives the ready duty.
    """
    ref = np.ascontiguousarray(np.broadcast_to(np.asarray(ref_lpm, dtype=np.float64), (bank.batch,)))
    out = np.empty(bank.batch)
    _invert(*bank.arrays, state, ref, out)
    return out


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


@njit(cache=True, inline="always")
def lead(lead_s, lag_s, ref_prev_lpm, out_prev_lpm, ref_lpm, dt_s):
    """One period of ``F(s)`` for one candidate by backward Euler: ``lag (y - y') / dt + y = lead (r - r') / dt + r``."""
    return (lag_s * out_prev_lpm + lead_s * (ref_lpm - ref_prev_lpm) + dt_s * ref_lpm) / (lag_s + dt_s)


@njit(cache=True)
def _lead(lead_s, lag_s, ref_prev, out_prev, ref, dt_s, out):
    for b in range(out.shape[0]):
        out[b] = lead(lead_s[b], lag_s[b], ref_prev[b], out_prev[b], ref[b], dt_s)


def lead_step(p: LeadParams, s: LeadState, ref_lpm: np.ndarray, dt_s: float) -> tuple[LeadState, np.ndarray]:
    """:func:`lead` for every candidate (arrays of shape (B,))."""
    r = np.broadcast_to(np.asarray(ref_lpm, dtype=np.float64), p.lead_s.shape).copy()
    y = np.empty(p.lead_s.shape)
    _lead(p.lead_s, p.lag_s, s.ref_prev_lpm, s.out_prev_lpm, r, float(dt_s), y)
    return LeadState(r, y), y
