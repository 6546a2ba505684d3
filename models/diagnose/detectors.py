"""One detector per effect word of DESIGN.md, and the greedy selection of effects.

A detector tests an effect's physical signature the only way that survives
the strongly autocorrelated residuals of a simulation: it fits the augmented
model (baseline + the effect's physical law, :mod:`models.diagnose.effects`)
and asks whether it predicts *held-out* blocks better. Nonlinear parameters
(time constants, delay, cracking duty, full-open flow) are searched
on a grid; for each cross-validation fold the grid point is chosen on that
fold's training rows only, so the held-out error is honest. An effect is
named when the pooled held-out error falls by more than its calibrated margin
(:mod:`models.diagnose.calibrate`, from effect-free recordings) and falls in
at least ``min_wins`` of the folds, and its parameters are physically
plausible. Effects are added greedily, strongest first, each on top of those
already named (forward selection with refit); the margin is the price of an
extra effect, as in an information criterion, so fewer effects are preferred.
Every step refits all linear coefficients (baseline gain, offset and loop
width, and each named effect's) with the new effect in place.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from . import effects as fx
from .calibrate import Margins
from .design import (JOINT_WITH_PI, Base, CVResult, Design, build, cross_validate, fit_final, flow_gain,
                     major_loop_half_width, refit_rows, unbend)
from .folds import Folds
from .signals import Signals

#: Effect words of DESIGN.md, in the order the chain applies them does not matter here.
WORDS = ("asymmetric_hysteresis", "coil_heating", "supply_pressure", "valve_dynamics", "transport_delay",
         "dead_zone", "saturation", "creep", "sensor_offset")
#: Most effects named in one recording.
MAX_EFFECTS = 4
#: A further effect must gain at least this fraction of what the strongest one did: no effect's
#: law is exact, and the structure its misfit leaves (a few per cent of its gain on the suite)
#: is otherwise taken up by another detector.
SECONDARY = 0.1
#: A fold counts in the majority vote only when the effect changes its held-out error by more
#: than this fraction: a dead zone or a saturation touches only the blocks that reach the range
#: ends, and the folds it leaves alone say nothing either way.
CHANGED = 0.002
#: A lag and a pure delay shift a smooth response alike (to first order both are ``-tau dq/dt``);
#: only steps and fast content tell them apart. When the other's held-out gain is within this of
#: the named one's, the recording cannot separate them and both are reported, each as the other's
#: alternative.
AMBIGUOUS = 0.02
#: The two words of the flow's time response, with their time parameter.
DYNAMIC = ("valve_dynamics", "transport_delay")
TIME_PARAM = {"valve_dynamics": "tau_s", "transport_delay": "delay_s"}


@dataclass(frozen=True)
class Effect:
    """What the diagnosis knows of one effect word.

    Attributes
    ----------
    word : str
        DESIGN.md effect word.
    physics : str
        One line: the law modelled.
    units : dict
        Reported parameter -> unit (DESIGN.md's for the effect parameter).
    plausible : dict
        Reported parameter -> (lo, hi) physically plausible range.
    grid : callable
        ``grid(sig, base) -> {param: values}`` of the nonlinear parameters (empty: linear only).
    applicable : callable
        ``applicable(sig, base) -> None`` or the reason it cannot be identified.
    """

    word: str
    physics: str
    units: dict
    plausible: dict
    grid: Callable
    applicable: Callable = lambda sig, base: None


def _always(sig, base):
    return None


def _dead_zone_grid(sig: Signals, base: Base) -> dict:
    # cracking duties just above the lowest duty and the low duty quantiles (each masks the rows
    # at or below one of them, so a held level right at the cracking duty is either shut or open,
    # not both), and evenly over the lower 40 % of the duty span (a recording that rests at one
    # low level, as a ventilator's expiration does, has all its low quantiles at that level)
    q = np.percentile(sig.duty_pct, [0, 0.5, 1, 2, 3, 4, 5, 7, 9, 12, 15, 20, 25, 30])
    span = np.linspace(q[0], q[0] + 0.4 * np.ptp(sig.duty_pct), 41)
    c = np.unique(np.concatenate([q, span[1:]])) + 1e-6
    return {"cracking_pct": c[c <= 50.0]}


def _saturation_grid(sig: Signals, base: Base) -> dict:
    q = np.percentile(sig.flow_lpm, [75, 82, 88, 92, 95, 97, 98.5, 99.3])
    return {"full_open_lpm": np.unique(np.round(q, 2))}


def _heating_grid(sig: Signals, base: Base) -> dict:
    if sig.coil_temp_c is not None:
        return {}
    dur = sig.t_s[-1] - sig.t_s[0]
    tau = np.geomspace(20.0, 2000.0, 11)  # a solenoid coil warms over minutes
    # start: the coil's rise at the first sample as a fraction of the steady rise there (0 = cold start)
    return {"tau_s": tau[tau <= 2.0 * dur], "start": np.array([0.0, 1.0])}


def _no_supply(sig, base):
    return None if sig.supply_bar is not None else "no varying supply_bar column: the pressure cannot be seen"


def _offset_identifiable(sig, base):
    if base.refit:
        return ("absorbed by the offset c of Eq. (4) of a baseline fitted on this recording; "
                "give the simulation's model file (--model) to test it")
    return None


def _dead_zone_applicable(sig, base):
    return None if len(_dead_zone_grid(sig, base)["cracking_pct"]) else "the duty never goes low enough"


EFFECTS = {
    "asymmetric_hysteresis": Effect(
        "asymmetric_hysteresis", "every play operator's descending threshold lifted in proportion to the input level "
        "(generalized PI), to first order, the PI refitted with it",
        {"extra_width": "relative (1 = twice as wide) at full flow",
         "lift_pct": "% duty (descending thresholds at the top of the range)"}, {"lift_pct": (0.005, 20.0)},
        lambda sig, base: {}),
    "coil_heating": Effect(
        "coil_heating", "tau dT/dt = rise55 (duty/55 %)^2 - T; effective duty = duty / (1 + 0.00393 T), "
        "to first order",
        {"rise55_k": "K (steady rise at 55 % duty)", "tau_s": "s", "start": "fraction of the steady rise at t = 0",
         "copper_law_ratio": "- (measured temperature: 1 = copper's 0.393 %/K)", "coil_temp_span_k": "K"},
        {"rise55_k": (0.05, 200.0), "tau_s": (10.0, 3600.0), "copper_law_ratio": (0.3, 3.0)}, _heating_grid),
    "supply_pressure": Effect(
        "supply_pressure", "flow x ((p + 1.013) / (p_mean + 1.013))^exponent from the supply_bar column, "
        "to first order, the PI refitted with it",
        {"exponent": "- (1 = choked flow)", "wander_bar": "bar (half the range of supply_bar)"},
        {"exponent": (0.3, 2.0)}, lambda sig, base: {}, _no_supply),
    "valve_dynamics": Effect(
        "valve_dynamics", "first-order lag of the flow: tau dq/dt = q_static - q, sampled with the command "
        "held (phase 1) or already seen within its sample (phase 0)",
        {"tau_s": "s", "phase": "- (share of the previous sample's command)"}, {"tau_s": (0.0, 2.0)},
        lambda sig, base: {"tau_s": np.geomspace(0.005 / sig.rate_hz, 1.5, 40), "phase": np.linspace(0.0, 1.0, 5)}),
    "transport_delay": Effect(
        "transport_delay", "pure delay from command to measured flow",
        {"delay_s": "s"}, {"delay_s": (0.0, 1.0)},
        lambda sig, base: {"delay_s": np.geomspace(0.005 / sig.rate_hz, 0.8, 48)}),
    "dead_zone": Effect(
        "dead_zone", "no flow while the duty is below the cracking duty",
        {"cracking_pct": "%"}, {"cracking_pct": (0.5, 50.0)}, _dead_zone_grid, _dead_zone_applicable),
    "saturation": Effect(
        "saturation", "flow clipped at the full-open flow",
        {"full_open_lpm": "L/min"}, {"full_open_lpm": (10.0, 400.0)}, _saturation_grid),
    "creep": Effect(
        "creep", "after each reversal the flow drifts on the way it went, to a fraction a of the last "
        "reversal-to-reversal step, first order with tau",
        {"amplitude": "fraction of the last reversal step", "tau_s": "s"},
        {"amplitude": (0.003, 0.5), "tau_s": (0.3, 1000.0)},
        lambda sig, base: {"tau_s": np.geomspace(0.5, min(400.0, (sig.t_s[-1] - sig.t_s[0]) / 4), 11)}),
    "sensor_offset": Effect(
        "sensor_offset", "constant zero offset of the flow sensor",
        {"offset_lpm": "L/min"}, {"offset_lpm": (-30.0, 30.0)}, lambda sig, base: {}, _offset_identifiable),
}


def grid_points(effect: Effect, sig: Signals, base: Base) -> list[dict]:
    """Every combination of the effect's nonlinear grid ({} once for a linear effect)."""
    g = effect.grid(sig, base)
    keys = list(g)
    return [dict(zip(keys, v)) for v in itertools.product(*(g[k] for k in keys))]


@dataclass
class Candidate:
    """The held-out test of one effect on top of a chain.

    Attributes
    ----------
    word : str
        Effect word.
    gain : float
        Relative fall of the pooled held-out squared error (the score).
    wins : int
        Folds whose held-out error fell.
    params : dict
        Nonlinear parameters chosen on all training rows.
    test_before, test_after : ndarray
        Held-out squared error per fold.
    changed : int
        Folds whose held-out error the effect changes by more than :data:`CHANGED`.
    """

    word: str
    gain: float
    wins: int
    params: dict
    test_before: np.ndarray
    test_after: np.ndarray
    base: Base | None = None
    changed: int = 0

    def majority(self, min_wins: int) -> bool:
        """Lower in ``min_wins`` folds, or in a majority (at least two) of the folds it changes."""
        return self.wins >= min(min_wins, self.changed // 2 + 1) and self.wins >= 2


#: Static effects at the end of the range: the baseline is refitted without the rows they explain.
STATIC = ("dead_zone", "saturation")


def test_effect(word: str, chain: dict, before: CVResult, base: Base, sig: Signals, folds: Folds) -> Candidate:
    """Cross-validated test of ``word`` added to ``chain``."""
    points = grid_points(EFFECTS[word], sig, base)
    results = [cross_validate(design(word, base, sig, {**chain, word: p}, folds)[0], sig.flow_lpm, folds)
               for p in points]
    train = np.array([r.train for r in results])          # (G, K)
    test = np.array([r.test for r in results])
    pick = np.argmin(train, axis=0)                        # per fold, chosen on its training rows
    after = test[pick, np.arange(folds.k)]
    best = points[int(np.argmin(train.sum(axis=1)))]
    new_base = None
    if word in JOINT_WITH_PI and base.refit:
        new_base = design(word, base, sig, {**chain, word: best}, folds)[1]
    if word in STATIC and base.refit:
        ch = {**chain, word: best}
        d = build(base, sig, ch)
        refit = refit_rows(base, sig, folds.train & d.fit_ok & (flow_gain(sig, ch) > 0))
        cv = cross_validate(build(refit, sig, ch), sig.flow_lpm, folds)
        if cv.test.sum() < after.sum():
            after, new_base = cv.test, refit
    gain = 1.0 - after.sum() / before.test.sum()
    changed = np.abs(after - before.test) > CHANGED * before.test
    return Candidate(word, float(gain), int(np.sum((after < before.test) & changed)), dict(best), before.test, after,
                     new_base, int(changed.sum()))


def design(word: str, base: Base, sig: Signals, chain: dict, folds: Folds) -> tuple[Design, Base]:
    """The design of ``chain`` when testing ``word``, and its base (the PI refitted jointly with an
    effect it absorbs, :func:`models.diagnose.design.unbend`)."""
    b = unbend(base, sig, chain, folds.train) if word in JOINT_WITH_PI else base
    return build(b, sig, chain), b


def refine(word: str, chain: dict, params: dict, base: Base, sig: Signals, folds: Folds) -> dict:
    """Polish the nonlinear parameters of ``word`` on the training rows (log-scale bounded search)."""
    grid = EFFECTS[word].grid(sig, base)
    params = dict(params)
    y = sig.flow_lpm
    rows = folds.train
    for key, values in grid.items():
        values = np.asarray(values, dtype=float)
        if len(values) < 3 or np.any(values <= 0):
            continue
        i = int(np.argmin(np.abs(values - params[key])))
        lo, hi = np.log(values[max(i - 1, 0)]), np.log(values[min(i + 1, len(values) - 1)])

        def cost(u):
            d = design(word, base, sig, {**chain, word: {**params, key: float(np.exp(u))}}, folds)[0]
            return train_sse(d, y, rows)

        res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 0.02, "maxiter": 12})
        if res.fun < cost(np.log(params[key])):
            params[key] = float(np.exp(res.x))
    return params


