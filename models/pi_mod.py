"""The modified Prandtl-Ishlinskii model: the PI family's model for real valves.

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

The plays may be the generalized operators of Al Janaideh, Rakheja & Su
(2009), as in :mod:`models.pi_asym`: every descending threshold ``r_i (1 + a
psi(x))`` widens with the input level. ``S`` acts on the output only, so it
cannot make the loop's width in duty vary with the level; the envelope can,
and the bench valve's descending branch is wider at high flow (bench
validation RMSE: Kuhnen's form 2.13 L/min, pi-asym 0.89, this one 0.81).
With ``a = 0`` (the default, and every model file without ``a``) the model
is Kuhnen's; with ``S`` the identity it is the asymmetric PI.

Invertibility: every rising and falling slope of the plays positive
(Kuhnen's loading slopes when ``a = 0``; :mod:`models.pi_asym` otherwise) and
every segment slope of ``S`` positive. ``S^{-1}`` is again a superposition of
one-sided dead zones, in closed form (Kuhnen): thresholds ``h_i' = S(h_i)``,
weights ``g_0' = 1/g_0``, ``g_i' = -g_i / (sigma_i sigma_{i-1})`` (sigma: the
partial sums; Eq. 7's second line on the output axis). The plays' inverse is
the inverse PI of Eq. (5)-(7) when ``a = 0``, and otherwise the one input
whose generalized plays give ``S^{-1}[Q - c]``, found by bisection to
rounding (the output is strictly increasing in each sample's input). So
``forward(inverse(Q)) == Q`` and ``inverse(forward(x)) == x`` to rounding.

Inside the dead zone every duty below cracking gives (nearly) no flow: the
model keeps a small positive slope there, so its inverse fed a zero flow
returns the duty at which the modelled flow reaches zero on the present
branch, the cracking duty of the valve's present memory (what a feedforward
does with it is in :mod:`controller.laws.feedforward`).

Fit (:func:`fit_pi_mod`): output-error least squares on the preprocessed
recording, in the plays' partial sums and the segment slopes of ``S`` (all
bounded below by a small positive slope, the middle one fixed at 1 since
the plays' gain can take it; falling slopes held by penalty rows), and the
offset, with the exact Jacobian (``scipy.optimize.least_squares``, trust
region reflective), from two starts: Kuhnen's (the constrained PI, ``S`` the
identity) and the asymmetric PI's (its envelope searched, then held). The
invertible candidate with the least in-sample error is kept, the starts
included, so it is never worse in sample than either.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from . import inverse_pi, play
from .inverse_pi import invert_pi
from .pi import MIN_SLOPE, PIModel, fit_pi
from .pi_asym import (AsymmetricPIModel, InverseAsymmetricPI, design, down_scale, down_scales, falling_constraint,
                      fit_pi_asym, solve_input)

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
    """The modified PI in normalized units (Kuhnen's when ``a = 0``).

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
    a, p : float
        Descending envelope of the plays (:mod:`models.pi_asym`): every descending threshold
        is ``r_i (1 + a psi(x))``; ``a = 0`` (the default): Eq. (1), Kuhnen's model.
    """

    r: np.ndarray
    w: np.ndarray
    h: np.ndarray
    g: np.ndarray
    offset: float = 0.0
    floor: float = -np.inf
    y0: np.ndarray = field(default=None)
    a: float = 0.0
    p: float = 1.0
    kind: ClassVar[str] = "pi-mod"

    def __post_init__(self):
        for name in ("r", "w", "h", "g"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        y0 = np.full_like(self.r, np.nan) if self.y0 is None else np.asarray(self.y0, dtype=np.float64)
        object.__setattr__(self, "y0", y0)
        for name in ("offset", "floor", "a", "p"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def pi(self) -> PIModel:
        """The play part alone (no offset) when it is Eq. (1)'s (``a = 0``): ``p = w^T H_r[x]``."""
        return PIModel(self.r, self.w, 0.0, self.y0)

    @property
    def plays(self) -> AsymmetricPIModel:
        """The play part alone (no offset), generalized operators (``a = 0``: Eq. 1)."""
        return AsymmetricPIModel(self.r, self.w, self.a, self.p, 0.0)

    @property
    def exact(self) -> bool:
        """The inverse is in closed form (Eq. 1 plays, ``a = 0``); else solved per sample to rounding."""
        return self.a == 0.0

    def init(self, x0: float) -> np.ndarray:
        """Play operator states at the first sample, Eq. (3)."""
        return play.init(self.r, x0, self.y0)

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: Eq. (1) (generalized when ``a > 0``), Eq. (4), then ``S`` and the offset."""
        s = np.array(state, dtype=np.float64)
        p = play.bank_step(self.r, self.w, down_scale(float(x), self.a, self.p), s, float(x))
        return s, max(dead_zone(self.h, self.g, p) + self.offset, self.floor)

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        p, s = play.play_weighted(self.r, self.w, x, state, down_scales(x, self.a, self.p))
        return np.maximum(apply_dead_zone(self.h, self.g, p) + self.offset, self.floor), s

    @property
    def invertible(self) -> bool:
        """Every rising and falling slope of the plays positive (Kuhnen's loading slopes when
        ``a = 0``) and every segment slope of ``S`` positive."""
        return self.plays.invertible and bool(np.all(segment_slopes(self.h, self.g) > 0))

    def inverse(self) -> "InverseModifiedPI":
        """The closed-form inverse (output to input)."""
        if not self.invertible:
            raise ValueError("modified PI is not invertible: a loading or a dead-zone slope is not positive")
        return InverseModifiedPI(self)

    def to_params(self) -> dict:
        y0 = None if np.all(np.isnan(self.y0)) else self.y0.tolist()
        return {"r": self.r.tolist(), "w": self.w.tolist(), "h": self.h.tolist(), "g": self.g.tolist(),
                "offset": self.offset, "floor": self.floor, "y0": y0, "a": self.a, "p": self.p}

    @classmethod
    def from_params(cls, d: dict) -> "ModifiedPIModel":
        return cls(r=d["r"], w=d["w"], h=d["h"], g=d["g"], offset=d["offset"], floor=d["floor"], y0=d.get("y0"),
                   a=d.get("a", 0.0), p=d.get("p", 1.0))


@njit(cache=True, inline="always")
def solve(r, w, a, p, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, exact, fwd_state, work, q):
    """The input that takes the forward play memory ``fwd_state`` to output ``q`` (memory unchanged).

    ``x = Gamma^{-1}[S^{-1}[q - c]]``: ``S^{-1}`` in closed form (Kuhnen), then the plays'
    inverse, in closed form when ``exact`` (Eq. 7 from the forward memory, then Eq. 5-6;
    ``a = 0``), else the one input whose generalized plays give it, by bisection to rounding
    (:func:`models.pi_asym.solve_input`). A closed valve (``q <= closed``) gives ``x_closed``.
    With ``h_inv = [0]``, ``g_inv = [1]`` and ``closed = -inf`` it is the plain PI's inverse
    (``exact``) or the asymmetric PI's (not).
    """
    if q <= closed:
        return x_closed
    z = dead_zone(h_inv, g_inv, q - offset)
    if exact:
        return inverse_pi.solve(r, w, r_inv, w_inv, fwd_state, work, z)
    # any state lies within the bands of the input that made it: start the search at their mean
    guess = 0.0
    for i in range(fwd_state.shape[0]):
        guess += fwd_state[i]
    return solve_input(r, w, a, p, fwd_state, z, guess / fwd_state.shape[0])


@njit(cache=True)
def _invert(r, w, a, p, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, exact, q, fwd_state):
    out = np.empty(q.shape[0])
    s = fwd_state.copy()
    work = np.empty(r.shape[0])
    for k in range(q.shape[0]):
        x = solve(r, w, a, p, r_inv, w_inv, h_inv, g_inv, offset, closed, x_closed, exact, s, work, q[k])
        play.bank_step(r, w, down_scale(x, a, p), s, x)  # the forward memory follows the input found
        out[k] = x
    return out, s


@dataclass(frozen=True, eq=False)
class InverseModifiedPI:
    """Inverse of a :class:`ModifiedPIModel`, output to input: ``x = Gamma^{-1}[S^{-1}[Q - c]]``.

    The state is the forward play memory: each sample's input comes from it
    (``S^{-1}`` in closed form, then Eq. 7 for the inverse operators' memory and
    Eq. 5-6 when ``a = 0``, bisection through the generalized plays otherwise),
    and the memory then follows that input. Outputs above
    :attr:`closed` are inverted exactly (``forward(inverse(Q)) == Q``); a closed
    valve (``Q <= closed``, where the model is nearly flat and any input below
    cracking fits) gives the bottom of the input range: the valve closed, the
    state a valve that has seen no flow is in.
    """

    forward: ModifiedPIModel
    kind: ClassVar[str] = "inverse-pi-mod"

    def __post_init__(self):
        f = self.forward
        if f.exact:
            inv = invert_pi(f.pi)
            r_inv, w_inv = inv.r, inv.w
        else:  # solved per sample through the forward plays: no inverse operators
            r_inv, w_inv = np.zeros_like(f.r), np.zeros_like(f.w)
        h_inv, g_inv = invert_dead_zone(f.h, f.g)
        for name, v in (("r_inv", r_inv), ("w_inv", w_inv), ("h_inv", h_inv), ("g_inv", g_inv)):
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
        return _invert(f.r, f.w, f.a, f.p, self.r_inv, self.w_inv, self.h_inv, self.g_inv, f.offset, self.closed,
                       self.x_closed, f.exact, y, np.asarray(state, dtype=np.float64))

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


def _refine(A, y, s0, c0, h, G, min_slope):
    """Output-error least squares of ``(s, sigma, c)`` from the plays' partial sums ``s0`` and offset
    ``c0`` with ``S`` the identity; ``(s, sigma, c, squared error)``.

    ``A``: the plays' regressors in the partial sums; ``h``: the dead-zone thresholds (middle
    one zero). Rising slopes ``s`` and segment slopes ``sigma`` are bounds (>= ``min_slope``);
    the falling slopes ``G @ s`` of generalized plays (None: Eq. 1 plays, they are ``s``) are
    held above ``2 min_slope`` by penalty rows, stiff enough that the result stays above
    ``min_slope`` (checked by the caller).
    """
    m, k = A.shape[1], (len(h) - 1) // 2
    free = np.r_[0:k, k + 1:2 * k + 1]  # the middle slope is fixed at 1: the plays' gain takes it
    floor = float(np.min(y))
    stiff = 10.0 * np.sqrt(len(y))

    def unpack(theta):
        sigma = np.ones(2 * k + 1)
        sigma[free] = theta[m:m + 2 * k]
        return theta[:m], sigma, theta[-1]

    def residual(theta):
        s, sigma, c = unpack(theta)
        out = np.maximum(_segment_basis(h, A @ s) @ sigma + c, floor) - y
        if G is None:
            return out
        return np.concatenate([out, stiff * np.minimum(G @ s - 2.0 * min_slope, 0.0)])

    def jac(theta):
        s, sigma, c = unpack(theta)
        p = A @ s
        phi = _segment_basis(h, p)
        live = (phi @ sigma + c > floor)[:, None]  # rows at the floor do not move with the parameters
        J = np.column_stack([A * _local_slope(h, sigma, p)[:, None], phi[:, free], np.ones(len(p))]) * live
        if G is None:
            return J
        pen = np.zeros((m, J.shape[1]))
        pen[:, :m] = stiff * G * (G @ s < 2.0 * min_slope)[:, None]
        return np.vstack([J, pen])

    lb = np.concatenate([np.full(m + 2 * k, min_slope), [-np.inf]])
    theta0 = np.maximum(np.concatenate([s0, np.ones(2 * k), [c0]]), lb + min_slope * 1e-3)  # strictly inside
    res = least_squares(residual, theta0, jac=jac, bounds=(lb, np.full(len(lb), np.inf)), method="trf",
                        x_scale="jac", max_nfev=200)
    s, sigma, c = unpack(res.x)
    return s, sigma, c, float(np.sum(residual(res.x)[:len(y)] ** 2))


def fit_pi_mod(x: np.ndarray, y: np.ndarray, n: int = 50, k: int = N_DEAD_ZONE,
               min_slope: float = MIN_SLOPE, envelope: tuple[float, float] | None = None) -> ModifiedPIModel:
    """Fit the plays, the dead-zone superposition and the offset (see the module docstring).

    Two starts, each refined by :func:`_refine` with its envelope held: Kuhnen's (``a = 0``,
    the constrained PI of :func:`models.pi.fit_pi`) and the asymmetric PI's (envelope searched
    by :func:`models.pi_asym.fit_pi_asym`). The invertible result with the least in-sample
    squared error is kept, the starts themselves (``S`` the identity) among the candidates,
    so the fit is never worse in sample than either the PI or the asymmetric PI.

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n : int
        Number of Eq. (2) thresholds (the zero threshold comes on top).
    k : int
        Dead-zone operators on each side of the origin.
    min_slope : float
        Lower bound on every rising, falling and dead-zone segment slope.
    envelope : (a, p), optional
        Hold the plays' descending envelope (``(0, 1)``: Kuhnen's model alone) instead of
        trying both starts.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    floor = float(np.min(y))
    if envelope is None or tuple(envelope) == (0.0, 1.0):
        pi = fit_pi(x, y, n=n, min_slope=min_slope)
        starts = [(pi.r, pi.w, 0.0, 1.0, pi.offset)]
    else:
        starts = []
    if envelope is None or tuple(envelope) != (0.0, 1.0):
        asym = fit_pi_asym(x, y, n=n, min_slope=min_slope, envelope=envelope)
        starts.append((asym.r, asym.w, asym.a, asym.p, asym.offset))
    best, best_sse = None, np.inf
    for r, w, a, p, c0 in starts:
        A = design(r, a, p, x)[:, :-1]  # columns in the partial sums (loading slopes)
        s0 = np.cumsum(w)
        p0 = A @ s0
        h = dead_zone_thresholds(min(float(p0.min()), -1e-3), max(float(p0.max()), 1e-3), k)
        G = falling_constraint(r, a, p) if a > 0.0 else None
        s, sigma, c, sse = _refine(A, y, s0, c0, h, G, min_slope)
        identity = ModifiedPIModel(r=r, w=w, h=np.zeros(1), g=np.ones(1), offset=c0, floor=floor, a=a, p=p)
        refined = ModifiedPIModel(r=r, w=np.diff(s, prepend=0.0), h=h, g=_slopes_to_weights(h, sigma), offset=c,
                                  floor=floor, a=a, p=p)
        for model, err in ((refined, sse), (identity, float(np.sum((identity.predict(x)[0] - y) ** 2)))):
            if err < best_sse and model.invertible:
                best, best_sse = model, err
    return best


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> ModifiedPIModel:
    """Fitting entry point shared by every kind (see :mod:`models.fitting`)."""
    return fit_pi_mod(x, y, n=50 if n is None else n)
