"""The Prandtl-Ishlinskii (PI) model, Eq. (1)-(4) of the paper.

``y(k) = sum_i w_i y_i(k) + c = w^T H_r[x(k), y_0] + c``       # Eq. (4), offset c added

Thresholds follow Eq. (2), ``r_i = i/(n+1) max|x|`` for i = 1..n, with one
more operator of threshold ``r_0 = 0`` (the identity) in front: the closed-
form inverse of Eq. (7) starts from ``w_1' = 1/w_1`` for an operator of zero
threshold, and without one the model's slope right after every reversal is
zero, so it could not be inverted. The model works in normalized units
(inputs in [-1, 1], so ``max|x| = 1``); :class:`models.model.FittedModel`
carries the scaling to physical units.

Weights come from linear least squares on the operator outputs. The
*constrained* fit (the default) bounds every partial sum ``sum_{j<=i} w_j``
(the slope of the loading curve on its i-th segment) below by a small
positive number, which is exactly Kuhnen's condition for the inverse of
Eq. (7) to exist; it is solved as a bounded problem in the partial sums
(``scipy.optimize.lsq_linear``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy.optimize import lsq_linear

from . import play

#: Lower bound on the loading-curve slope in normalized units (output/input).
MIN_SLOPE = 1e-3


def thresholds(n: int, x_max: float = 1.0) -> np.ndarray:
    """Eq. (2) thresholds ``i/(n+1) * x_max`` for i = 1..n, after a zero threshold."""
    i = np.arange(1, n + 1, dtype=np.float64)
    return np.concatenate([[0.0], i / (n + 1) * x_max])


@dataclass(frozen=True, eq=False)
class PIModel:
    """A fitted PI model in normalized units.

    Attributes
    ----------
    r : ndarray, shape (m,)
        Thresholds, ascending, ``r[0] == 0`` for an invertible model.
    w : ndarray, shape (m,)
        Weights of Eq. (4).
    offset : float
        Output offset ``c``.
    y0 : ndarray, shape (m,)
        ``y_i0`` of Eq. (3), the operator memory before the first sample; NaN (the
        default, ``null`` in the model file) means at rest at the first input.
    """

    r: np.ndarray
    w: np.ndarray
    offset: float = 0.0
    y0: np.ndarray = field(default=None)
    kind: ClassVar[str] = "pi"

    def __post_init__(self):
        object.__setattr__(self, "r", np.asarray(self.r, dtype=np.float64))
        object.__setattr__(self, "w", np.asarray(self.w, dtype=np.float64))
        y0 = np.full_like(self.r, np.nan) if self.y0 is None else np.asarray(self.y0, dtype=np.float64)
        object.__setattr__(self, "y0", y0)
        object.__setattr__(self, "offset", float(self.offset))

    # -- stepping (deluca shape: init() gives the state, step is pure) --
    def init(self, x0: float) -> np.ndarray:
        """Operator states at the first sample, Eq. (3)."""
        return play.init(self.r, x0, self.y0)

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: Eq. (1) then Eq. (4)."""
        s = play.step(self.r, state, x)
        return s, float(self.w @ s) + self.offset

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; returns ``(y, final_state)``.

        Without ``state`` the operators start from Eq. (3) at ``x[0]``.
        """
        x = np.asarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        y, s = play.play_weighted(self.r, self.w, x, state)
        return y + self.offset, s

    # -- properties of the weights --
    def loading_slopes(self) -> np.ndarray:
        """Slope of the initial loading curve on each segment ``[r_i, r_{i+1})``: partial sums of w."""
        return np.cumsum(self.w)

    @property
    def invertible(self) -> bool:
        """Kuhnen's condition: zero first threshold and every partial sum of w positive."""
        return bool(self.r[0] == 0.0 and np.all(self.loading_slopes() > 0))

    def inverse(self):
        """Closed-form inverse, Eq. (7) (see :func:`models.inverse_pi.invert_pi`)."""
        from .inverse_pi import invert_pi

        return invert_pi(self)

    # -- model file --
    def to_params(self) -> dict:
        y0 = None if np.all(np.isnan(self.y0)) else self.y0.tolist()
        return {"r": self.r.tolist(), "w": self.w.tolist(), "offset": self.offset, "y0": y0}

    @classmethod
    def from_params(cls, p: dict) -> "PIModel":
        return cls(r=p["r"], w=p["w"], offset=p["offset"], y0=p.get("y0"))


