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
   named word, with all the other confirmed words in place, must lower the
   RMSE of the chain without it, and that chain's residual must follow its
   correction (slope and correlation of the residual against the correction);
   of the words that fail, the weakest is dropped and the others checked again.
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
from .design import build, clip, fit_baseline, fit_final, fixed_base, memory_start_s, unbend
from .detectors import (AMBIGUOUS, EXPLAINED, MIN_CORRELATION, MIN_SLOPE, Selection, chain_params, follows, select_effects,
                        without)
from .folds import Folds, make_folds
from .residuals import Location, locate, where
from .signals import Signals, noise_lpm, raw_signals, running_rows, work_signals
from .trace import ALTERNATIVE, NAMED, UNCONFIRMED, Decision, explain
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
        RMSE (L/min) on the final holdout without and with this effect, every other confirmed
        effect in place (an alternative: in the place of the word it is the alternative to).
    params : dict
        Parameters in the units of DESIGN.md's effect table.
    alternative_to : str, optional
        The named word this one fits as well as (a lag for a delay or the reverse): it is not in
        the augmented model's chain.
    slope, correlation : float
        Holdout residual without the finding regressed on its correction: the slope (1: the
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
        Prediction with and without each finding, every other confirmed finding in place: with it
        is ``augmented_lpm``, except for an alternative finding (a lag that a delay fits as well,
        or the reverse), whose law takes the place of the word it is the alternative to.
    holdout : ndarray of bool
        Rows never used to fit anything.
    baseline : Metrics
        Baseline against the whole recording.
    findings : list of Finding
        Strongest first (by the fall of the holdout error each brings), an alternative after the
        word it is the alternative to; empty when none.
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
        folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    except ValueError as exc:
        raise InputError(f"{rec.path}: {exc}") from None
    base = fit_baseline(sig, folds) if model is None else fixed_base(model, sig)
    sel = select_effects(base, sig, folds, margins, progress=progress)
    undecided = _undecided(sel, sig, raw, folds)
    hold = folds.holdout_at(raw.t_s) & ~undecided
    baseline_lpm = clip(base.predict(raw, {}), None, bool(base.shut(raw).any()))
    y = raw.flow_lpm
    fits = _ChainFits(sel, sig, raw, folds, baseline_lpm)
    words, unconfirmed = _confirm(sel, fits, y, hold)
    findings, steps_lpm, before_lpm, unconfirmed = _findings(sel, words, fits, raw, hold, margins, unconfirmed)
    augmented = fits.predict(fits.chain(words))
    trace = sel.trace + unconfirmed
    last = {d.word: d for d in trace}
    named = {f.effect for f in findings}
    model_info = {
        "baseline": {"kind": base.model.kind,
                     "source": "model file (held fixed)" if model is not None else
                     "paper's symmetric PI, n = 50, fitted on the training rows only",
                     **({"seat": {"seat_pct": base.seat[0], "gain_lpm_per_pct": base.seat[1],
                                  "meaning": "the PI's input is held at the seat duty; below it the flow "
                                             "closes along a line of this slope"}} if base.seat else {}),
                     "holdout": metrics(y[hold], baseline_lpm[hold]).to_dict()},
        "augmented": {"effects": {f.effect: f.params for f in findings},
                      "units": {f.effect: VOCABULARY[f.effect].units for f in findings},
                      "plausible": {f.effect: VOCABULARY[f.effect].plausible for f in findings},
                      "caveats": {f.effect: c for f in findings if (c := VOCABULARY[f.effect].caveat(f.params))},
                      "holdout": metrics(y[hold], augmented[hold]).to_dict()},
        "rejected": {w: explain(d) for w, d in last.items() if w not in named and w not in sel.nuisance},
        "not_identifiable": {**sel.not_identifiable, **_invisible(sel, named, base, sig, folds),
                             **_absorbed(sel, named, base, sig, (y - augmented)[hold])},
        "trace": [d.to_dict() for d in trace],
        "validation": {"holdout_fraction": float(np.mean(hold)), "holdout_undecided_rows": int(undecided.sum()),
                       "cv_folds": folds.k,
                       "blocks": len(folds.block_fold), "block_s": float(np.diff(folds.block_edges_s)[0]),
                       "work_rate_hz": sig.rate_hz, "rows": len(raw), "margins": margins.to_dict(),
                       "confirmation": "an effect that passes the cross-validation is asserted only if, with every "
                                       "other confirmed effect in place, it also lowers the holdout RMSE and the "
                                       "holdout residual without it follows its correction "
                                       f"(slope >= {MIN_SLOPE}, correlation >= {MIN_CORRELATION}); of those that "
                                       "do not, the weakest is dropped and the others checked again; the holdout "
                                       "decides that yes or no and is never fitted on"},
    }
    return Diagnosis(raw.t_s, raw.duty_pct, y, baseline_lpm, augmented, steps_lpm, before_lpm, hold,
                     metrics(y, baseline_lpm), findings, locate(raw.t_s, raw.duty_pct, y, baseline_lpm), model_info,
                     trace)


def _undecided(sel: Selection, sig: Signals, raw: Signals, folds: Folds) -> np.ndarray:
    """Rows of ``raw`` that a setting of the final chain's words the training rows cannot tell apart
    from another treats differently (:meth:`Word.undecided`: a row between the training rows a
    cracking duty lies between): left out of the holdout, which would judge the law on where within
    that gap the setting fell, not on whether the recording shows it."""
    out = np.zeros(len(raw.t_s), dtype=bool)
    for w, p in sel.chain.items():
        others = {k: v for k, v in sel.chain.items() if k != w}
        rows = VOCABULARY[w].undecided(sig, p, others, folds.train, raw)
        if rows is not None:
            out |= rows
    return out


def _confirm(sel: Selection, fits: "_ChainFits", y: np.ndarray, hold: np.ndarray) -> tuple[list, list]:
    """The words of the search's final chain the holdout confirms, each with all the other confirmed
    words in place: ``(confirmed words in chain order, unconfirmed decisions)``.

    A word is confirmed when the holdout residual of the chain without it falls once it is added,
    and follows its correction (:func:`_unconfirmed`). Each word is held against the whole chain,
    not against the words named before it: a clip corrects the right rows only once the coil
    heating that moves the flow along the thermal history is modelled (a clip at 140 L/min named
    before the heating raised the holdout RMSE of the lag named before it, 2.53 -> 2.77 L/min; with
    the heating in place it lowers it, 1.46 -> 1.40). Of the words that fail, the one whose holdout
    error falls least is dropped and the others are checked again: a word dropped changes what each
    other explains.
    """
    words, unconfirmed = list(sel.chain), []
    while words:
        full = fits.predict(fits.chain(words))[hold]
        failing = []
        for w in words:
            without = fits.predict(fits.chain(v for v in words if v != w))[hold]
            why = _unconfirmed(y[hold] - without, full - without)
            if why:
                failing.append((_fall(y[hold], without, full), w, why))
        if not failing:
            break
        _, w, why = min(failing)
        words.remove(w)
        d = next(d for d in reversed(sel.trace) if d.word == w and d.outcome == NAMED)
        why = f"with {', '.join(words)} in place, {why}" if words else why
        unconfirmed.append(Decision(**{**d.to_dict(), "outcome": UNCONFIRMED, "why": why}))
    return words, unconfirmed


def _fall(y: np.ndarray, before: np.ndarray, after: np.ndarray) -> float:
    """Relative fall of the squared error of ``before`` once ``after`` replaces it (0..1; negative:
    it rose)."""
    return 1.0 - float(np.sum((y - after) ** 2)) / float(np.sum((y - before) ** 2))


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


def _findings(sel: Selection, words: list, fits: "_ChainFits", raw: Signals, hold: np.ndarray, margins: Margins,
              unconfirmed: list) -> tuple:
    """The findings of the confirmed ``words``, strongest first (by the fall of the holdout error
    each brings): each held against the confirmed chain without it, so that its holdout RMSE before
    and after, its prediction and the one before it are what the confirmation judged. A lag or a
    delay is reported with its alternative when the recording cannot tell them apart (the other
    law in its place in the same chain). Returns ``(findings, steps_lpm, before_lpm, unconfirmed)``.
    """
    y = raw.flow_lpm
    chain = fits.chain(words)
    full, params = fits.predict(chain), fits.params(chain)
    ranked = []
    for w in words:
        if w in sel.nuisance:  # in the model, not a finding (:attr:`Selection.nuisance`)
            continue
        step = next(s for s in sel.steps if s.word == w)
        prev = fits.predict(fits.chain(v for v in words if v != w))
        alt = sel.alternatives.get(w)
        alt_pred = None
        if alt is not None:
            a = alt[0].word
            alt_chain = {(a if v == w else v): (alt[1][a] if v == w else p) for v, p in chain.items()}
            alt_pred = fits.predict(alt_chain)
            why = _unconfirmed(y[hold] - prev[hold], alt_pred[hold] - prev[hold])
            if why:
                d = next(d for d in reversed(sel.trace) if d.word == a and d.outcome == ALTERNATIVE)
                unconfirmed = unconfirmed + [Decision(**{**d.to_dict(), "outcome": UNCONFIRMED,
                                                         "why": f"alternative to {w}: {why}"})]
                alt_pred = None
        note = ""
        if alt_pred is not None:
            note = (f"; {alt[0].word} also explains it (held-out gain {100 * alt[0].gain:.1f} % against "
                    f"{100 * step.gain:.1f} %): this recording cannot tell a lag from a pure delay (they differ by "
                    f"less than {100 * AMBIGUOUS:.0f} %, or the response is late by less than one sample); "
                    f"the augmented model keeps {w}")
        found = [(_finding(step, params[w], margins, raw, y, hold, prev, full, note), full, prev)]
        if alt_pred is not None:
            note = (f"; the alternative to {w} (held-out gain {100 * step.gain:.1f} %): this recording "
                    f"cannot tell a lag from a pure delay (a smooth excitation shifts both alike, and within a "
                    f"sample they are one thing)")
            found.append((_finding(alt[0], fits.params(alt_chain)[a], margins, raw, y, hold, prev, alt_pred, note, w),
                          alt_pred, prev))
        ranked.append((_fall(y[hold], prev[hold], full[hold]), found))
    ranked.sort(key=lambda r: -r[0])
    found = [f for _, fs in ranked for f in fs]
    return [f[0] for f in found], [f[1] for f in found], [f[2] for f in found], unconfirmed


def _invisible(sel: Selection, named: set, base, sig: Signals, folds: Folds) -> dict:
    """The words not named with a probe size (:attr:`Word.probe`: the time response, the asymmetry)
    that this excitation shows by less than :data:`VISIBLE` of the noise: not identifiable on it,
    rather than absent (breaths stepping down to a rest below the valve's opening never sample the
    descending branch an asymmetry widens)."""
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


def _absorbed(sel: Selection, named: set, base, sig: Signals, held_out_lpm: np.ndarray) -> dict:
    """The words not named whose law's signature the recording shows (:meth:`Word.absorbed`) while
    the named words, on a baseline fitted on the recording, explain it to within the noise
    (:data:`EXPLAINED`): not identifiable against that baseline, rather than absent.

    Judged by ``held_out_lpm``, the holdout residual of the model the diagnosis gives (the baseline
    as fitted, with the confirmed words): the search's reference, its PI refitted with the slope's
    steps held near zero, opens less steeply than the baseline, which passed a cracking duty's jump
    at the breaths' rest to within the noise (1.0 x) where the reference left 1.8 x."""
    if not base.refit:  # a model file held fixed absorbs nothing
        return {}
    chain = {w: p for w, p in sel.chain.items() if w in named}
    if _rmse(held_out_lpm) > EXPLAINED * noise_lpm(sig.flow_lpm):
        return {}
    out = {}
    for w, word in VOCABULARY.items():
        if w not in named and w not in sel.not_identifiable and (why := word.absorbed(sig, chain)):
            out[w] = f"not identifiable against a baseline fitted on this recording: {why}"
    return out


class _ChainFits:
    """Sub-chains of the search's final chain fitted on the training rows, memoized: what the
    holdout judges (it is never fitted on).

    Each sub-chain keeps its words' nonlinear parameters from the search and has the PI refitted
    under it from the search's reference, with every linear coefficient; the empty chain is the
    baseline as given. Under a clip, the refit holds near zero the steps of the operators that mostly
    the clipped rows move (:func:`.design.unbend` with ``untold``): a held-out breath that first reaches
    a new top leaves a memory of them that no training row shows.
    """

    def __init__(self, sel: Selection, sig: Signals, raw: Signals, folds: Folds, baseline_lpm: np.ndarray):
        self.sel, self.sig, self.raw, self.folds = sel, sig, raw, folds
        self._memo = {"[]": (baseline_lpm, None, None, None)}

    def chain(self, words) -> dict:
        """The search's chain restricted to ``words`` (in the chain's order); a lag or delay left out
        leaves its share of the time response to the other if kept and that fits the training rows
        better (:func:`.detectors.without`)."""
        keep, chain = set(words), dict(self.sel.chain)
        for w in self.sel.chain:
            if w not in keep:
                options = without(chain, w, self.sig.rate_hz)
                chain = options[0] if len(options) == 1 else min(options, key=self._train_sse)
        return chain

    def _train_sse(self, chain: dict) -> float:
        """Squared error of ``chain``'s fit on the training rows (working grid)."""
        _, d, theta, _ = self._fit(chain)
        e = (self.sig.flow_lpm - d.predict(theta))[self.folds.train]
        return float(e @ e)

    def _fit(self, chain: dict) -> tuple:
        key = repr(list(chain.items()))
        if key not in self._memo:
            sig, folds = self.sig, self.folds
            b = unbend(self.sel.reference, sig, chain, folds.train, untold=True)
            d = build(b, sig, chain)
            theta = fit_final(d, sig.flow_lpm, folds.train)
            self._memo[key] = build(b, self.raw, chain).predict(theta), d, theta, b
        return self._memo[key]

    def predict(self, chain: dict) -> np.ndarray:
        """Prediction (L/min) of ``chain`` on the recording's rows."""
        return self._fit(chain)[0]

    def params(self, chain: dict) -> dict:
        """Word -> its parameters in physical units from the fit of ``chain``."""
        _, d, theta, b = self._fit(chain)
        return chain_params(chain, d, theta, self.sig, b) if chain else {}


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
