"""The paper's Table 1 on any recording, plus its inverse-PI check (§3).

:func:`compare_response` fits every model kind on one recording, scores each
in-sample (as Table 1) and on a validation recording never used in fitting,
and runs the inverse check; :func:`compare_plot` draws Fig. 3 (flow against
duty, measured and fitted) per model with the residual against duty split by
branch direction.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .fitting import evaluate, fit_recording
from .inverse_pi import fit_inverse_pi
from .metrics import Metrics, metrics
from .model import FittedModel
from .preprocess import preprocess
from .recording import Recording

#: Model kinds the comparison runs, in Table 1 order.
COMPARE_KINDS: tuple[str, ...] = ("bouc-wen", "pi", "pi-asym", "preisach", "preisach-cont")
#: The paper fits its direct inverse with 25 thresholds (§2.3).
INVERSE_N = 25


@dataclass(frozen=True)
class ModelResult:
    """One row of Table 1.

    Attributes
    ----------
    kind : str
    fit_s : float
        Wall time of preprocessing and fitting (s).
    in_sample : Metrics
        On the fitted recording (L/min).
    validation : Metrics or None
        On the validation recording (L/min).
    model : FittedModel
    prediction_lpm : ndarray
        In-sample prediction, one value per recording row.
    """

    kind: str
    fit_s: float
    in_sample: Metrics
    validation: Metrics | None
    model: FittedModel
    prediction_lpm: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class InverseCheck:
    """The paper's inverse check: forward PI output fed to the inverse, against the duty (%).

    Attributes
    ----------
    closed_form : Metrics
        Through the Eq. (7) inverse that feedforward uses.
    direct_fit : Metrics
        Through the paper's directly fitted inverse (n = 25).
    on_measured_flow : Metrics
        The Eq. (7) inverse fed the *measured* flow: the feedforward error a
        controller would see on this recording.
    """

    closed_form: Metrics
    direct_fit: Metrics
    on_measured_flow: Metrics

    def to_json(self) -> dict:
        def duty(m: Metrics) -> dict:
            return {"duty_mae_pct": m.mae, "duty_rmse_pct": m.rmse, "r": m.r}

        return {
            **duty(self.closed_form),
            "method": "closed-form inverse, Eq. (7)",
            "direct_fit_n25": duty(self.direct_fit),
            "on_measured_flow": duty(self.on_measured_flow),
        }


@dataclass(frozen=True)
class Comparison:
    """Table 1 for one recording; ``to_json`` gives the DESIGN.md layout."""

    recording: Recording
    validation: Recording | None
    results: dict
    inverse: InverseCheck

    def to_json(self) -> dict:
        models = {}
        for kind, res in self.results.items():
            d = {"mae": res.in_sample.mae, "rmse": res.in_sample.rmse, "r": res.in_sample.r, "fit_s": res.fit_s}
            if res.validation is not None:
                d["validation"] = res.validation.to_dict()
            models[kind] = d
        return {"models": models, "inverse_pi": self.inverse.to_json()}

    def table(self) -> str:
        """Table 1 layout: in-sample and, when given, validation figures."""
        head = f"{'model':<15}{'MAE':>8}{'RMSE':>8}{'r':>9}{'fit s':>8}"
        if self.validation is not None:
            head += f"  |{'val MAE':>9}{'val RMSE':>10}{'val r':>9}"
        lines = [f"Table 1 on {self.recording.path}" + (f", validated on {self.validation.path}" if self.validation else ""),
                 head, "-" * len(head)]
        for kind, res in self.results.items():
            m = res.in_sample
            line = f"{kind:<15}{m.mae:8.2f}{m.rmse:8.2f}{m.r:9.4f}{res.fit_s:8.2f}"
            if res.validation is not None:
                v = res.validation
                line += f"  |{v.mae:9.2f}{v.rmse:10.2f}{v.r:9.4f}"
            lines.append(line)
        inv = self.inverse
        lines.append(
            f"inverse PI (duty %): Eq. (7) MAE {inv.closed_form.mae:.2e} RMSE {inv.closed_form.rmse:.2e};"
            f" direct fit n={INVERSE_N} MAE {inv.direct_fit.mae:.3f} RMSE {inv.direct_fit.rmse:.3f};"
            f" on measured flow MAE {inv.on_measured_flow.mae:.3f} RMSE {inv.on_measured_flow.rmse:.3f}"
        )
        return "\n".join(lines)


def inverse_check(model: FittedModel, rec: Recording) -> InverseCheck:
    """Paper §3: the forward PI's flow fed to the inverse, compared with the recorded duty."""
    duty = rec.duty_pct
    x_u = model.x_scale.to_unit(duty)
    forward_state = model.core.init(x_u[0])
    q_u, _ = model.core.predict(x_u, forward_state)
    inv = model.inverse
    d_u, _ = inv.predict(q_u, inv.init(q_u[0], forward_state=forward_state))
    closed = metrics(duty, model.x_scale.from_unit(d_u))
    pre = preprocess(rec.t_s, duty, rec.flow_lpm)
    direct = fit_inverse_pi(model.y_scale.to_unit(pre.y), model.x_scale.to_unit(pre.x), n=INVERSE_N)
    d2_u, _ = direct.predict(q_u)
    measured, _ = model.inverse_predict(rec.flow_lpm)
    return InverseCheck(closed, metrics(duty, model.x_scale.from_unit(d2_u)), metrics(duty, measured))