def train_sse(design: Design, y: np.ndarray, rows: np.ndarray) -> float:
    """Squared error on ``rows`` of the least-squares fit on those rows."""
    from .design import _solve

    fr = rows & design.fit_ok
    p = design.X.shape[1]
    if p:
        X = design.X[fr]
        theta = _solve(X.T @ X, X.T @ (y - design.F)[fr])
    else:
        theta = np.zeros(0)
    e = design.predict(theta)[rows] - y[rows]
    return float(e @ e)


def physical_params(word: str, chain: dict, design: Design, theta: np.ndarray, sig: Signals, base: Base) -> dict:
    """The effect's parameters in the units of DESIGN.md's effect table (see ``Effect.units``)."""
    p = {k: float(v) for k, v in chain[word].items()}
    coef = dict(zip(design.names, theta))
    if word == "asymmetric_hysteresis":
        # lift of the descending thresholds at the top of the range, in duty and over the major loop's half-width
        p["lift_pct"] = float(coef[word]) * base.shape_scale.half_range
        h = major_loop_half_width(base.shape.r, base.lift_w)
        if h > 1e-3:
            p["extra_width"] = float(coef[word]) / h
    elif word == "creep":
        p["amplitude"] = float(coef[word])
    elif word == "coil_heating" and sig.coil_temp_c is not None:
        p["copper_law_ratio"] = float(coef[word])  # 1: the measured temperature explains it by 0.393 %/K
        p["coil_temp_span_k"] = float(np.ptp(sig.coil_temp_c))
    elif word == "coil_heating":
        p["rise55_k"] = float(coef[word])
    elif word == "sensor_offset":
        p["offset_lpm"] = float(coef[word])
    elif word == "supply_pressure":
        p["exponent"] = float(coef[word])
        lo, hi = np.percentile(sig.supply_bar, [1, 99])
        p["wander_bar"] = float(hi - lo) / 2.0
    return p


