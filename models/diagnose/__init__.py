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
   each word's exact law refined by bounded nonlinear least squares, parameters
   reported in physical units with a plausibility check; the final chain is refined
   as a whole, and a word that no longer earns its margin with all the others in
   place is dropped (the backward check).
5. *Confirm*: on the final holdout (rows never used to fit anything) each
   finding must lower the RMSE, and the residual it explains must follow its
   correction (slope and correlation of the residual against the correction).
6. *Show*: the holdout before/after RMSE of every finding; the words the
   excitation cannot show are said to be not identifiable on it.

A closed-loop run recording (``valvectl run --record``: a ``state`` column) is
diagnosed on its longest stretch of ``running`` rows; the excitation is then
the controller's own duty.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..metrics import Metrics, metrics
from ..model import FittedModel
from ..recording import InputError, Recording
from .calibrate import Margins, load_margins
from .design import build, clip, fit_baseline, fit_final, fixed_base, unbend
from .detectors import AMBIGUOUS, MIN_CORRELATION, MIN_SLOPE, Selection, follows, select_effects
from .folds import Folds, make_folds
from .residuals import Location, locate, where
from .signals import Signals, noise_lpm, raw_signals, running_rows, work_signals
from .trace import UNCONFIRMED, Decision, explain
from .words import VOCABULARY


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
    slope, correlation : float
        Holdout residual before the finding regressed on its correction: the slope (1: the
        correction is the residual's size) and the correlation.
    """

    effect: str
    where: str
    evidence: str
    score: float
    holdout_rmse_before: float
    holdout_rmse_after: float
    params: dict
    alternative_to: str | None = None
    slope: float = float("nan")
    correlation: float = float("nan")

    def to_dict(self) -> dict:
        d = {"effect": self.effect, "where": self.where, "evidence": self.evidence, "score": self.score,
             "holdout_rmse_before": self.holdout_rmse_before, "holdout_rmse_after": self.holdout_rmse_after}
        if self.alternative_to is not None:
            d["alternative_to"] = self.alternative_to
        return d


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Result of :func:`diagnose_response`; per-row arrays are on the recording's own rows.

    Attributes
    ----------
    t_s, duty_pct, flow_lpm : ndarray
        The recording (for a closed-loop run, its running rows).
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
    trace : list of Decision
        Every test of the search and what was decided.
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
    trace: list = field(default_factory=list)

    def to_json(self) -> dict:
        """D.json: ``{"baseline": {"mae","rmse","r"}, "findings": [...], "model": {...}}``."""
        return {"baseline": self.baseline.to_dict(), "findings": [f.to_dict() for f in self.findings],
                "model": self.model}


#: An effect the excitation shows by less than this fraction of the noise RMS (at a plausible size)
#: is reported as not identifiable on it.
VISIBLE = 0.5


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e * e)))


def diagnose_response(rec: Recording, model: FittedModel | None = None, margins: Margins | None = None,
                      progress=None) -> Diagnosis:
    """Diagnose a recording against a model file, or against the paper's PI fitted on it.

    Parameters
    ----------
    rec : Recording
        The recording (``t_s``, ``duty_pct``, ``flow_lpm``; ``supply_bar`` and
        ``coil_temp_c`` drive their laws when present; a ``state`` column marks a
        closed-loop run, whose ``running`` rows are used).
    model : FittedModel, optional
        The simulation to hold the recording against (held fixed); for a closed-loop
        run, the model its feedforward used.
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
    rec, rest = running_rows(rec)
    raw = raw_signals(rec, rest)
    sig = work_signals(rec, rest)
    try:
        folds = make_folds(sig.t_s)
    except ValueError as exc:
        raise InputError(f"{rec.path}: {exc}") from None
    base = fit_baseline(sig, folds) if model is None else fixed_base(model, sig)
    sel = select_effects(base, sig, folds, margins, progress=progress)
    hold = folds.holdout_at(raw.t_s)
    baseline_lpm = clip(base.predict(raw, {}), None, bool(base.shut(raw).any()))
    steps, preds, unconfirmed = _confirm(sel, sig, raw, folds, hold, baseline_lpm)
    findings, steps_lpm, before_lpm, unconfirmed = _findings(sel, steps, preds, sig, raw, folds, hold, baseline_lpm,
                                                             margins, unconfirmed)
    augmented = preds[-1] if preds else baseline_lpm
    y = raw.flow_lpm
    trace = sel.trace + unconfirmed
    last = {d.word: d for d in trace}
    named = {f.effect for f in findings}
    model_info = {
        "baseline": {"kind": base.model.kind,
                     "source": "model file (held fixed)" if model is not None else
                     "paper's symmetric PI, n = 50, fitted on the training rows only",
                     "holdout": metrics(y[hold], baseline_lpm[hold]).to_dict()},
        "augmented": {"effects": {f.effect: f.params for f in findings},
                      "units": {f.effect: VOCABULARY[f.effect].units for f in findings},
                      "plausible": {f.effect: VOCABULARY[f.effect].plausible for f in findings},
                      "caveats": {f.effect: c for f in findings if (c := VOCABULARY[f.effect].caveat(f.params))},
                      "holdout": metrics(y[hold], augmented[hold]).to_dict()},
        "rejected": {w: explain(d) for w, d in last.items() if w not in named},
        "not_identifiable": {**sel.not_identifiable, **_invisible(sel, named, base, sig, folds)},
        "trace": [d.to_dict() for d in trace],
        "validation": {"holdout_fraction": float(np.mean(hold)), "cv_folds": folds.k,
                       "blocks": len(folds.block_fold), "block_s": float(np.diff(folds.block_edges_s)[0]),
                       "work_rate_hz": sig.rate_hz, "rows": len(raw), "margins": margins.to_dict(),
                       "confirmation": "an effect that passes the cross-validation is asserted only if it also "
                                       "lowers the holdout RMSE and the holdout residual follows its correction "
                                       f"(slope >= {MIN_SLOPE}, correlation >= {MIN_CORRELATION}); the holdout "
                                       "decides that yes or no and is never fitted on"},
    }
    return Diagnosis(raw.t_s, raw.duty_pct, y, baseline_lpm, augmented, steps_lpm, before_lpm, hold,
                     metrics(y, baseline_lpm), findings, locate(raw.t_s, raw.duty_pct, y, baseline_lpm), model_info,
                     trace)


def _confirm(sel: Selection, sig: Signals, raw: Signals, folds: Folds, hold: np.ndarray, baseline_lpm: np.ndarray):
    """Drop, one at a time, the first named effect the holdout does not confirm: ``(steps, chain
    predictions, unconfirmed decisions)``."""
    steps, unconfirmed = list(sel.steps), []
    y = raw.flow_lpm
    while True:
        preds = _chain_predictions(steps, sel.chain, sel.reference, sig, raw, folds, rebase=bool(unconfirmed))
        bad = None
        for i, (prev, pred) in enumerate(zip([baseline_lpm] + preds, preds)):
            why = _unconfirmed(y[hold] - prev[hold], pred[hold] - prev[hold])
            if why:
                bad = i, why
                break
        if bad is None:
            return steps, preds, unconfirmed
        i, why = bad
        d = next(d for d in sel.trace if d.word == steps[i].word and d.outcome == "named")
        unconfirmed.append(Decision(**{**d.to_dict(), "outcome": UNCONFIRMED, "why": why}))
        del steps[i]


def _unconfirmed(resid: np.ndarray, delta: np.ndarray) -> str | None:
    """Why a correction ``delta`` does not explain the holdout residual ``resid`` before it, or None."""
    before, after = _rmse(resid), _rmse(resid - delta)
    if after >= before:
        return f"holdout RMSE {before:.4f} -> {after:.4f} L/min, not lower"
    slope, corr = follows(resid, delta)
    if slope < MIN_SLOPE or corr < MIN_CORRELATION:
        return (f"the holdout residual does not follow the correction (slope {slope:.3g}, needs {MIN_SLOPE}; "
                f"correlation {corr:.3g}, needs {MIN_CORRELATION})")
    return None


def _findings(sel, steps, preds, sig, raw, folds, hold, baseline_lpm, margins, unconfirmed):
    """The findings of the confirmed chain, each lag/delay with its alternative when the recording
    cannot tell them apart."""
    y = raw.flow_lpm
    findings, steps_lpm, before_lpm = [], [], []
    prev = baseline_lpm
    for i, step in enumerate(steps):
        alt = sel.alternatives.get(step.word)
        alt_pred = None
        if alt is not None:
            kept = [s.word for s in steps[:i]]
            alt_chain = {w: p for w, p in alt[1].items() if w in kept or w == alt[0].word}
            alt_base = alt[0].base or (steps[i - 1].base if i else sel.reference)
            theta = fit_final(build(alt_base, sig, alt_chain), sig.flow_lpm, folds.train)
            alt_pred = build(alt_base, raw, alt_chain).predict(theta)
            why = _unconfirmed(y[hold] - prev[hold], alt_pred[hold] - prev[hold])
            if why:
                d = next(d for d in sel.trace if d.word == alt[0].word)
                unconfirmed = unconfirmed + [Decision(**{**d.to_dict(), "outcome": UNCONFIRMED,
                                                         "why": f"alternative to {step.word}: {why}"})]
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
    return findings, steps_lpm, before_lpm, unconfirmed


def _invisible(sel: Selection, named: set, base, sig: Signals, folds: Folds) -> dict:
    """The time-response words not named whose plausible size this excitation shows by less than
    :data:`VISIBLE` of the noise: not identifiable on it, rather than absent."""
    out = {}
    noise = noise_lpm(sig.flow_lpm)
    cur = sel.steps[-1].base if sel.steps and sel.steps[-1].base is not None else sel.reference
    q0 = build(cur, sig, sel.chain)
    theta = fit_final(q0, sig.flow_lpm, folds.train)
    before = q0.predict(theta)
    for w, word in VOCABULARY.items():
        if w in named or not word.probe or w in sel.not_identifiable:
            continue
        d = build(cur, sig, {**sel.chain, w: word.probe})
        # the change the effect makes at a plausible size, less what the refitted baseline absorbs of it
        rest = sig.flow_lpm - (d.predict(theta) - before)
        absorbed = d.predict(fit_final(d, rest, folds.train))
        shown = _rmse((d.predict(theta) - before) - (absorbed - before))
        if shown < VISIBLE * noise:
            size = ", ".join(f"{k} = {v:g} {word.units.get(k, '')}".rstrip() for k, v in word.probe.items())
            out[w] = (f"not identifiable on this excitation: at {size} it changes the prediction by "
                      f"{shown:.3g} L/min RMS beyond what the baseline absorbs, under {VISIBLE:g} x the noise "
                      f"({noise:.3g} L/min)")
    return out


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
    eff = VOCABULARY[step.word]
    ptxt = ", ".join(f"{k} = {v:.4g} {eff.units.get(k, '')}".rstrip() for k, v in params.items())
    slope, corr = follows((y - before)[hold], (after - before)[hold])
    caveat = eff.caveat(params)
    evidence = (f"{eff.physics}; {step.law} law; held-out squared error {-100 * step.gain:.1f} % over "
                f"{len(step.test_after)} blocked folds (margin -{100 * margins.gain[step.word]:.1f} %), lower in "
                f"{step.wins} of them; holdout residual against the correction: slope {slope:.2f}, correlation "
                f"{corr:.2f}; fitted {ptxt} (plausible{f'; but {caveat}' if caveat else ''}){note}")
    return Finding(step.word, where(raw.t_s, raw.duty_pct, y, after - before), evidence, round(float(step.gain), 6),
                   _rmse((before - y)[hold]), _rmse((after - y)[hold]), params, alternative_to, slope, corr)