def compare_response(
    rec: Recording,
    validate: Recording | None = None,
    kinds: Sequence[str] = COMPARE_KINDS,
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Fit each kind on ``rec``; score in-sample and on ``validate``; run the inverse check."""
    results = {}
    for kind in kinds:
        if progress:
            progress(kind)
        model = fit_recording(kind, rec)
        pred, _ = model.predict(rec.duty_pct)
        val = evaluate(model, validate.duty_pct, validate.flow_lpm) if validate is not None else None
        results[kind] = ModelResult(kind, model.meta["fit_s"], metrics(rec.flow_lpm, pred), val, model, pred)
    pi = results["pi"].model if "pi" in results else fit_recording("pi", rec)
    return Comparison(rec, validate, results, inverse_check(pi, rec))


def branch_direction(duty_pct: np.ndarray) -> np.ndarray:
    """+1 where the duty is rising, -1 where falling, 0 where it holds (sign of the change)."""
    d = np.diff(duty_pct, prepend=duty_pct[0])
    direction = np.sign(d)
    # Carry the last direction through holds: hysteresis remembers the branch it is on.
    idx = np.where(direction != 0, np.arange(len(d)), 0)
    np.maximum.accumulate(idx, out=idx)
    return np.where(direction[idx] != 0, direction[idx], 0)


def compare_plot(comparison: Comparison, path: str) -> None:
    """Fig. 3 per model (flow vs duty, measured and fitted) and residual vs duty by branch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rec = comparison.recording
    kinds = list(comparison.results)
    fig, axes = plt.subplots(len(kinds), 2, figsize=(12, 3.2 * len(kinds)), squeeze=False)
    direction = branch_direction(rec.duty_pct)
    step = max(1, len(rec) // 20000)
    for row, kind in zip(axes, kinds):
        res = comparison.results[kind]
        ax = row[0]
        ax.plot(rec.duty_pct[::step], rec.flow_lpm[::step], color="tab:orange", lw=0.6, label="measured $Q_m$")
        ax.plot(rec.duty_pct[::step], res.prediction_lpm[::step], color="tab:blue", lw=0.6, label=r"fitted $\hat{Q}$")
        ax.set_title(f"{kind}: MAE {res.in_sample.mae:.2f} L/min, r {res.in_sample.r:.4f}")
        ax.set_xlabel("duty cycle (%)")
        ax.set_ylabel("flow (L/min)")
        ax.legend(loc="upper left", fontsize=8)
        ax = row[1]
        resid = res.prediction_lpm - rec.flow_lpm
        for sign, color, label in ((1, "tab:green", "ascending"), (-1, "tab:red", "descending")):
            sel = (direction == sign)
            ax.plot(rec.duty_pct[sel][::step], resid[sel][::step], ".", ms=1, color=color, label=label)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("duty cycle (%)")
        ax.set_ylabel("fitted - measured (L/min)")
        ax.legend(loc="upper left", fontsize=8, markerscale=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