#: Search-range ends where an effect's time constant is not resolved, so its law cannot be told
#: from a static one: heating faster than the lower end is a static gain error, creep or a lag
#: slower than the upper end is a persistent offset or a drift.
UNRESOLVED = {"coil_heating": ("tau_s", "low"), "creep": ("tau_s", "high"),
              "valve_dynamics": ("tau_s", "high"), "transport_delay": ("delay_s", "high")}


def unresolved(word: str, params: dict, sig: Signals, base: Base) -> str | None:
    """Why the effect's time constant is not resolved (at the end of its search range), or None."""
    if word not in UNRESOLVED:
        return None
    key, side = UNRESOLVED[word]
    grid = EFFECTS[word].grid(sig, base).get(key)
    if grid is None or key not in params:
        return None
    lo, hi = float(np.min(grid)), float(np.max(grid))
    v = params[key]
    if (side == "low" and v <= lo * 1.05) or (side == "high" and v >= hi / 1.05):
        return f"{key} = {v:.4g} at the {side} end of its search range ({lo:.4g}..{hi:.4g}): not resolved"
    return None


def implausible(word: str, params: dict) -> str | None:
    """Why the parameters are not physical for the effect, or None."""
    bad = []
    for k, (lo, hi) in EFFECTS[word].plausible.items():
        if k in params:
            v = params[k]
            if not lo <= v <= hi:
                bad.append(f"{k} = {params[k]:.4g} outside {lo:g}..{hi:g} {EFFECTS[word].units[k]}")
    return "; ".join(bad) or None


