"""The augmented model: baseline plus a chain of effects, as a linear regression.

For fixed nonlinear parameters (time constants, delay, exponent, cracking
duty, full-open flow) every effect of :mod:`models.diagnose.effects` keeps the
model linear in its remaining unknowns, so the augmented model is::

    q(t) = min(F(t) + X(t) theta, q_sat)

The hysteresis core is the baseline's, with its weights as fitted: a PI of
50 operators refitted on 5/6 of the training blocks is far less stable on
the sixth (rare excursions set the states of the wide operators) than the
effects it is meant to reveal. With a baseline fitted on the recording, its
prediction enters as a free *gain* and *offset* (the two ways the baseline
absorbed an effect on average); with a model file, the model's prediction is
held fixed in ``F``. Each linear effect adds one column (asymmetric width,
creep amplitude, sensor offset); transforms of the whole flow (pressure gain,
lag, dead zone) act on ``F`` and on every column; input transforms (delay,
coil heating) feed the model a different duty.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from .. import play
from ..model import FittedModel
from ..pi import MIN_SLOPE, PIModel, _least_squares, fit_pi
from ..preprocess import Scaling
from . import effects as fx
from .folds import Folds
from .signals import Signals

#: Relative ridge on the normal equations (keeps a column that is all zero harmless).
RIDGE = 1e-10
#: Operators of the paper's symmetric PI baseline (Eq. 2).
BASELINE_N = 50


@dataclass(frozen=True, eq=False)
class Base:
    """The simulation the recording is held against.

    Attributes
    ----------
    refit : bool
        True: the PI weights are refitted with every augmentation (no model
        file); False: the model file's prediction is held fixed.
    model : FittedModel
        The baseline model (for ``refit``, the PI fitted on the training rows).
    shape : PIModel
        A PI whose output is in the model's normalized output unit, giving the
        loop shape for the asymmetric-branch column (the model itself when it
        is a PI).
    shape_scale : Scaling
        Duty scaling of ``shape``'s input.
    """

    refit: bool
    model: FittedModel
    shape: PIModel
    shape_scale: Scaling
    cache: dict = field(default_factory=dict, repr=False)

    def response(self, sig: Signals, x: np.ndarray, key: tuple, want_excess: bool) -> tuple:
        """Model prediction for duty ``x`` (and the descending excess, L/min), cached by input transform ``key``."""
        k = (id(sig), key)
        hit = self.cache.get(k)
        if hit is None or (want_excess and hit[1] is None):
            q = hit[0] if hit is not None else self.model.predict(x)[0]
            excess = None
            if want_excess:
                x_unit = self.shape_scale.to_unit(x)
                excess = fx.descending_excess(pi_columns(self.shape.r, x_unit), x_unit, self.shape.w) * self.y_half
            if len(self.cache) > 48:
                self.cache.clear()
            hit = self.cache[k] = (q, excess)
        return hit

    @property
    def x_scale(self) -> Scaling:
        return self.model.x_scale

    @property
    def y_half(self) -> float:
        return self.model.y_scale.half_range


def pi_columns(r: np.ndarray, x_unit: np.ndarray) -> np.ndarray:
    """Play operator outputs, Eq. (1), started by Eq. (3) at the first input."""
    Y, _ = play.play_response(r, x_unit, play.init(r, x_unit[0], 0.0))
    return Y


@dataclass(frozen=True, eq=False)
class Design:
    """Columns of the augmented model on one sample grid.

    Attributes
    ----------
    F : ndarray, shape (N,)
        Fixed part (L/min).
    X : ndarray, shape (N, p)
        Free columns; ``theta`` in L/min per column unit.
    names : tuple of str
        Column names: ``gain`` and ``offset`` (refitted baseline), then effect words.
    fit_ok : ndarray of bool
        Rows the fit may use (saturated rows are left to the clip).
    clip_hi : float or None
        Full-open flow (L/min) the prediction is clipped to.
    """

    F: np.ndarray
    X: np.ndarray
    names: tuple
    fit_ok: np.ndarray
    clip_hi: float | None = None

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """``min(F + X theta, clip_hi)`` for one ``theta`` (p,) or several (p, K) -> (N,) or (N, K)."""
        return self.predict_rows(theta, slice(None))

    def predict_rows(self, theta: np.ndarray, rows) -> np.ndarray:
        """:meth:`predict` on the rows ``rows`` only."""
        F = self.F[rows]
        q = (F if theta.ndim == 1 else F[:, None]) + self.X[rows] @ theta
        return q if self.clip_hi is None else np.minimum(q, self.clip_hi)


def build(base: Base, sig: Signals, chain: dict) -> Design:
    """Columns of baseline + the effects in ``chain`` on the grid of ``sig``.

    Parameters
    ----------
    base : Base
        The baseline.
    sig : Signals
        Signals on the grid to build on.
    chain : dict
        ``{effect word: {parameter: value}}`` with the nonlinear parameters
        (see :data:`models.diagnose.detectors.EFFECTS`); linear effects have ``{}``.
    """
    rate = sig.rate_hz
    x = input_duty(sig, chain)
    names: list[str] = []
    F, excess = base.response(sig, x, _key(chain), "asymmetric_hysteresis" in chain)
    ref = F
    cols = []
    if base.refit:
        cols += [F[:, None], np.ones((len(x), 1))]
        names += ["gain", "offset"]
        F = np.zeros(len(x))
    if "asymmetric_hysteresis" in chain:
        cols.append((excess * np.clip(ref, 0.0, None) / fx.FULL_FLOW_LPM)[:, None])
        names.append("asymmetric_hysteresis")
    X = np.hstack(cols) if cols else np.zeros((len(x), 0))
    gain = flow_gain(sig, chain)
    F, X, ref = F * gain, X * gain[:, None], ref * gain
    if "valve_dynamics" in chain:
        tau = chain["valve_dynamics"]["tau_s"]
        F, X = fx.first_order_lag(F, rate, tau), fx.first_order_lag(X, rate, tau)
        ref = fx.first_order_lag(ref, rate, tau)
    extra = []
    if "creep" in chain:
        # the column is the unrelaxed flow change; its coefficient is minus the creep amplitude
        extra.append(fx.creep_term(ref, rate, chain["creep"]["tau_s"]))
        names.append("creep")
    if "sensor_offset" in chain:
        extra.append(np.ones(len(x)))
        names.append("sensor_offset")
    if extra:
        X = np.hstack([X, np.column_stack(extra)])
    fit_ok = np.ones(len(x), dtype=bool)
    clip_hi = None
    if "saturation" in chain:
        clip_hi = chain["saturation"]["full_open_lpm"]
        fit_ok = ref < clip_hi
    return Design(F, X, tuple(names), fit_ok, clip_hi)


@dataclass(frozen=True)
class CVResult:
    """Cross-validated errors of one design.

    Attributes
    ----------
    sse : ndarray, shape (K, K)
        ``sse[k, j]``: squared error on the rows of fold j of the model fitted without fold k.
    n : ndarray, shape (K,)
        Rows per fold.
    """

    sse: np.ndarray
    n: np.ndarray

    @property
    def test(self) -> np.ndarray:
        """Held-out squared error per fold."""
        return np.diag(self.sse).copy()

    @property
    def train(self) -> np.ndarray:
        """Training squared error of each fold's model."""
        return self.sse.sum(axis=1) - self.test


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    p = A.shape[0]
    lam = RIDGE * max(np.trace(A) / p, 1e-12)
    return cho_solve(cho_factor(A + lam * np.eye(p)), b)


