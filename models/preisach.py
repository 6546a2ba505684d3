"""The discrete Preisach model (paper §2.1, §2.3): relay hysterons on the alpha >= beta grid.

``y(k) = sum_{i>=j} mu_ij gamma_{alpha_i beta_j}[x](k) + c``,  ``mu_ij >= 0``

A relay ``gamma_{alpha beta}`` is +1 once the input reaches its up-switching
level ``alpha``, -1 once it falls below its down-switching level ``beta``, and
holds its value in between. With ``N_h`` levels per axis the triangular grid
``alpha_i >= beta_j`` holds ``N_h (N_h + 1) / 2`` relays (1275 for the paper's
``N_h = 50``); the diagonal ``alpha = beta`` relays are memoryless steps. The
levels are the centres of ``N_h`` equal cells over [-1, 1] (normalized input).

Weights come from non-negative least squares (the paper's NNLS): the relay
regressor matrix is sequential in time and its rows repeat while the input
stays between two levels, so the fit keeps one row per run of unchanged relay
states with its sample count as weight (an exact compression of the squared
error), and one column per set of relays that switch together on the fitted
record (their weight is shared equally: the data cannot tell them apart).
Relays that never switch on the fitted record get no weight; the offset ``c``
takes their constant part.

The relays are updated in numba-compiled loops; prediction switches only the
relays whose levels the input crossed since the last sample (found in the
sorted levels) and updates the weighted sum by them, without the N x 1275
matrix. At the first sample the relays sit
in the state of an input relaxed at ``x0`` (the Preisach image of a PI
without memory, Eq. 3 with ``y_i0 = x0``): every relay with ``alpha <= x0`` up,
``beta > x0`` down, and in between up below the line ``alpha + beta = 2 x0``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.optimize import nnls

from .pi_asym import InverseAsymmetricPI

#: The paper's discretization: 50 levels, 1275 relays.
N_H = 50


def levels(n_h: int) -> np.ndarray:
    """Switching levels: centres of ``n_h`` equal cells over [-1, 1]."""
    return -1.0 + (2.0 * np.arange(n_h) + 1.0) / n_h


def grid(n_h: int) -> tuple[np.ndarray, np.ndarray]:
    """``(alpha, beta)`` of the ``n_h (n_h + 1) / 2`` relays with ``alpha >= beta``."""
    lv = levels(n_h)
    i, j = np.tril_indices(n_h)  # i >= j
    return lv[i].copy(), lv[j].copy()


def relaxed_state(alpha: np.ndarray, beta: np.ndarray, x0: float) -> np.ndarray:
    """Relay states (+1/-1, int8) of an input relaxed at ``x0``."""
    up = (alpha <= x0) | ((beta <= x0) & (alpha + beta < 2.0 * x0))
    return np.where(up, 1, -1).astype(np.int8)


@njit(cache=True, inline="always")
def switch(alpha, beta, g, xk):
    """Switch the relays ``g`` (+1/-1, in place) for input ``xk``; True when any changed."""
    changed = False
    for i in range(alpha.shape[0]):
        if xk >= alpha[i]:
            if g[i] != 1:
                g[i] = 1
                changed = True
        elif xk < beta[i]:
            if g[i] != -1:
                g[i] = -1
                changed = True
    return changed


@njit(cache=True)
def _nearest_step(keys, weights, start, stop, kmin, kmax, base, target, lo_end, hi_end, base_at_end):
    """Input where the increasing staircase ``base + sum_{keys_i <= x} weights_i`` over
    ``keys[start:stop]`` (within ``[kmin, kmax]``; ``weights >= 0``; ``x`` in ``[lo_end, hi_end]``)
    is at its level nearest ``target``. A level's own value maps to the middle of its interval
    (``hi_end`` for the top level: nothing more to give), and targets between two levels
    linearly from there to the step between them, which the midpoint of the two levels
    reaches: the input is continuous and non-decreasing in ``target``, and always on the
    nearest level. With ``base_at_end`` the level ``base`` is the range's last the other way
    (nothing moves the sum that way) and maps to ``lo_end``, where the other way's call puts it.
    The entries are reordered in place.

    The level crossing ``target`` is found by splitting the candidate keys at the middle of
    their range and keeping the side it lies in: one pass over the survivors per split, O(n)
    for keys spread over the range.
    """
    prev, nxt = lo_end, hi_end  # ends of the interval of level `base` / of the level after the crossing
    while stop > start:
        pivot = 0.5 * (kmin + kmax) if kmax > kmin else kmax
        i, left, left_max, right_min = start, 0.0, kmin, kmax
        for q in range(start, stop):  # keys <= pivot to the front
            k = keys[q]
            if k <= pivot:
                keys[q], weights[q], keys[i], weights[i] = keys[i], weights[i], k, weights[q]
                left += weights[i]
                left_max = max(left_max, k)
                i += 1
            else:
                right_min = min(right_min, k)
        if kmax == kmin:  # the step: level base on [prev, kmin), base + left on [kmin, nxt)
            low = lo_end if base_at_end and prev == lo_end else 0.5 * (prev + kmin)
            high = hi_end if nxt >= hi_end else 0.5 * (kmin + nxt)
            half = base + 0.5 * left
            if target <= base or left <= 0.0:
                return low
            if target >= base + left:
                return high
            if target < half:  # nearer the level below: inside its interval, up to the step
                return low + (kmin - low) * (target - base) / (half - base)
            return kmin + (high - kmin) * (target - half) / (base + left - half)
        if base + left >= target:  # the crossing is among the keys <= pivot
            nxt, stop, kmax = right_min, i, left_max
        else:
            base += left
            prev, start, kmin = left_max, i, right_min
    return hi_end if nxt >= hi_end else 0.5 * (prev + nxt)  # target at or beyond the last level


@njit(cache=True)
def solve_input(alpha, beta, mu, g, target, lo, hi):
    """The input in ``[lo, hi]`` whose relays, switched from ``g``, give the weighted sum nearest ``target``.

    With ``mu >= 0`` the sum after one more sample is a non-decreasing staircase in
    that sample's input: flat between the largest ``beta`` of the relays up and the
    least ``alpha`` of those down, rising at each down relay's ``alpha``, falling
    below each up relay's ``beta``. The level nearest ``target`` is found in O(relays)
    and an input on it returned (:func:`_nearest_step`: continuous in ``target``; a
    level itself gives the middle of its interval, the top or bottom level the range
    end). ``g`` is not modified.
    """
    m = alpha.shape[0]
    keys = np.empty(m)  # rising candidates from the front, falling ones (mirrored, x -> -x) from the back
    weights = np.empty(m)
    now, flat_lo, flat_hi = 0.0, lo, hi
    up, down = 0, m
    rise_min, rise_max, fall_min, fall_max = np.inf, -np.inf, np.inf, -np.inf
    for i in range(m):
        now += mu[i] * g[i]
        if mu[i] == 0.0:  # switches nothing the output sees
            continue
        if g[i] > 0:
            flat_lo = max(flat_lo, beta[i])
            if beta[i] > lo:  # switches down below beta
                down -= 1
                keys[down], weights[down] = -beta[i], 2.0 * mu[i]
                fall_min = min(fall_min, -beta[i])
                fall_max = max(fall_max, -beta[i])
        else:
            flat_hi = min(flat_hi, alpha[i])
            if alpha[i] <= hi:  # switches up at alpha
                keys[up], weights[up] = alpha[i], 2.0 * mu[i]
                rise_min = min(rise_min, alpha[i])
                rise_max = max(rise_max, alpha[i])
                up += 1
    # at the top level (nothing rises) a target at it gives hi, and one just below it starts there;
    # at the bottom level alike with lo
    if target >= now:
        return _nearest_step(keys, weights, 0, up, rise_min, rise_max, now, target, flat_lo, hi, down == m)
    return -_nearest_step(keys, weights, down, m, fall_min, fall_max, -now, -target, -flat_hi, -lo, up == 0)


@njit(cache=True)
def _invert(alpha, beta, mu, y, state, lo, hi):
    out = np.empty(y.shape[0])
    g = state.copy()
    for k in range(y.shape[0]):
        out[k] = solve_input(alpha, beta, mu, g, y[k], lo, hi)
        switch(alpha, beta, g, out[k])
    return out, g


@njit(cache=True)
def _weighted(alpha, beta, mu, x, state, by_alpha, by_beta):
    # After a sample at xp every relay with alpha <= xp is up and every one with
    # beta > xp down, so the next sample switches only those with alpha in (xp, x]
    # (rising) or beta in (x, xp] (falling): found in the sorted levels, and the
    # weighted sum is updated by the switched relays alone.
    g = state.copy()
    out = np.empty(x.shape[0])
    if x.shape[0] == 0:
        return out, g
    a_sorted = alpha[by_alpha]
    b_sorted = beta[by_beta]
    switch(alpha, beta, g, x[0])
    acc = 0.0
    for i in range(g.shape[0]):
        acc += mu[i] * g[i]
    out[0] = acc
    for k in range(1, x.shape[0]):
        xp, xk = x[k - 1], x[k]
        if xk > xp:
            for q in range(np.searchsorted(a_sorted, xp, "right"), np.searchsorted(a_sorted, xk, "right")):
                i = by_alpha[q]
                if g[i] != 1:
                    g[i] = 1
                    acc += 2.0 * mu[i]
        elif xk < xp:
            for q in range(np.searchsorted(b_sorted, xk, "right"), np.searchsorted(b_sorted, xp, "right")):
                i = by_beta[q]
                if g[i] != -1:
                    g[i] = -1
                    acc -= 2.0 * mu[i]
        out[k] = acc
    return out, g


@njit(cache=True)
def _runs(alpha, beta, x, state):
    """Relay states of each run of samples with unchanged states, and each sample's run."""
    g = state.copy()
    rows = np.empty((x.shape[0], g.shape[0]), dtype=np.int8)
    run = np.empty(x.shape[0], dtype=np.int64)
    n = -1
    for k in range(x.shape[0]):
        if switch(alpha, beta, g, x[k]) or n < 0:
            n += 1
            rows[n] = g
        run[k] = n
    return rows[: n + 1].copy(), run, g