def regressors(r: np.ndarray, x: np.ndarray, y0: np.ndarray | None = None) -> np.ndarray:
    """Operator outputs for the fit (N x m), operators started by Eq. (3) at ``x[0]`` (at rest by default)."""
    y0 = np.full_like(r, np.nan) if y0 is None else y0
    Y, _ = play.play_response(r, x, play.init(r, x[0], y0))
    return Y


def fit_pi(
    x: np.ndarray,
    y: np.ndarray,
    n: int = 50,
    constrained: bool = True,
    min_slope: float = MIN_SLOPE,
    rows: np.ndarray | None = None,
) -> PIModel:
    """Fit PI weights and offset by least squares (paper §2.3).

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n : int
        Number of Eq. (2) thresholds (the zero threshold comes on top).
    constrained : bool
        Keep every loading-curve slope >= ``min_slope`` (invertible model).
    min_slope : float
        Lower bound for the slopes, normalized units.
    rows : ndarray of bool, optional
        Rows the least squares may use (all by default); the operators still
        run over the whole input, so held-out rows keep the memory right.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r = thresholds(n, x_max=float(np.max(np.abs(x))) if len(x) else 1.0)
    # The valve is taken to rest at the first input (y0 NaN: every operator at x(0)), the
    # recording's start as the paper's protocol holds it; predictions start the same way.
    Y = regressors(r, x)
    if rows is not None:
        Y, y = Y[rows], y[rows]
    w, offset, _ = fit_weights(Y, y, constrained=constrained, min_slope=min_slope)
    return PIModel(r=r, w=w, offset=offset)


def fit_weights(Y: np.ndarray, y: np.ndarray, extra: np.ndarray | None = None, constrained: bool = True,
                min_slope: float = MIN_SLOPE, nonnegative: bool = False) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares weights and offset of Eq. (4) on given operator outputs, with optional extra columns.

    Parameters
    ----------
    Y : ndarray, shape (N, m)
        Play operator outputs (or any linear transform of them applied row-wise in time,
        such as a delay or a lag of every column).
    y : ndarray, shape (N,)
        Output, normalized.
    extra : ndarray, shape (N, p), optional
        Further columns fitted jointly, without bounds.
    constrained : bool
        Keep every loading-curve slope (partial sum of the weights) >= ``min_slope``.
    nonnegative : bool
        Keep every weight >= 0 instead (the classical PI: a non-negative density of play
        operators, each an elementary hysteresis of the same sign).

    Returns
    -------
    w : ndarray, shape (m,)
        Weights.
    offset : float
        Offset ``c``.
    coef : ndarray, shape (p,)
        Coefficients of ``extra``.
    """
    m = Y.shape[1]
    extra = np.zeros((len(y), 0)) if extra is None else extra
    if nonnegative:
        A = np.column_stack([Y, np.ones(len(y)), extra])
        theta = _least_squares(A, y, np.concatenate([np.zeros(m), np.full(1 + extra.shape[1], -np.inf)]))
        return theta[:m], float(theta[m]), theta[m + 1:]
    YD = slope_columns(Y)
    # extra columns scaled to the operators' size, so that the Gram matrix stays well enough
    # conditioned for its Cholesky factor (else the N-row QR, a hundred times slower)
    scale = np.sqrt(np.mean(extra * extra, axis=0)) if len(y) else np.ones(extra.shape[1])
    scale = np.where(scale > 0, scale, 1.0)
    A = np.column_stack([YD, np.ones(len(y)), extra / scale])
    free = np.full(1 + extra.shape[1], -np.inf)
    lb = np.concatenate([np.full(m, min_slope), free]) if constrained else None
    theta = _least_squares(A, y, lb)
    return np.diff(theta[:m], prepend=0.0), float(theta[m]), theta[m + 1:] / scale