def _fold_grams(X: np.ndarray, r: np.ndarray, seg: list) -> tuple:
    """``X^T X``, ``X^T r`` and ``r^T r`` over each row segment."""
    A = np.stack([X[i].T @ X[i] for i in seg])
    b = np.stack([X[i].T @ r[i] for i in seg])
    c = np.array([r[i] @ r[i] for i in seg])
    return A, b, c


def cross_validate(design: Design, y: np.ndarray, folds: Folds) -> CVResult:
    """Fit on all folds but one (least squares), predict every fold; for each left-out fold.

    Without a clip the squared errors follow from per-fold normal equations
    (``e^T e = c - 2 theta^T b + theta^T A theta``), so no prediction is formed.
    """
    K = folds.k
    seg_all = folds.segments()
    fit_rows = folds.fit_ok & design.fit_ok
    seg_fit = [i[fit_rows[i]] for i in seg_all]
    resid = y - design.F
    p = design.X.shape[1]
    if p:
        A, b, _ = _fold_grams(design.X, resid, seg_fit)
        At, bt = A.sum(axis=0), b.sum(axis=0)
        theta = np.column_stack([_solve(At - A[k], bt - b[k]) for k in range(K)])
    else:
        theta = np.zeros((0, K))
    if design.clip_hi is None:
        Aa, ba, ca = _fold_grams(design.X, resid, seg_all)
        # sse[k, j] for theta_k on fold j
        sse = ca[None, :] - 2.0 * (theta.T @ ba.T) + np.einsum("pk,jpq,qk->kj", theta, Aa, theta)
    else:
        sse = np.empty((K, K))
        for j, i in enumerate(seg_all):
            e = design.predict_rows(theta, i) - y[i][:, None]
            sse[:, j] = np.sum(e * e, axis=0)
    return CVResult(sse, np.array([len(i) for i in seg_all]))


