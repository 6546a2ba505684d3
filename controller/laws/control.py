"""The controllers the CLI names, composed from the laws: ``pid``, ``ff``, ``ff+pid``, ``ff+kf``.

=========  =====================================================  ==========================
word       duty                                                   feedback
=========  =====================================================  ==========================
``pid``    ``PID(ref - meas)``                                    PID alone
``ff``     ``inv(F r)``                                           none
``ff+pid`` ``inv(F r) + PID(ref - meas)``                         PID around the feedforward
``ff+kf``  ``inv(F r - bias_hat)``                                Kalman bias estimate
=========  =====================================================  ==========================

``r`` is the feedforward's reference: ``ref`` itself, or the reference
``preview_s`` ahead when the reference is a known profile (the loop passes
it as ``ref_ff_lpm``), which lets the feedforward act the valve's transport
delay early. ``F`` is the lag inversion of
:class:`controller.laws.feedforward.LeadParams` (identity when absent).
The feedback always compares the measured flow with ``ref`` now. ``inv`` is
the inverse of the feedforward's model, of any invertible kind
(:mod:`controller.laws.feedforward`), from the model's memory of the duty
actually applied.

Every duty passes the same rate limit and [min, max] clamp
(:mod:`controller.laws.limits`). :class:`Command` splits the applied duty
into ``ff_pct``, the feedforward of ``r`` alone; ``fb_pct``, the feedback
law's own output (the PID's ``kp e + I + D``; for ``ff+kf`` the duty the
bias correction adds, ``invPI(F r - bias_hat) - invPI(F r)``); and
``limit_pct``, what the rate limit and the clamp took away, so
``duty = ff + fb + limit`` always.

One compiled kernel steps every word (:func:`advance`): it loops over the
candidates and calls each law's one implementation, the numba functions of
:mod:`.pid`, :mod:`.kalman`, :mod:`.limits` and :mod:`.feedforward`. The
live loop calls it for its batch of one through :class:`Live` (one call of
an address and four numbers on one buffer: microseconds a step), the sweep for
hundreds of candidates at once. Parameters are packed once per
:class:`ControllerParams` (:attr:`ControllerParams.kernel`); the state is
one matrix per batch plus the feedforward model's operator memory and the
Kalman filter's model history, advanced in place by :func:`advance` and
copied by the pure :func:`step`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numba import carray, njit

from . import feedforward as ffw
from . import kalman, limits, pid
from models.borrow import pointer
from models.direct import direct

MODES = ("pid", "ff", "ff+pid", "ff+kf")
PID, FF, FF_PID, FF_KF = range(4)

# -- parameter columns of Kernel.P (B, N_PARAMS) --
(DUTY_MIN, DUTY_MAX, RATE, KP, KI, KD, TF, TT, KF_A, KF_GAIN_FLOW, KF_GAIN_BIAS, KF_DELAY, LEAD_S, LAG_S,
 N_PARAMS) = range(15)

# -- state columns of ControllerState.x (B, N_STATE) --
(DUTY, INTEGRAL, DERIV, MEAS_PREV, FLOW_EST, BIAS_EST, LEAD_REF, LEAD_OUT, N_STATE) = range(9)



class Kernel(NamedTuple):
    """:class:`ControllerParams` as the kernel takes it: the word's index, the lead's presence, the
    parameter matrix (columns above) and the feedforward's model (:func:`feedforward.arrays`; a bank
    of no operators without feedforward, of the same types, so one compiled kernel serves every word)."""

    mode: int
    lead: bool
    P: np.ndarray
    bank: tuple


def _no_bank(batch: int) -> tuple:
    """A model bank of no operators: the feedforward's types for the words without one."""
    import dataclasses

    def of(f):
        shape = (batch,) if f.name in ("method", "a", "p", "offset", "floor", "closed", "duty_center", "duty_half",
                                       "flow_center", "flow_half", "ready_margin_pct") else (batch, 0)
        return np.zeros(shape, dtype=np.int64 if f.name == "method" else np.float64)

    return tuple(of(f) for f in dataclasses.fields(ffw.ModelBank))


