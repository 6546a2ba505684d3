"""The modified Prandtl-Ishlinskii model of Kuhnen: the PI family's model for real valves.

Model followed: K. Kuhnen (2003), "Modeling, identification and compensation
of complex hysteretic nonlinearities: a modified Prandtl-Ishlinskii
approach", European Journal of Control 9(4), 407-418. A PI (Eq. 1-4 of the
paper in ``paper/``) is followed by a memoryless superposition of one-sided
dead-zone operators on its output:

``p(k) = sum_i w_i y_i(k)``                                       # Eq. (4), play operators of Eq. (1)
``Q(k) = S[p](k) + c``,  ``S[p] = sum_j g_j d_{h_j}(p)``           # Kuhnen's output superposition
``d_h(p) = max(p - h, 0)`` (h > 0), ``p`` (h = 0), ``min(p - h, 0)`` (h < 0)

``S`` is a continuous piecewise-linear map through the origin whose slope on
the segment beyond ``h_i`` is the partial sum of the weights from ``g_0``
outwards. That is what a real valve adds at its range ends: below its
cracking duty the flow stays at zero (a segment of almost no slope at the
bottom) and at full opening it saturates (one at the top), neither of which
the PI's central symmetry can follow.

Invertibility (Kuhnen): every loading slope of the PI (partial sums of
``w``, zero first threshold) and every segment slope of ``S`` positive. The
inverse is then again of the same form, in closed form: the inverse PI of
Eq. (5)-(7) after ``S^{-1}``, which is a superposition of one-sided dead
zones with thresholds ``h_i' = S(h_i)`` and weights
``g_0' = 1/g_0``, ``g_i' = -g_i / (sigma_i sigma_{i-1})`` (sigma: the partial
sums; Eq. 7's second line on the output axis). So
``forward(inverse(Q)) == Q`` and ``inverse(forward(x)) == x`` to rounding.

Inside the dead zone every duty below cracking gives (nearly) no flow: the
model keeps a small positive slope there, so its inverse fed a zero flow
returns the duty at which the modelled flow reaches zero on the present
branch, the cracking duty of the valve's present memory (what a feedforward
does with it is in :mod:`controller.laws.feedforward`).

Fit: output-error least squares on the preprocessed recording, in the PI's
partial sums and the segment slopes of ``S`` (all bounded below by a small
positive slope, the middle one fixed at 1 since the PI's gain can take it),
and the offset; started from the constrained PI fit (``S`` the identity) and
solved with bounds (``scipy.optimize.least_squares``, trust region
reflective) with the exact Jacobian.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from . import inverse_pi, play
from .inverse_pi import invert_pi
from .pi import MIN_SLOPE, PIModel, fit_weights, regressors, thresholds
from .pi_asym import InverseAsymmetricPI

#: One-sided dead-zone operators on each side of the origin (Kuhnen's output superposition).
N_DEAD_ZONE = 6
#: Flows within this fraction of the output range above the closed flow count as closed for the
#: inverse: the model is nearly flat there, so its inverse would turn sensor noise into duty jumps.
CLOSED_BAND = 0.01


@njit(cache=True, inline="always")
def dead_zone(h, g, z):
    """``sum_j g_j d_{h_j}(z)``: Kuhnen's superposition of one-sided dead-zone operators at ``z``."""
    acc = 0.0
    for j in range(h.shape[0]):
        if h[j] > 0.0:
            d = z - h[j] if z > h[j] else 0.0
        elif h[j] < 0.0:
            d = z - h[j] if z < h[j] else 0.0
        else:
            d = z
        acc += g[j] * d
    return acc


@njit(cache=True)
def _dead_zone_all(h, g, z):
    out = np.empty(z.shape[0])
    for k in range(z.shape[0]):
        out[k] = dead_zone(h, g, z[k])
    return out


def apply_dead_zone(h: np.ndarray, g: np.ndarray, z: np.ndarray) -> np.ndarray:
    """:func:`dead_zone` over an array."""
    z = np.asarray(z, dtype=np.float64)
    return _dead_zone_all(np.ascontiguousarray(h, dtype=np.float64), np.ascontiguousarray(g, dtype=np.float64),
                          np.ascontiguousarray(z).reshape(-1)).reshape(z.shape)