def fit_final(design: Design, y: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Least-squares ``theta`` on ``rows`` (the rows the design may fit on)."""
    fr = rows & design.fit_ok
    if design.X.shape[1] == 0:
        return np.zeros(0)
    X = design.X[fr]
    return _solve(X.T @ X, X.T @ (y - design.F)[fr])


def fit_baseline(sig: Signals, folds: Folds, n: int = BASELINE_N) -> Base:
    """The paper's symmetric PI (Eq. 2-4, ``n`` operators, constrained) fitted on the training rows only."""
    xs = Scaling.from_data(sig.duty_pct)
    ys = Scaling.from_data(sig.flow_lpm[folds.train])
    core = fit_pi(xs.to_unit(sig.duty_pct), ys.to_unit(sig.flow_lpm), n=n, rows=folds.train)
    model = FittedModel("pi", core, xs, ys, meta={"source": "fitted on the training rows", "n": n})
    return Base(True, model, core, xs)


def fixed_base(model: FittedModel, sig: Signals) -> Base:
    """A model file as the fixed baseline; its loop shape from its own PI, or a PI fitted to its prediction."""
    core = model.core
    if isinstance(core, PIModel):
        return Base(False, model, core, model.x_scale)
    xs = Scaling.from_data(sig.duty_pct)
    shape = fit_pi(xs.to_unit(sig.duty_pct), model.y_scale.to_unit(model.predict(sig.duty_pct)[0]), n=BASELINE_N)
    return Base(False, model, shape, xs)


def input_duty(sig: Signals, chain: dict) -> np.ndarray:
    """The duty the hysteresis sees: command delayed, then the coil-heating effective duty."""
    x = sig.duty_pct
    if "transport_delay" in chain:
        x = fx.delayed(x, sig.rate_hz, chain["transport_delay"]["delay_s"])
    if "coil_heating" in chain:
        p = chain["coil_heating"]
        if sig.coil_temp_c is not None:
            rise = sig.coil_temp_c - 20.0  # R(T) = R_20 (1 + alpha (T - 20 C))
        else:
            steady0 = p["rise55_k"] * (x[0] / fx.HEATING_REF_DUTY_PCT) ** 2
            rise = fx.coil_temperature_rise(x, sig.rate_hz, p["tau_s"], p["rise55_k"], p.get("start", 1.0) * steady0)
        x = fx.effective_duty(x, rise, float(np.mean(rise)))
    return x


def flow_gain(sig: Signals, chain: dict) -> np.ndarray:
    """Pointwise factor on the whole flow: dead zone (on the delayed command) times supply-pressure gain."""
    g = np.ones(len(sig.t_s))
    if "dead_zone" in chain:
        x = sig.duty_pct
        if "transport_delay" in chain:
            x = fx.delayed(x, sig.rate_hz, chain["transport_delay"]["delay_s"])
        g = g * fx.open_mask(x, chain["dead_zone"]["cracking_pct"])
    if "supply_pressure" in chain and sig.supply_bar is not None:
        g = g * fx.pressure_gain(sig.supply_bar, float(np.mean(sig.supply_bar)), chain["supply_pressure"]["exponent"])
    return g


def refit_base(base: Base, sig: Signals, chain: dict, rows: np.ndarray) -> Base:
    """Refit the baseline PI's weights *through* the chain on ``rows`` (paper's constrained fit).

    A baseline fitted on a recording that has an effect has bent its weights
    to absorb part of it (a lag widens the loop, a heating coil lowers the
    gain); once the effect is modelled, the weights are refitted with it, so
    the next effect is tested against the corrected hysteresis. The play
    operator outputs go through the same whole-flow transforms as the model's
    prediction (dead zone, pressure gain, lag) and are fitted together with
    the effect columns; the loading-curve slopes stay positive
    (:data:`models.pi.MIN_SLOPE`, Kuhnen's condition).
    """
    if not base.refit or not chain:
        return base
    core = base.model.core
    xs, ys = base.model.x_scale, base.model.y_scale
    d = build(base, sig, chain)
    Y = pi_columns(core.r, xs.to_unit(input_duty(sig, chain)))
    m = Y.shape[1]
    YD = Y.copy()
    YD[:, :-1] -= Y[:, 1:]  # partial-sum unknowns, as in models.pi.fit_pi
    # the whole-flow transforms act on the operator columns as on the prediction
    g = flow_gain(sig, chain)
    cols = np.column_stack([YD * g[:, None], g])
    if "valve_dynamics" in chain:
        cols = fx.first_order_lag(cols, sig.rate_hz, chain["valve_dynamics"]["tau_s"])
    A = np.column_stack([cols, d.X[:, 2:]])
    fr = rows & d.fit_ok
    lb = np.full(A.shape[1], -np.inf)
    lb[:m] = MIN_SLOPE * ys.half_range
    theta = _least_squares(A[fr], sig.flow_lpm[fr], lb)
    w = np.diff(theta[:m], prepend=0.0) / ys.half_range
    offset = (theta[m] - ys.center) / ys.half_range
    new = PIModel(r=core.r, w=w, offset=offset, y0=core.y0)
    model = FittedModel("pi", new, xs, ys, meta={**base.model.meta, "refitted_with": list(chain)})
    return Base(True, model, new, xs)


def _key(chain: dict) -> tuple:
    return (tuple(chain.get("transport_delay", {}).items()), tuple(chain.get("coil_heating", {}).items()))
