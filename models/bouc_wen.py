"""The Bouc-Wen model (paper §1, §2.1), integrated over input increments.

``dh/dt = A dx/dt - beta |dx/dt| |h|^(n-1) h - gamma dx/dt |h|^n``

is rate-independent: dividing by ``dx/dt`` gives the form integrated here,

``dh/dx = A - (beta sign(dx h) + gamma) |h|^n``,
``y = a x + b h + c``.

Integrating over the input's increments (not over time) makes the
discretization independent of the sample rate: each sample's increment
``dx`` is split into equal sub-steps no longer than :data:`MAX_SUBSTEP`
(normalized input) and each is taken with classical Runge-Kutta (order 4),
so the fit at ~10 Hz and a prediction at 100 Hz solve the same equation to
well below the sensor noise. The loop is numba-compiled.

Identification (the paper used Simulink's parameter estimation): ``A = 1``
(the scale of ``h`` is carried by ``b``); ``beta`` and ``gamma`` enter through
``u = beta + gamma > 0`` (``h`` saturates while loading, at ``u^(-1/n)``) and
``v = beta - gamma >= 0`` (unloading slope ``A + v |h|^n`` never below ``A``):
the bounded, dissipative class of Ikhouane & Rodellar (2007, "Systems with
Hysteresis", Wiley). ``u, v`` are searched in log scale within
:data:`SHAPE_BOUNDS`, ``n`` within :data:`N_BOUNDS`. Bounded nonlinear
least squares (``scipy.optimize.least_squares``) over these three, from
several starts (on every :data:`COARSE`-th sample, then the best refined on
all), with ``a, b, c`` solved by linear least squares inside every evaluation
(variable projection). At the first sample ``h = 0`` (no memory).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.optimize import least_squares

#: Longest integration sub-step in normalized input units.
MAX_SUBSTEP = 0.005
#: Bounds of the exponent n.
N_BOUNDS = (0.5, 6.0)
#: Bounds of beta + gamma and beta - gamma.
SHAPE_BOUNDS = (1e-3, 1e3)
#: The multi-start search keeps every COARSE-th sample (the refinement uses all).
COARSE = 4


@njit(cache=True, inline="always")
def _rhs(h, s, beta, gamma, n):
    # dh/dx for an increment of sign s: A - (beta sign(dx h) + gamma)|h|^n, A = 1.
    sg = 1.0 if s * h > 0 else (-1.0 if s * h < 0 else 0.0)
    return 1.0 - (beta * sg + gamma) * abs(h) ** n


@njit(cache=True, inline="always")
def integrate(h, dx, beta, gamma, n, max_sub):
    """``h`` after an input increment ``dx`` (RK4 in substeps of at most ``max_sub``)."""
    m = int(np.ceil(abs(dx) / max_sub))
    if m == 0:
        return h
    d = dx / m
    s = 1.0 if d > 0 else -1.0
    for _ in range(m):
        k1 = _rhs(h, s, beta, gamma, n)
        k2 = _rhs(h + 0.5 * d * k1, s, beta, gamma, n)
        k3 = _rhs(h + 0.5 * d * k2, s, beta, gamma, n)
        k4 = _rhs(h + d * k3, s, beta, gamma, n)
        h = h + d / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return h


@njit(cache=True)
def _hysteretic(x, x_prev, h, beta, gamma, n, max_sub):
    out = np.empty(x.shape[0])
    for k in range(x.shape[0]):
        h = integrate(h, x[k] - x_prev, beta, gamma, n, max_sub)
        x_prev = x[k]
        out[k] = h
    return out, x_prev, h


def hysteretic_naive(x: np.ndarray, x_prev: float, h: float, beta: float, gamma: float, n: float,
                     max_sub: float = MAX_SUBSTEP) -> np.ndarray:
    """Reference implementation: the same integration as a plain Python loop (benchmark baseline)."""
    out = np.empty(len(x))
    for k, xk in enumerate(x):
        dx = xk - x_prev
        m = int(np.ceil(abs(dx) / max_sub))
        for _ in range(m):
            d = dx / m
            s = np.sign(d)

            def f(v):
                return 1.0 - (beta * np.sign(s * v) + gamma) * abs(v) ** n

            k1 = f(h)
            k2 = f(h + 0.5 * d * k1)
            k3 = f(h + 0.5 * d * k2)
            k4 = f(h + d * k3)
            h = h + d / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        x_prev = xk
        out[k] = h
    return out


@dataclass(frozen=True, eq=False)
class BoucWenModel:
    """Bouc-Wen model in normalized units (``A = 1``).

    Attributes
    ----------
    beta, gamma, n : float
        Shape of the hysteretic variable ``h``.
    a, b, c : float
        Output ``y = a x + b h + c``.
    """

    beta: float
    gamma: float
    n: float
    a: float
    b: float
    c: float
    kind: ClassVar[str] = "bouc-wen"

    def __post_init__(self):
        for name in ("beta", "gamma", "n", "a", "b", "c"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def init(self, x0: float) -> np.ndarray:
        """State ``[x_prev, h]`` at the first sample: ``h = 0``."""
        return np.array([float(x0), 0.0])

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: integrate ``h`` over the increment, then the output."""
        h = integrate(state[1], float(x) - state[0], self.beta, self.gamma, self.n, MAX_SUBSTEP)
        return np.array([float(x), h]), self.a * float(x) + self.b * h + self.c

    def hysteretic(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The hysteretic variable ``h`` over an input, and the final state."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        h, xp, hn = _hysteretic(x, float(state[0]), float(state[1]), self.beta, self.gamma, self.n, MAX_SUBSTEP)
        return h, np.array([xp, hn])

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        h, s = self.hysteretic(x, state)
        return self.a * x + self.b * h + self.c, s

    def to_params(self) -> dict:
        return {k: getattr(self, k) for k in ("beta", "gamma", "n", "a", "b", "c")}

    @classmethod
    def from_params(cls, d: dict) -> "BoucWenModel":
        return cls(**{k: d[k] for k in ("beta", "gamma", "n", "a", "b", "c")})


def _linear_part(x, h, y):
    """``(a, b, c)`` by least squares and the residual ``a x + b h + c - y``."""
    A = np.column_stack([x, h, np.ones_like(x)])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    return coef, A @ coef - y


def fit_bouc_wen(x: np.ndarray, y: np.ndarray, starts: int = 6, seed: int = 0) -> BoucWenModel:
    """Fit ``beta, gamma, n`` (bounded, several starts) and ``a, b, c`` (inner least squares).

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    starts : int
        Number of starting points: a fixed central one, the rest drawn
        log-uniformly within the bounds (seeded, reproducible).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)

    def shape(q):
        u, v, n = np.exp(q[0]), np.exp(q[1]), q[2]  # u = beta + gamma, v = beta - gamma
        return 0.5 * (u + v), 0.5 * (u - v), n

    def residual(q, xs, ys):
        beta, gamma, n = shape(q)
        h, _, _ = _hysteretic(xs, xs[0], 0.0, beta, gamma, n, MAX_SUBSTEP)
        if not np.isfinite(h).all():
            # a shape whose state diverges on this input is no fit (and would break the SVD)
            return np.full_like(ys, 1e3 * (np.ptp(ys) + 1.0))
        return _linear_part(xs, h, ys)[1]

    lo = np.log(SHAPE_BOUNDS[0]), np.log(SHAPE_BOUNDS[1])
    bounds = ([lo[0], lo[0], N_BOUNDS[0]], [lo[1], lo[1], N_BOUNDS[1]])
    rng = np.random.default_rng(seed)
    q0s = [np.array([np.log(2.0), np.log(1.0), 1.5])]
    q0s += [np.array([rng.uniform(np.log(0.1), np.log(100.0)), rng.uniform(np.log(0.01), np.log(100.0)),
                      rng.uniform(*N_BOUNDS)]) for _ in range(starts - 1)]
    # The model is rate-independent and the sub-steps keep the integration accurate for
    # larger increments, so the starts run on every COARSE-th sample; the best is refined on all.
    xc, yc = x[::COARSE].copy(), y[::COARSE]
    best = None
    for q0 in q0s:
        sol = least_squares(residual, q0, args=(xc, yc), bounds=bounds, diff_step=1e-6, max_nfev=200)
        if best is None or sol.cost < best.cost:
            best = sol
    best = least_squares(residual, best.x, args=(x, y), bounds=bounds, diff_step=1e-6, max_nfev=100)
    beta, gamma, n = shape(best.x)
    h, _, _ = _hysteretic(x, x[0], 0.0, beta, gamma, n, MAX_SUBSTEP)
    (a, b, c), _ = _linear_part(x, h, y)
    return BoucWenModel(beta=beta, gamma=gamma, n=n, a=a, b=b, c=c)


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> BoucWenModel:
    """Fitting entry point shared by every kind; ``n`` (a resolution) does not apply to Bouc-Wen."""
    return fit_bouc_wen(x, y)