def segment_slopes(h: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Slope of ``S`` on each segment, in the order of ``h`` (ascending, one zero threshold):
    the partial sums of ``g`` from the zero threshold outwards."""
    i0 = int(np.flatnonzero(h == 0.0)[0])
    sigma = np.empty_like(g)
    sigma[i0:] = np.cumsum(g[i0:])
    sigma[:i0 + 1] = np.cumsum(g[i0::-1])[::-1]
    return sigma


def invert_dead_zone(h: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds and weights of ``S^{-1}``, again a superposition of one-sided dead zones (Kuhnen).

    ``h_i' = S(h_i)``; ``g_0' = 1/g_0``; outwards on each side
    ``g_i' = 1/sigma_i - 1/sigma_{i-1} = -g_i / (sigma_i sigma_{i-1})``.
    """
    h = np.asarray(h, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    sigma = segment_slopes(h, g)
    if not np.all(sigma > 0):
        raise ValueError("dead-zone superposition is not invertible: a segment slope is not positive")
    i0 = int(np.flatnonzero(h == 0.0)[0])
    g_inv = np.empty_like(g)
    g_inv[i0] = 1.0 / g[i0]
    g_inv[i0 + 1:] = -g[i0 + 1:] / (sigma[i0 + 1:] * sigma[i0:-1])
    g_inv[:i0] = -g[:i0] / (sigma[:i0] * sigma[1:i0 + 1])
    return apply_dead_zone(h, g, h), g_inv


def dead_zone_thresholds(p_min: float, p_max: float, k: int = N_DEAD_ZONE) -> np.ndarray:
    """``k`` thresholds evenly inside each of ``(p_min, 0)`` and ``(0, p_max)``, and the zero one, ascending."""
    j = np.arange(1, k + 1) / (k + 1)
    return np.concatenate([(p_min * j)[::-1], [0.0], p_max * j])


@dataclass(frozen=True, eq=False)
class ModifiedPIModel:
    """Kuhnen's modified PI in normalized units.

    Attributes
    ----------
    r, w : ndarray, shape (m,)
        Play thresholds (Eq. 2 after a zero one) and weights (Eq. 4).
    h, g : ndarray, shape (2K + 1,)
        Dead-zone thresholds (ascending, one zero) and weights of ``S``.
    offset : float
        Output offset ``c``.
    floor : float
        The valve's closed flow: the output never falls below it (no flow through a
        closed valve; the lowest flow of the identification recording).
    y0 : ndarray, shape (m,)
        Play memory before the first sample (Eq. 3); NaN: at rest at the first input.
    """

    r: np.ndarray
    w: np.ndarray
    h: np.ndarray
    g: np.ndarray
    offset: float = 0.0
    floor: float = -np.inf
    y0: np.ndarray = field(default=None)
    kind: ClassVar[str] = "pi-mod"

    def __post_init__(self):
        for name in ("r", "w", "h", "g"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        y0 = np.full_like(self.r, np.nan) if self.y0 is None else np.asarray(self.y0, dtype=np.float64)
        object.__setattr__(self, "y0", y0)
        object.__setattr__(self, "offset", float(self.offset))
        object.__setattr__(self, "floor", float(self.floor))

    @property
    def pi(self) -> PIModel:
        """The play part alone (no offset): ``p = w^T H_r[x]``."""
        return PIModel(self.r, self.w, 0.0, self.y0)

    def init(self, x0: float) -> np.ndarray:
        """Play operator states at the first sample, Eq. (3)."""
        return play.init(self.r, x0, self.y0)

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: Eq. (1), Eq. (4), then ``S`` and the offset."""
        s = np.array(state, dtype=np.float64)
        p = play.bank_step(self.r, self.w, 1.0, s, float(x))
        return s, max(dead_zone(self.h, self.g, p) + self.offset, self.floor)

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.asarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        p, s = play.play_weighted(self.r, self.w, x, state)
        return np.maximum(apply_dead_zone(self.h, self.g, p) + self.offset, self.floor), s

    @property
    def invertible(self) -> bool:
        """Kuhnen's conditions: the PI part invertible and every segment slope of ``S`` positive."""
        return self.pi.invertible and bool(np.all(segment_slopes(self.h, self.g) > 0))

    def inverse(self) -> "InverseModifiedPI":
        """The closed-form inverse (output to input)."""
        if not self.invertible:
            raise ValueError("modified PI is not invertible: a loading or a dead-zone slope is not positive")
        return InverseModifiedPI(self)

    def to_params(self) -> dict:
        y0 = None if np.all(np.isnan(self.y0)) else self.y0.tolist()
        return {"r": self.r.tolist(), "w": self.w.tolist(), "h": self.h.tolist(), "g": self.g.tolist(),
                "offset": self.offset, "floor": self.floor, "y0": y0}

    @classmethod
    def from_params(cls, d: dict) -> "ModifiedPIModel":
        return cls(r=d["r"], w=d["w"], h=d["h"], g=d["g"], offset=d["offset"], floor=d["floor"], y0=d.get("y0"))


@njit(cache=True, inline="always")
def solve(r, w, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, fwd_state, work, q):
    """The input that takes the forward play memory ``fwd_state`` to output ``q`` (memory unchanged).

    ``x = Gamma^{-1}[S^{-1}[q - c]]`` in closed form (Eq. 7 from the forward memory, then
    Eq. 5-6); a closed valve (``q <= closed``) gives ``x_closed``. With ``h_inv = [0]``,
    ``g_inv = [1]`` and ``closed = -inf`` it is the plain PI's inverse.
    """
    if q <= closed:
        return x_closed
    return inverse_pi.solve(r, w, r_inv, w_inv, fwd_state, work, dead_zone(h_inv, g_inv, q - offset))


@njit(cache=True)
def _invert(r, w, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, q, fwd_state):
    out = np.empty(q.shape[0])
    s = fwd_state.copy()
    work = np.empty(r.shape[0])
    for k in range(q.shape[0]):
        x = solve(r, w, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, s, work, q[k])
        play.bank_step(r, w, 1.0, s, x)  # the forward memory follows the input found
        out[k] = x
    return out, s


@dataclass(frozen=True, eq=False)
class InverseModifiedPI:
    """Inverse of a :class:`ModifiedPIModel`, output to input: ``x = Gamma^{-1}[S^{-1}[Q - c]]``.

    The state is the forward play memory: each sample's input comes from it in
    closed form (Eq. 7 for the inverse operators' memory, ``S^{-1}``, then
    Eq. 5-6), and the memory then follows that input. Outputs above
    :attr:`closed` are inverted exactly (``forward(inverse(Q)) == Q``); a closed
    valve (``Q <= closed``, where the model is nearly flat and any input below
    cracking fits) gives the bottom of the input range: the valve closed, the
    state a valve that has seen no flow is in.
    """

    forward: ModifiedPIModel
    kind: ClassVar[str] = "inverse-pi-mod"

    def __post_init__(self):
        f = self.forward
        inv = invert_pi(f.pi)
        h_inv, g_inv = invert_dead_zone(f.h, f.g)
        for name, v in (("r_inv", inv.r), ("w_inv", inv.w), ("h_inv", h_inv), ("g_inv", g_inv)):
            object.__setattr__(self, name, np.ascontiguousarray(v))

    @property
    def closed(self) -> float:
        """Outputs at or below this level are a closed valve (:data:`CLOSED_BAND` above the floor)."""
        return self.forward.floor + 2.0 * CLOSED_BAND

    #: Input of a closed valve: the bottom of the identified range.
    x_closed: ClassVar[float] = -1.0

    def init(self, y0: float, forward_state: np.ndarray | None = None) -> np.ndarray:
        """Forward memory at the first sample: ``forward_state`` when given, else at rest at the input
        whose output at rest is ``y0`` (every operator at ``x0``, output ``S(sum(w) x0) + c``)."""
        if forward_state is not None:
            return np.array(forward_state, dtype=np.float64)
        f = self.forward
        x0 = (self.x_closed if y0 <= self.closed
              else dead_zone(self.h_inv, self.g_inv, float(y0) - f.offset) / float(np.sum(f.w)))
        return f.init(x0)

    #: One sample: the input giving output ``y``, and the forward memory after it (as pi-asym's inverse).
    step = InverseAsymmetricPI.step

    def predict(self, y: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Input that produces the output sequence ``y``; ``(x, final_state)``."""
        f = self.forward
        y = np.ascontiguousarray(y, dtype=np.float64)
        if state is None:
            state = self.init(y[0])
        return _invert(f.r, f.w, self.r_inv, self.w_inv, self.h_inv, self.g_inv, f.offset, self.closed,
                       self.x_closed, y, np.asarray(state, dtype=np.float64))

    def to_params(self) -> dict:
        return {"forward": self.forward.to_params()}

    @classmethod
    def from_params(cls, d: dict) -> "InverseModifiedPI":
        return cls(ModifiedPIModel.from_params(d["forward"]))


def _segments(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ends ``(lo, hi)`` of the segment whose slope is ``sigma_j``, for each threshold index j.

    Below the origin ``sigma_j`` holds between ``h_{j-1}`` and ``h_j``, above it between ``h_j``
    and ``h_{j+1}``; the zero threshold's slope spans both of its neighbours.
    """
    i0 = int(np.flatnonzero(h == 0.0)[0])
    ext = np.concatenate([[-np.inf], h, [np.inf]])
    j = np.arange(len(h))
    lo = np.where(j <= i0, ext[j], ext[j + 1])
    hi = np.where(j >= i0, ext[j + 2], ext[j + 1])
    return lo, hi


def _segment_basis(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``Phi`` (N x len(h)) with ``S(p) = Phi @ sigma``: the signed length of [0, p] in each segment."""
    lo, hi = _segments(h)
    pp = p[:, None]
    above = np.clip(np.minimum(pp, hi) - np.maximum(0.0, lo), 0.0, None)
    below = np.clip(np.minimum(0.0, hi) - np.maximum(pp, lo), 0.0, None)
    return above - below


def _local_slope(h: np.ndarray, sigma: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``dS/dp`` at each ``p``: the slope of the segment it lies in."""
    lo, _ = _segments(h)
    return sigma[np.searchsorted(lo[1:], p, side="left")]


def _slopes_to_weights(h: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    i0 = int(np.flatnonzero(h == 0.0)[0])
    g = np.empty_like(sigma)
    g[i0] = sigma[i0]
    g[i0 + 1:] = np.diff(sigma[i0:])
    g[:i0] = sigma[:i0] - sigma[1:i0 + 1]
    return g


def fit_pi_mod(x: np.ndarray, y: np.ndarray, n: int = 50, k: int = N_DEAD_ZONE,
               min_slope: float = MIN_SLOPE) -> ModifiedPIModel:
    """Fit the play weights, the dead-zone superposition and the offset (see the module docstring).

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n : int
        Number of Eq. (2) thresholds (the zero threshold comes on top).
    k : int
        Dead-zone operators on each side of the origin.
    min_slope : float
        Lower bound on every loading slope and every dead-zone segment slope.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r = thresholds(n, x_max=float(np.max(np.abs(x))))
    Y = regressors(r, x)
    w0, c0, _ = fit_weights(Y, y, min_slope=min_slope)
    A = Y.copy()
    A[:, :-1] -= Y[:, 1:]  # columns in the partial sums (loading slopes), as in models.pi.fit_weights
    s0 = np.cumsum(w0)
    p0 = A @ s0
    h = dead_zone_thresholds(min(float(p0.min()), -1e-3), max(float(p0.max()), 1e-3), k)
    i0 = k
    m = len(r)
    free = np.r_[0:i0, i0 + 1:2 * k + 1]  # the middle slope is fixed at 1

    def unpack(theta):
        sigma = np.ones(2 * k + 1)
        sigma[free] = theta[m:m + 2 * k]
        return theta[:m], sigma, theta[-1]

    floor = float(np.min(y))

    def residual(theta):
        s, sigma, c = unpack(theta)
        return np.maximum(_segment_basis(h, A @ s) @ sigma + c, floor) - y

    def jac(theta):
        s, sigma, c = unpack(theta)
        p = A @ s
        phi = _segment_basis(h, p)
        live = (phi @ sigma + c > floor)[:, None]  # rows at the floor do not move with the parameters
        return np.column_stack([A * _local_slope(h, sigma, p)[:, None], phi[:, free], np.ones(len(p))]) * live

    lb = np.concatenate([np.full(m + 2 * k, min_slope), [-np.inf]])
    theta0 = np.maximum(np.concatenate([s0, np.ones(2 * k), [c0]]), lb + min_slope * 1e-3)  # strictly inside
    res = least_squares(residual, theta0, jac=jac, bounds=(lb, np.full(len(lb), np.inf)), method="trf",
                        x_scale="jac", max_nfev=200)
    s, sigma, c = unpack(res.x)
    return ModifiedPIModel(r=r, w=np.diff(s, prepend=0.0), h=h, g=_slopes_to_weights(h, sigma), offset=c, floor=floor)


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> ModifiedPIModel:
    """Fitting entry point shared by every kind (see :mod:`models.fitting`)."""
    return fit_pi_mod(x, y, n=50 if n is None else n)
