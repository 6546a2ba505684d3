"""The linear play (backlash) operator, Eq. (1) and (3) of the paper: the one implementation.

``y_i(k) = max{x(k) - r_i, min{x(k) + r_i, y_i(k-1)}}``       # Eq. (1)
``y_i(0) = max{x(0) - r_i, min{x(0) + r_i, y_i0}}``           # Eq. (3)

:func:`eq1` is the operator, written once as a numba kernel inlined into
every caller: the PI and its inverse (Eq. 5 is Eq. 1 on the output), the
generalized operators of the asymmetric PI (a descending threshold of its
own), the modified PI, the simulated valve's kernel and the feedforward. It
takes the ascending and the descending thresholds separately; Eq. (1) is
the case of equal ones.

The recursion is sequential in time, so the time loops are compiled and run
over the operators of a bank: :func:`bank_step` advances a bank by one
sample and returns the weighted sum (Eq. 4 without offset); the whole-input
kernels below give the full operator response (the regressor matrix a
least-squares fit needs) or the weighted sum only (what prediction needs,
without the N x n matrix). The plain numpy loop that checks them lives in
``tests/oracles.py``.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def eq1(y_prev, x, r_up, r_down):
    """Eq. (1) with ascending threshold ``r_up`` and descending threshold ``r_down``.

    ``max{x - r_up, min{x + r_down, y(k-1)}}``; the paper's operator has ``r_up == r_down``.
    """
    # written as the paper writes it: min and max compile to branch-free vminsd/vmaxsd, where the
    # equivalent conditional compiled to two data-dependent branches per operator (mispredicted at
    # each reversal); the same value for finite inputs with r_up + r_down >= 0
    return max(x - r_up, min(x + r_down, y_prev))


@njit(cache=True, inline="always")
def bank_step(r, w, down_scale, y, x):
    """One sample of a bank of operators, in place; returns ``sum_i w_i y_i`` (Eq. 4 without offset).

    Operator ``i`` has thresholds ``r_i`` ascending and ``r_i * down_scale`` descending
    (``down_scale = 1``: Eq. 1 exactly, ``r * 1.0 == r``). The sum runs in operator order.
    """
    acc = 0.0
    for i in range(r.shape[0]):
        y[i] = eq1(y[i], x, r[i], r[i] * down_scale)
        acc += w[i] * y[i]
    return acc


@njit(cache=True)
def _clamp_each(r, x, y_prev, out):
    # element-wise Eq. (1)/(3) over flat arrays
    for i in range(r.shape[0]):
        out[i] = eq1(y_prev[i], x[i], r[i], r[i])


@njit(cache=True)
def _response(r, x, down_scale, state):
    n = r.shape[0]
    out = np.empty((x.shape[0], n))
    y = state.copy()
    for k in range(x.shape[0]):
        for i in range(n):
            y[i] = eq1(y[i], x[k], r[i], r[i] * down_scale[k])
            out[k, i] = y[i]
    return out, y


@njit(cache=True)
def _weighted(r, w, x, down_scale, state):
    out = np.empty(x.shape[0])
    y = state.copy()
    for k in range(x.shape[0]):
        out[k] = bank_step(r, w, down_scale[k], y, x[k])
    return out, y


def _scale(down_scale, n):
    return np.ones(n) if down_scale is None else np.ascontiguousarray(down_scale, dtype=np.float64)


def init(r: np.ndarray, x0, y0: np.ndarray | float = 0.0) -> np.ndarray:
    """Initial operator states, Eq. (3); ``r``, ``x0`` and ``y0`` broadcast together
    (one bank: ``r`` (n,) and a scalar ``x0``; B banks: ``r`` (B, n) and ``x0`` (B, 1)).

    A ``y_i0`` of NaN means *at rest*: the operator starts at ``x(0)`` (Eq. 3 with
    ``y_i0 = x(0)``), the memory of a valve that has been held at its first input.
    """
    r, x0, y0 = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (r, x0, y0)))
    flat = [np.ascontiguousarray(v).reshape(-1) for v in (r, x0, y0)]
    flat[2] = np.where(np.isnan(flat[2]), flat[1], flat[2])
    out = np.empty(flat[0].shape)
    _clamp_each(*flat, out)
    return out.reshape(r.shape)


def step(r: np.ndarray, state: np.ndarray, x) -> np.ndarray:
    """One sample of Eq. (1) for a bank (``r``, ``state`` (n,), ``x`` scalar) or for B banks
    (``r`` and ``state`` (B, n), ``x`` (B, 1)); returns the new state (= the outputs)."""
    state = np.asarray(state, dtype=np.float64)
    r, x = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), state.shape)).reshape(-1)
            for v in (r, x))
    out = np.empty(state.size)
    _clamp_each(r, x, np.ascontiguousarray(state).reshape(-1), out)
    return out.reshape(state.shape)


def play_response(r: np.ndarray, x: np.ndarray, state: np.ndarray,
                  down_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Outputs of every operator over a whole input, Eq. (1).

    Parameters
    ----------
    r : ndarray, shape (n,)
        Thresholds, in the units of ``x``.
    x : ndarray, shape (N,)
        Input samples.
    state : ndarray, shape (n,)
        Operator states before the first sample (``y_i(k-1)`` for k = 0);
        use :func:`init` for Eq. (3).
    down_scale : ndarray, shape (N,), optional
        Per sample, the descending thresholds' factor (generalized operators of
        :mod:`models.pi_asym`); Eq. (1) when None.

    Returns
    -------
    Y : ndarray, shape (N, n)
        Operator outputs.
    state : ndarray, shape (n,)
        Final states, to continue in another chunk (like ``lfilter``'s ``zf``).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    return _response(np.ascontiguousarray(r, dtype=np.float64), x, _scale(down_scale, len(x)),
                     np.ascontiguousarray(state, dtype=np.float64))


def play_weighted(r: np.ndarray, w: np.ndarray, x: np.ndarray, state: np.ndarray,
                  down_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted sum ``sum_i w_i y_i(k)`` over a whole input (Eq. 4 without offset), and final states
    (``down_scale`` as in :func:`play_response`)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return _weighted(np.ascontiguousarray(r, dtype=np.float64), np.ascontiguousarray(w, dtype=np.float64), x,
                     _scale(down_scale, len(x)), np.ascontiguousarray(state, dtype=np.float64))