@dataclass(frozen=True, eq=False)
class ControllerParams:
    """One controller word over a batch of candidates.

    Attributes
    ----------
    mode : str
        One of :data:`MODES` (the same for the whole batch).
    limits : Limits
    forward : ModelBank or None
        The feedforward's model (modes starting with ``ff``): its inverse is the
        feedforward, its forward part follows the applied duty (the memory the
        inverse starts from), and ``ff+kf`` takes the filter's model flow
        ``m[k]`` from it.
    pid : PIDParams or None
        ``pid`` and ``ff+pid``.
    kf : KFParams or None
        ``ff+kf``.
    lead : LeadParams or None
        Lag inversion on the feedforward's reference (modes starting with ``ff``).
    """

    mode: str
    limits: limits.Limits
    forward: ffw.ModelBank | None = None
    pid: pid.PIDParams | None = None
    kf: kalman.KFParams | None = None
    lead: ffw.LeadParams | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"unknown controller {self.mode!r} (one of {', '.join(MODES)})")
        need = {"ff": ("forward",), "pid": ("pid",), "ff+pid": ("forward", "pid"), "ff+kf": ("forward", "kf")}
        for name in need[self.mode]:
            if getattr(self, name) is None:
                raise ValueError(f"controller {self.mode!r} needs {name}")

    @property
    def batch(self) -> int:
        return self.limits.duty_min_pct.shape[0]

    @cached_property
    def kernel(self) -> Kernel:
        """The packed form, built once (parameters are frozen)."""
        B = self.batch
        P = np.zeros((B, N_PARAMS))
        lim = self.limits
        P[:, DUTY_MIN], P[:, DUTY_MAX], P[:, RATE] = lim.duty_min_pct, lim.duty_max_pct, lim.rate_pct_per_s
        if self.pid is not None:
            g = self.pid
            P[:, KP], P[:, KI], P[:, KD], P[:, TF], P[:, TT] = g.kp, g.ki, g.kd, g.tf_s, g.tt_s
        if self.kf is not None:
            k = self.kf
            P[:, KF_A], P[:, KF_GAIN_FLOW], P[:, KF_GAIN_BIAS], P[:, KF_DELAY] = k.a, k.k_flow, k.k_bias, k.delay_steps
        lead = self.lead is not None and self.forward is not None
        if lead:
            P[:, LEAD_S], P[:, LAG_S] = self.lead.lead_s, self.lead.lag_s
        bank = self.forward.arrays if self.forward is not None else _no_bank(B)
        return Kernel(MODES.index(self.mode), lead, P, bank)


class ControllerState(NamedTuple):
    """State of a batch, arrays the kernel advances in place.

    Attributes
    ----------
    mode : int
        Index in :data:`MODES` of the word this state belongs to.
    x : ndarray, shape (B, N_STATE)
        Last applied duty (the rate limit's memory), PID integral and
        derivative terms and previous measurement, Kalman flow and bias
        estimates, the lead's previous input and output (columns above).
    forward : ndarray, shape (B, n)
        Forward operator memory: the valve's, as driven by the applied duty (n = 0 without feedforward).
    hist : ndarray, shape (B, L)
        Kalman filter's model flows ``m[k]``, a ring (L = largest delay + 1).
    pos : ndarray of int64, shape (1,)
        Where ``m[k-1]`` was written in ``hist``.
    """

    mode: int
    x: np.ndarray
    forward: np.ndarray
    hist: np.ndarray
    pos: np.ndarray

    @property
    def duty_pct(self) -> np.ndarray:
        return self.x[:, DUTY]

    @property
    def bias_lpm(self) -> np.ndarray:
        """The Kalman filter's bias estimate (``ff+kf``), L/min."""
        return self.x[:, BIAS_EST]

    @property
    def kf(self) -> kalman.KFState | None:
        """The Kalman filter's state (``ff+kf``; views of this state), else None."""
        if self.mode != FF_KF:
            return None
        return kalman.KFState(self.x[:, FLOW_EST], self.x[:, BIAS_EST], self.hist, int(self.pos[0]))

    def copy(self) -> "ControllerState":
        return ControllerState(self.mode, self.x.copy(), self.forward.copy(), self.hist.copy(), self.pos.copy())


class Command(NamedTuple):
    """Applied duty and its split (``duty = ff + fb + limit``), %, arrays of shape (B,)."""

    duty_pct: np.ndarray
    ff_pct: np.ndarray
    fb_pct: np.ndarray  # the feedback law's own output
    limit_pct: np.ndarray  # what the rate limit and the clamp changed


