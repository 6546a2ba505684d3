"""Diagnosis: locate a sim-real mismatch, name the missing physics, model it, show the fit improve.

``diagnose_response(rec, model=None) -> Diagnosis`` (compute) and
:func:`models.diagnose.report.diagnose_plot` / :func:`write_report` (draw)
follow DESIGN.md, Diagnosis:

1. *Baseline*: the model file given, held fixed; or the paper's symmetric
   PI (n = 50) fitted on the training rows of the recording only.
2. *Locate*: :mod:`.residuals` summarises the baseline residual by time,
   duty, flow, branch and time since steps and reversals.
3. *Name*: :mod:`.detectors`, one per effect word, each the effect's physical
   law (:mod:`.effects`) added to the baseline and tested on held-out blocks
   (:mod:`.folds`) against margins calibrated on effect-free recordings
   (:mod:`.calibrate`).
4. *Model*: named effects are added greedily, all coefficients refitted (:mod:`.design`),
   parameters reported in physical units with a plausibility check.
5. *Show*: the final holdout (rows never used to fit anything) gives the
   before/after RMSE of every finding.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..metrics import Metrics, metrics
from ..model import FittedModel
from ..recording import InputError, Recording
from .calibrate import Margins, load_margins
from .design import build, fit_baseline, fit_final, fixed_base
from .detectors import EFFECTS, Selection, select_effects
from .folds import Folds, make_folds
from .residuals import Location, locate, where
from .signals import WORK_RATE_HZ, raw_signals, work_signals


@dataclass(frozen=True)
class Finding:
    """One named effect (the keys of DESIGN.md's findings, plus its parameters).

    Attributes
    ----------
    effect : str
        Effect word.
    where : str
        Where its correction concentrates.
    evidence : str
        The held-out test and the fitted parameters.
    score : float
        Relative fall of the cross-validated held-out squared error (0..1).
    holdout_rmse_before, holdout_rmse_after : float
        RMSE (L/min) on the final holdout without and with this effect (on top of the stronger ones).
    params : dict
        Parameters in the units of DESIGN.md's effect table.
    """

    effect: str
    where: str
    evidence: str
    score: float
    holdout_rmse_before: float
    holdout_rmse_after: float
    params: dict

    def to_dict(self) -> dict:
        return {"effect": self.effect, "where": self.where, "evidence": self.evidence, "score": self.score,
                "holdout_rmse_before": self.holdout_rmse_before, "holdout_rmse_after": self.holdout_rmse_after}


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Result of :func:`diagnose_response`; per-row arrays are on the recording's own rows.

    Attributes
    ----------
    t_s, duty_pct, flow_lpm : ndarray
        The recording.
    baseline_lpm, augmented_lpm : ndarray
        Baseline and augmented predictions (equal when nothing is found).
    steps_lpm : list of ndarray
        Prediction after each finding, in order (the last is ``augmented_lpm``).
    holdout : ndarray of bool
        Rows never used to fit anything.
    baseline : Metrics
        Baseline against the whole recording.
    findings : list of Finding
        Strongest first; empty when none.
    location : Location
        Where the baseline residual is.
    model : dict
        The baseline, the augmented model and the decision details (D.json ``model``).
    """

    t_s: np.ndarray
    duty_pct: np.ndarray
    flow_lpm: np.ndarray
    baseline_lpm: np.ndarray
    augmented_lpm: np.ndarray
    steps_lpm: list
    holdout: np.ndarray
    baseline: Metrics
    findings: list
    location: Location
    model: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """D.json: ``{"baseline": {"mae","rmse","r"}, "findings": [...], "model": {...}}``."""
        return {"baseline": self.baseline.to_dict(), "findings": [f.to_dict() for f in self.findings],
                "model": self.model}


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e * e)))


def diagnose_response(rec: Recording, model: FittedModel | None = None, margins: Margins | None = None,
                      progress=None) -> Diagnosis:
    """Diagnose a recording against a model file, or against the paper's PI fitted on it.

    Parameters
    ----------
    rec : Recording
        The recording (``t_s``, ``duty_pct``, ``flow_lpm``; ``supply_bar`` and
        ``coil_temp_c`` are used when present).
    model : FittedModel, optional
        The simulation to hold the recording against (held fixed).
    margins : Margins, optional
        Decision margins; the calibrated ones by default.
    progress : callable, optional
        Called with each effect word as it is tested.

    Raises
    ------
    InputError
        When the recording is too short for blocked cross-validation.
    """
    margins = margins or load_margins()
    raw = raw_signals(rec)
    sig = work_signals(rec)
    try:
        folds = make_folds(sig.t_s)
    except ValueError as exc:
        raise InputError(f"{rec.path}: {exc}") from None
    base = fit_baseline(sig, folds) if model is None else fixed_base(model, sig)
    sel = select_effects(base, sig, folds, margins, progress=progress)

    hold = folds.holdout_at(raw.t_s)
    y = raw.flow_lpm
    baseline_lpm = base.model.predict(raw.duty_pct)[0]
    preds = [baseline_lpm]
    chain = {}
    for step in sel.steps:
        chain = {**chain, step.word: sel.chain[step.word]}
        # each step's own baseline (refitted without the rows a dead zone or saturation explains)
        theta = fit_final(build(step.base, sig, chain), sig.flow_lpm, folds.train)
        preds.append(build(step.base, raw, chain).predict(theta))
    findings = []
    for i, step in enumerate(sel.steps):
        before, after = preds[i], preds[i + 1]
        p = sel.params[step.word]
        eff = EFFECTS[step.word]
        ptxt = ", ".join(f"{k} = {v:.4g} {eff.units.get(k, '')}".rstrip() for k, v in p.items())
        evidence = (f"{eff.physics}; held-out squared error {-100 * step.gain:.1f} % over {len(step.test_after)} "
                    f"blocked folds (margin -{100 * margins.gain[step.word]:.1f} %), lower in {step.wins} of them; "
                    f"fitted {ptxt} (plausible)")
        findings.append(Finding(step.word, where(raw.t_s, raw.duty_pct, y, after - before), evidence,
                                round(float(step.gain), 6), _rmse((before - y)[hold]), _rmse((after - y)[hold]), p))
    augmented = preds[-1]
    model_info = {
        "baseline": {"kind": base.model.kind,
                     "source": "model file (held fixed)" if model is not None else
                     "paper's symmetric PI, n = 50, fitted on the training rows only",
                     "holdout": metrics(y[hold], baseline_lpm[hold]).to_dict()},
        "augmented": {"effects": {f.effect: f.params for f in findings},
                      "units": {f.effect: EFFECTS[f.effect].units for f in findings},
                      "plausible": {f.effect: EFFECTS[f.effect].plausible for f in findings},
                      "holdout": metrics(y[hold], augmented[hold]).to_dict()},
        "rejected": sel.rejected,
        "not_identifiable": sel.not_identifiable,
        "validation": {"holdout_fraction": float(np.mean(hold)), "cv_folds": folds.k,
                       "blocks": len(folds.block_fold), "block_s": float(np.diff(folds.block_edges_s)[0]),
                       "work_rate_hz": sig.rate_hz, "margins": margins.to_dict()},
    }
    return Diagnosis(raw.t_s, raw.duty_pct, y, baseline_lpm, augmented, preds[1:], hold,
                     metrics(y, baseline_lpm), findings, locate(raw.t_s, raw.duty_pct, y, baseline_lpm), model_info)
