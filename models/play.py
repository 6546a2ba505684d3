"""The linear play (backlash) operator, Eq. (1) and (3) of the paper.

``y_i(k) = max{x(k) - r_i, min{x(k) + r_i, y_i(k-1)}}``       # Eq. (1)
``y_i(0) = max{x(0) - r_i, min{x(0) + r_i, y_i0}}``           # Eq. (3)

The recursion is sequential in time, so the time loop is compiled with numba
and vectorized over the operators of a bank. Two kernels: the full operator
response (the regressor matrix a least-squares fit needs) and the weighted
sum only (what prediction needs, without the N x n matrix).
:func:`play_response_numpy` is the plain per-sample numpy loop kept as the
reference implementation for tests and the benchmark baseline.
"""
from __future__ import annotations

import numpy as np
from numba import njit


def init(r: np.ndarray, x0, y0: np.ndarray | float = 0.0) -> np.ndarray:
    """Initial operator states, Eq. (3).

    A ``y_i0`` of NaN means *at rest*: the operator starts at ``x(0)`` (Eq. 3 with
    ``y_i0 = x(0)``), the memory of a valve that has been held at its first input.
    """
    r = np.asarray(r, dtype=np.float64)
    x0 = np.asarray(x0, dtype=np.float64)
    y0 = np.where(np.isnan(y0), x0, y0)
    return np.maximum(x0 - r, np.minimum(x0 + r, y0)).astype(np.float64)


def step(r: np.ndarray, state: np.ndarray, x: float) -> np.ndarray:
    """One sample of Eq. (1) for a bank of operators; returns the new state (= outputs)."""
    return np.maximum(x - r, np.minimum(x + r, state))


@njit(cache=True, inline="always")
def _eq1(y_prev, x, r):
    # Eq. (1): max{x - r, min{x + r, y(k-1)}}
    lo = x - r
    hi = x + r
    return lo if y_prev < lo else (hi if y_prev > hi else y_prev)


@njit(cache=True)
def _response(r, x, state):
    n = r.shape[0]
    out = np.empty((x.shape[0], n))
    y = state.copy()
    for k in range(x.shape[0]):
        for i in range(n):
            y[i] = _eq1(y[i], x[k], r[i])
            out[k, i] = y[i]
    return out, y


@njit(cache=True)
def _weighted(r, w, x, state):
    n = r.shape[0]
    out = np.empty(x.shape[0])
    y = state.copy()
    for k in range(x.shape[0]):
        acc = 0.0
        for i in range(n):
            y[i] = _eq1(y[i], x[k], r[i])
            acc += w[i] * y[i]
        out[k] = acc
    return out, y


def play_response(r: np.ndarray, x: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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

    Returns
    -------
    Y : ndarray, shape (N, n)
        Operator outputs.
    state : ndarray, shape (n,)
        Final states, to continue in another chunk (like ``lfilter``'s ``zf``).
    """
    return _response(
        np.ascontiguousarray(r, dtype=np.float64),
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(state, dtype=np.float64),
    )


def play_weighted(
    r: np.ndarray, w: np.ndarray, x: np.ndarray, state: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted sum ``sum_i w_i y_i(k)`` over a whole input (Eq. 4 without offset), and final states."""
    return _weighted(
        np.ascontiguousarray(r, dtype=np.float64),
        np.ascontiguousarray(w, dtype=np.float64),
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(state, dtype=np.float64),
    )


def play_response_numpy(r: np.ndarray, x: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference implementation: a plain per-sample numpy loop over Eq. (1)."""
    r = np.asarray(r, dtype=np.float64)
    y = np.asarray(state, dtype=np.float64).copy()
    out = np.empty((len(x), len(r)))
    for k, xk in enumerate(np.asarray(x, dtype=np.float64)):
        y = np.maximum(xk - r, np.minimum(xk + r, y))
        out[k] = y
    return out, y