@dataclass
class Selection:
    """Outcome of the greedy forward selection.

    Attributes
    ----------
    chain : dict
        Named effects (in the order added) with their nonlinear parameters.
    steps : list of Candidate
        The accepted test of each named effect.
    params : dict
        Word -> parameters in physical units (:func:`physical_params`).
    rejected : dict
        Word -> why it was not named (best gain, folds, margin, plausibility).
    not_identifiable : dict
        Word -> why it cannot be tested on this recording with this baseline.
    alternatives : dict
        Named word -> ``(candidate, chain, physical params)`` of the other word of :data:`DYNAMIC`
        when the recording cannot tell a lag from a delay: the same chain with the other law
        in its place.
    reference : Base
        What the first tests were held against (:func:`reference`).
    """

    chain: dict = field(default_factory=dict)
    steps: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    not_identifiable: dict = field(default_factory=dict)
    alternatives: dict = field(default_factory=dict)
    reference: Base | None = None


def reference(base: Base, sig: Signals, folds: Folds) -> tuple[Base, CVResult]:
    """What the first tests are held against: the baseline, its PI refitted the way every test
    refits it (:func:`models.diagnose.design.unbend`, unconstrained on the training rows), and its
    cross-validated errors."""
    cur = unbend(base, sig, {}, folds.train)
    return cur, cross_validate(build(cur, sig, {}), sig.flow_lpm, folds)


