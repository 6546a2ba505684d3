"""The continuous Preisach model from reversal curves and the Everett function (paper §2.3).

The Preisach density ``mu(alpha, beta)`` enters only through the Everett
function, the weight of the triangle under a point of the Preisach plane,

``F(alpha, beta) = integral over beta <= b <= a <= alpha of mu(a, b)``,   ``F = 0`` for ``alpha <= beta``.

Identification (Mayergoyz, "Mathematical Models of Hysteresis", 1991, ch. 1).
After a reversal at ``R`` that followed the extremum ``P``, every relay of the
triangle between ``P`` and ``R`` is switched the same way, so along the
reversal curve, until the input passes ``P`` again,

``F(R, x) = (y(R) - y(x)) / 2`` on a descending curve from a maximum ``R``,
``F(x, R) = (y(x) - y(R)) / 2`` on an ascending curve from a minimum ``R``.

These first-order reversal curves (FORCs) are read from every reversal of the
(preprocessed) recording, against its memory staircase (so a curve continues
past small loops it wipes out, see :func:`reversal_curves`); with the paper's
protocol of growing sinusoids they are vertical and horizontal lines of the
alpha-beta plane. Their values are
interpolated onto the regular alpha-beta mesh (``scipy.interpolate.griddata``,
linear inside the data, nearest outside), with ``F = 0`` on and below the
diagonal; the offset is then fitted by least squares.

Prediction. The memory is the staircase of dominant alternating extrema
``M_1 > M_2 > ...`` and ``m_1 < m_2 < ...`` (wiping-out: an input passing an
earlier extremum erases it and its partner). The output is

``y = c + 2 sum_k [F(M_k, m_{k-1}) - F(M_k, m_k)]``   (``m_0`` below the range),

the last term read at the current input (``F(x, m_{n-1})`` rising,
``F(M_n, m_{n-1}) - F(M_n, x)`` falling). ``F`` is evaluated bilinearly on the
mesh in a numba-compiled loop that keeps the completed terms' sum and
re-evaluates it only when the staircase changes. At the first sample the
memory is that of an input relaxed at ``x0`` (a staircase of extrema
``x0 +- k h``, mesh step h, closing on ``x0``), as for the other models.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.interpolate import griddata

from .recording import InputError

#: Mesh resolution: intervals per axis over [-1, 1].
N_MESH = 50
#: Staircase capacity (alternating extrema kept; beyond it the innermost pair is merged).
STACK = 256
# State layout: [x_prev, direction, count, extrema...]
_HEAD = 3


@njit(cache=True, inline="always")
def _everett(E, alpha, beta):
    """Bilinear ``F(alpha, beta)`` on the regular mesh over [-1, 1]; 0 for ``alpha <= beta``."""
    if alpha <= beta:
        return 0.0
    n = E.shape[0] - 1
    a = min(max(alpha, -1.0), 1.0)
    b = min(max(beta, -1.0), 1.0)
    fa = (a + 1.0) * 0.5 * n
    fb = (b + 1.0) * 0.5 * n
    i = min(int(fa), n - 1)
    j = min(int(fb), n - 1)
    ta = fa - i
    tb = fb - j
    return ((1 - ta) * (1 - tb) * E[i, j] + ta * (1 - tb) * E[i + 1, j]
            + (1 - ta) * tb * E[i, j + 1] + ta * tb * E[i + 1, j + 1])


@njit(cache=True)
def _completed(E, st, count, falling):
    """Sum of the staircase terms that do not involve the current input."""
    # Extrema st[0..count-1] alternate max, min, max, ... (st[0] a max, m_0 = below the range).
    total = 0.0
    prev_min = -2.0
    k = 0
    while k < count:
        M = st[k]
        if k + 1 < count:
            m = st[k + 1]
            total += _everett(E, M, prev_min) - _everett(E, M, m)
            prev_min = m
        elif falling:
            total += _everett(E, M, prev_min)  # minus F(M, x), added per sample
        k += 2
    return total


@njit(cache=True, inline="always")
def _staircase(st, count, d, xp, xk):
    """Move the memory staircase from input ``xp`` to ``xk``: ``(count, direction, changed)``."""
    changed = False
    if xk != xp:
        nd = 1.0 if xk > xp else -1.0
        if nd != d:
            if count == st.shape[0]:
                count -= 2  # full: merge the innermost (smallest) loop away
            st[count] = xp  # the reversal: a max when turning down, a min when turning up
            count += 1
            d = nd
            changed = True
        # Wiping-out: passing the previous extremum of the same kind erases the last pair.
        while count >= 2 and ((d > 0 and count % 2 == 0 and xk >= st[count - 2])
                              or (d < 0 and count % 2 == 1 and xk <= st[count - 2])):
            count -= 2
            changed = True
    return count, d, changed


@njit(cache=True, inline="always")
def _value(E, st, count, d, base, xk):
    """Output (before offset) for input ``xk`` on the staircase, from the completed terms ``base``."""
    if d > 0:
        last = _everett(E, xk, st[count - 1] if count > 0 else -2.0)
    else:
        last = -_everett(E, st[count - 1], xk)
    return 2.0 * (base + last)


@njit(cache=True)
def sample(E, s, xk):
    """One sample in place on a state ``[x_prev, direction, count, extrema...]``; the output before offset."""
    st = s[_HEAD:]
    count, d, _ = _staircase(st, int(s[2]), s[1], s[0], xk)
    s[0], s[1], s[2] = xk, d, count
    return _value(E, st, count, d, _completed(E, st, count, d < 0), xk)


@njit(cache=True)
def _run(E, x, state):
    s = state.copy()
    st = s[_HEAD:]
    out = np.empty(x.shape[0])
    xp = s[0]
    d = s[1]
    count = int(s[2])
    base = _completed(E, st, count, d < 0)
    for k in range(x.shape[0]):
        xk = x[k]
        count, d, changed = _staircase(st, count, d, xp, xk)
        if changed:  # the completed terms change only with the staircase
            base = _completed(E, st, count, d < 0)
        xp = xk
        out[k] = _value(E, st, count, d, base, xk)
    s[0] = xp
    s[1] = d
    s[2] = count
    return out, s


def relaxed_state(x0: float, n_mesh: int = N_MESH) -> np.ndarray:
    """Staircase of an input relaxed at ``x0``: extrema ``x0 +- k h`` closing on ``x0``, then rising."""
    h = 2.0 / n_mesh
    k = np.arange(int((1.0 + abs(x0)) / h) + 1, 0, -1)  # the outermost pair lies beyond [-1, 1]
    ext = np.empty(2 * len(k))
    ext[0::2] = x0 + k * h
    ext[1::2] = x0 - k * h
    s = np.zeros(_HEAD + STACK)
    s[0], s[1], s[2] = x0, 1.0, len(ext)
    s[_HEAD:_HEAD + len(ext)] = ext
    return s


@dataclass(frozen=True, eq=False)
class ContinuousPreisachModel:
    """Continuous Preisach model in normalized units.

    Attributes
    ----------
    everett : ndarray, shape (n+1, n+1)
        ``F(alpha_i, beta_j)`` on the mesh ``-1 + 2 i / n`` (rows alpha, columns beta).
    offset : float
        Output offset ``c``.
    """

    everett: np.ndarray
    offset: float = 0.0
    kind: ClassVar[str] = "preisach-cont"

    def __post_init__(self):
        object.__setattr__(self, "everett", np.ascontiguousarray(self.everett, dtype=np.float64))
        object.__setattr__(self, "offset", float(self.offset))

    @property
    def n_mesh(self) -> int:
        return self.everett.shape[0] - 1

    def init(self, x0: float) -> np.ndarray:
        """Memory staircase at the first sample: relaxed at ``x0``."""
        return relaxed_state(float(x0), self.n_mesh)

    def step(self, state: np.ndarray, x: float) -> tuple[np.ndarray, float]:
        """One sample: update the staircase, then the Everett sum."""
        y, s = _run(self.everett, np.array([float(x)]), state)
        return s, float(y[0]) + self.offset

    def predict(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Output over an input sequence; ``(y, final_state)``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if state is None:
            state = self.init(x[0])
        y, s = _run(self.everett, x, np.asarray(state, dtype=np.float64))
        return y + self.offset, s

    def to_params(self) -> dict:
        return {"everett": self.everett.tolist(), "offset": self.offset}

    @classmethod
    def from_params(cls, d: dict) -> "ContinuousPreisachModel":
        return cls(everett=d["everett"], offset=d["offset"])


@dataclass(frozen=True)
class ReversalCurves:
    """Everett samples read from the first-order reversal curves of a recording.

    Attributes
    ----------
    alpha, beta, everett : ndarray
        Points of the alpha-beta plane and ``F`` there.
    reversals : int
        Number of reversal curves used.
    """

    alpha: np.ndarray
    beta: np.ndarray
    everett: np.ndarray
    reversals: int


def reversal_curves(x: np.ndarray, y: np.ndarray, n_mesh: int = N_MESH) -> ReversalCurves:
    """Everett samples from every reversal curve of a recording.

    At a maximum ``R`` every relay with ``alpha <= R`` is up, so the falling
    curve from ``R`` reads ``F(R, x)`` until the input passes the extremum ``P``
    below it in the memory staircase (beyond ``P``, relays switched up by an
    earlier, larger maximum switch too); likewise for rising curves. The
    samples are read against the recording's own staircase, with wiping-out:
    once the input passes ``P``, both are erased and the curve is read against
    the reversal before them. The recording is taken to start relaxed at
    ``x[0]``, as the models do (:func:`relaxed_state`), which bounds the
    first curves; those staircase corners have no measured output, so only
    curves from a measured reversal are read.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    s0 = relaxed_state(float(x[0]), n_mesh)
    # Below the staircase, a pair no input passes: the bound of curves that wiped out everything.
    ext_x = [np.inf, -np.inf] + list(s0[_HEAD:_HEAD + int(s0[2])])
    ext_y = [np.nan] * len(ext_x)
    a, b, f = [], [], []
    direction = s0[1]
    curves = 0
    for k in range(1, len(x)):
        if x[k] == x[k - 1]:
            continue
        d = 1.0 if x[k] > x[k - 1] else -1.0
        if d != direction:
            ext_x.append(x[k - 1])
            ext_y.append(y[k - 1])
            curves += 1
        direction = d
        while len(ext_x) >= 2 and (x[k] - ext_x[-2]) * d >= 0:
            del ext_x[-2:], ext_y[-2:]  # wiping-out
        if len(ext_x) >= 2 and not np.isnan(ext_y[-1]):
            if d > 0:  # ascending from the minimum ext_x[-1]
                a.append(x[k]), b.append(ext_x[-1]), f.append(0.5 * (y[k] - ext_y[-1]))
            else:  # descending from the maximum ext_x[-1]
                a.append(ext_x[-1]), b.append(x[k]), f.append(0.5 * (ext_y[-1] - y[k]))
    return ReversalCurves(np.array(a), np.array(b), np.array(f), curves)