@njit(cache=True)
def _advance(mode, has_lead, P, method, r, w, a, p_asym, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0,
             dc, dh, fc, fh, margin, beta, X, Y, H, pos, ref, meas, ref_ff, dt, out):
    # the bank's arrays come as separate arguments: the dispatcher types arrays fast, tuples slowly
    bank = (method, r, w, a, p_asym, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0, dc, dh, fc, fh,
            margin, beta)
    work = np.empty(Y.shape[1])  # the inverse's scratch
    k_old = pos[0]
    k_new = (k_old + 1) % H.shape[1]
    for b in range(X.shape[0]):
        duty, ff, fb = law_step(mode, has_lead, P[b], X[b], bank, b, Y[b], work, H[b], k_old, k_new, ref[b],
                                meas[b], ref_ff[b], dt, True)
        out[b, 0] = duty
        out[b, 1] = ff
        out[b, 2] = fb
        out[b, 3] = duty - ff - fb
    if mode == FF_KF:
        pos[0] = k_new


@njit(cache=True, inline="always")
def law_step(mode, has_lead, p, x, bank, b, y, work, hist, k_old, k_new, ref, meas, ref_ff, dt, split):
    """One candidate, one period: ``(duty, ff, fb)``, %; its state rows advanced in place.

    ``p``, ``x``: its rows of :attr:`Kernel.P` and :attr:`ControllerState.x`; ``bank``, ``b``: the
    feedforward's model bank and its index there; ``y``: its forward operator memory; ``work``:
    scratch of the same length; ``hist``: its ring of model flows, ``m[k-1]`` at ``k_old``, ``m[k]``
    written at ``k_new`` (``ff+kf``). ``split``: whether ``ff`` and ``fb`` are wanted (the live
    loop's duty split); without it (a sweep needs the duty alone) ``ff+kf`` does not invert the
    unbiased reference whose only use is the split, and ``ff`` and ``fb`` are not meaningful.
    """
    prev = x[DUTY]
    ff = 0.0
    if mode == PID or mode == FF_PID:
        integral = x[INTEGRAL]
        if mode == FF_PID:
            ff = _feedforward(has_lead, p, x, bank, b, y, work, ref_ff, dt)
        x[INTEGRAL], x[DERIV], duty = pid.update(
            p[KP], p[KI], p[KD], p[TF], p[TT], integral, x[DERIV], x[MEAS_PREV], ref, meas, dt, ff, prev,
            p[DUTY_MIN], p[DUTY_MAX], p[RATE])
        x[MEAS_PREV] = meas
        fb = p[KP] * (ref - meas) + integral + x[DERIV]  # the law's own kp e + I + D
    elif mode == FF:
        ff = _feedforward(has_lead, p, x, bank, b, y, work, ref_ff, dt)
        duty = limits.limit(ff, prev, dt, p[DUTY_MIN], p[DUTY_MAX], p[RATE])
        fb = 0.0
    else:  # ff+kf
        r = _lead(has_lead, p, x, ref_ff, dt)
        m = hist[(k_old - int(p[KF_DELAY])) % hist.shape[0]]
        x[FLOW_EST], x[BIAS_EST] = kalman.correct(p[KF_A], p[KF_GAIN_FLOW], p[KF_GAIN_BIAS], x[FLOW_EST],
                                                  x[BIAS_EST], m, meas)
        if r > 0.0:
            u = ffw.invert_one(bank, b, y, work, r - x[BIAS_EST])
            ff = ffw.invert_one(bank, b, y, work, r) if split else u  # the inverses leave the memory as it was
        else:  # a reference of no flow closes the valve whatever the bias estimate says
            u = ff = ffw.invert_one(bank, b, y, work, r)
        duty = limits.limit(u, prev, dt, p[DUTY_MIN], p[DUTY_MAX], p[RATE])
        fb = u - ff
    if mode != PID:
        model = ffw.forward_one(bank, b, y, duty)  # the model's memory follows the applied duty
        if mode == FF_KF:
            hist[k_new] = model
    x[DUTY] = duty
    return duty, ff, fb


@njit(cache=True, inline="always")
def _feedforward(has_lead, p, x, bank, b, memory, work, ref_ff, dt):
    # F r, then the model's inverse from the forward memory, which saw the duty actually applied
    # (Eq. 7): a duty the limits cut short leaves no mismatch behind, and the forward flow m[k] is
    # exactly the flow the inverse aimed at
    return ffw.invert_one(bank, b, memory, work, _lead(has_lead, p, x, ref_ff, dt))


