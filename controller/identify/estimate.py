"""Every model kind fitted on the sweep, validated on the held-out steps; the feedforward's kind chosen.

The hysteresis models are static (rate independent) and the valve puts its
lag and delay behind them, so:

- each kind is fitted (:func:`models.fitting.fit_model`, the paper's
  preprocessing) on the rows of the range ramp, the sweep and the reversals
  against the static flow of each row: the flow read ``delay`` later with the
  first-order lag inverted (:func:`.dynamics.static_flow`), twice: from the first row on the
  duty as commanded (the valve was at rest at the lowest duty, as every
  model's memory starts; the models see the dead zone and the full-open end
  and the memory they leave), and from the sweep's entry into the working
  range on the duty held to that range (memory wiped below it; the models
  spend their resolution where the valve moves). The fit that validates
  better is kept;
- each is validated on the step rows, never fitted, through the lag and delay
  the steps gave (:mod:`models.diagnose.effects`), driven from the first row;
- the feedforward is the invertible kind with the least validation RMSE among
  those the feedforward law can run (:func:`feedforward_ready`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from models.diagnose.effects import delayed, first_order_lag
from models.fitting import KINDS, fit_model
from models.metrics import Metrics, metrics
from models.model import FittedModel

from .dynamics import Dynamics, static_flow

FIT_PHASES = ("range", "sweep", "reversals")
VALIDATION_PHASE = "steps"


@dataclass(frozen=True)
class KindResult:
    """One row of Table 1 for the identification.

    Attributes
    ----------
    kind : str
    fit_s : float
        Wall time of the fit, s.
    in_sample : Metrics
        On the fitted rows, through the lag and delay (L/min).
    validation : Metrics
        On the step rows (L/min).
    invertible : bool
        Whether the feedforward can invert it (:func:`feedforward_ready`).
    model : FittedModel
    duty_range : str
        ``commanded`` (from the first row) or ``working`` (held to the working range, from the
        sweep's entry into it): the input the kept fit saw.
    fit_rows : ndarray of int
        The rows it was fitted on.
    """

    kind: str
    fit_s: float
    in_sample: Metrics
    validation: Metrics
    invertible: bool
    model: FittedModel = field(repr=False)
    duty_range: str = "commanded"
    fit_rows: np.ndarray = field(default=None, repr=False)


@dataclass(frozen=True)
class Estimate:
    """All kinds and the chosen one; rows (of the recording) fitted and validated."""

    results: dict
    chosen: str
    validation_rows: np.ndarray

    @property
    def model(self) -> FittedModel:
        return self.results[self.chosen].model

    def to_json(self) -> dict:
        return {k: {"mae": r.in_sample.mae, "rmse": r.in_sample.rmse, "r": r.in_sample.r, "fit_s": r.fit_s,
                    "validation": r.validation.to_dict(), "invertible": r.invertible, "duty_range": r.duty_range}
                for k, r in self.results.items()}


def feedforward_ready(model: FittedModel) -> bool:
    """Whether the loop's feedforward law (:mod:`controller.laws.feedforward`) can invert this model."""
    from controller.laws import feedforward as ffw

    try:
        ffw.bank(model)
    except (ValueError, AttributeError, TypeError):
        return False
    return True


def predict_flow(model: FittedModel, duty_pct: np.ndarray, rate_hz: float, tau_s: float, delay_s: float) -> np.ndarray:
    """The model's flow behind the valve's lag and delay (a loop's view: one period more), L/min.

    The duty is held to the model's identified input range, as the valve's
    plunger is seated below it and fully open above it.
    """
    lo = model.x_scale.center - model.x_scale.half_range
    hi = model.x_scale.center + model.x_scale.half_range
    q, _ = model.predict(np.clip(duty_pct, lo, hi))
    return delayed(first_order_lag(q, rate_hz, tau_s), rate_hz, delay_s)


def estimate(t_s: np.ndarray, duty_pct: np.ndarray, flow_lpm: np.ndarray, phase: np.ndarray, lo_pct: float,
             hi_pct: float, dyn: Dynamics, rate_hz: float, kinds: Sequence[str] = KINDS,
             progress: Callable[[str], None] | None = None, fresh: np.ndarray | None = None,
             observed: np.ndarray | None = None) -> Estimate:
    """Fit ``kinds`` on the sweep and reversals, validate on the steps, choose the feedforward's kind.

    Parameters
    ----------
    t_s, duty_pct, flow_lpm, phase : ndarray
        The identification recording and each row's protocol phase.
    lo_pct, hi_pct : float
        The working range (cracking and full-open duty), for the second fit of each kind.
    dyn : Dynamics
        Lag and delay from the steps (``delay_s`` in the loop's convention: one period less
        than the command-to-measurement delay).
    rate_hz : float
        The recording's step rate, Hz.
    fresh : ndarray of bool, optional
        Rows whose flow was received in that step (the fit reads the flow ahead from them only).
    observed : ndarray of bool, optional
        Rows the figures may be scored on (:attr:`.timeline.Timeline.observed`: not inside a stall's
        reading gap, where the flow is interpolated); all when not given.

    The rows must be evenly spaced at ``rate_hz`` (:func:`.timeline.timeline`): the lag, the delay and
    the fits' lowpass count rows as time.
    """
    seen = np.ones(len(t_s), dtype=bool) if observed is None else np.asarray(observed, dtype=bool)
    val_mask = (phase == VALIDATION_PHASE) & seen
    f = np.ones(len(t_s), dtype=bool) if fresh is None else np.asarray(fresh, dtype=bool)
    end = int(np.flatnonzero(val_mask)[-1]) + 1 if val_mask.any() else len(t_s)
    sweep_rows = np.flatnonzero(phase == "sweep")
    entry = int(sweep_rows[np.argmax(duty_pct[sweep_rows] >= lo_pct)])  # the sweep enters the working range
    # (name, duty the model sees, first row): from the valve at rest on the duty as commanded, or from
    # the sweep's entry into the working range (memory wiped below it) on the duty held to that range
    inputs = (("commanded", duty_pct, 0), ("working", np.clip(duty_pct, lo_pct, hi_pct), entry))
    fit_end = int(np.flatnonzero(np.isin(phase, FIT_PHASES))[-1]) + 1
    # the static flow of each command row the fits may use, per first row (its smoothing spans its rows only)
    static = {first: static_flow(t_s, flow_lpm, f, t_s[first:fit_end], dyn.tau_s, dyn.delay_s + 1.0 / rate_hz)
              for _, _, first in inputs}
    results = {}
    for kind in kinds:
        if progress:
            progress(kind)
        for name, x, first in inputs:
            fit_mask = np.isin(phase, FIT_PHASES)
            fit_mask[:first] = False
            fit_idx = np.flatnonzero(fit_mask)
            try:
                model = fit_model(kind, t_s[fit_idx], x[fit_idx], static[first][fit_idx - first], source="identification")
            except (np.linalg.LinAlgError, ValueError) as e:
                # one kind that cannot be fitted on this valve must not cost the whole identification
                sys.stderr.write(f"identify: {kind} on the {name} duty not fitted: {e}\n")
                continue
            pred = np.full(len(t_s), np.nan)
            pred[first:end] = predict_flow(model, x[first:end], rate_hz, dyn.tau_s, dyn.delay_s + 1.0 / rate_hz)
            scored = fit_mask & seen
            r = KindResult(kind, model.meta["fit_s"], metrics(flow_lpm[scored], pred[scored]),
                           metrics(flow_lpm[val_mask], pred[val_mask]), feedforward_ready(model), model, name,
                           fit_idx)
            if kind not in results or r.validation.rmse < results[kind].validation.rmse:
                results[kind] = r
    invertible = [k for k, r in results.items() if r.invertible]
    if not invertible:
        raise ValueError(f"the feedforward can run none of the kinds fitted ({', '.join(kinds)})")
    chosen = min(invertible, key=lambda k: results[k].validation.rmse)
    return Estimate(results, chosen, np.flatnonzero(val_mask))


def table(est: Estimate) -> str:
    """Table 1 as Markdown: in-sample and validation figures per kind, the chosen one marked."""
    lines = ["| model | duty seen | MAE | RMSE | r | validation MAE | validation RMSE | validation r | fit s | invertible |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | :---: |"]
    for k, r in est.results.items():
        m, v = r.in_sample, r.validation
        name = f"**{k}** (feedforward)" if k == est.chosen else k
        lines.append(f"| {name} | {r.duty_range} | {m.mae:.2f} | {m.rmse:.2f} | {m.r:.4f} | {v.mae:.2f} | {v.rmse:.2f} | {v.r:.4f} "
                     f"| {r.fit_s:.1f} | {'yes' if r.invertible else 'no'} |")
    return "\n".join(lines)


def loops_plot(est: Estimate, duty_pct: np.ndarray, flow_lpm: np.ndarray, rate_hz: float, dyn: Dynamics, ax=None):
    """Flow against duty on the fitted rows: measured, and the chosen model behind the lag and delay; the figure."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 5))
    else:
        fig = ax.figure
    idx = est.results[est.chosen].fit_rows
    pred = predict_flow(est.model, duty_pct[idx[0]:], rate_hz, dyn.tau_s, dyn.delay_s + 1.0 / rate_hz)[idx - idx[0]]
    step = max(1, len(idx) // 20000)
    ax.plot(duty_pct[idx][::step], flow_lpm[idx][::step], ".", ms=1, color="tab:orange", alpha=0.4, label="measured")
    ax.plot(duty_pct[idx][::step], pred[::step], color="tab:blue", lw=0.6, label=f"{est.chosen} (fitted)")
    ax.set_xlabel("duty cycle (%)")
    ax.set_ylabel("flow (L/min)")
    ax.set_title("major and minor loops: range ramp, sweep and reversals")
    ax.legend(loc="upper left", markerscale=6)
    fig.tight_layout()
    return fig
