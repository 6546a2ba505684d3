"""An asymmetric Prandtl-Ishlinskii model: generalized play operators whose
descending threshold widens with the input level.

Model followed: the *generalized* PI of Al Janaideh, Rakheja & Su (2009),
"A generalized Prandtl-Ishlinskii model for characterizing the hysteresis
and saturation nonlinearities of smart actuators", Smart Mater. Struct. 18,
045001. Its play operator has different envelope functions for the
ascending and the descending input,

``y_i(k) = max{gamma_l(x(k)) - r_i, min{gamma_r(x(k)) + r_i, y_i(k-1)}}``,

so ascending and descending branches need not be point-symmetric. Here the
ascending envelope is the identity (as in Eq. 1) and the descending one is
level- and threshold-dependent,

``y_i(k) = max{x(k) - r_i, min{x(k) + r_i (1 + a psi(x(k))), y_i(k-1)}}``
``psi(x) = ((x + 1) / 2)^p``  clipped to [0, 1]                (psi in [0, 1])

i.e. operator i's descending threshold grows from ``r_i`` at the bottom of
the range to ``r_i (1 + a)`` at the top. This is a variant of their form (they
share one gamma_r among all operators): scaling the widening with ``r_i``
makes the descending branch *wider*, more so at high flow, which is what the
paper reports for the valve (§4, errors above 140 L/min). In exploratory
fits on the bench identification recording a shared envelope
``x + a psi(x)`` kept about 1.7 times the in-sample RMSE of this form
(0.93 against 0.55 L/min). With ``a = 0`` the operators are those of Eq. (1)
and the model is a PI (:mod:`models.pi`), started without memory.

Output: ``y(k) = sum_i w_i y_i(k) + c`` (Eq. 4 with offset). Thresholds are
those of Eq. (2) after a zero threshold, as in :mod:`models.pi`.

Invertibility and the inverse. From a state reached by any input history
the operators start to move, as ``x`` leaves its last value, in the order of
their thresholds, so each sample's output is a continuous function of that
sample's input with slope ``s_j = sum_{i<=j} w_i`` when rising and
``s_j + a psi'(x) t_j``, ``t_j = sum_{i<=j} w_i r_i``, when falling, with
operators 0..j moving. The fit keeps both above a small positive bound
(linear constraints on the weights; for the falling one, at the largest
``psi'`` at which operator j can move for inputs within the fitted range,
see :func:`falling_gain`), so that function is strictly increasing. The
inverse (:class:`InverseAsymmetricPI`) solves it per sample by bisection, to
rounding; the closed form of Al Janaideh, Rakheja & Su (2011, IEEE/ASME
Trans. Mechatronics 16(4)) covers shared envelopes only.

The model has no stored memory: at the first sample the operators are
relaxed at the input (Eq. 3 with ``y_i0 = x(0)``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.linalg import eigh
from scipy.optimize import lsq_linear, minimize, nnls

from . import play
from .pi import MIN_SLOPE, thresholds

#: Search box of the envelope parameters ``a`` (widening at the top) and ``p`` (shape).
A_BOUNDS = (0.0, 40.0)
P_BOUNDS = (1.0, 10.0)


@njit(cache=True, inline="always")
def _psi(x, p):
    u = 0.5 * (x + 1.0)
    if u <= 0.0:
        return 0.0
    if u >= 1.0:
        return 1.0
    return u**p


@njit(cache=True, inline="always")
def down_scale(x, a, p):
    """Factor of every descending threshold at input ``x``: ``1 + a psi(x)``."""
    if a == 0.0:  # Eq. (1), without the power (psi is finite: 1 + 0 psi is exactly 1)
        return 1.0
    return 1.0 + a * _psi(x, p)


@njit(cache=True)
def down_scales(x, a, p):
    """:func:`down_scale` at every sample of ``x``."""
    out = np.empty(x.shape[0])
    for k in range(x.shape[0]):
        out[k] = down_scale(x[k], a, p)
    return out


@njit(cache=True)
def _output(r, w, a, p, y, x):
    """Weighted output after input ``x`` from operator states ``y`` (not modified)."""
    return play.bank_step(r, w, down_scale(x, a, p), y.copy(), x)


@njit(cache=True)
def solve_input(r, w, a, p, state, target, x_guess):
    """The input ``x`` whose output from ``state`` equals ``target`` (monotone; bisection)."""
    lo = x_guess - 1.0
    hi = x_guess + 1.0
    width = 2.0
    while _output(r, w, a, p, state, lo) > target:
        width *= 2.0
        lo = hi - width
    while _output(r, w, a, p, state, hi) < target:
        width *= 2.0
        hi = lo + width
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if _output(r, w, a, p, state, mid) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@njit(cache=True)
def _invert(r, w, a, p, y, state, x_guess):
    out = np.empty(y.shape[0])
    s = state.copy()
    x = x_guess
    for k in range(y.shape[0]):
        x = solve_input(r, w, a, p, s, y[k], x)
        play.bank_step(r, w, down_scale(x, a, p), s, x)
        out[k] = x
    return out, s


def envelope(x: np.ndarray, p: float) -> np.ndarray:
    """``psi(x) = ((x + 1)/2)^p`` clipped to [0, 1]: where the descending widening acts."""
    return np.clip(0.5 * (np.asarray(x, dtype=np.float64) + 1.0), 0.0, 1.0) ** p


@dataclass(frozen=True, eq=False)
class AsymmetricPIModel:
    """Asymmetric (generalized) PI in normalized units.

    Attributes
    ----------
    r : ndarray, shape (m,)
        Ascending thresholds, ``r[0] == 0``.
    w : ndarray, shape (m,)
        Weights.
    a : float
        Relative widening of every descending threshold at the top of the range.
    p : float
        Exponent of ``psi``: how the widening is concentrated towards the top.
    offset : float
        Output offset ``c``.
    """

    r: np.ndarray
    w: np.ndarray
    a: float = 0.0
    p: float = 1.0
    offset: float = 0.0
    kind: ClassVar[str] = "pi-asym"

    def __post_init__(self):
        object.__setattr__(self, "r", np.asarray(self.r, dtype=np.float64))
        object.__setattr__(self, "w", np.asarray(self.w, dtype=np.float64))
        for name in ("a", "p", "offset"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def init(self, x0: float) -> np.ndarray:
        """Operator states at the first sample: relaxed at ``x0`` (Eq. 3 with ``y_i0 = x0``, no memory)."""
        return np.full(len(self.r), float(x0))

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample of the generalized play bank, then Eq. (4)."""
        s = np.array(state, dtype=np.float64)
        y = play.bank_step(self.r, self.w, down_scale(float(x), self.a, self.p), s, float(x))
        return s, y + self.offset

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        y, s = play.play_weighted(self.r, self.w, x, state, down_scales(x, self.a, self.p))
        return y + self.offset, s

    def response(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Every operator's output (N x m) and the final states."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        return play.play_response(self.r, x, state, down_scales(x, self.a, self.p))

    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """Least output slopes with operators 0..j active: rising ``s_j``, falling (inputs within [-1, 1])."""
        s = np.cumsum(self.w)
        t = np.cumsum(self.w * self.r)
        return s, s + falling_gain(self.r, self.a, self.p) * np.minimum(t, 0.0)

    @property
    def invertible(self) -> bool:
        """Zero first threshold and every rising and falling slope positive (see module docstring)."""
        up, down = self.slopes()
        return bool(self.r[0] == 0.0 and np.all(up > 0) and np.all(down > 0))

    def inverse(self) -> "InverseAsymmetricPI":
        """The inverse core (output to input), for feedforward."""
        if not self.invertible:
            raise ValueError("asymmetric PI is not invertible: a rising or falling slope is not positive")
        return InverseAsymmetricPI(self)

    def to_params(self) -> dict:
        return {"r": self.r.tolist(), "w": self.w.tolist(), "a": self.a, "p": self.p, "offset": self.offset}

    @classmethod
    def from_params(cls, d: dict) -> "AsymmetricPIModel":
        return cls(r=d["r"], w=d["w"], a=d["a"], p=d["p"], offset=d["offset"])


@dataclass(frozen=True, eq=False)
class InverseAsymmetricPI:
    """Inverse of an :class:`AsymmetricPIModel`, output ``y`` to input ``x``.

    The state is the forward operator states; each step finds the one input
    that makes the forward output equal ``y`` from that state (strictly
    increasing in the input, see the module docstring), then advances the
    forward operators with it. ``forward.predict(inverse.predict(y)[0])``
    returns ``y`` to rounding, and ``inverse(forward(x)) == x`` wherever the
    forward output moves with the input.
    """

    forward: AsymmetricPIModel
    kind: ClassVar[str] = "inverse-pi-asym"

    def init(self, y0: float, forward_state: np.ndarray | None = None) -> np.ndarray:
        """Inverse state at the first sample.

        With ``forward_state`` (the forward operators after the first input) it
        is used as is; without, the operators start relaxed as in
        :meth:`AsymmetricPIModel.init`, at the input whose relaxed output is
        ``y0``: ``x0 = (y0 - c) / sum(w)``.
        """
        if forward_state is not None:
            return np.asarray(forward_state, dtype=np.float64).copy()
        f = self.forward
        return f.init((float(y0) - f.offset) / float(np.sum(f.w)))

    def step(self, state: np.ndarray, y: float) -> tuple[np.ndarray, float]:
        """One sample: the input giving output ``y``, and the advanced forward state."""
        x, s = self.predict(np.array([float(y)]), state)
        return s, float(x[0])

    def predict(self, y: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Input sequence that produces ``y``; ``(x, final_state)``."""
        f = self.forward
        y = np.ascontiguousarray(y, dtype=np.float64)
        if state is None:
            state = self.init(y[0])
        state = np.asarray(state, dtype=np.float64)
        # Any state lies within the bands of the input that made it: start the search there.
        guess = float(np.median(state))
        return _invert(f.r, f.w, f.a, f.p, y - f.offset, state, guess)

    def to_params(self) -> dict:
        return {"forward": self.forward.to_params()}

    @classmethod
    def from_params(cls, d: dict) -> "InverseAsymmetricPI":
        return cls(AsymmetricPIModel.from_params(d["forward"]))


def regressors(r: np.ndarray, a: float, p: float, x: np.ndarray) -> np.ndarray:
    """Operator outputs (N x m) for the fit, operators relaxed at ``x[0]``."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return play.play_response(r, x, np.full(len(r), x[0]), down_scales(x, a, p))[0]


def design(r, a, p, x):
    """Regressors in the partial-sum unknowns ``(s_1..s_m, c)``: column j is ``Y_j - Y_{j+1}``."""
    Y = regressors(r, a, p, x)
    Y[:, :-1] -= Y[:, 1:]
    return np.column_stack([Y, np.ones(len(x))])


def _compressed(A, b):
    """``R, c, e`` with ``||A t - b||^2 = ||R t - c||^2 + e`` for every t.

    From the Gram matrix, ``A^T A = V diag(lam) V^T`` and ``R = diag(sqrt(lam)) V^T``:
    the N rows are read once, and the small problem is solved many times in the
    envelope search. Directions the data does not excite (operators that never
    move apart, ``lam`` ~ 0) get zero rows, so rank-deficient records still fit.
    """
    lam, V = eigh(A.T @ A)
    keep = lam > lam[-1] * 1e-13
    root = np.sqrt(np.where(keep, lam, 0.0))
    proj = V.T @ (A.T @ b)
    c = np.where(keep, proj / np.where(keep, root, 1.0), 0.0)
    return root[:, None] * V.T, c, float(b @ b - c @ c)


def _fit_bounded(R, c, e, min_slope):
    """Partial sums and offset with only the rising slopes bounded (``s_j >= min_slope``); and the squared error."""
    m = R.shape[1] - 1
    lb = np.concatenate([np.full(m, min_slope), [-np.inf]])
    res = lsq_linear(R, c, bounds=(lb, np.full(m + 1, np.inf)), method="bvls", tol=1e-12, max_iter=5000)
    return res.x, float(np.sum((R @ res.x - c) ** 2)) + e


def falling_gain(r: np.ndarray, a: float, p: float) -> np.ndarray:
    """Largest ``a psi'(x)`` at which operator j can move while the input falls.

    No operator state exceeds the largest input so far (rising moves give
    ``x - r_j``, a relaxed start ``x``), so for inputs within [-1, 1] operator j
    moves down only at ``x < 1 - r_j (1 + a psi(x)) <= 1 - r_j``; ``psi'`` grows
    with x, so the bound is ``a psi'(1 - r_j) = a (p/2) (1 - r_j/2)^(p-1)``.
    """
    return a * 0.5 * p * np.clip(1.0 - 0.5 * np.asarray(r, dtype=np.float64), 0.0, 1.0) ** (p - 1.0)


def falling_constraint(r, a, p):
    """Matrix G with ``G @ s`` = the least falling slopes ``s_j + falling_gain_j t_j`` (for t_j < 0)."""
    m = len(r)
    # t_j = sum_{i<=j} r_i (s_i - s_{i-1}) = r_j s_j - sum_{i<j} s_i (r_{i+1} - r_i)
    dr = np.diff(r)
    T = np.tril(np.broadcast_to(-np.append(dr, 0.0), (m, m)), k=-1) + np.diag(r)
    return np.eye(m) + falling_gain(r, a, p)[:, None] * T


def _fit_weights(R, c, e, r, a, p, min_slope):
    """Constrained least squares for ``(s, c)``: rising and falling slopes >= ``min_slope``."""
    m = len(r)
    theta, _ = _fit_bounded(R, c, e, min_slope)
    G = falling_constraint(r, a, p)
    if np.all(G @ theta[:m] >= min_slope * (1 - 1e-9)):
        return theta  # optimal for the larger feasible set, so here too
    C = np.zeros((2 * m, m + 1))
    C[:m, :m] = np.eye(m)
    C[m:, :m] = G
    return _least_distance(R, c, C, np.full(2 * m, min_slope))


def _least_distance(R, c, C, d):
    """``argmin ||R t - c||`` subject to ``C t >= d``, through least-distance programming.

    Lawson & Hanson (1974), "Solving Least Squares Problems", ch. 23: with
    ``t = R^-1 (u + c)`` the problem is the least-norm ``u`` with
    ``C R^-1 u >= d - C R^-1 c``, whose solution follows from one NNLS. Directions
    the data leaves unexcited get a tiny ridge so that ``R`` is invertible.
    """
    lam, V = eigh(R.T @ R)
    lam = np.maximum(lam, lam[-1] * 1e-10)
    Rinv = V / np.sqrt(lam)  # R2^-1 for R2 = diag(sqrt(lam)) V^T, the same Gram as R
    c2 = (V.T @ (R.T @ c)) / np.sqrt(lam)
    Gu = C @ Rinv
    h = d - Gu @ c2
    E = np.vstack([Gu.T, h])
    f = np.zeros(E.shape[0])
    f[-1] = 1.0
    v, _ = nnls(E, f, maxiter=50 * E.shape[1])
    res = E @ v - f
    if abs(res[-1]) < 1e-12:
        raise ValueError("slope constraints cannot all be met")
    u = -res[:-1] / res[-1]
    return Rinv @ (u + c2)


def fit_pi_asym(
    x: np.ndarray,
    y: np.ndarray,
    n: int = 50,
    min_slope: float = MIN_SLOPE,
    envelope: tuple[float, float] | None = None,
) -> AsymmetricPIModel:
    """Fit the envelope ``(a, p)``, the weights and the offset.

    The envelope minimizes the in-sample squared error over ``(a, p)`` (a
    coarse grid, then Nelder-Mead, within :data:`A_BOUNDS` and
    :data:`P_BOUNDS`), with the weights by bounded linear least squares at
    each candidate; the final weights meet the invertibility constraints.
    The recording's first state is unknown: the operators start relaxed at
    ``x[0]`` (no memory assumed), as :meth:`AsymmetricPIModel.init` does.

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n : int
        Number of Eq. (2) thresholds (the zero threshold comes on top).
    min_slope : float
        Lower bound on rising and falling output slopes, normalized units.
    envelope : (a, p), optional
        Fix the envelope instead of searching it (``(0, 1)``: the symmetric PI).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r = thresholds(n, x_max=float(np.max(np.abs(x))))

    def cost(ap):
        a, p = np.clip(ap, (A_BOUNDS[0], P_BOUNDS[0]), (A_BOUNDS[1], P_BOUNDS[1]))
        return _fit_bounded(*_compressed(design(r, a, p, x), y), min_slope)[1]

    if envelope is None:
        grid = [(a, p) for a in (0.0, 1.0, 4.0, 12.0) for p in (1.0, 2.5, 5.0)]
        start = min(grid, key=cost)
        res = minimize(cost, np.array(start) + (0.5, 0.25), method="Nelder-Mead",
                       options={"xatol": 1e-2, "fatol": 1e-6, "maxfev": 60})
        a, p = np.clip(res.x, (A_BOUNDS[0], P_BOUNDS[0]), (A_BOUNDS[1], P_BOUNDS[1]))
        if cost((a, p)) > cost(start):
            a, p = start
    else:
        a, p = envelope
    theta = _fit_weights(*_compressed(design(r, a, p, x), y), r, a, p, min_slope)
    w = np.diff(theta[: len(r)], prepend=0.0)
    return AsymmetricPIModel(r=r, w=w, a=a, p=p, offset=theta[-1])


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> AsymmetricPIModel:
    """Fitting entry point shared by every kind (see :mod:`models.fitting`)."""
    return fit_pi_asym(x, y, n=50 if n is None else n)