@njit(cache=True, inline="always")
def _lead(has_lead, p, x, ref_ff, dt):
    # F r: the lag inversion, stepped here once per period
    if not has_lead:
        return ref_ff
    r = ffw.lead(p[LEAD_S], p[LAG_S], x[LEAD_REF], x[LEAD_OUT], ref_ff, dt)
    x[LEAD_REF] = ref_ff
    x[LEAD_OUT] = r
    return r


def advance(k: Kernel, s: ControllerState, ref_lpm: np.ndarray, meas_lpm: np.ndarray, ref_ff_lpm: np.ndarray,
            dt_s: float, out: np.ndarray) -> None:
    """One period for every candidate, in place: ``s`` advances, ``out`` (B, 4) receives duty, ff, fb, limit (%).

    The hot loops' form of :func:`step` (no allocation): arrays (B,) of
    float64, ``k`` from :attr:`ControllerParams.kernel`.
    """
    _advance(k.mode, k.lead, k.P, *k.bank, s.x, s.forward, s.hist, s.pos, ref_lpm, meas_lpm, ref_ff_lpm, dt_s, out)


@njit(cache=True, inline="always")
def _rows(F, L, i):
    """View ``i`` of the live buffer as a matrix (layout row ``i``: offset, rows, columns)."""
    return F[L[i, 0]:L[i, 0] + L[i, 1] * L[i, 2]].reshape((L[i, 1], L[i, 2]))


@njit(cache=True, inline="always")
def _col(F, L, i):
    """View ``i`` of the live buffer as a vector."""
    return F[L[i, 0]:L[i, 0] + L[i, 1] * L[i, 2]]


#: Rows of the live buffer's layout (:class:`Live`): 0 the parameters P, 1 to N_BANK - 1 the bank's
#: float fields (row = field index), then the state, its saved copy, io; in the int buffer pos, its
#: saved copy and the bank's method; out, the filter's health last.
N_BANK = 21
(_X, _FWD, _HIST, _X_SAVED, _FWD_SAVED, _HIST_SAVED, _IO, _POS, _POS_SAVED, _METHOD, _OUT, _HEALTH) = range(
    N_BANK, N_BANK + 12)
#: The filter's health row (``ff+kf``; :mod:`controller.supervisor`): its settings (the low-pass's time
#: constant, s, nan: no health figures; the innovation's bound, L/min, and hold time, s), then the
#: low-passed innovation, how long it has been beyond the bound, the model flow through the valve's lag
#: and the low-passed model error (nan before the first step), L/min and s.
(_G_TAU, _G_LIMIT, _G_HOLD, _G_INNOV, _G_BEYOND, _G_LAG, _G_MISMATCH, _N_HEALTH) = range(8)
#: A live step's verdict (:meth:`Live.step`): the duty stands, it is not finite, the filter diverged.
STEP_OK, BAD_COMMAND, DIVERGED = range(3)


@njit(cache=True, inline="always")
def _diverged(G, z, predicted, m, a, dt):
    """The filter's health after one step of measured flow ``z`` (``G``: the health row, advanced):
    whether its low-passed innovation stayed beyond the bound for the hold time. Also low-passes the
    model's flow error: the measurement minus the model flow ``m`` through the filter's lag ``a``."""
    g = 1.0 - math.exp(-dt / G[_G_TAU])
    G[_G_INNOV] += (z - predicted - G[_G_INNOV]) * g
    lag = m if G[_G_LAG] != G[_G_LAG] else a * G[_G_LAG] + (1.0 - a) * m
    G[_G_LAG] = lag
    mis = G[_G_MISMATCH]
    G[_G_MISMATCH] = z - lag if mis != mis else mis + (z - lag - mis) * g
    G[_G_BEYOND] = G[_G_BEYOND] + dt if abs(G[_G_INNOV]) > G[_G_LIMIT] else 0.0
    return G[_G_BEYOND] >= G[_G_HOLD] - 1e-12 or not math.isfinite(G[_G_INNOV])


#: The live header (:class:`Live`), int64: the word's index, the lead's presence, then address and length of
#: the float buffer, the int buffer and the layout (rows of 3).
_H_MODE, _H_LEAD, _H_F, _H_NF, _H_I, _H_NI, _H_L, _H_NL, _N_HEAD = range(9)