#: Above this condition number of the compressed triangle, compress by QR instead of Cholesky.
_CHOLESKY_COND_MAX = 1e6


def slope_columns(Y: np.ndarray) -> np.ndarray:
    """Operator outputs as the columns of the slope unknowns of :func:`fit_weights`.

    Unknowns: partial sums ``s_i = sum_{j<=i} w_j`` (the loading-curve slopes), so ``w = D s``
    with ``D`` the first difference; ``Y @ w = (Y @ D) @ s``, whose columns ``Y_i - Y_{i+1}``
    (last: ``Y_m``) are far better conditioned than Y's (about 1e3 against 4e3 on the bench
    recording).

    Parameters
    ----------
    Y : ndarray, shape (N, m)
        Play operator outputs (normalized input units).

    Returns
    -------
    ndarray, shape (N, m)
        ``Y @ D`` (normalized input units).
    """
    YD = np.empty_like(Y)
    np.subtract(Y[:, :-1], Y[:, 1:], out=YD[:, :-1])  # (one pass: no copy of Y first)
    YD[:, -1] = Y[:, -1]
    return YD


@dataclass(frozen=True, eq=False)
class SlopeRows:
    """The operator part of :func:`fit_weights`' normal equations on a set of rows, formed once.

    A refit on the same operators and rows with other extra columns or another output (every
    grid point of a screen that refits the PI with an effect column) reuses it: the N x m
    product and the gather of the rows are its cost.

    Attributes
    ----------
    YD : ndarray, shape (n, m)
        :func:`slope_columns` of the rows (normalized input units).
    gram : ndarray, shape (m, m)
        ``YD^T YD``.
    total : ndarray, shape (m,)
        ``YD^T 1`` (the offset's column).
    """

    YD: np.ndarray
    gram: np.ndarray
    total: np.ndarray

    @classmethod
    def of(cls, Y: np.ndarray) -> "SlopeRows":
        """The normal equations' operator part of the operator outputs ``Y`` (n, m)."""
        YD = slope_columns(Y)
        return cls(YD, YD.T @ YD, YD.sum(axis=0))


