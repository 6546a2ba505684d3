"""The paper's Table 1 on any recording, plus its inverse-PI check (§3).

:func:`compare_response` fits every model kind on one recording, scores each
in-sample (as Table 1) and on a validation recording never used in fitting,
and runs the inverse check; :func:`compare_plot` (or ``Comparison.plot()``)
returns the figure: Fig. 3 (flow against duty, measured and fitted) per model
with the residual against duty split by branch direction, the validation and
the inverse checks; :func:`write_compare_report` writes it as Markdown + PNG.
"""
from __future__ import annotations

import os
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
COMPARE_KINDS: tuple[str, ...] = ("bouc-wen", "pi", "pi-asym", "pi-mod", "preisach", "preisach-cont")
#: The inverse fed the recorded flow is scored over rows with at least this flow (L/min, DESIGN.md):
#: below it a valve in its dead zone says nothing about the duty.
INVERSE_MIN_FLOW_LPM = 2.0
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
    validation_prediction_lpm : ndarray or None
        Prediction on the validation recording, one value per its row.
    inverse_on_measured_flow : Metrics or None
        For invertible kinds, the model's inverse fed the recorded flow against the
        recorded duty (%), over rows with flow >= :data:`INVERSE_MIN_FLOW_LPM`.
    """

    kind: str
    fit_s: float
    in_sample: Metrics
    validation: Metrics | None
    model: FittedModel
    prediction_lpm: np.ndarray = field(repr=False)
    validation_prediction_lpm: np.ndarray | None = field(default=None, repr=False)
    inverse_on_measured_flow: Metrics | None = None


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
    #: The Eq. (7) inverse fed the recorded flow: the duty it gives per recording row, %.
    inverse_duty_pct: np.ndarray | None = field(default=None, repr=False)

    def plot(self, ax=None):
        """:func:`compare_plot` of this comparison; returns the figure."""
        return compare_plot(self, ax)

    def to_json(self) -> dict:
        models = {}
        for kind, res in self.results.items():
            d = {"mae": res.in_sample.mae, "rmse": res.in_sample.rmse, "r": res.in_sample.r, "fit_s": res.fit_s}
            if res.validation is not None:
                d["validation"] = res.validation.to_dict()
            if res.inverse_on_measured_flow is not None:
                m = res.inverse_on_measured_flow
                d["inverse"] = {"on_measured_flow": {"duty_mae_pct": m.mae, "duty_rmse_pct": m.rmse, "r": m.r}}
            models[kind] = d
        return {"models": models, "inverse_pi": self.inverse.to_json()}

    def table(self) -> str:
        """Table 1 layout: in-sample and, when given, validation figures."""
        head = f"{'model':<15}{'MAE':>8}{'RMSE':>8}{'r':>9}{'fit s':>8}{'inv %':>7}"
        if self.validation is not None:
            head += f"  |{'val MAE':>9}{'val RMSE':>10}{'val r':>9}"
        lines = [f"Table 1 on {self.recording.path}" + (f", validated on {self.validation.path}" if self.validation else ""),
                 head, "-" * len(head)]
        for kind, res in self.results.items():
            m = res.in_sample
            inv = res.inverse_on_measured_flow
            line = f"{kind:<15}{m.mae:8.2f}{m.rmse:8.2f}{m.r:9.4f}{res.fit_s:8.2f}" + (
                f"{inv.mae:7.2f}" if inv is not None else f"{'-':>7}")
            if res.validation is not None:
                v = res.validation
                line += f"  |{v.mae:9.2f}{v.rmse:10.2f}{v.r:9.4f}"
            lines.append(line)
        inv = self.inverse
        lines.append(f"inv %: each invertible kind's inverse fed the recorded flow, duty MAE over rows with"
                     f" flow >= {INVERSE_MIN_FLOW_LPM:g} L/min")
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


def inverse_on_measured_flow(model: FittedModel, rec: Recording) -> Metrics | None:
    """The model's inverse fed the recorded flow against the recorded duty (%), over rows with
    flow >= :data:`INVERSE_MIN_FLOW_LPM`; None for a kind without an inverse."""
    if model.inverse is None:
        return None
    duty, _ = model.inverse_predict(rec.flow_lpm)
    rows = rec.flow_lpm >= INVERSE_MIN_FLOW_LPM
    return metrics(rec.duty_pct[rows], duty[rows]) if rows.sum() > 1 else None


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
        val_pred = model.predict(validate.duty_pct)[0] if validate is not None else None
        results[kind] = ModelResult(kind, model.meta["fit_s"], metrics(rec.flow_lpm, pred), val, model, pred, val_pred,
                                    inverse_on_measured_flow(model, rec))
    pi = results["pi"].model if "pi" in results else fit_recording("pi", rec)
    return Comparison(rec, validate, results, inverse_check(pi, rec), pi.inverse_predict(rec.flow_lpm)[0])


def branch_direction(duty_pct: np.ndarray) -> np.ndarray:
    """+1 where the duty is rising, -1 where falling, 0 where it holds (sign of the change)."""
    d = np.diff(duty_pct, prepend=duty_pct[0])
    direction = np.sign(d)
    # Carry the last direction through holds: hysteresis remembers the branch it is on.
    idx = np.where(direction != 0, np.arange(len(d)), 0)
    np.maximum.accumulate(idx, out=idx)
    return np.where(direction[idx] != 0, direction[idx], 0)


def compare_plot(comparison: Comparison, ax=None):
    """Fig. 3 per model, its residual by branch, its validation, and the inverse checks; returns the figure.

    One row per model: flow against duty, measured and fitted (in-sample
    figures in the title); the residual against duty split by branch
    direction; with a validation recording, the same model on it (never
    fitted there). A last row: the Eq. (7) inverse fed the recorded flow
    against the recorded duty (what a feedforward gets wrong on this valve),
    and the duty errors of the three inverse checks.

    ``ax``: an array of axes of shape (models + 1, 2 or 3); a new figure when None.
    """
    rec = comparison.recording
    kinds = list(comparison.results)
    ncol = 3 if comparison.validation is not None else 2
    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6 * ncol, 3.2 * (len(kinds) + 1)), layout="constrained")
        ax = fig.subplots(len(kinds) + 1, ncol, squeeze=False)
    else:
        fig = ax[0][0].figure
    direction = branch_direction(rec.duty_pct)
    step = max(1, len(rec) // 20000)
    for row, kind in zip(ax, kinds):
        res = comparison.results[kind]
        a = row[0]
        a.plot(rec.duty_pct[::step], rec.flow_lpm[::step], color="tab:orange", lw=0.6, label="measured $Q_m$")
        a.plot(rec.duty_pct[::step], res.prediction_lpm[::step], color="tab:blue", lw=0.6, label=r"fitted $\hat{Q}$")
        a.set_title(f"{kind}: MAE {res.in_sample.mae:.2f} L/min, r {res.in_sample.r:.4f} (in-sample)", fontsize=9)
        a.set_xlabel("duty cycle (%)")
        a.set_ylabel("flow (L/min)")
        a.legend(loc="upper left", fontsize=8)
        a = row[1]
        resid = res.prediction_lpm - rec.flow_lpm
        for sign, color, label in ((1, "tab:green", "ascending"), (-1, "tab:red", "descending")):
            sel = (direction == sign)
            a.plot(rec.duty_pct[sel][::step], resid[sel][::step], ".", ms=1, color=color, label=label)
        a.axhline(0, color="k", lw=0.5)
        a.set_xlabel("duty cycle (%)")
        a.set_ylabel("fitted - measured (L/min)")
        a.legend(loc="upper left", fontsize=8, markerscale=8)
        if ncol == 3:
            val, a = comparison.validation, row[2]
            vs = max(1, len(val) // 20000)
            a.plot(val.duty_pct[::vs], val.flow_lpm[::vs], color="tab:orange", lw=0.6, label="measured")
            if res.validation_prediction_lpm is not None:
                a.plot(val.duty_pct[::vs], res.validation_prediction_lpm[::vs], color="tab:purple", lw=0.6,
                       label="predicted")
            v = res.validation
            a.set_title(f"validation: MAE {v.mae:.2f} L/min, r {v.r:.4f} (never fitted)", fontsize=9)
            a.set_xlabel("duty cycle (%)")
            a.set_ylabel("flow (L/min)")
            a.legend(loc="upper left", fontsize=8)
    inv, row = comparison.inverse, ax[len(kinds)]
    a = row[0]
    if comparison.inverse_duty_pct is not None:
        a.plot(rec.t_s[::step], rec.duty_pct[::step], lw=0.7, color="k", label="recorded duty")
        a.plot(rec.t_s[::step], comparison.inverse_duty_pct[::step], lw=0.6, color="tab:blue",
               label="Eq. (7) inverse of the measured flow")
        a.legend(loc="upper right", fontsize=8)
    a.set_title(f"inverse on measured flow: duty MAE {inv.on_measured_flow.mae:.2f} %", fontsize=9)
    a.set_xlabel("time (s)")
    a.set_ylabel("duty (%)")
    a = row[1]
    checks = {"Eq. (7) round trip": inv.closed_form, f"direct fit n={INVERSE_N}": inv.direct_fit,
              "on measured flow": inv.on_measured_flow}
    x = np.arange(len(checks))
    a.bar(x - 0.2, [m.mae for m in checks.values()], 0.4, label="MAE")
    a.bar(x + 0.2, [m.rmse for m in checks.values()], 0.4, label="RMSE")
    a.set_xticks(x, list(checks), fontsize=8)
    a.set_ylabel("duty error (%)")
    a.set_title("inverse PI checks (paper §3)", fontsize=9)
    a.legend(fontsize=8)
    for extra in row[2:]:
        extra.set_visible(False)
    return fig


def write_compare_report(comparison: Comparison, folder) -> "os.PathLike":
    """``folder/report.md``: Table 1 (in-sample and validation), the inverse checks, and the figure."""
    from .report import write_report

    blocks = ["```\n" + comparison.table() + "\n```", "{fig:compare}",
              "Rows: each model's Fig. 3, its residual by branch" + (", its validation" if comparison.validation
                                                                      is not None else "")
              + "; last row: the inverse checks."]
    return write_report(folder, f"Table 1 on {comparison.recording.path}", blocks, {"compare": comparison.plot()})