@njit(cache=True)
def _live_step(head, ref_lpm, meas_lpm, ref_ff_lpm, dt):
    # One address and four floats: numba's entry point types, unboxes and releases each argument,
    # and an array's unboxing (a new owner record) cost ~0.5 us cold where an integer's costs
    # nothing (models.borrow.pointer); the 33 arrays of the kernel's own signature were most of a
    # live step. Views by the layout of Live; the state is saved before it advances
    # (Live.rollback), the filter's prediction taken from the state before, and its health
    # (the supervisor's, held here so that a step is one call) judged after.
    h = carray(pointer(head, np.int64), _N_HEAD)
    F = carray(pointer(h[_H_F], np.float64), h[_H_NF])
    I = carray(pointer(h[_H_I], np.int64), h[_H_NI])
    L = carray(pointer(h[_H_L], np.int64), (h[_H_NL], 3))
    mode, has_lead = h[_H_MODE], h[_H_LEAD] != 0
    P = _rows(F, L, 0)
    X, Y, H = _rows(F, L, _X), _rows(F, L, _FWD), _rows(F, L, _HIST)
    pos = _col(I, L, _POS)
    _rows(F, L, _X_SAVED)[:] = X
    _rows(F, L, _FWD_SAVED)[:] = Y
    _rows(F, L, _HIST_SAVED)[:] = H
    _col(I, L, _POS_SAVED)[0] = pos[0]
    predicted = m = np.nan
    if mode == FF_KF:
        m = H[0, (pos[0] - int(P[0, KF_DELAY])) % H.shape[1]]
        predicted = kalman.prediction(P[0, KF_A], X[0, FLOW_EST], X[0, BIAS_EST], m)
    io = _col(F, L, _IO)
    io[0], io[1], io[2] = ref_lpm, meas_lpm, ref_ff_lpm
    out = _rows(F, L, _OUT)
    _advance(mode, has_lead, P, _col(I, L, _METHOD), _rows(F, L, 1), _rows(F, L, 2), _col(F, L, 3), _col(F, L, 4),
             _rows(F, L, 5), _rows(F, L, 6), _col(F, L, 7), _col(F, L, 8), _rows(F, L, 9), _rows(F, L, 10),
             _rows(F, L, 11), _rows(F, L, 12), _col(F, L, 13), _rows(F, L, 14), _col(F, L, 15), _col(F, L, 16),
             _col(F, L, 17), _col(F, L, 18), _col(F, L, 19), _rows(F, L, 20), X, Y, H, pos, io[0:1], io[1:2],
             io[2:3], dt, out)
    G = _col(F, L, _HEALTH)
    verdict = STEP_OK
    if not math.isfinite(out[0, 0]):  # never command what the law could not compute
        verdict = BAD_COMMAND
    elif mode == FF_KF and G[_G_TAU] == G[_G_TAU] and _diverged(G, meas_lpm, predicted, m, P[0, KF_A], dt):
        verdict = DIVERGED
    return out[0, 0], out[0, 1], out[0, 2], out[0, 3], verdict, G[_G_MISMATCH]