def fit_weights_on(parts: list, min_slope: float = MIN_SLOPE,
                   step_ridge: "float | np.ndarray" = 0.0) -> tuple[np.ndarray, float, np.ndarray]:
    """:func:`fit_weights` (constrained, with extra columns) on the union of row sets, from their
    normal equations.

    Parameters
    ----------
    parts : list of (SlopeRows, ndarray, ndarray)
        Per row set: its :class:`SlopeRows`, the output on its rows (n,), normalized, and the
        extra columns on its rows (n, p).
    min_slope : float
        Lower bound for the loading-curve slopes, normalized units.
    step_ridge : float or ndarray, shape (m - 1,)
        A ridge ``sum_{i>=1} step_ridge_i w_i^2`` on the weights of the operators with a threshold (the
        steps of the loading-curve slope; one value for all, or one per operator ``1..m-1``): a step
        the rows do not identify (operators that move together, or hardly at all) stays near zero, the
        slope going on as the rows below it tell, instead of opposite steps running off against each
        other.

    Returns
    -------
    w : ndarray, shape (m,)
        Weights.
    offset : float
        Offset ``c``.
    coef : ndarray, shape (p,)
        Coefficients of the extra columns.
    """
    m, p = parts[0][0].gram.shape[0], parts[0][2].shape[1]
    n = sum(len(y) for _, y, _ in parts)
    # extra columns scaled to the operators' size, as fit_weights scales them
    scale = np.sqrt(sum(np.sum(E * E, axis=0) for _, _, E in parts) / n) if n else np.ones(p)
    scale = np.where(scale > 0, scale, 1.0)
    # the upper triangle, block by block: operators, offset, extra columns
    G = np.zeros((m + 1 + p, m + 1 + p))
    Atb = np.zeros(m + 1 + p)
    for ops, y, E in parts:
        Es = E / scale
        cross = ops.YD.T @ np.column_stack([y, Es])
        G[:m, :m] += ops.gram
        G[:m, m] += ops.total
        G[:m, m + 1:] += cross[:, 1:]
        G[m, m] += len(y)
        G[m, m + 1:] += Es.sum(axis=0)
        G[m + 1:, m + 1:] += Es.T @ Es
        Atb[:m] += cross[:, 0]
        Atb[m] += y.sum()
        Atb[m + 1:] += Es.T @ y
    G = np.triu(G) + np.triu(G, 1).T
    lam = np.broadcast_to(np.asarray(step_ridge, dtype=np.float64), (m - 1,))
    ridged = bool(np.any(lam > 0))
    if ridged:
        # on the steps w_i = s_i - s_(i-1), i >= 1, of the slopes s the solver works in: a tridiagonal
        # D^T diag(lam) D of the m - 1 differences
        i = np.arange(m - 1)
        G[i, i] += lam
        G[i + 1, i + 1] += lam
        G[i, i + 1] -= lam
        G[i + 1, i] -= lam
    lb = np.concatenate([np.full(m, min_slope), np.full(1 + p, -np.inf)])
    R = _cholesky_triangle(G)
    if R is None:  # ill conditioned: the rows themselves, compressed by QR
        A = np.vstack([np.column_stack([ops.YD, np.ones(len(y)), E / scale]) for ops, y, E in parts])
        b = np.concatenate([y for _, y, _ in parts])
        if ridged:
            D = np.sqrt(lam)[:, None] * (np.eye(m, k=1) - np.eye(m))[:-1]
            A = np.vstack([A, np.column_stack([D, np.zeros((m - 1, 1 + p))])])
            b = np.concatenate([b, np.zeros(m - 1)])
        theta = _least_squares(A, b, lb)
    else:
        theta = _bounded(R, np.linalg.solve(R.T, Atb), lb)
    return np.diff(theta[:m], prepend=0.0), float(theta[m]), theta[m + 1:] / scale


def _cholesky_triangle(G: np.ndarray) -> np.ndarray | None:
    """Upper triangle ``R`` with ``R^T R = G``, or ``None`` when ``G`` is not positive definite or
    ``R``'s condition number is above :data:`_CHOLESKY_COND_MAX`."""
    try:
        R = np.linalg.cholesky(G).T
    except np.linalg.LinAlgError:
        return None
    return R if np.linalg.cond(R) < _CHOLESKY_COND_MAX else None


def _bounded(R: np.ndarray, c: np.ndarray, lb: np.ndarray | None) -> np.ndarray:
    """``argmin ||R t - c||`` subject to ``t >= lb``; the free optimum when it already meets the
    bounds (it is then the bounded one too: a convex problem)."""
    free = np.linalg.lstsq(R, c, rcond=None)[0]
    if lb is None or np.all(free >= lb):
        return free
    res = lsq_linear(R, c, bounds=(lb, np.full(len(lb), np.inf)), method="bvls", tol=1e-12, max_iter=5000)
    return res.x


def _least_squares(A: np.ndarray, b: np.ndarray, lb: np.ndarray | None = None) -> np.ndarray:
    """``argmin ||A t - b||`` subject to ``t >= lb``, on a compressed problem.

    ``||A t - b||^2 = ||R t - c||^2 + const`` with ``R^T R = A^T A`` and ``R^T c = A^T b``,
    so the problem is solved on the small triangle ``R`` instead of the N rows of ``A``
    (Cholesky of the Gram matrix when well conditioned, QR otherwise).
    """
    R = _cholesky_triangle(A.T @ A)
    if R is not None:
        c = np.linalg.solve(R.T, A.T @ b)
    else:
        Rab = np.linalg.qr(np.column_stack([A, b]), mode="r")
        R, c = Rab[: A.shape[1], : A.shape[1]], Rab[: A.shape[1], A.shape[1]]
    return _bounded(R, c, lb)


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> PIModel:
    """Fitting entry point shared by every kind (see :mod:`models.fitting`)."""
    return fit_pi(x, y, n=50 if n is None else n, constrained=True)
