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
from .design import build, fit_baseline, fit_final, fixed_base, unbend
from .detectors import AMBIGUOUS, EFFECTS, select_effects
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
    alternative_to : str, optional
        The named word this one fits as well as (a lag for a delay or the reverse): it is not in
        the augmented model's chain.
    """

    effect: str
    where: str
    evidence: str
    score: float
    holdout_rmse_before: float
    holdout_rmse_after: float
    params: dict
    alternative_to: str | None = None

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
    steps_lpm, before_lpm : list of ndarray
        Prediction after and before each finding, in order; an alternative finding (a lag that a
        delay fits as well, or the reverse) has its own prediction and is not in the chain, so
        ``augmented_lpm`` is the last prediction of the chain.
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
    before_lpm: list
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
    steps, root = list(sel.steps), sel.reference
    unconfirmed = {}
    while True:
        preds = _chain_predictions(steps, sel.chain, root, sig, raw, folds, rebase=bool(unconfirmed))
        errs = [_rmse((p - y)[hold]) for p in [baseline_lpm] + preds]
        bad = next((i for i in range(len(steps)) if errs[i + 1] >= errs[i]), None)
        if bad is None:
            break
        unconfirmed[steps[bad].word] = (f"passed the cross-validation but did not lower the holdout RMSE "
                                        f"({errs[bad]:.4f} -> {errs[bad + 1]:.4f} L/min): not asserted")
        del steps[bad]
    findings, steps_lpm, before_lpm = [], [], []
    prev = baseline_lpm
    for i, step in enumerate(steps):
        alt = sel.alternatives.get(step.word)
        alt_pred = None
        if alt is not None:
            kept = [s.word for s in steps[:i]]
            alt_chain = {w: p for w, p in alt[1].items() if w in kept or w == alt[0].word}
            alt_base = alt[0].base or (steps[i - 1].base if i else root)
            theta = fit_final(build(alt_base, sig, alt_chain), sig.flow_lpm, folds.train)
            alt_pred = build(alt_base, raw, alt_chain).predict(theta)
            if _rmse((alt_pred - y)[hold]) >= errs[i]:
                unconfirmed[alt[0].word] = f"alternative to {step.word} that did not lower the holdout RMSE"
                alt_pred = None
        note = ""
        if alt_pred is not None:
            note = (f"; {alt[0].word} also explains it (held-out gain {100 * alt[0].gain:.1f} % against "
                    f"{100 * step.gain:.1f} %): this recording cannot tell a lag from a pure delay (they differ by "
                    f"less than {100 * AMBIGUOUS:.0f} %, or the response is late by less than one sample); "
                    f"the augmented model keeps {step.word}")
        findings.append(_finding(step, sel.params[step.word], margins, raw, y, hold, prev, preds[i], note))
        steps_lpm.append(preds[i])
        before_lpm.append(prev)
        if alt_pred is not None:
            note = (f"; the alternative to {step.word} (held-out gain {100 * step.gain:.1f} %): this recording "
                    f"cannot tell a lag from a pure delay (a smooth excitation shifts both alike, and within a "
                    f"sample they are one thing)")
            findings.append(_finding(alt[0], alt[2], margins, raw, y, hold, prev, alt_pred, note, step.word))
            steps_lpm.append(alt_pred)
            before_lpm.append(prev)
        prev = preds[i]
    augmented = prev
    model_info = {
        "baseline": {"kind": base.model.kind,
                     "source": "model file (held fixed)" if model is not None else
                     "paper's symmetric PI, n = 50, fitted on the training rows only",
                     "holdout": metrics(y[hold], baseline_lpm[hold]).to_dict()},
        "augmented": {"effects": {f.effect: f.params for f in findings},
                      "units": {f.effect: EFFECTS[f.effect].units for f in findings},
                      "plausible": {f.effect: EFFECTS[f.effect].plausible for f in findings},
                      "holdout": metrics(y[hold], augmented[hold]).to_dict()},
        "rejected": {**sel.rejected, **unconfirmed},
        "not_identifiable": sel.not_identifiable,
        "validation": {"holdout_fraction": float(np.mean(hold)), "cv_folds": folds.k,
                       "blocks": len(folds.block_fold), "block_s": float(np.diff(folds.block_edges_s)[0]),
                       "work_rate_hz": sig.rate_hz, "margins": margins.to_dict(),
                       "confirmation": "an effect that passes the cross-validation is asserted only if it also "
                                       "lowers the holdout RMSE; the holdout decides that yes or no and is never "
                                       "fitted on"},
    }
    return Diagnosis(raw.t_s, raw.duty_pct, y, baseline_lpm, augmented, steps_lpm, before_lpm, hold,
                     metrics(y, baseline_lpm), findings, locate(raw.t_s, raw.duty_pct, y, baseline_lpm), model_info)


def _chain_predictions(steps, chain: dict, root, sig, raw, folds, rebase: bool) -> list:
    """Prediction (recording rows) after each step of the chain, each with its own refitted baseline.

    ``rebase``: an effect was dropped from the middle of the chain, so the PI weights of the later
    steps (refitted with it present) are refitted under what is left.
    """
    preds, sub = [], {}
    for step in steps:
        sub = {**sub, step.word: chain[step.word]}
        b = unbend(root, sig, sub, folds.train) if rebase else step.base
        theta = fit_final(build(b, sig, sub), sig.flow_lpm, folds.train)
        preds.append(build(b, raw, sub).predict(theta))
    return preds


def _finding(step, params: dict, margins: Margins, raw, y, hold, before, after, note: str,
             alternative_to: str | None = None) -> Finding:
    eff = EFFECTS[step.word]
    ptxt = ", ".join(f"{k} = {v:.4g} {eff.units.get(k, '')}".rstrip() for k, v in params.items())
    evidence = (f"{eff.physics}; held-out squared error {-100 * step.gain:.1f} % over {len(step.test_after)} "
                f"blocked folds (margin -{100 * margins.gain[step.word]:.1f} %), lower in {step.wins} of them; "
                f"fitted {ptxt} (plausible){note}")
    return Finding(step.word, where(raw.t_s, raw.duty_pct, y, after - before), evidence, round(float(step.gain), 6),
                   _rmse((before - y)[hold]), _rmse((after - y)[hold]), params, alternative_to)