def relay_response(alpha: np.ndarray, beta: np.ndarray, x: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Every relay's output (N x m, int8) over an input: the plain regressor matrix."""
    rows, run, _ = _runs(alpha, beta, np.ascontiguousarray(x, dtype=np.float64), state)
    return rows[run]


def relay_response_numpy(alpha: np.ndarray, beta: np.ndarray, x: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Reference implementation: a per-sample numpy update of every relay."""
    g = np.asarray(state, dtype=np.int8).copy()
    out = np.empty((len(x), len(g)), dtype=np.int8)
    for k, xk in enumerate(np.asarray(x, dtype=np.float64)):
        g[xk >= alpha] = 1
        g[xk < beta] = -1  # beta <= alpha: never both
        out[k] = g
    return out


@dataclass(frozen=True, eq=False)
class PreisachModel:
    """A discrete Preisach model in normalized units.

    Attributes
    ----------
    alpha, beta : ndarray, shape (m,)
        Up- and down-switching levels, ``alpha >= beta``.
    mu : ndarray, shape (m,)
        Non-negative relay weights.
    offset : float
        Output offset ``c``.
    """

    alpha: np.ndarray
    beta: np.ndarray
    mu: np.ndarray
    offset: float = 0.0
    kind: ClassVar[str] = "preisach"

    def __post_init__(self):
        for name in ("alpha", "beta", "mu"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        object.__setattr__(self, "offset", float(self.offset))

    def init(self, x0: float) -> np.ndarray:
        """Relay states at the first sample: relaxed at ``x0``."""
        return relaxed_state(self.alpha, self.beta, float(x0))

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: switch the relays, then the weighted sum."""
        g = state.copy()
        switch(self.alpha, self.beta, g, float(x))
        return g, float(self.mu @ g) + self.offset

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        y, g = _weighted(self.alpha, self.beta, self.mu, x, np.asarray(state, dtype=np.int8),
                         np.argsort(self.alpha, kind="stable"), np.argsort(self.beta, kind="stable"))
        return y + self.offset, g

    @property
    def invertible(self) -> bool:
        """Every relay weight non-negative: the output is then non-decreasing in each sample's input."""
        return bool(np.all(self.mu >= 0.0))

    def inverse(self) -> "InversePreisach":
        """The numerical inverse (output to input)."""
        if not self.invertible:
            raise ValueError("Preisach model is not invertible: a relay weight is negative")
        return InversePreisach(self)

    def to_params(self) -> dict:
        return {"alpha": self.alpha.tolist(), "beta": self.beta.tolist(), "mu": self.mu.tolist(),
                "offset": self.offset}

    @classmethod
    def from_params(cls, d: dict) -> "PreisachModel":
        return cls(alpha=d["alpha"], beta=d["beta"], mu=d["mu"], offset=d["offset"])


@dataclass(frozen=True, eq=False)
class InversePreisach:
    """Inverse of a :class:`PreisachModel`, output to input, solved per sample (:func:`solve_input`).

    The state is the forward relay states; each sample's input is one in the
    identified range [-1, 1] whose switched relays give the output nearest the
    target (:func:`solve_input`), and the relays then switch with it. The forward
    model is a staircase in each sample's input, so ``forward(inverse(y))`` is the
    reachable level nearest ``y``: ``y`` itself only where ``y`` is a level.
    """

    forward: PreisachModel
    kind: ClassVar[str] = "inverse-preisach"
    #: The identified input range: the inverse never leaves it.
    x_range: ClassVar[tuple[float, float]] = (-1.0, 1.0)

    def init(self, y0: float, forward_state: np.ndarray | None = None) -> np.ndarray:
        """Relay states at the first sample: ``forward_state`` when given, else relaxed at the input whose
        relays, coming up from the bottom of the range, give ``y0``."""
        if forward_state is not None:
            return np.asarray(forward_state, dtype=np.int8).copy()
        f = self.forward
        x0 = solve_input(f.alpha, f.beta, f.mu, f.init(self.x_range[0]), float(y0) - f.offset, *self.x_range)
        return f.init(x0)

    #: One sample: the input giving output ``y``, and the switched relays (through :meth:`predict`).
    step = InverseAsymmetricPI.step

    def predict(self, y: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Input sequence that produces ``y`` (to the staircase's levels); ``(x, final_state)``."""
        f = self.forward
        y = np.ascontiguousarray(y, dtype=np.float64)
        if state is None:
            state = self.init(y[0])
        return _invert(f.alpha, f.beta, f.mu, y - f.offset, np.asarray(state, dtype=np.int8), *self.x_range)

    def to_params(self) -> dict:
        return {"forward": self.forward.to_params()}

    @classmethod
    def from_params(cls, d: dict) -> "InversePreisach":
        return cls(PreisachModel.from_params(d["forward"]))


def fit_preisach(x: np.ndarray, y: np.ndarray, n_h: int = N_H) -> PreisachModel:
    """Relay weights by non-negative least squares, offset free.

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n_h : int
        Levels per axis; ``n_h (n_h + 1) / 2`` relays.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    alpha, beta = grid(n_h)
    rows, run, _ = _runs(alpha, beta, x, relaxed_state(alpha, beta, x[0]))
    count = np.bincount(run, minlength=len(rows)).astype(np.float64)
    mean_y = np.bincount(run, weights=y, minlength=len(rows)) / count
    # Relays that switch together on this record are one column; constant ones none.
    cols, inverse = np.unique(rows, axis=1, return_inverse=True)
    inverse = inverse.ravel()
    varies = np.ptp(cols, axis=0) > 0
    A = cols[:, varies].astype(np.float64)
    # Runs weighted by their length: sum_k (a_k mu + c - y_k)^2 = sum_runs n (a mu + c - mean y)^2 + const.
    sw = np.sqrt(count)
    design = np.column_stack([A, np.ones(len(rows)), -np.ones(len(rows))]) * sw[:, None]
    sol, _ = nnls(design, mean_y * sw, maxiter=50 * design.shape[1])
    per_col = np.zeros(cols.shape[1])
    per_col[varies] = sol[: A.shape[1]]
    members = np.bincount(inverse, minlength=cols.shape[1])
    mu = per_col[inverse] / members[inverse]
    return PreisachModel(alpha=alpha, beta=beta, mu=mu, offset=sol[-2] - sol[-1])


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> PreisachModel:
    """Fitting entry point shared by every kind (see :mod:`models.fitting`); ``n`` is ``N_h``."""
    return fit_preisach(x, y, n_h=N_H if n is None else n)
