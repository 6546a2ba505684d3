"""The inverse Prandtl-Ishlinskii model, Eq. (5)-(7) of the paper.

``x_i'(k) = max{y(k) - r_i', min{y(k) + r_i', x_i'(k-1)}}``   # Eq. (5)
``x(k) = sum_i w_i' x_i'(k)``                                 # Eq. (6)

The inverse of a PI is again a PI (Kuhnen); :func:`invert_pi` computes its
thresholds, weights and initial state in closed form, Eq. (7), from a
forward model whose first threshold is zero and whose loading-curve slopes
(partial sums of the weights) are positive. The forward offset is removed
before the inverse operators see the output. For such a model
``inverse(forward(x)) == x`` up to rounding, for any input sequence.

:func:`fit_inverse_pi` is the paper's other route: a PI with n = 25
thresholds fitted directly from output to input.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numba import njit

from . import play
from .pi import PIModel, fit_pi


class NotInvertible(ValueError):
    """The forward PI violates Kuhnen's condition (see :attr:`PIModel.invertible`)."""


@dataclass(frozen=True, eq=False)
class InversePI:
    """Inverse PI in normalized units, from output ``y`` back to input ``x``.

    Attributes
    ----------
    r : ndarray
        Inverse thresholds ``r'``, Eq. (7).
    w : ndarray
        Inverse weights ``w'``, Eq. (7).
    offset : float
        Forward offset ``c``, subtracted from ``y`` first.
    x0 : ndarray
        Inverse operator states ``x_i'(0)`` matching the forward model's ``y0``, Eq. (7);
        NaN when the forward model starts at rest (then so does the inverse: a forward
        memory at rest at ``x(0)`` maps by Eq. (7) to every ``x_i'(0) = y(0) - c``).
    """

    r: np.ndarray
    w: np.ndarray
    offset: float
    x0: np.ndarray = field(default=None)
    kind: ClassVar[str] = "inverse-pi"

    def __post_init__(self):
        object.__setattr__(self, "r", np.asarray(self.r, dtype=np.float64))
        object.__setattr__(self, "w", np.asarray(self.w, dtype=np.float64))
        x0 = np.full_like(self.r, np.nan) if self.x0 is None else np.asarray(self.x0, dtype=np.float64)
        object.__setattr__(self, "x0", x0)

    def init(self, y0: float, forward_state: np.ndarray | None = None) -> np.ndarray:
        """Inverse operator states at the first sample.

        With ``forward_state`` (the forward operators' ``y_i(0)``) the states follow
        Eq. (7) exactly; without, Eq. (5) is applied at ``y0`` to the stored ``x0``.
        """
        if forward_state is not None:
            return _initial_state(self._forward_w, forward_state)
        return play.init(self.r, y0 - self.offset, self.x0)

    def step(self, state: np.ndarray, y: float) -> tuple[np.ndarray, float]:
        """One sample of Eq. (5)-(6)."""
        s = play.step(self.r, state, y - self.offset)
        return s, float(self.w @ s)

    def predict(self, y: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Input that produces the output sequence ``y``; returns ``(x, final_state)``."""
        y = np.asarray(y, dtype=np.float64)
        if state is None:
            state = self.init(y[0])
        return play.play_weighted(self.r, self.w, y - self.offset, state)

    @property
    def _forward_w(self) -> np.ndarray:
        # Recover the forward weights from Eq. (7): w_1 = 1/w_1', then the partial sums.
        s = np.empty_like(self.w)
        s[0] = 1.0 / self.w[0]
        for i in range(1, len(self.w)):
            # w_i' = -w_i / (s_i s_{i-1}) and w_i = s_i - s_{i-1}  =>  1/s_i = 1/s_{i-1} + w_i'
            s[i] = 1.0 / (1.0 / s[i - 1] + self.w[i])
        return np.diff(s, prepend=0.0)

    def to_params(self) -> dict:
        x0 = None if np.all(np.isnan(self.x0)) else self.x0.tolist()
        return {"r": self.r.tolist(), "w": self.w.tolist(), "offset": self.offset, "x0": x0}

    @classmethod
    def from_params(cls, p: dict) -> "InversePI":
        return cls(r=p["r"], w=p["w"], offset=p["offset"], x0=p.get("x0"))


@njit(cache=True, inline="always")
def eq7_state(w, y_state, out):
    """Eq. (7), last line, into ``out``: ``x_i' = sum_{j<i} w_j y_i + sum_{j>=i} w_j y_j``.

    The inverse operators' memory that matches forward operator outputs ``y_state``.
    """
    n = w.shape[0]
    tail = 0.0
    for i in range(n - 1, -1, -1):
        tail += w[i] * y_state[i]
        out[i] = tail
    head = 0.0
    for i in range(n):
        out[i] += head * y_state[i]
        head += w[i]


@njit(cache=True)
def _eq7_state(w, y_state):
    out = np.empty(w.shape[0])
    eq7_state(w, y_state, out)
    return out


@njit(cache=True, inline="always")
def solve(r, w, r_inv, w_inv, fwd_state, work, p):
    """The input that takes forward operators in ``fwd_state`` to weighted output ``p`` (Eq. 5-7).

    ``work`` receives the inverse operators' memory (Eq. 7 from ``fwd_state``), stepped with ``p``.
    Forward memory is not changed.
    """
    eq7_state(w, fwd_state, work)
    return play.bank_step(r_inv, w_inv, 1.0, work, p)


def _initial_state(w: np.ndarray, y_state: np.ndarray) -> np.ndarray:
    """Eq. (7), last line, for arrays (see :func:`eq7_state`)."""
    return _eq7_state(np.ascontiguousarray(w, dtype=np.float64), np.ascontiguousarray(y_state, dtype=np.float64))


def invert_pi(model: PIModel) -> InversePI:
    """Closed-form inverse of a forward PI, Eq. (7).

    Raises
    ------
    NotInvertible
        If ``r[0] != 0`` or a partial sum of the weights is not positive.
    """
    if not model.invertible:
        raise NotInvertible(
            "PI model is not invertible: it needs a zero first threshold and positive loading slopes "
            "(fit it with constrained=True)"
        )
    r, w = model.r, model.w
    s = np.cumsum(w)  # s_i = w_1 + ... + w_i
    w_inv = np.empty_like(w)
    w_inv[0] = 1.0 / w[0]  # Eq. (7), first line
    w_inv[1:] = -w[1:] / (s[1:] * s[:-1])  # Eq. (7), second line
    # Eq. (7), third line: r_i' = sum_{j<=i} w_j (r_i - r_j) = s_i r_i - sum_{j<=i} w_j r_j
    r_inv = s * r - np.cumsum(w * r)
    x0 = _initial_state(w, model.y0)
    return InversePI(r=r_inv, w=w_inv, offset=model.offset, x0=x0)


def fit_inverse_pi(y: np.ndarray, x: np.ndarray, n: int = 25) -> PIModel:
    """The paper's directly fitted inverse: a PI with ``n`` thresholds from output to input."""
    return fit_pi(y, x, n=n, constrained=True)