class Live:
    """One controller (batch of one) advanced in place by one compiled call: the live loop's :func:`step`.

    The parameters, the feedforward's model and the state live in one float and one
    int buffer; :meth:`step` runs :func:`_advance` on views of them, found by address
    (:func:`models.borrow.pointer`), so a step costs one call of an address and four
    numbers and allocates nothing. The buffers are this object's, never reallocated.

    Parameters
    ----------
    p : ControllerParams
        Batch of one.
    health : SupervisorSettings or None
        For ``ff+kf``, the bounds of the filter's health that :meth:`step` judges
        (:class:`controller.supervisor.SupervisorSettings`: ``tau_s``,
        ``innovation_limit_lpm``, ``innovation_hold_s``); None: no health figures.

    Attributes
    ----------
    state : ControllerState
        Views of the buffers: the state :meth:`step` advances.
    """

    def __init__(self, p: ControllerParams, health=None):
        if p.batch != 1:
            raise ValueError("Live steps one controller (batch of one)")
        k = p.kernel
        if len(k.bank) != N_BANK:
            raise ValueError(f"the live layout has {N_BANK} bank fields, the feedforward {len(k.bank)}")
        s = init(p, 0.0)
        g = np.full(_N_HEALTH, np.nan)
        if health is not None:
            g[[_G_TAU, _G_LIMIT, _G_HOLD]] = health.tau_s, health.innovation_limit_lpm, health.innovation_hold_s
        rows = [k.P, *k.bank[1:], s.x, s.forward, s.hist, s.x, s.forward, s.hist, np.zeros(3), s.pos, s.pos,
                k.bank[0], np.zeros((1, 4)), g]  # in layout order
        is_int = [a.dtype == np.int64 for a in rows]
        self._F = np.zeros(sum(a.size for a, i in zip(rows, is_int) if not i))
        self._I = np.zeros(sum(a.size for a, i in zip(rows, is_int) if i), dtype=np.int64)
        layout, views, offset = [], [], {True: 0, False: 0}
        for a, i in zip(rows, is_int):
            shape = a.shape if a.ndim == 2 else (a.shape[0], 1)
            o = offset[i]
            view = (self._I if i else self._F)[o:o + a.size].reshape(shape)
            view[:] = a.reshape(shape)
            layout.append((o, *shape))
            views.append(view if a.ndim == 2 else view[:, 0])
            offset[i] += a.size
        self._L = np.array(layout, dtype=np.int64)
        self._scratch = self._F.copy(), self._I.copy()  # rehearse()'s buffers
        # the buffers by address (models.borrow.pointer): this object keeps them, never reallocated
        self._heads = [np.array([k.mode, k.lead, F.ctypes.data, F.size, I.ctypes.data, I.size, self._L.ctypes.data,
                                 len(self._L)], dtype=np.int64) for F, I in ((self._F, self._I), self._scratch)]
        self._head, self._scratch_head = (h.ctypes.data for h in self._heads)
        # the kernel's machine code, called without numba's dispatcher (models.direct)
        self._step = direct(_live_step, self._head, 0.0, 0.0, 0.0, 0.0)
        self._saved = views[_X_SAVED], views[_FWD_SAVED], views[_HIST_SAVED], views[_POS_SAVED]
        self._io = views[_IO]
        self._health = views[_HEALTH]
        self.reset_health()
        self.state = ControllerState(k.mode, views[_X], views[_FWD], views[_HIST], views[_POS])

    def load(self, s: ControllerState) -> ControllerState:
        """Make ``s`` (of the same controller) the state advanced from now on; returns :attr:`state`."""
        x, fwd, hist, pos = self.state[1:]
        x[:], fwd[:], hist[:], pos[:] = s.x, s.forward, s.hist, s.pos
        return self.state

    def reset_health(self) -> None:
        """The filter's health from scratch: innovation zero, model error unknown (nan)."""
        g = self._health
        g[_G_INNOV] = g[_G_BEYOND] = 0.0
        g[_G_LAG] = g[_G_MISMATCH] = np.nan

    def step(self, ref_lpm: float, meas_lpm: float, ff_ref_lpm: float, dt_s: float) -> tuple:
        """One period in place: ``(duty, ff, fb, limit, verdict, mismatch)``: %, then :data:`STEP_OK`,
        :data:`BAD_COMMAND` (a duty not finite) or :data:`DIVERGED` (``ff+kf``: the filter's low-passed
        innovation beyond its bound for its hold time), and the low-passed model error (``ff+kf`` with
        ``health``: the measured flow minus the model flow through the valve's lag, L/min; else nan).
        A step whose verdict is not :data:`STEP_OK` is to be undone (:meth:`rollback`)."""
        return self._step(self._head, ref_lpm, meas_lpm, ff_ref_lpm, dt_s)

    def rehearse(self, dt_s: float) -> None:
        """The last step again, on scratch copies of the buffers: the machine code and the data of a
        step pass through the caches, and the state is untouched (the loop's rehearsal before a
        deadline, :class:`controller.loop.LoopSettings`)."""
        F, I = self._scratch
        np.copyto(F, self._F)
        np.copyto(I, self._I)
        io = self._io
        self._step(self._scratch_head, float(io[0]), float(io[1]), float(io[2]), dt_s)

    def rollback(self) -> ControllerState:
        """Undo the last :meth:`step` (a step whose duty cannot be commanded); returns :attr:`state`."""
        x, fwd, hist, pos = self.state[1:]
        x[:], fwd[:], hist[:], pos[:] = self._saved
        return self.state