def everett_mesh(curves: ReversalCurves, n_mesh: int = N_MESH) -> np.ndarray:
    """``F`` on the regular mesh: linear interpolation of the samples, nearest outside, 0 off the triangle.

    Relays beyond the inputs seen never switched, so they get no weight:
    mesh points outside the input range take ``F`` at the nearest point of it.
    """
    g = np.linspace(-1.0, 1.0, n_mesh + 1)
    lo = min(curves.beta.min(), curves.alpha.min())
    hi = max(curves.alpha.max(), curves.beta.max())
    A, B = np.meshgrid(np.clip(g, lo, hi), np.clip(g, lo, hi), indexing="ij")
    # Samples are dense along each curve (and curves repeat): average them in bins of a
    # quarter mesh step, which keeps the triangulation small and averages the noise.
    step = 0.5 / n_mesh
    cell = np.round(np.column_stack([curves.alpha, curves.beta]) / step).astype(np.int64)
    _, idx = np.unique(cell, axis=0, return_inverse=True)
    idx = idx.ravel()
    count = np.bincount(idx)
    mean = np.column_stack([np.bincount(idx, w) / count for w in (curves.alpha, curves.beta, curves.everett)])
    # F vanishes on the diagonal: known points that anchor the interpolation there.
    diag = np.linspace(lo, hi, n_mesh + 1)
    pts = np.column_stack([np.concatenate([mean[:, 0], diag]), np.concatenate([mean[:, 1], diag])])
    pf = np.concatenate([mean[:, 2], np.zeros_like(diag)])
    E = griddata(pts, pf, (A, B), method="linear")
    holes = np.isnan(E)
    if holes.any():
        E[holes] = griddata(pts, pf, (A[holes], B[holes]), method="nearest")
    E[A <= B] = 0.0
    return E


def fit_preisach_cont(x: np.ndarray, y: np.ndarray, n_mesh: int = N_MESH) -> ContinuousPreisachModel:
    """Everett mesh from the recording's reversal curves, then the offset by least squares.

    Parameters
    ----------
    x, y : ndarray
        Input and output, normalized to [-1, 1].
    n_mesh : int
        Mesh intervals per axis.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    curves = reversal_curves(x, y, n_mesh)
    if len(curves.everett) < 3:
        raise InputError("preisach-cont: the input turns too rarely to read reversal curves (at least twice needed)")
    E = everett_mesh(curves, n_mesh)
    model = ContinuousPreisachModel(everett=E, offset=0.0)
    pred, _ = model.predict(x)
    return ContinuousPreisachModel(everett=E, offset=float(np.mean(y - pred)))


def fit_core(x: np.ndarray, y: np.ndarray, rate_hz: float, n: int | None = None) -> ContinuousPreisachModel:
    """Fitting entry point shared by every kind; ``n`` is the mesh resolution."""
    return fit_preisach_cont(x, y, n_mesh=N_MESH if n is None else n)
