"""Kalman-corrected feedforward: estimate the feedforward model's flow error, feed it back.

State model, per loop period ``dt`` (all in L/min)::

    flow[k+1] = a flow[k] + (1 - a) (m[k - d] + bias[k]) + w_flow
    bias[k+1] = bias[k]                                   + w_bias
    z[k]      = flow[k]                                   + v

with ``a = exp(-dt / tau_s)`` the valve's first-order lag, ``d`` the
transport delay in periods, ``m[k]`` the flow the forward PI model predicts
for the duty applied at step k, ``bias`` the additive flow error of that
model (supply pressure, temperature, fit error) and ``z`` the measured flow.
Noise choices: ``R = r_lpm**2`` is the flow sensor's noise variance;
``Q = diag(q_flow_lpm**2, q_bias_lpm**2)`` per period, where ``q_flow_lpm``
covers the fast model error (hysteresis branches the PI gets slightly wrong,
unmodelled lag) and ``q_bias_lpm`` sets how fast the bias may wander, i.e.
the bandwidth of the correction.

The correction: the feedforward inverts ``ref - bias_hat`` instead of
``ref``, so once ``bias_hat`` converges the plant makes the reference flow.

:func:`design` builds the filter as a filterpy ``KalmanFilter`` (F, B, H, Q,
R), the reference implementation. The loop runs the steady-state
(Kalman-gain) form over arrays of candidates, with the gain from the discrete
algebraic Riccati equation of the same F, H, Q, R: a few scalar operations
per step instead of filterpy's ~17 µs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit


def matrices(tau_s: float, dt_s: float, q_flow_lpm: float, q_bias_lpm: float, r_lpm: float):
    """``F, B, H, Q, R`` of the state model above for one candidate."""
    a = float(np.exp(-dt_s / tau_s)) if tau_s > 0 else 0.0
    F = np.array([[a, 1.0 - a], [0.0, 1.0]])
    B = np.array([[1.0 - a], [0.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.diag([q_flow_lpm**2, q_bias_lpm**2])
    R = np.array([[r_lpm**2]])
    return F, B, H, Q, R


def design(tau_s: float, dt_s: float, q_flow_lpm: float, q_bias_lpm: float, r_lpm: float, flow0_lpm: float = 0.0):
    """The filterpy ``KalmanFilter`` for one candidate (``predict(u=m[k-1-d])`` then ``update(z[k])``)."""
    from filterpy.kalman import KalmanFilter

    F, B, H, Q, R = matrices(tau_s, dt_s, q_flow_lpm, q_bias_lpm, r_lpm)
    kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=1)
    kf.F, kf.B, kf.H, kf.Q, kf.R = F, B, H, Q, R
    kf.x = np.array([[flow0_lpm], [0.0]])
    kf.P = np.diag([r_lpm**2, 100.0])  # bias unknown to within ~10 L/min at start
    return kf


def steady_gain(F, H, Q, R) -> np.ndarray:
    """Steady-state Kalman gain (shape (2,)) from the prior covariance of the DARE."""
    import scipy.linalg  # here: the loop's and the CLI's modules load without scipy

    P = scipy.linalg.solve_discrete_are(F.T, H.T, Q, R)
    S = H @ P @ H.T + R
    return (P @ H.T / S).ravel()


@dataclass(frozen=True, eq=False)
class KFParams:
    """Steady-state filter per candidate, arrays of shape (B,).

    Attributes
    ----------
    a : ndarray
        ``exp(-dt / tau_s)``, the lag's pole per period.
    k_flow, k_bias : ndarray
        Steady-state Kalman gains for the flow and bias states.
    delay_steps : ndarray of int
        Transport delay ``d`` in periods.
    """

    a: np.ndarray
    k_flow: np.ndarray
    k_bias: np.ndarray
    delay_steps: np.ndarray

    @classmethod
    def make(cls, tau_s, delay_s, dt_s: float, q_flow_lpm, q_bias_lpm, r_lpm, batch: int = 1) -> "KFParams":
        """Gains for each candidate (arguments broadcast to shape (B,))."""
        cols = np.broadcast_arrays(*(np.broadcast_to(np.asarray(v, dtype=np.float64), (batch,))
                                     for v in (tau_s, delay_s, q_flow_lpm, q_bias_lpm, r_lpm)))
        a, kf, kb = (np.empty(batch) for _ in range(3))
        for i, (tau, _, qf, qb, r) in enumerate(zip(*cols)):
            f = design(tau, dt_s, qf, qb, r)  # filterpy holds the design; the loop runs its steady state
            a[i] = f.F[0, 0]
            kf[i], kb[i] = steady_gain(f.F, f.H, f.Q, f.R)
        delay = np.rint(cols[1] / dt_s).astype(np.int64)
        return cls(a, kf, kb, delay)


class KFState(NamedTuple):
    """Estimates and the history of model flows the delay still holds back."""

    flow_lpm: np.ndarray
    bias_lpm: np.ndarray
    model_hist_lpm: np.ndarray  # (B, L) ring buffer of m[k], L = max delay + 1
    pos: int  # index where m[k-1] was written


def init(p: KFParams, flow0_lpm, model0_lpm=None, bias0_lpm=0.0) -> KFState:
    """Flow estimate at the first measurement, bias ``bias0_lpm``, model history filled with ``model0_lpm``."""
    b = p.a.shape
    flow = np.broadcast_to(np.asarray(flow0_lpm, dtype=np.float64), b).copy()
    m0 = flow - bias0_lpm if model0_lpm is None else np.broadcast_to(model0_lpm, b)
    hist = np.repeat(np.asarray(m0, dtype=np.float64)[:, None], int(p.delay_steps.max()) + 1, axis=1)
    return KFState(flow, np.broadcast_to(np.asarray(bias0_lpm, dtype=np.float64), b).copy(), hist, 0)


@njit(cache=True, inline="always")
def prediction(a, flow_lpm, bias_lpm, model_lpm):
    """One candidate's flow predicted for this step from the delayed model flow ``m[k-1-d]``, L/min.

    The bias is the model's error on flow the valve passes: where the model has the valve closed
    (``m = 0``) the valve passes none whatever the bias.
    """
    return a * flow_lpm + (1.0 - a) * (model_lpm + bias_lpm if model_lpm > 0.0 else 0.0)


@njit(cache=True, inline="always")
def correct(a, k_flow, k_bias, flow_lpm, bias_lpm, model_lpm, z_lpm):
    """One candidate: predict with ``m[k-1-d]``, correct with the measurement ``z[k]``; ``(flow, bias)``.

    While the model has the valve closed the bias estimate is held: a closed valve says nothing about
    the model's error on an open one, and learning it anew on every breath costs each breath's start
    (a hysteresis model's error persists from breath to breath where its branch is wrong).
    """
    flow_pred = prediction(a, flow_lpm, bias_lpm, model_lpm)
    innov = z_lpm - flow_pred
    return flow_pred + k_flow * innov, bias_lpm + (k_bias * innov if model_lpm > 0.0 else 0.0)


def delayed_model(p: KFParams, s: KFState) -> np.ndarray:
    """``m[k-1-d]``: the model flow of the duty applied one period plus the transport delay ago, L/min."""
    n = s.model_hist_lpm.shape[1]
    return s.model_hist_lpm[np.arange(len(p.a)), (s.pos - p.delay_steps) % n]


@njit(cache=True)
def _predict(a, flow, bias, m, out):
    for b in range(out.shape[0]):
        out[b] = prediction(a[b], flow[b], bias[b], m[b])


def predict(p: KFParams, s: KFState) -> np.ndarray:
    """:func:`prediction` for every candidate (the measurement minus it is the innovation), L/min."""
    out = np.empty(p.a.shape)
    _predict(p.a, np.ascontiguousarray(s.flow_lpm), np.ascontiguousarray(s.bias_lpm), delayed_model(p, s), out)
    return out


@njit(cache=True)
def _update(a, kf, kb, flow, bias, m, z, flow_out, bias_out):
    for b in range(flow_out.shape[0]):
        flow_out[b], bias_out[b] = correct(a[b], kf[b], kb[b], flow[b], bias[b], m[b], z[b])


def update(p: KFParams, s: KFState, z_lpm: np.ndarray) -> KFState:
    """:func:`correct` for every candidate (arrays of shape (B,))."""
    b = p.a.shape
    flow, bias = np.empty(b), np.empty(b)
    _update(p.a, p.k_flow, p.k_bias, np.ascontiguousarray(s.flow_lpm), np.ascontiguousarray(s.bias_lpm),
            delayed_model(p, s), np.ascontiguousarray(np.broadcast_to(np.asarray(z_lpm, dtype=np.float64), b)),
            flow, bias)
    return KFState(flow, bias, s.model_hist_lpm, s.pos)


def push(s: KFState, model_lpm: np.ndarray) -> KFState:
    """Record ``m[k]``, the model flow for the duty applied this period."""
    pos = (s.pos + 1) % s.model_hist_lpm.shape[1]
    hist = s.model_hist_lpm.copy()
    hist[:, pos] = model_lpm
    return KFState(s.flow_lpm, s.bias_lpm, hist, pos)


def resume(s: KFState, z_lpm) -> KFState:
    """After a gap in the measurements: flow estimate reseeded, bias estimate held."""
    return KFState(np.broadcast_to(z_lpm, s.flow_lpm.shape).astype(np.float64), s.bias_lpm, s.model_hist_lpm, s.pos)