def init(p: ControllerParams, meas_lpm, duty0_pct=0.0) -> ControllerState:
    """Cold start: integral and bias zero, derivative and filter at ``meas_lpm``, valve at ``duty0_pct``.

    The lead starts at rest at zero flow: the first reference is a step for it.
    """
    B = p.batch
    meas = np.broadcast_to(np.asarray(meas_lpm, dtype=np.float64), (B,))
    x = np.zeros((B, N_STATE))
    x[:, DUTY] = duty0_pct
    x[:, MEAS_PREV] = meas
    x[:, FLOW_EST] = meas
    fwd = ffw.init(p.forward, x[:, DUTY]) if p.forward is not None else np.zeros((B, 0))
    L = int(p.kf.delay_steps.max()) + 1 if p.kf is not None else 1
    hist = np.repeat(meas[:, None], L, axis=1)  # model flows before the start: the flow measured
    return ControllerState(MODES.index(p.mode), x, fwd, hist, np.zeros(1, dtype=np.int64))


def step(p: ControllerParams, s: ControllerState, ref_lpm, meas_lpm, dt_s: float, ref_ff_lpm=None):
    """One period for every candidate: ``(state, Command)``, ``s`` left as it was.

    ``ref_ff_lpm`` is the feedforward's reference (``ref_lpm`` when None).
    """
    B = p.batch

    def col(v):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (B,)))

    s = s.copy()
    out = np.empty((B, 4))
    advance(p.kernel, s, col(ref_lpm), col(meas_lpm), col(ref_lpm if ref_ff_lpm is None else ref_ff_lpm),
            float(dt_s), out)
    return s, Command(out[:, 0], out[:, 1], out[:, 2], out[:, 3])


def resume(p: ControllerParams, s: ControllerState, meas_lpm, duty_applied_pct) -> ControllerState:
    """Back to running after a gap in the measurements (bumpless).

    The rate limit starts from the duty actually applied (the safe duty) and
    the forward memory has seen it; the derivative memory and the flow
    estimate restart at the fresh measurement; the integral and the bias
    estimate are held from before the gap.
    """
    s = s.copy()
    x = s.x
    x[:, DUTY] = duty_applied_pct
    x[:, DERIV] = 0.0
    x[:, MEAS_PREV] = meas_lpm
    x[:, FLOW_EST] = meas_lpm
    if p.forward is not None:
        s = s._replace(forward=ffw.step(p.forward, s.forward, x[:, DUTY])[0])
    return s


def transfer(p: ControllerParams, s_old: ControllerState, ref_lpm, meas_lpm) -> ControllerState:
    """Bumpless switch to the controller ``p`` while running with state ``s_old``.

    The new law starts from the duty last applied: its rate limit continues
    from it and a PID integral takes what the feedforward and the P and D
    terms leave, so the first duty of the new law equals the last one of the
    old (within the rate limit). ``ff+kf`` keeps the bias estimate if the old
    law had one.
    """
    s = init(p, meas_lpm, s_old.duty_pct)
    x = s.x
    if p.kernel.lead:
        x[:, LEAD_REF] = x[:, LEAD_OUT] = ref_lpm  # at rest at the reference
    if s_old.mode == FF_KF and p.kf is not None:
        x[:, BIAS_EST] = s_old.bias_lpm
    if p.pid is not None:
        ff = ffw.invert(p.forward, s.forward, ref_lpm) if p.forward is not None else 0.0
        g = pid.transfer(p.pid, pid.PIDState(x[:, INTEGRAL], x[:, DERIV], x[:, MEAS_PREV]), ref_lpm, meas_lpm, ff,
                         s_old.duty_pct)
        x[:, INTEGRAL], x[:, DERIV], x[:, MEAS_PREV] = g
    return s


def repeat(p: ControllerParams, times: int) -> ControllerParams:
    """The batch of ``p`` repeated ``times`` times along the candidate axis (to vary some gains after)."""
    import dataclasses

    def rep(obj):
        if obj is None:
            return None
        return dataclasses.replace(obj, **{f.name: np.repeat(getattr(obj, f.name), times, axis=0)
                                           for f in dataclasses.fields(obj)
                                           if isinstance(getattr(obj, f.name), np.ndarray)})

    return dataclasses.replace(p, **{k: rep(getattr(p, k)) for k in ("limits", "forward", "pid", "kf", "lead")})