def select_effects(base: Base, sig: Signals, folds: Folds, margins: Margins, progress=None) -> Selection:
    """Greedy forward selection of effects by blocked cross-validation.

    Parameters
    ----------
    base, sig, folds : Base, Signals, Folds
        Baseline, working-grid signals and their folds.
    margins : Margins
        Calibrated per-effect margins on the relative held-out gain, and the fold majority.
    progress : callable, optional
        Called with each effect word as it is tested.
    """
    sel = Selection()
    words = []
    for w in WORDS:
        reason = EFFECTS[w].applicable(sig, base)
        if reason:
            sel.not_identifiable[w] = reason
        else:
            words.append(w)
    y = sig.flow_lpm
    cur, before = reference(base, sig, folds)
    sel.reference = cur
    while words and len(sel.chain) < MAX_EFFECTS:
        cands = {}
        for w in words:
            if progress:
                progress(w)
            cands[w] = test_effect(w, sel.chain, before, cur, sig, folds)
        passing = []
        for c in cands.values():
            need = margins.gain[c.word]
            if sel.steps:  # the law of a named effect leaves part of it for other detectors to take up
                need = max(need, SECONDARY * sel.steps[0].gain)
            if c.gain > need and c.majority(margins.min_wins):
                passing.append(c)
            else:
                sel.rejected[c.word] = (f"held-out error {-100 * c.gain:+.2f} % (needs below -{100 * need:.2f} %), "
                                        f"lower in {c.wins}/{len(c.test_after)} folds, {c.changed} changed "
                                        f"(needs {margins.min_wins}, or a majority of two or more changed)")
        accepted = None
        for c in sorted(passing, key=lambda c: -c.gain):
            found = _accept(c, sel.chain, cur, sig, folds)
            if isinstance(found, str):
                sel.rejected[c.word] = f"fits better but is not physical or not resolved: {found}"
                continue
            accepted = found
            break
        if accepted is None:
            break
        c, sel.chain, phys = accepted
        prev = cur
        # the PI's weights refitted under the named effects, so the next tests start from its best
        cur = c.base = unbend(c.base or cur, sig, sel.chain, folds.train)
        sel.params[c.word] = phys
        sel.steps.append(c)
        sel.rejected.pop(c.word, None)
        done = {c.word}
        if c.word in DYNAMIC:
            other = cands.get(DYNAMIC[1 - DYNAMIC.index(c.word)])
            # within a sample a lag and a delay are one thing: how late the sample is depends on
            # when in the period the flow was read (a lag whose command moves between samples
            # answers as an interpolated delay)
            sub_sample = phys[TIME_PARAM[c.word]] * sig.rate_hz < 1.0
            if (other is not None and any(o is other for o in passing)
                    and (c.gain - other.gain < AMBIGUOUS or sub_sample)):
                alt = _accept(other, {w: p for w, p in sel.chain.items() if w != c.word}, prev, sig, folds)
                if not isinstance(alt, str):
                    sel.alternatives[c.word] = alt
                    sel.rejected.pop(other.word, None)
                    done.add(other.word)
        words = [w for w in words if w not in done and w not in sel.rejected or
                 (w in sel.rejected and not sel.rejected[w].startswith("fits better"))]
        before = cross_validate(build(cur, sig, sel.chain), y, folds)
    return sel


def _accept(c: Candidate, chain: dict, cur: Base, sig: Signals, folds: Folds):
    """Polish a passing candidate's parameters and check them: ``(c, chain, physical params)``, or why not."""
    b = cur if c.word in JOINT_WITH_PI else c.base or cur
    params = refine(c.word, chain, c.params, b, sig, folds)
    chain = {**chain, c.word: params}
    d, b = design(c.word, b, sig, chain, folds)
    phys = physical_params(c.word, chain, d, fit_final(d, sig.flow_lpm, folds.train), sig, b)
    why = implausible(c.word, phys) or unresolved(c.word, phys, sig, b)
    if why:
        return why
    c.params = params
    if c.word in JOINT_WITH_PI:
        c.base = b
    return c, chain, phys
