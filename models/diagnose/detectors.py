"""The search: each effect word tested on held-out blocks, and the greedy selection of effects.

A test asks whether the augmented model (baseline + the word's law,
:mod:`models.diagnose.words`) predicts *held-out* blocks better, the only
test that survives the strongly autocorrelated residuals of a simulation.
It runs in two stages:

1. *Screen*: the word's linearized columns over the grid of its nonlinear
   parameters; for each cross-validation fold the grid point is chosen on
   that fold's training rows only, so the held-out error is honest.
2. *Refine*: where the word has an exact nonlinear law (the effective duty
   of a warm coil, the generalized PI's widened descending thresholds), its
   physical parameters are refined from the screen's estimate by bounded
   nonlinear least squares on the training rows, the PI refitted inside
   (variable projection), and the exact law is cross-validated in turn; the
   law with the lower training error is the word's candidate. Large effects
   (a coil 30 K warm, a loop twice as wide) are then modelled as well as
   small ones, where the first-order column saturates.

A word is named when the pooled held-out error falls by more than its
calibrated margin (:mod:`models.diagnose.calibrate`, from effect-free
recordings) in a majority of folds, its parameters are physically plausible
and resolved, and the recording has the rows its law needs (a dead zone
needs rows where the flow really stops). Words are added greedily, strongest
first, each on top of those already named; every step refits all linear
coefficients. The final chain is then refined as a whole and checked backwards:
each named word must still earn its margin with all the others in place, and
one that no longer does is dropped (a word named early can have taken up the
residual of one the recording hid until later). Every test and decision is
recorded in a trace (:mod:`models.diagnose.trace`).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from .calibrate import Margins
from .design import (STATIC_KNOTS, Base, CVResult, Design, build, censored, cross_validate, fit_baseline, fit_final,
                     has_dynamics, memory_epochs, solve, unbend, unplaced_epochs)
from .folds import Folds
from .signals import Signals, noise_lpm
from .trace import ALTERNATIVE, BELOW_MARGIN, DROPPED, MASKED, NAMED, NOT_PHYSICAL, UNSUPPORTED, Decision
from .words import DYNAMIC, MIN_EXPLAINED_SHARE, VOCABULARY, WORDS, Word, explained_where_largest

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
#: Screens of a lag and a delay within this relative held-out gain of each other: both exact laws are
#: refined and compared (:func:`_lag_or_delay`), the alternative reported if they are within
#: :data:`AMBIGUOUS`.
COMPARED = 0.05
#: A held-out misfit (RMS) above this many times the sensor noise, after the strongest effect the
#: screens found, is gross: every word's exact law is refined whatever its linearized screen found.
GROSS = 3.0
#: Searches started again from another first word when the chain found leaves a gross misfit
#: (:func:`select_effects`).
RESTARTS = 2
#: A time constant at the unresolved end of its grid gives way to a resolved one whose training error
#: is within this fraction of the reference's (:func:`_resolved_best`).
TIE = 0.005
#: A word refused below its margin by its screen's held-out gain within this fraction of the margin is
#: screened again once the chain is refined (:func:`_forward_again`).
NEAR_MISS = 0.5
#: Time parameter of each word of :data:`DYNAMIC`.
TIME_PARAM = {"valve_dynamics": "tau_s", "transport_delay": "delay_s"}
#: A lag whose time constant is under this many sample periods has settled to 2 % by the next sample
#: (``exp(-4)``): a recording shows no smoothing of it, only how late the flow is, which a delay states
#: with one parameter (:func:`_named_before`).
SETTLED_SAMPLES = 0.25
#: Function evaluations of one exact-law refinement (besides those of its Jacobians).
REFINE_EVALS = 16
#: Relative step (of the log-scale parameters) of the refinement's finite-difference Jacobian: a
#: heating's rise and time constant trade off along a narrow curved valley, across which a 1 % step
#: (a 5 % change of a time constant) differences the valley's walls, not its floor; the refinement
#: then steps into a wall, shrinks its trust region and stops far from the minimum.
REFINE_DIFF_STEP = 1e-3
#: Training rows an exact-law refinement fits on (a regular subsample beyond this).
REFINE_ROWS = 12000
#: Training rows the starts of an exact-law refinement are compared on (they only need ranking).
START_ROWS = 4000
#: Grid points of a static law re-ranked with the PI unbent (:func:`_unbent_best`), with their neighbours.
STATIC_LEADS = 5
#: Training rows the PI is refitted on at each grid point of a joint screen (a regular subsample
#: beyond this; 51 weights are well placed by far fewer, and the refit is the screen's cost).
SCREEN_ROWS = 30000
#: A correction must follow the residual it is held against: the least-squares slope of the
#: residual before it on the correction at least this (0.5: the correction is at most twice
#: what it explains) ...
MIN_SLOPE = 0.5
#: ... and their correlation at least this.
MIN_CORRELATION = 0.1


def follows(resid: np.ndarray, delta: np.ndarray) -> tuple[float, float]:
    """Slope and correlation of ``resid`` regressed on ``delta``, both through the origin.

    Through the origin, because a correction is a change of the prediction, not a shape up to a
    constant: a sensor offset's constant correction follows a residual that has its mean.
    """
    dd, rr = float(delta @ delta), float(resid @ resid)
    if dd <= 0 or rr <= 0:
        return 0.0, 0.0
    dr = float(delta @ resid)
    return dr / dd, dr / np.sqrt(dd * rr)


def grid_points(word: Word, sig: Signals, base: Base) -> list[dict]:
    """Every combination of the word's nonlinear grid ({} once for a linear word)."""
    g = word.grid(sig, base)
    keys = list(g)
    return [dict(zip(keys, (float(v) for v in vals))) for vals in itertools.product(*(g[k] for k in keys))]


@dataclass
class Candidate:
    """The held-out test of one word on top of a chain.

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
    base : Base, optional
        The PI refitted with the word in place (joint and static words).
    changed : int
        Folds whose held-out error the word changes by more than :data:`CHANGED`.
    train_gain : float
        Relative fall of the training squared error.
    law : str
        ``"exact"`` or ``"linearized"``.
    refined : bool
        The exact law was refined (:func:`_exact`).
    chain : dict, optional
        The chain the word joins when its test moved another word's parameters (the other word of
        :data:`DYNAMIC` made earlier by the word's lateness, :func:`split`); ``None``: the chain as named.
    """

    word: str
    gain: float
    wins: int
    params: dict
    test_before: np.ndarray
    test_after: np.ndarray
    base: Base | None = None
    changed: int = 0
    train_gain: float = 0.0
    law: str = "linearized"
    refined: bool = False
    chain: dict | None = None

    def majority(self, min_wins: int) -> bool:
        """Lower in ``min_wins`` folds, or in a majority (at least two) of the folds it changes."""
        return self.wins >= min(min_wins, self.changed // 2 + 1) and self.wins >= 2


def design(word: str, base: Base, sig: Signals, chain: dict, folds: Folds,
           rows: np.ndarray | None = None) -> tuple[Design, Base]:
    """The design of ``chain`` when testing ``word`` (the laws that read the duty the magnetics see
    moved along with its own, :func:`carried`), and its base (the PI refitted jointly with a word it
    absorbs on ``rows``, by default the training rows: :func:`models.diagnose.design.unbend`)."""
    chain = carried(word, sig, chain)
    if not VOCABULARY[word].joint_with_pi:
        return build(base, sig, chain), base
    b = unbend(base, sig, chain, _subsample(folds.train, SCREEN_ROWS) if rows is None else rows)
    return build(b, sig, chain), b


def carried(word: str, sig: Signals, chain: dict) -> dict:
    """``chain`` with its other laws moved along with the duty the magnetics see under ``word``'s exact
    input-side law (:meth:`Word.carried`); ``chain`` itself when ``word`` has none in it."""
    w = VOCABULARY[word]
    if w.input_side != "duty" or word not in chain or not w.is_exact(chain[word]):
        return chain
    return {k: (p if k == word else VOCABULARY[k].carried(sig, p, chain)) for k, p in chain.items()}


def _candidate(word, params, cv: CVResult, before: CVResult, base, law) -> Candidate:
    after = cv.test
    gain = 1.0 - after.sum() / before.test.sum()
    changed = np.abs(after - before.test) > CHANGED * before.test
    return Candidate(word, float(gain), int(np.sum((after < before.test) & changed)), dict(params), before.test,
                     after, base, int(changed.sum()), float(1.0 - cv.train.sum() / before.train.sum()), law)


def test_effect(word: str, chain: dict, before: CVResult, base: Base, sig: Signals, folds: Folds,
                margin: float = 0.0, gross: bool = False) -> Candidate:
    """Cross-validated test of ``word`` added to ``chain``: the screen, then the exact law when the
    screen's training error falls by more than ``margin``, or whenever the misfit is ``gross``
    (the linearized columns then say nothing of a large effect: a coil 90 K warm shifts the
    effective duty by a third, far past a first-order column)."""
    w = VOCABULARY[word]
    # (and the exact law at gross sizes, :meth:`Word.sized`: a first-order column under-explains those)
    points = grid_points(w, sig, base) + w.placed(sig, chain) + w.sized(sig, base, chain)
    chains = [chain] * len(points)
    # beside the other word of the time response, also with the lateness shared between the two: the
    # one named first took up the whole lateness (a lag and a delay of 35 ms each read as one 73 ms lag),
    # and on top of it this word only adds more
    shared = [(p, ch) for p in points for ch in split(word, p, chain, sig, base)]
    points, chains = points + [p for p, _ in shared], chains + [ch for _, ch in shared]
    results = [cross_validate(design(word, base, sig, {**ch, word: p}, folds)[0], sig.flow_lpm, folds)
               for p, ch in zip(points, chains)]
    train = np.array([r.train for r in results])          # (G, K)
    test = np.array([r.test for r in results])
    pick = np.argmin(train, axis=0)                        # per fold, chosen on its training rows
    best_i = _resolved_best(w, points, train.sum(axis=1), float(before.train.sum()))
    if w.static and base.refit and train.sum(axis=1)[best_i] < before.train.sum():
        # (only where the law lowers the training error even with the PI bent through it)
        best_i = _unbent_best(word, points, train.sum(axis=1), chain, base, sig, folds)
    best, moved, refined = points[best_i], chains[best_i] is not chain, False
    chain = chains[best_i]
    cv = CVResult(results[best_i].sse.copy(), results[best_i].n)
    cv.sse[np.diag_indices(folds.k)] = test[pick, np.arange(folds.k)]
    new_base = design(word, base, sig, {**chain, word: best}, folds)[1] if w.joint_with_pi and base.refit else None
    if w.static and base.refit:
        # a static law at a range end bends a PI fitted through it: refitted without the rows it explains
        refit = unbend(base, sig, {**chain, word: best}, folds.train)
        if w.resolution:
            # and placed to the word's resolution between its grid neighbours on the PI so refitted: a
            # cracking duty between two grid points shuts the rows of neither, and a breath's rise
            # crosses the gap within a sample or two
            fine = refine(word, chain, best, refit, sig, folds)
            if fine != best:
                refit = unbend(base, sig, {**chain, word: fine}, folds.train)
        else:
            fine = best
        cv_r = cross_validate(build(refit, sig, {**chain, word: fine}), sig.flow_lpm, folds)
        if cv_r.test.sum() < cv.test.sum():
            cv, new_base, best = cv_r, refit, fine
    elif (word in DYNAMIC and base.refit and chain and not has_dynamics(chain)
          and 1.0 - cv.test.sum() / before.test.sum() > margin):
        # a PI fitted without the lateness widens its loop to take up what it can of it (a lag on a
        # chirp lags more as the frequency rises): beside a law named first, refitted under it, the
        # screen on that PI saw a quarter of the lag (a 53 ms lag beside a coil's heating, 6 % of the
        # held-out error where the PI refitted with it gains 26 %), and the heating took up the rest.
        # Refined with the PI refitted at each setting, it is cross-validated so, against the PI
        # refitted with a time response that does nothing (no reverse flow at the valve: a change of
        # the fit's form, not a lateness)
        still = {**chain, "transport_delay": {"delay_s": 0.0}}
        d0 = build(unbend(base, sig, still, folds.train), sig, still)
        cv_0 = cross_validate(d0, sig.flow_lpm, folds)
        fine = refine_time(word, chain, best, base, sig, folds)[1]
        refit = unbend(base, sig, {**chain, word: fine}, folds.train)
        dr = build(refit, sig, {**chain, word: fine})
        cv_r = cross_validate(dr, sig.flow_lpm, folds)
        # and it must be the residual where its correction is largest: a lateness of a sample trims
        # the edges of another law's misfit (a creep's beside a clip on the paper sweep), and gains
        share = explained_where_largest(sig.flow_lpm, d0.predict(fit_final(d0, sig.flow_lpm, folds.train)),
                                        dr.predict(fit_final(dr, sig.flow_lpm, folds.train)), noise_lpm(sig.flow_lpm))
        if (1.0 - cv_r.test.sum() / cv_0.test.sum() > 1.0 - cv.test.sum() / before.test.sum()
                and share >= MIN_EXPLAINED_SHARE):
            cv, new_base, before, best, refined = cv_r, refit, cv_0, fine, True
    cand = _candidate(word, best, cv, before, new_base, "exact" if w.is_exact(best) else "linearized")
    cand.refined = refined
    if cand.train_gain > margin or gross:
        exact = _exact(w, chain, cand, before, base, sig, folds)
        if exact is not None and exact.train_gain >= cand.train_gain:
            cand = exact
    if moved:
        cand.chain = chain
    level = _level_refined(word, chain, cand, before, base, sig, folds)
    if level is not None:
        cand = level
    if shared and cand.train_gain > margin:
        # the two refined together from the best split, and cross-validated in turn: the screen holds
        # the PI fitted under the word named first, whose loop took up part of its lateness
        j = len(points) - len(shared) + int(np.argmin(train.sum(axis=1)[len(points) - len(shared):]))
        others, params = refine_time(word, chains[j], points[j], base, sig, folds)
        full = {**others, word: params}
        b = unbend(base, sig, full, folds.train)
        pair = _candidate(word, params, cross_validate(build(b, sig, full), sig.flow_lpm, folds), before, None,
                          "linearized")
        if pair.train_gain >= cand.train_gain:
            pair.refined, pair.chain = True, others
            cand = pair
    return cand


def _level_refined(word: str, chain: dict, cand: Candidate, before: CVResult, base: Base, sig: Signals,
                   folds: Folds) -> Candidate | None:
    """The test of a word that moves the flow's level (:attr:`Word.shifts_level`) with the chain's exact
    input-side laws refined jointly with it, or of one that drifts along the recording (:attr:`Word.drifts`)
    with those on the duty (a warm coil's) and its own screened time constant (:func:`_screened_range`),
    when that fits the training rows better than the screen beside them as named; ``None`` otherwise.

    Named first, a heating takes up a sensor offset the recording also holds in its size and time
    constant (a coil 23.5 K warm with a 2.3 L/min offset, against its model file: 27 K and 272 s
    for 150 s), and the offset screened beside it so sized then gains a few per cent, not the
    third of the error it takes with the heating refined jointly with it. A creep's drift after the
    reversals, the flow moving on slowly the way it went as a coil's warming moves it, is taken up
    alike: on a foreign chirp (a coil 22 K warm, a creep of 0.1 relaxing over 12 s) the heating named
    first read 18.5 K and 256 s, and the creep screened beside it gained 8.8 %, under a tenth of the
    heating's gain; with the heating and the creep's time constant refined jointly with it, 22 K and
    147 s, a creep of 0.097 over 11.8 s.
    """
    w = VOCABULARY[word]
    inside = [k for k, p in chain.items() if VOCABULARY[k].input_side and VOCABULARY[k].is_exact(p)
              and any(q in p for q in VOCABULARY[k].bounds(sig, base.root))]
    if not w.shifts_level:
        # a drift in time trades with a law that drifts in time (a coil's warming, on the duty), not with
        # an asymmetry's widening of the loop, which is static: refined jointly with it, a creep of a
        # hundredth over a second took up the misfit of a lag and an offset beside it
        inside = [k for k in inside if VOCABULARY[k].input_side == "duty"]
    if not ((w.shifts_level or w.drifts) and inside and cand.train_gain > 0.0):
        return None
    own = _screened_range(w, cand.params, sig, base.root)
    full = refine_jointly(inside, {**chain, word: cand.params}, base.root, sig, folds, screened=own)
    b = unbend(base.root, sig, full, folds.train)
    level = _candidate(word, full[word], cross_validate(build(b, sig, full), sig.flow_lpm, folds), before,
                       None, cand.law)
    if level.train_gain <= cand.train_gain:
        return None
    level.refined, level.chain = True, {k: p for k, p in full.items() if k != word}
    return level


def _screened_range(w: Word, params: dict, sig: Signals, root: Base) -> tuple:
    """``((word, parameter, lo, hi), ...)``: the positive screened grid parameters of ``w`` set in
    ``params`` (a creep's time constant), each refinable within its grid's range but the unresolved
    end (:attr:`Word.unresolved`, never refined onto: :func:`refine`)."""
    out = []
    for k, v in w.grid(sig, root).items():
        v = np.sort(np.asarray(v, dtype=float))
        if k not in params or len(v) < 3 or not np.all(v > 0):
            continue
        if w.unresolved is not None and w.unresolved[0] == k:
            v = v[1:] if w.unresolved[1] == "low" else v[:-1]
        out.append((w.word, k, float(v[0]), float(v[-1])))
    return tuple(out)


def split(word: str, params: dict, chain: dict, sig: Signals, base: Base) -> list:
    """``chain`` with the other word of :data:`DYNAMIC` made earlier by the lateness of ``word`` at
    ``params`` (:meth:`Word.lateness_s`), so that the two together are as late as it was alone: one
    chain for each setting of the other's screened parameters but its time (a lag's sampling phase);
    none when ``word`` has no time response, the other is not in ``chain``, or it cannot be made that
    early.

    Of a time response a smooth excitation sees the lateness only (to first order a lag and a delay
    are both ``-lateness dq/dt``); the share between a lag's smoothing and a delay's shift is in the
    faster content, and so is a lag's phase: a lag named alone takes the phase that makes it most
    like the whole response (the command held, phase 1, for a lag and a delay of 30 ms each).
    """
    if word not in DYNAMIC or (other := DYNAMIC[1 - DYNAMIC.index(word)]) not in chain:
        return []
    o = VOCABULARY[other]
    late = o.lateness_s(chain[other], sig.rate_hz) - VOCABULARY[word].lateness_s(params, sig.rate_hz)
    grid = o.grid(sig, base)
    shape = [k for k in grid if k != TIME_PARAM[other]]
    settings = [chain[other]]
    if shape:
        settings += [{**chain[other], **dict(zip(shape, map(float, v)))}
                     for v in itertools.product(*(grid[k] for k in shape))]
    moved = [o.with_lateness(p, late, sig.rate_hz) for p in settings]
    return [{**chain, other: m} for m in moved if m is not None]


def refine_time(word: str, chain: dict, params: dict, base: Base, sig: Signals, folds: Folds,
                loop: bool = False) -> tuple:
    """``word`` of :data:`DYNAMIC` at ``params`` refined on the training rows together with the other one
    if ``chain`` has it (as :func:`split` left it): ``(chain, params)``; ``loop``: beside a model file's
    free curve of the duty on each branch (:func:`models.diagnose.design.loop_curves`).

    Every screened parameter of the two (the lag's time constant and sampling phase, the delay) by
    bounded nonlinear least squares within its grid's range, a positive one in log scale, the PI
    refitted at each evaluation (it takes up part of a time response in its loop's width). They trade
    along the valley where the lateness (:meth:`Word.lateness_s`) is held, which one parameter at a
    time between its grid neighbours crawls along: a 30 ms lag beside a clip was refined to 18 ms
    with the command held (phase 1, the lateness right, the shape not), and beside a 37 ms delay a
    lag of 35 ms for 30 and 45 left a misfit that a creep of 0.4 % took up.
    """
    pair = [w for w in DYNAMIC if w == word or w in chain]
    grids = {w: VOCABULARY[w].grid(sig, base) for w in pair}
    current = {w: params if w == word else chain[w] for w in pair}
    keys = [(w, k) for w in pair for k in grids[w] if k in current[w]]
    log = np.array([bool(np.all(np.asarray(grids[w][k]) > 0)) for w, k in keys])
    lo = np.array([np.min(grids[w][k]) for w, k in keys])
    hi = np.array([np.max(grids[w][k]) for w, k in keys])

    def to_free(v):
        return np.where(log, np.log(np.where(log, v, 1.0)), v)

    lo, hi = to_free(lo), to_free(hi)
    x0 = np.clip(to_free(np.array([current[w][k] for w, k in keys])), lo + 1e-9, hi - 1e-9)
    rows, y = _subsample(folds.train), sig.flow_lpm

    def chain_at(x):
        v = np.where(log, np.exp(x), x)
        moved = {w: dict(current[w]) for w in pair}
        for (w, k), value in zip(keys, v.tolist()):
            moved[w][k] = value
        return {**chain, **moved}

    def resid(x):
        ch = chain_at(x)
        return train_residual(build(unbend(base, sig, ch, rows) if base.refit else base, sig, ch, static=loop,
                                    branches=loop), y, rows)

    res = least_squares(resid, x0, bounds=(lo, hi), diff_step=REFINE_DIFF_STEP, max_nfev=REFINE_EVALS, xtol=1e-3,
                        ftol=1e-6)
    best = chain_at(res.x)
    return {w: p for w, p in best.items() if w != word}, best[word]


def without(chain: dict, word: str, rate_hz: float) -> list:
    """``chain`` less ``word``; and, if ``word`` is one of :data:`DYNAMIC` and the other is in ``chain``,
    also with the other made as late as the two were together (the inverse of :func:`split`). Either
    may be the chain without ``word``: the other kept its own share beside a spurious one, or the two
    split one response between them and the other alone must carry its whole lateness. The one that
    fits the training rows better is (:func:`lighter`)."""
    rest = {w: p for w, p in chain.items() if w != word}
    if word not in DYNAMIC or (other := DYNAMIC[1 - DYNAMIC.index(word)]) not in rest:
        return [rest]
    o = VOCABULARY[other]
    late = o.lateness_s(rest[other], rate_hz) + VOCABULARY[word].lateness_s(chain[word], rate_hz)
    moved = o.with_lateness(rest[other], late, rate_hz)
    return [rest] if moved is None else [rest, {**rest, other: moved}]


def lighter(chains: list, root: Base, sig: Signals, folds: Folds) -> dict:
    """Of ``chains``, the one whose training error is least, the PI refitted under each from ``root``."""
    if len(chains) == 1:
        return chains[0]
    return min(chains, key=lambda ch: train_sse(build(unbend(root, sig, ch, folds.train), sig, ch), sig.flow_lpm,
                                                folds.train))


def _resolved_best(w: Word, points: list, train_sse: np.ndarray, ref_sse: float) -> int:
    """The grid point of least training error, unless it sits at the unresolved end of the word's
    time constant (:attr:`Word.unresolved`) and a resolved point fits within :data:`TIE` as well:
    the time constant is then poorly determined (a creep after the slow reversals of a sweep is
    mostly absorbed by the PI refitted with it), not beyond the range, and the word is tested there."""
    best = int(np.argmin(train_sse))
    if w.unresolved is None or w.unresolved[0] not in points[best]:
        return best
    key, side = w.unresolved
    vals = np.array([p[key] for p in points])
    end = vals.min() if side == "low" else vals.max()
    inner = np.flatnonzero(vals != end)
    if vals[best] != end or not len(inner):
        return best
    j = int(inner[np.argmin(train_sse[inner])])
    return j if train_sse[j] <= train_sse[best] + TIE * ref_sse else best


def _unbent_best(word: str, points: list, bent_sse: np.ndarray, chain: dict, base: Base, sig: Signals,
                 folds: Folds) -> int:
    """The grid point of a static law whose training error is least with the PI refitted without the
    rows it explains, among the :data:`STATIC_LEADS` best with the PI as it is and their neighbours.

    A PI fitted through a dead zone's shut rows is bent (its gain and offset stretched to reach
    zero flow), and the cracking duty it prefers is off by a held level: the one that fits best
    once the PI is unbent is the law's.

    Ranked on as many rows as a refinement fits on: what tells two close cracking duties apart is the
    few rows between them (a breath's rise crosses 44.7-45.1 % in one sample), which a sparser
    subsample misses; the leads then tie, and the first of them was taken (behind a 40 ms delay a
    PI unbent under a cracking duty below the valve's took up its jump with a loading curve diving
    under zero flow just below it, and the training error is flat down there).
    """
    order = np.argsort(bent_sse)[:STATIC_LEADS]
    near = sorted({int(j) for i in order for j in (i - 1, i, i + 1) if 0 <= j < len(points)})
    rows = _subsample(folds.train)
    return min(near, key=lambda i: unbent_sse(word, chain, points[i], base, sig, rows))


def unbent_sse(word: str, chain: dict, params: dict, base: Base, sig: Signals, rows: np.ndarray) -> float:
    """Training error on ``rows`` of ``chain`` with the static ``word`` at ``params``, the PI refitted
    on ``rows`` without the rows the law explains (:func:`models.diagnose.design.unbend`)."""
    ch = {**chain, word: params}
    return train_sse(build(unbend(base, sig, ch, rows), sig, ch), sig.flow_lpm, rows)


def _placed_sse(word: str, chain: dict, params: dict, base: Base, sig: Signals, rows: np.ndarray) -> float:
    """:func:`unbent_sse` of the time response ``word`` at ``params`` with the static laws of ``chain``
    the rows place (:meth:`Word.placed`) placed again beside it, each at its best lead.

    The rows at the valve are read back through the time response: a cracking duty placed beside a
    16 ms delay and a delay refined beside that cracking duty held each other 0.1 % and 6 ms off (for
    a 22 ms delay), as far as a search of one with the other held could see."""
    ch = dict(chain)
    for s in [k for k in chain if VOCABULARY[k].static]:
        others = {k: v for k, v in ch.items() if k != s}
        leads = VOCABULARY[s].placed(sig, {**others, word: params})
        if leads:
            ch[s] = min(leads, key=lambda q: unbent_sse(s, {**others, word: params}, q, base, sig, rows))
    return unbent_sse(word, ch, params, base, sig, rows)


def _exact(w: Word, chain: dict, screen: Candidate, before: CVResult, base: Base, sig: Signals,
           folds: Folds) -> Candidate | None:
    """The word's exact law, refined from the screen and cross-validated (``None``: no exact law)."""
    ch = {**chain, w.word: screen.params}
    d, b = design(w.word, base, sig, ch, folds)
    theta = fit_final(d, sig.flow_lpm, folds.train)
    coef = _coef(w.word, d, theta)
    starts = w.exact_starts(screen.params, coef if coef is not None else 0.0, sig, b, chain)
    if not starts:
        return None
    # a gross size of the exact law the screen chose (:meth:`Word.sized`) is refined from on its own, not
    # ranked among the starts: beside a clip on the paper sweep, x9.75 lifted by the loop's half-width
    # ranked below a widening in proportion, which refined to widen 1.7 with 2 % more training error
    # than the lift refined from it (widen 0.001), and explained 43 % of the residual where its
    # correction is largest (:meth:`.words.AsymmetricHysteresis.support`): the word was refused
    own = [screen.params] if w.is_exact(screen.params) else []
    params = _multistart(w, chain, starts, base, sig, folds, own)
    d, b = design(w.word, base, sig, {**chain, w.word: params}, folds)
    cv = cross_validate(d, sig.flow_lpm, folds)
    c = _candidate(w.word, params, cv, before, b if base.refit else None, "exact")
    c.refined = True
    return c


def beside_recorded(word: str, sig: Signals, chain: dict) -> dict:
    """``chain`` with the laws driven by a state the recording measures (:meth:`Word.recorded`, the
    supply's wander) that it lacks, to place ``word``'s nonlinear law beside: the word is still
    tested without them.

    A measured state's law has no parameter to place, only a coefficient, and a law placed without
    it takes up what it can of its wander: a coil 30 K warm beside a supply wandering by 0.2 bar on a
    mixed recording, held against its model file, had its time constant refined alone onto the upper
    bound of its refinement (the slow wander read as a warming) and was refused, and a sensor offset
    of -11 L/min took up the heating; placed beside the supply's column it is resolved (30 K, 180 s
    once the three are named).
    """
    extra = {k: {} for k, v in VOCABULARY.items() if k != word and k not in chain and v.recorded(sig)}
    return {**chain, **extra} if extra else chain


def _multistart(w: Word, chain: dict, starts: list, base: Base, sig: Signals, folds: Folds,
                own: list = ()) -> dict:
    """The exact law of ``w`` joining ``chain``, refined from the best of ``starts`` of each setting of
    the parameters the refinement keeps fixed, and from each of ``own``, the best so refined on the
    training rows.

    Beside a law with a hard edge on the duty ``w`` moves (a cracking duty beside a heating), the
    starts are ranked and refined with that edge smoothed (:func:`smoothed`), and the refined
    settings compared with it hard."""
    rows = _subsample(folds.train, START_ROWS)
    soft = smoothed(w, chain, sig)
    edged = soft != chain

    def sse(p, rows=rows):
        return train_sse(design(w.word, base, sig, {**soft, w.word: p}, folds, rows)[0], sig.flow_lpm, rows)

    def refined_best(g):
        if not edged:
            return [refine(w.word, soft, min(g, key=sse), base, sig, folds)]
        # beside an edge, the error of a start is mostly the rows it misplaces about the edge, few and
        # held together (a hold whose effective duty drifts across the cracking duty as the coil
        # warms), and ranks the starts by how near they lie to the law's valley, not by its floor
        # beneath them (a coil 36 K warm on a 150 s time constant: 55 K on 540 s ranked first, a point
        # of the valley's far end the refinement does not leave): the best few are each refined
        return [refine(w.word, soft, p, base, sig, folds) for p in sorted(g, key=sse)[:EDGE_LEADS]]

    # the best start of each setting of the parameters the refinement keeps fixed (a coil warm or
    # cold at the start), each refined: a fixed setting that is wrong is otherwise made up for by
    # the refined ones (a warm start read as a coil four times as hot)
    box = w.bounds(sig, base)
    refined = [p for g in _groups(w, starts, box).values() for p in refined_best(g)] + [
        refine(w.word, soft, p, base, sig, folds) for p in own]
    # a part of the law that holds some rows at a setting of its own (a valve's input floor) must fit
    # them better than the law without it: one that fits them worse only frees the PI elsewhere (a
    # valve opening with a jump just above the lowest duty, a concealed dead zone, had those rows held
    # at a floor so that the PI need not bend to them, and the rest of the range fitted better)
    refined = [p for p in refined if _holds(w, p, chain, base, sig, folds)]
    # a setting whose refinement ran onto a bound of its box has not found the law's minimum (a coil
    # read as warm from the start trades its rise against its time constant up to the largest rise):
    # the settings refined to the inside are compared, if any
    inside = [p for p in refined if _inside(p, box, w.settled_ends)] or refined
    best = _tied_choice(w, chain, inside, base, sig, folds, least=edged)
    if _floor_supported(w, best, chain, base, sig, folds):
        return best
    # an input floor the recording refutes (:meth:`Word.support`: below it, where the law closes the
    # valve along a seat's line, the valve measures shut) gives way to the floors halfway to its
    # neighbours (:meth:`Word.between`) and the others: a coil 36 K warm on a mixed excitation, its floor
    # refined best at 37.8 %, was refused for it and nothing was named; the next floor up, 39.7 %, reads
    # 47 K, and 38.7 % 36.9 K
    mids = [p for p in inside if p is not best]
    for g in _groups(w, w.between(best, starts), box).values():
        mids += refined_best(g)
    mids = [p for p in mids if _holds(w, p, chain, base, sig, folds)]
    while mids:
        best = _tied_choice(w, chain, mids, base, sig, folds, least=edged)
        if _floor_supported(w, best, chain, base, sig, folds):
            return best
        mids = [p for p in mids if p is not best]
    return best


def _groups(w: Word, starts: list, box: dict) -> dict:
    """``starts`` by the setting of the parameters the refinement keeps fixed, the set of those it refines
    (a heating with and without its valve's input floor) and the law's valley (:meth:`Word.basin`)."""
    groups = {}
    for p in starts:
        key = (tuple(sorted((k, v) for k, v in p.items() if k not in box)), tuple(sorted(k for k in p if k in box)),
               w.basin(p))
        groups.setdefault(key, []).append(p)
    return groups


def smoothed(w: Word, chain: dict, sig: Signals) -> dict:
    """``chain`` with the edges of its laws smoothed (:meth:`Word.smoothed`) for the search of ``w``'s
    exact law on the duty the magnetics see; ``chain`` itself for any other word.

    A cracking duty carried along with a heating (:meth:`.words.DeadZone.carried`) shuts the rows
    below it on the effective duty: the heating's training error then counts the rows that cross the
    edge on the wrong side, a staircase in its rise and time constant, on which the refinement stops
    where it starts (from 20 K on 144 s for a coil 22.8 K warm on 180 s, a point at twice the
    error of the truth: the refinement's finite differences step on one tread). Smoothed, the error
    falls continuously towards the valley's floor and the refinement reaches it; the settings it
    reaches are then compared with the hard edge (:func:`_tied_choice`)."""
    if w.input_side != "duty":
        return chain
    return {k: VOCABULARY[k].smoothed(sig, p) for k, p in chain.items()}


def _tied_choice(w: Word, chain: dict, settings: list, base: Base, sig: Signals, folds: Folds,
                 least: bool = False) -> dict:
    """The setting of ``settings`` (``w``'s exact law joining ``chain``) of the lowest training error,
    unless it ties with others: among those whose error is higher by at most :data:`PHYSICS_TIE` of
    the error the best explains, the first within the word's physics (:meth:`Word.within_physics`),
    then by the word's preference among settings a fit cannot tell apart (:meth:`Word.tie_rank`).

    A setting beyond the word's physics (a coil read as 130 K warm from the start) takes up another
    word's misfit; a coil warm from the start and a cold one trade exactly to first order on a PI
    fitted on the recording (:meth:`.words.CoilHeating.tie_rank`), and which one wins was the
    misfit's choice (a warm 59 K for a cold 30 K beside a clip).

    With ``least``, among settings that tie so and whose error is within :data:`LEAST_TIE` of the
    lowest, the least effect (:meth:`Word.extent`) before the lowest error: settings refined from several points of a valley along which the law's parameters
    trade (a heating's rise and time constant beside a cracking duty) that the recording does not
    tell apart (on the paper's sweep, a coil 24 K warm on 180 s fitted within 10 % of the error it
    explains as 49 K on 570 s, a warming the recording sees as a ramp)."""
    if len(settings) == 1:
        return settings[0]
    rows = _subsample(folds.train)
    err = [train_sse(design(w.word, base, sig, {**chain, w.word: p}, folds, rows)[0], sig.flow_lpm, rows)
           for p in settings]
    best = min(err)
    none = train_sse(design(w.word, base, sig, chain, folds, rows)[0], sig.flow_lpm, rows)
    near = [i for i, e in enumerate(err) if e - best <= PHYSICS_TIE * max(none - best, 0.0)
            and (not least or e <= (1.0 + LEAST_TIE) * best)]
    return settings[min(near, key=lambda i: (not w.within_physics(settings[i]), w.tie_rank(settings[i]),
                                             w.extent(settings[i]) if least else 0.0, err[i]))]


#: A refined setting gives way to one within the word's physics (:meth:`Word.within_physics`), or one the
#: word prefers among those a fit cannot tell apart (:meth:`Word.tie_rank`), whose training error is
#: higher by at most this fraction of the error the former explains.
PHYSICS_TIE = 0.1
#: Starts of each setting each refined beside a smoothed edge (:func:`_multistart`).
EDGE_LEADS = 3
#: Settings of a law that tie (:func:`_tied_choice`) and whose training error is within this fraction of
#: the lowest give way to the least effect among them.
LEAST_TIE = 0.1
#: A refined parameter within this factor of a bound of its box is at the bound.
AT_BOUND = 1.02


def _holds(w: Word, params: dict, chain: dict, base: Base, sig: Signals, folds: Folds) -> bool:
    """Whether the part of ``params`` that holds some rows (:meth:`Word.held`) fits those of the
    training rows better than the law without it, the PI refitted under each (``True``: no such part)."""
    part = w.held(sig, params, base)
    if part is None:
        return True
    rest, rows = part
    full = _subsample(folds.train)
    held = rows[full]
    e = [train_residual(design(w.word, base, sig, {**chain, w.word: p}, folds, full)[0], sig.flow_lpm, full)[held]
         for p in (params, rest)]
    return bool(held.any()) and float(e[0] @ e[0]) < float(e[1] @ e[1])


def _floor_supported(w: Word, params: dict, chain: dict, base: Base, sig: Signals, folds: Folds) -> bool:
    """Whether the recording bears out the input floor of ``params`` (:meth:`Word.floor`,
    :meth:`Word.support` on the law's own fit; ``True``: no floor)."""
    if w.floor(params)[0] is None:
        return True
    d, _ = design(w.word, base, sig, {**chain, w.word: params}, folds)
    after = d.predict(fit_final(d, sig.flow_lpm, folds.train))
    return w.support(sig, params, None, noise_lpm(sig.flow_lpm), chain, after_lpm=after) is None


def _inside(params: dict, box: dict, settled: tuple = ()) -> bool:
    """Whether every parameter of ``params`` refined within ``box`` stays off its bounds (but those
    whose ends are settings of the law, ``settled``: a name, both ends; ``(name, "low")``, the lower)."""
    return all((lo * AT_BOUND < params[k] or (k, "low") in settled) and params[k] < hi / AT_BOUND
               for k, (lo, hi) in box.items() if k in params and k not in settled)


def _at_upper_bound(w: Word, params: dict, sig: Signals, base: Base) -> str | None:
    """Why an exact law refined onto the upper bound of its box is not resolved, or ``None``: it
    wanted more than its law can be (a heating whose time constant is twice the recording shows
    little of its curvature, a slow drift read as heat; a coil twice its cold resistance).
    The box is the one :func:`refine` searched, the linearized law's time constant included: a
    heating column whose time constant runs beyond twice the recording is a ramp in time."""
    box = {k: v for k, v in w.bounds(sig, base).items() if k in params and k not in w.settled_ends}
    over = [f"{k} = {params[k]:.4g} at the upper bound {hi:g} of its refinement" for k, (lo, hi) in box.items()
            if k in params and params[k] >= hi / AT_BOUND]
    return "; ".join(f"{o}: not resolved" for o in over) or None


def _beyond_physics(w: Word, params: dict, chain: dict) -> str | None:
    """Why a law beyond its word's physics (:meth:`Word.within_physics`) on top of named words is
    refused, or ``None``: beyond it a law is credible only as the recording's strongest effect; on top
    of another it takes up that one's misfit (a lag's read as a coil 100 K warm from the start)."""
    if not chain or w.within_physics(params):
        return None
    return (f"beyond what its physics reaches ({', '.join(f'{k} = {v:.4g}' for k, v in params.items())}) on top of "
            f"{', '.join(chain)}: it takes up their misfit")


def _coef(word: str, d: Design, theta: np.ndarray) -> float | None:
    """The fitted coefficient of ``word``'s (first) column, or ``None`` when it has none."""
    return float(theta[d.names.index(word)]) if word in d.names else None


def train_sse(d: Design, y: np.ndarray, rows: np.ndarray) -> float:
    """Squared error on ``rows`` of the least-squares fit on those rows."""
    e = train_residual(d, y, rows)
    return float(e @ e)


def train_residual(d: Design, y: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Residual on ``rows`` of the least-squares fit on those rows."""
    d = censored(d, y, rows)
    fr = rows & d.fit_ok
    p = d.X.shape[1]
    if p:
        X = d.X[fr]
        theta = solve(X.T @ X, X.T @ (y - d.F)[fr])
    else:
        theta = np.zeros(0)
    return d.predict(theta)[rows] - y[rows]


def _subsample(rows: np.ndarray, n: int | None = None) -> np.ndarray:
    """A regular subsample of ``rows`` of about ``n`` (default :data:`REFINE_ROWS`): every exact-law
    evaluation refits the PI, and a smooth law of a few parameters needs no more than some ten
    thousand rows to place them."""
    every = max(1, int(rows.sum()) // (n or REFINE_ROWS))
    return rows & (np.arange(len(rows)) % every == 0)


def refine(word: str, chain: dict, params: dict, base: Base, sig: Signals, folds: Folds) -> dict:
    """Refine the nonlinear parameters of ``word`` on the training rows.

    The exact law's parameters (:meth:`Word.bounds`) by bounded nonlinear least squares in log
    scale, the PI and every linear coefficient refitted at each evaluation; a screened grid
    parameter by a bounded scalar search between its grid neighbours.
    """
    w = VOCABULARY[word]
    y, rows = sig.flow_lpm, folds.train
    params = dict(params)
    box = {k: v for k, v in w.bounds(sig, base).items() if k in params}
    if box:
        rows = _subsample(rows)
        keys = list(box)
        # a parameter refined as its ratio to another (a heating's rise over its time constant: the
        # initial warming rate, which a short recording pins down while the two alone trade off)
        over = [keys.index(w.ratio_of[k]) if k in w.ratio_of and w.ratio_of[k] in box else -1 for k in keys]
        lo = np.log([box[k][0] for k in keys])
        hi = np.log([box[k][1] for k in keys])

        def to_free(v):
            return np.array([v[i] - (v[j] if j >= 0 else 0.0) for i, j in enumerate(over)])

        def from_free(u):
            return np.array([u[i] + (u[j] if j >= 0 else 0.0) for i, j in enumerate(over)])

        flo = np.array([lo[i] - (hi[j] if j >= 0 else 0.0) for i, j in enumerate(over)])
        fhi = np.array([hi[i] - (lo[j] if j >= 0 else 0.0) for i, j in enumerate(over)])
        u0 = np.clip(to_free(np.log([max(params[k], 1e-12) for k in keys])), flo + 1e-9, fhi - 1e-9)

        def values(u):
            return dict(zip(keys, np.exp(np.clip(from_free(u), lo, hi)).tolist()))

        def resid(u):
            return train_residual(design(word, base, sig, {**chain, word: {**params, **values(u)}}, folds, rows)[0],
                                  y, rows)

        res = least_squares(resid, u0, bounds=(flo, fhi), diff_step=REFINE_DIFF_STEP, max_nfev=REFINE_EVALS, xtol=1e-3,
                            ftol=1e-6)
        return {**params, **values(res.x)}
    grid = w.grid(sig, base)
    fine_rows = _subsample(rows)
    for key, values in grid.items():
        values = np.asarray(values, dtype=float)
        if len(values) < 3 or key not in params:
            continue
        # between the grid neighbours, to the word's resolution of it, else in log scale for a
        # positive parameter (a time constant)
        step = w.resolution.get(key)
        log = step is None and bool(np.all(values > 0))
        to, back = (np.log, np.exp) if log else (float, float)
        i = int(np.argmin(np.abs(values - params[key])))
        first, last = 0, len(values) - 1
        if w.unresolved is not None and w.unresolved[0] == key:
            # never onto the unresolved end (it was passed over, or is refused anyway)
            first, last = (1, last) if w.unresolved[1] == "low" else (0, last - 1)
        lo, hi = to(values[max(i - 1, first)]), to(values[min(i + 1, last)])
        if not lo < hi:
            continue

        def cost(u):
            p = {**params, key: float(back(u))}
            if word in DYNAMIC and base.refit:
                return _placed_sse(word, chain, p, base, sig, fine_rows)
            if w.static and base.refit:
                # the PI refitted under each setting: with the PI held, a cracking duty is drawn to
                # where the PI fitted at the start closes by itself (it is refitted without the rows
                # the setting explains), and a time constant is drawn short, the lateness a PI fitted
                # without it took up in its loop's width (a loop is a phase lag on a smooth excitation)
                return unbent_sse(word, chain, p, base, sig, fine_rows)
            return train_sse(design(word, base, sig, {**chain, word: p}, folds)[0], y, rows)

        tol = 0.02 if log else step or 0.02 * (hi - lo)
        res = min((minimize_scalar(cost, bounds=(to(a), to(b)), method="bounded", options={"xatol": tol, "maxiter": 12})
                   for a, b in w.pieces(key, float(back(lo)), float(back(hi)), sig.rate_hz)), key=lambda r: r.fun)
        if res.fun < cost(to(params[key])):
            params[key] = float(back(res.x))
    return params


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
        Word -> parameters in physical units.
    trace : list of Decision
        Every word's test in every round and what was decided.
    not_identifiable : dict
        Word -> why it cannot be tested on this recording with this baseline.
    alternatives : dict
        Named word -> ``(candidate, chain, physical params)`` of the other word of :data:`DYNAMIC`
        when the recording cannot tell a lag from a delay: the same chain with the other law
        in its place.
    reference : Base
        What the first tests were held against (:func:`reference`).
    loop_misfit : dict
        Word -> why it was last refused (a lag or delay) or dropped held against a model file: it
        explains no more than the model's misfit of the valve's loop (:func:`_static_misfit`,
        :func:`_symmetric_misfit`). One not named in the end is not identifiable against that model
        file (:func:`_loop_masked`).
    nuisance : set
        Words of the chain kept in the model but not reported: a sensor offset no shut row reads, within
        the model file's own misfit of the loading curve (:func:`_level_within_misfit`), is a free
        constant of the baseline, as a PI fitted on the recording has its offset c (Eq. 4). Dropped,
        the other words took its constant up (a creep of 0.17 beside an offset of -1.16 L/min on a
        chirp read 0.06; an asymmetry of extra width 0.2 named beside a clip and a supply).
    openings : list
        The words that passed their margin in the first round, strongest first (:func:`select_effects`
        restarts from them).
    """

    chain: dict = field(default_factory=dict)
    steps: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    trace: list = field(default_factory=list)
    not_identifiable: dict = field(default_factory=dict)
    alternatives: dict = field(default_factory=dict)
    reference: Base | None = None
    loop_misfit: dict = field(default_factory=dict)
    nuisance: set = field(default_factory=set)
    openings: list = field(default_factory=list)

    def last(self) -> dict:
        """Word -> its last decision."""
        return {d.word: d for d in self.trace}


def reference(base: Base, sig: Signals, folds: Folds) -> tuple[Base, CVResult]:
    """What the first tests are held against: the baseline, its PI refitted the way every test
    refits it (:func:`models.diagnose.design.unbend`, on the training rows), and its
    cross-validated errors."""
    cur = unbend(base, sig, {}, folds.train)
    return cur, cross_validate(build(cur, sig, {}), sig.flow_lpm, folds)


def _decision(c: Candidate, rnd: int, need: float, margins: Margins, outcome: str, why: str = "") -> Decision:
    return Decision(c.word, rnd, c.gain, need, c.wins, c.changed, len(c.test_after), margins.min_wins, c.law,
                    outcome, why)


def select_effects(base: Base, sig: Signals, folds: Folds, margins: Margins, progress=None) -> Selection:
    """Greedy forward selection of effects by blocked cross-validation, then the backward check.

    Once the forward search has named its words and refined them with the whole chain
    (:func:`_backfit`), each named word must still earn its margin with all the others in place
    (:func:`_backward`): a word named early can have taken up the residual of a larger one the
    recording hid until later (a creep reads a warming coil's drift as long as a clip hides the
    heating's law). A word that no longer earns it is dropped, and the forward search resumes
    without it, so that a word refused while it was in place is tried again.

    Parameters
    ----------
    base, sig, folds : Base, Signals, Folds
        Baseline, working-grid signals and their folds.
    margins : Margins
        Calibrated per-effect margins on the relative held-out gain, and the fold majority.
    progress : callable, optional
        Called with each effect word as it is tested.
    """
    sel = _search(base, sig, folds, margins, progress)
    noise = noise_lpm(sig.flow_lpm)

    def held_out(s: Selection) -> CVResult:
        return cross_validate(build(unbend(s.reference, sig, s.chain, folds.train), sig, s.chain), sig.flow_lpm,
                              folds)

    best = held_out(sel)
    if misfit(best) <= GROSS * noise:
        return sel
    # the greedy search's first word took up a misfit that only several laws together explain: searched
    # again from each other word that passed in the first round, the chain of least held-out error kept
    first = sel.steps[0].word if sel.steps else None
    for w in [w for w in sel.openings if w != first][:RESTARTS]:
        again = _search(base, sig, folds, margins, progress, first=w)
        cv = held_out(again)
        if cv.test.sum() < (1.0 - AMBIGUOUS) * best.test.sum():
            lower = int(np.sum(cv.test < best.test))
            again.trace.append(Decision(
                w, max((d.round for d in again.trace), default=0) + 1, 1.0 - cv.test.sum() / best.test.sum(),
                AMBIGUOUS, lower, lower, len(cv.test), margins.min_wins, "exact", NAMED, f"the search started from {w} rather than {first}: the chain it names has "
                f"{100 * (1.0 - cv.test.sum() / best.test.sum()):.1f} % less held-out error "
                f"({misfit(cv):.3g} against {misfit(best):.3g} L/min RMS)"))
            sel, best = again, cv
    return sel


def _search(base: Base, sig: Signals, folds: Folds, margins: Margins, progress=None, first: str | None = None
            ) -> Selection:
    """The search of :func:`select_effects`, its first round restricted to ``first`` when given."""
    sel = Selection()
    words = []
    for w in WORDS:
        reason = VOCABULARY[w].applicable(sig, base)
        if reason:
            sel.not_identifiable[w] = reason
        else:
            words.append(w)
    cur, before = reference(base, sig, folds)
    sel.reference = cur
    noise = noise_lpm(sig.flow_lpm)
    rnd, dropped = 0, set()
    while True:
        rnd = _forward(sel, words, cur, before, sig, folds, margins, noise, rnd, progress, first)
        _backfit(sel, sig, folds)
        rnd = _forward_again(sel, words, sig, folds, margins, noise, rnd, progress)
        gone = _backward(sel, sig, folds, margins, rnd)
        if gone is None and dropped:
            # the final chain, after the backward check dropped a word: the static laws' support read on it
            gone = _unsupported_after_drop(sel, sig, folds, margins, noise, dropped, rnd)
        if gone is None:
            gone = _static_after_search(sel, sig, folds, margins, rnd)
        if gone is None:
            gone = _level_after_search(sel, sig, folds, margins, noise, rnd)
        if gone is None:
            _lag_or_delay_again(sel, sig, folds, noise, margins, rnd)
            for w, p in list(sel.chain.items()):
                sel.chain[w] = _midway(w, {k: v for k, v in sel.chain.items() if k != w}, p, sel.reference, sig,
                                       folds)
            _loop_masked(sel)
            return sel
        # the spurious word never comes back; the others are tested again on the chain without it
        dropped.add(gone)
        rnd += 1
        words = [w for w in WORDS if w not in sel.not_identifiable and w not in sel.chain and w not in dropped]
        cur = unbend(sel.reference, sig, sel.chain, folds.train)
        before = cross_validate(build(cur, sig, sel.chain), sig.flow_lpm, folds)


def _forward_again(sel: Selection, words: list, sig: Signals, folds: Folds, margins: Margins,
                   noise: float, rnd: int, progress=None) -> int:
    """The forward search once more, for the words its last round refused below their margin by less
    than :data:`NEAR_MISS`, on the chain as :func:`_backfit` refined it, with the PI refitted from the
    reference under it (then refined again with whatever it adds); returns the next round's number.

    The words were screened beside the PI each word named refitted in turn, whose shape took up what
    it could of the residual, and beside laws sized one after the other: a heating named beside a
    delay on breaths, the creep explained 5.7 % of the held-out error for 9.7 % needed, and 17.6 %
    beside the chain refined with the reference's PI refitted under it."""
    last = {d.word: d for d in sel.trace}
    left = [w for w in words if w not in sel.chain and w in last and last[w].outcome == BELOW_MARGIN
            and last[w].gain >= NEAR_MISS * last[w].need]
    if not left:
        return rnd
    n = len(sel.chain)
    cur = unbend(sel.reference, sig, sel.chain, folds.train)
    before = cross_validate(build(cur, sig, sel.chain), sig.flow_lpm, folds)
    rnd = _forward(sel, left, cur, before, sig, folds, margins, noise, rnd, progress)
    if len(sel.chain) > n:
        _backfit(sel, sig, folds)
    return rnd


def _forward(sel: Selection, words: list, cur: Base, before: CVResult, sig: Signals, folds: Folds,
             margins: Margins, noise: float, rnd: int, progress=None, first: str | None = None) -> int:
    """Add to ``sel`` the strongest acceptable of ``words`` on top of its chain, round after round,
    until none passes (``cur``, ``before``: the chain's base and its cross-validated errors);
    returns the next round's number. The first round (``rnd`` 0) records its passing words in
    ``sel.openings`` and, with ``first``, tries that word alone."""
    while words and len(sel.chain) < MAX_EFFECTS:
        cands = {}
        for w in words:
            if progress:
                progress(w)
            cands[w] = test_effect(w, sel.chain, before, cur, sig, folds, margins.gain[w])
        _gross_exact(cands, words, sel, before, cur, sig, folds, margins, noise)
        passing = _passing(cands, sel, margins, rnd)
        if rnd == 0:
            sel.openings = [c.word for c in passing]
            if first is not None:
                passing = [c for c in passing if c.word == first]
        accepted, refused = _first_acceptable(passing, sel.chain, cur, sig, folds, noise, margins)
        for c, outcome, why in refused:
            sel.trace.append(_decision(c, rnd, _need(c, sel, margins), margins, outcome, why))
            if outcome == MASKED and c.word in DYNAMIC:
                sel.loop_misfit[c.word] = why
        pair = _with_companion(refused, accepted, passing, cands, words, sel, cur, sig, folds, noise, margins)
        masking = None if pair is not None else _masking(refused, accepted)
        if masking is not None and _independent(accepted, masking[0], sel.reference, sig, folds, margins):
            # the rival explains the same residual only if the one found loses its place beside it: a
            # clip measured at its plateau still earns its place beside a dead zone whose gain came
            # from the PI refitted on the open rows, and is named
            masking = None
        if masking is not None:
            # a stronger law explains the residual but the recording lacks the rows that would show
            # it: the weaker one cannot be asserted (it may be taking up the other's residual), and
            # the stronger is said to be not identifiable here rather than guessed
            c, why = masking
            sel.not_identifiable[c.word] = f"not identifiable on this excitation: it fits best but {why}"
            a = accepted[0]
            sel.trace.append(_decision(a, rnd, _need(a, sel, margins), margins, MASKED,
                                       f"{c.word} explains more of the same residual (held-out gain "
                                       f"{100 * c.gain:.1f} % against {100 * a.gain:.1f} %) and this recording "
                                       f"cannot show {c.word}'s law"))
            return rnd + 1
        if pair is not None:
            pair_over = accepted[0] if accepted is not None else None
            accepted, companion = pair
            c, sel.chain, phys = accepted
            sel.params.update(phys)
            cur = c.base = unbend(c.base or cur, sig, sel.chain, folds.train)
            sel.steps += [c, companion]
            sel.trace.append(_decision(c, rnd, _need(c, sel, margins), margins, NAMED))
            sel.trace.append(_decision(companion, rnd, margins.gain[companion.word], margins, NAMED,
                                       f"named together with {c.word}: the recording shows each law only "
                                       f"beside the other"))
            if pair_over is not None and pair_over.word not in sel.chain:
                sel.trace.append(_decision(pair_over, rnd, _need(pair_over, sel, margins), margins, MASKED,
                                           f"{c.word} and {companion.word} together explain more of the same "
                                           f"residual (held-out)"))
            words = [w for w in words if w not in (c.word, companion.word)]
            before = cross_validate(build(cur, sig, sel.chain), sig.flow_lpm, folds)
            rnd += 1
            continue
        if accepted is None:
            return rnd + 1
        accepted, alt = _lag_or_delay(accepted, cands, passing, sel.chain, cur, sig, folds, noise, margins)
        c, sel.chain, phys = accepted
        sel.params[c.word] = phys
        # (the laws named before it, refined again beside it, :func:`_beside_resized`)
        resized = [s for s in sel.steps if not VOCABULARY[s.word].static and s.params != sel.chain[s.word]]
        for s in resized:
            s.params = sel.chain[s.word]
        _placed_again(c.word, sel, sig, folds)
        # the PI's weights refitted under the named effects, so the next tests start from its best
        cur = c.base = unbend(c.base or cur, sig, sel.chain, folds.train)
        if c.word in DYNAMIC:
            # the other word of the time response, if named, had this one as its alternative: it is
            # now named beside it (the two sharing the lateness)
            sel.alternatives.pop(DYNAMIC[1 - DYNAMIC.index(c.word)], None)
        sel.steps.append(c)
        if resized:
            _steps_refitted(sel, sig, folds)
        sel.trace.append(_decision(c, rnd, _need(c, sel, margins), margins, NAMED))
        if alt is not None:
            # (and still tested beside it: a lag and a delay together share the lateness, :func:`split`)
            sel.alternatives[c.word] = alt
            sel.trace.append(_decision(alt[0], rnd, _need(alt[0], sel, margins), margins, ALTERNATIVE))
        # a word refused is tried again after each word named: a larger effect not yet modelled may
        # have hidden its law (a coil's heating under a clip the PI bent through reads as no heating,
        # or as a dead zone), and two may (a coil 24 K warm beside a clip and a sensor offset, held
        # against its model file: its time constant ran onto its lower bound with neither named, then
        # with a spurious creep named, and was resolved once the clip was)
        words = [w for w in words if w != c.word]
        before = cross_validate(build(cur, sig, sel.chain), sig.flow_lpm, folds)
        rnd += 1
    return rnd


def held_out_prediction(d: Design, y: np.ndarray, folds: Folds) -> np.ndarray:
    """Each cross-validation fold's rows (L/min) predicted by the fit on the other folds' training
    rows; NaN on the holdout."""
    pred = np.full(len(y), np.nan)
    for k in range(folds.k):
        rows = folds.fold == k
        pred[rows] = d.predict(fit_final(d, y, folds.train & ~rows))[rows]
    return pred


def earns(word: str, chain: dict, root: Base, sig: Signals, folds: Folds, margins: Margins,
          refit_others: bool = False) -> tuple:
    """Whether the named ``word`` still earns its place in ``chain`` with every other word in place:
    ``(candidate, why)``, ``why`` the reason it does not, or ``None``.

    Both models are the chain as it stands (each word's parameters refined with the whole chain),
    with and without ``word`` (a lag's or delay's share of the time response then left out or given to
    the other, whichever fits better, :func:`without`), the PI refitted under each (from ``root``). The word must lower the
    held-out error by more than its calibrated margin in a fold majority, and the held-out residual
    of the chain without it must follow its correction (:data:`MIN_SLOPE`, :data:`MIN_CORRELATION`).
    With ``refit_others``, the chain without it is also taken with each other word refined once more
    without it (:func:`_refined_beside`), where that fits its training rows better: the others were
    refined beside it, and gave it the share of their own law it took up (a coil 10 K warm from the
    start, named on the paper sweep beside an asymmetry read x5.1 for x9.4 and a creep, gained 21 %
    held-out against them as they stood, 3 % against the asymmetry refined without it, read x8.5).
    """
    y = sig.flow_lpm
    others = lighter(without(chain, word, sig.rate_hz), root, sig, folds)
    where = "in place"
    if refit_others and others:
        moved = dict(others)
        for w in others:
            refined = _refined_beside(w, moved, root, sig, folds)
            if refined is not None:
                moved[w] = refined[0]
        if moved != others and lighter([others, moved], root, sig, folds) is moved:
            others, where = moved, "refined without it"
    b0, b1 = unbend(root, sig, others, folds.train), unbend(root, sig, chain, folds.train)
    d1 = build(b1, sig, chain)
    # the chain without the word may keep the PI refitted with it, where that fits its training rows
    # better: a word earns what its own columns add, not a PI its joint refit happened to bend better
    # (the refit's constrained, censored problem is not the fit's: a creep of amplitude -0.0007, its
    # column 0.02 L/min RMS beside a 50 ms lag, lowered the held-out error 7 % through the PI alone)
    d0 = min((build(b, sig, others) for b in (b0, b1)), key=lambda d: train_sse(d, y, folds.train))
    w = VOCABULARY[word]
    c = _candidate(word, chain[word], cross_validate(d1, y, folds), cross_validate(d0, y, folds), b1,
                   "exact" if w.is_exact(chain[word]) else "linearized")
    need = margins.gain[word]
    if not (c.gain > need and c.majority(margins.min_wins)):
        return c, (f"with {', '.join(others)} {where} its held-out error changes by {-100 * c.gain:+.2f} % "
                   f"(needs below -{100 * need:.2f} %), lower in {c.wins}/{len(c.test_after)} folds")
    p0, p1 = held_out_prediction(d0, y, folds), held_out_prediction(d1, y, folds)
    rows = folds.fold >= 0
    slope, corr = follows((y - p0)[rows], (p1 - p0)[rows])
    if slope < MIN_SLOPE or corr < MIN_CORRELATION:
        return c, (f"with {', '.join(others)} {where} the held-out residual does not follow its correction "
                   f"(slope {slope:.3g}, needs {MIN_SLOPE}; correlation {corr:.3g}, needs {MIN_CORRELATION})")
    return c, None


def _backward(sel: Selection, sig: Signals, folds: Folds, margins: Margins, rnd: int) -> str | None:
    """The backward check on the final chain of ``sel``: every named word tested with all the others
    in place, and refined again without it (:func:`earns`); of those that no longer earn their place, the one that gains least
    is dropped (from ``sel``, traced as :data:`DROPPED`), the others' exact laws refined again
    without it and the chain's PI refitted. Returns the dropped word, or ``None``.

    One at a time, because a word dropped changes what each other explains.
    """
    if len(sel.chain) < 2:
        return None
    failing = []
    for step in sel.steps:
        c, why = earns(step.word, sel.chain, sel.reference, sig, folds, margins, refit_others=True)
        # its reported parameters are read from the whole chain's fit: a linear column's coefficient
        # can leave the physical range the word was named in (a creep named beside a heating and a
        # supply wander on the paper sweep, read as -0.012 once the three were refined together)
        why = why or VOCABULARY[step.word].implausible(sel.params[step.word])
        if why:
            failing.append((c, why))
    if not failing:
        return None
    c, why = min(failing, key=lambda cw: cw[0].gain)
    sel.trace.append(_decision(c, rnd, margins.gain[c.word], margins, DROPPED, why))
    sel.steps = [s for s in sel.steps if s.word != c.word]
    sel.chain = lighter(without(sel.chain, c.word, sig.rate_hz), sel.reference, sig, folds)
    del sel.params[c.word]
    sel.alternatives.pop(c.word, None)
    _backfit(sel, sig, folds, dropped=True)
    return c.word


def _backfit(sel: Selection, sig: Signals, folds: Folds, dropped: bool = False) -> None:
    """Refine each named law's nonlinear parameters once more with every other named word in place
    (in ``sel``), and report every word's parameters from the chain as it then is.

    A word named first is refined before the others are known, and its parameters absorb part
    of them (a coil heating found before an asymmetry takes up some of the loop's widening; a
    creep named before the heating is sized takes up part of the drift; against a model file, an
    asymmetry's lift named before a sensor offset takes up part of the offset): one round of refinement
    with the whole chain puts each back on its own physics. Exact laws are refined by least
    squares, time constants and other screened parameters between their grid neighbours; a
    static law at a range end is placed again where the rows that show it place it with the others
    in place (:func:`_placed_beside`), and when it moves the others are refined once more beside it.
    A refined law is kept only where it lowers the training error and stays physical; the PI of every
    step is then refitted under the chain as it now is, and each word's reported parameters (a linear
    column's coefficient: a creep's amplitude, a supply's exponent) are those of the whole chain's
    fit, not of the round it was named in. ``dropped``: a word has just left the chain, so a single word
    left is refined too (without the one it shared the residual with), and the steps' PIs are
    refitted whatever changed.
    """
    if len(sel.chain) < (1 if dropped else 2):
        return
    changed = dropped
    for _ in range(2):
        placed_again = False
        for step in sel.steps:
            refined = _refined_beside(step.word, sel.chain, sel.reference, sig, folds, restart=True)
            if refined is None:
                continue
            step.params, sel.params[step.word] = refined
            sel.chain = carried(step.word, sig, {k: (step.params if k == step.word else p) for k, p in sel.chain.items()})
            for s in sel.steps:
                s.params = sel.chain[s.word]
            changed = True
            placed_again |= VOCABULARY[step.word].static
        if not placed_again:
            break
        # a static law placed again moves what the others were refined beside (a lag refined beside
        # a cracking duty placed under its earlier phase took up the misplaced jump): once more
    if _joint_restart(sel, sig, folds):
        changed = True
    _steps_refitted(sel, sig, folds, changed)


def _steps_refitted(sel: Selection, sig: Signals, folds: Folds, changed: bool = True) -> None:
    """The PI of every step of ``sel`` refitted under the chain up to it (when ``changed``), and each
    word's reported parameters read from the whole chain's fit."""
    if changed:
        sub = {}
        for step in sel.steps:
            sub = {**sub, step.word: sel.chain[step.word]}
            step.base = unbend(sel.reference, sig, sub, folds.train)
    d = build(sel.steps[-1].base, sig, sel.chain)
    sel.params.update(chain_params(sel.chain, d, fit_final(d, sig.flow_lpm, folds.train), sig, sel.steps[-1].base))


def _lag_or_delay_again(sel: Selection, sig: Signals, folds: Folds, noise: float, margins: Margins,
                        rnd: int) -> None:
    """A lag or delay named with the other as its alternative (:func:`_lag_or_delay`) decided again on
    the search's final chain: the alternative refined in its place beside every word named after it,
    and the two swapped when the alternative's held-out error is then the lower. Updates ``sel``.

    The two were ranked when named, before the words found after them: the misfit of a loop the PI
    could not yet bend (an asymmetry), not the time response, then decided between two laws a
    fraction of a sample apart. A 21 ms delay at 50 Hz was refined to 19.7 ms with the asymmetry not
    yet named, and a lag of 6.6 ms named in its place; beside the asymmetry the delay refined again
    fits better than the lag. The alternative is reported as refined on the final chain either way.
    """
    y = sig.flow_lpm

    def held_out_sse(chain: dict) -> float:
        return float(cross_validate(build(unbend(sel.reference, sig, chain, folds.train), sig, chain), y,
                                    folds).test.sum())

    for w in [w for w in sel.chain if w in DYNAMIC and w in sel.alternatives]:
        old = sel.alternatives[w][0]
        if old.word in sel.chain or len(sel.chain) < 2:
            continue
        others = {k: v for k, v in sel.chain.items() if k != w}
        root = unbend(sel.reference, sig, others, folds.train)
        again = _accept(replace(old, chain=None, refined=False, base=None), others, root, sig, folds, noise, margins)
        if isinstance(again[0], str):
            continue
        alt, alt_chain, alt_phys = again
        step = next(s for s in sel.steps if s.word == w)
        # the named one refined in its place too, beside the same words: a delay named before a creep
        # stayed at 45 ms for 52 (the PI refitted under it had taken up the rest of the lateness), and a
        # lag refined beside the creep fitted better than that delay, not than the delay at 52 ms
        kept = _accept(replace(step, chain=None, refined=False, base=None), others, root, sig, folds, noise,
                       margins)
        if not isinstance(kept[0], str) and held_out_sse(kept[1]) < held_out_sse(sel.chain):
            sel.chain = {k: kept[1][k] for k in sel.chain}
            sel.params[w], step.params = kept[2], sel.chain[w]
            _steps_refitted(sel, sig, folds)
        if _named_before((step, sel.chain, sel.params[w]), held_out_sse(sel.chain), again, held_out_sse(alt_chain),
                         sig.rate_hz):
            sel.alternatives[w] = again
            continue
        named = (step, dict(sel.chain), sel.params.pop(w))
        # the alternative takes the named one's place in the chain and among the steps
        sel.chain = {(alt.word if k == w else k): alt_chain[alt.word if k == w else k] for k in sel.chain}
        sel.steps = [alt if s is step else s for s in sel.steps]
        sel.params[alt.word] = alt_phys
        del sel.alternatives[w]
        sel.alternatives[alt.word] = named
        _steps_refitted(sel, sig, folds)
        why = f"decided again with {', '.join(others)} in place: its held-out error is the lower"
        sel.trace.append(_decision(alt, rnd, _need(alt, sel, margins), margins, NAMED, why))
        sel.trace.append(_decision(step, rnd, _need(step, sel, margins), margins, ALTERNATIVE, why))


def _joint_restart(sel: Selection, sig: Signals, folds: Folds) -> bool:
    """The exact laws of the chain that act on the valve's input (a coil's effective duty, an asymmetry's
    widened descending thresholds: :attr:`Word.input_side`) refined jointly, from where they are and from
    the other readings of each at the same size (:meth:`Word.readings`); the reading of least
    training error is kept unless the chain as it is ties with it (:func:`_tied_chain`), and only where
    every law stays physical and resolved. Updates ``sel``; returns whether it changed.

    Refined one after the other, each with the other held, two laws on the input trade along a valley
    that one alternation does not cross: a heating named beside an asymmetry widened in proportion to
    each threshold has the PI refitted under the two shrink its own loop into the widened one, and a
    heating and an asymmetry refined in turn from there stay in that basin (a coil 32 K warm with x8 on
    a mixed recording: read as x65, with 17 % more training error than the lift of every threshold).
    """
    root = sel.reference
    # (the duty's law first: the laws that read the duty the magnetics see are carried along with it)
    pair = sorted((w for w, p in sel.chain.items() if VOCABULARY[w].input_side and VOCABULARY[w].is_exact(p)
                   and any(k in p for k in VOCABULARY[w].bounds(sig, root))),
                  key=lambda w: VOCABULARY[w].input_side != "duty")
    if len(pair) < 2:
        return False
    starts = [(dict(sel.chain), ())]
    for w in pair:
        starts += [({**sel.chain, w: p}, tuple((w, k) for k in held))
                   for p, held in VOCABULARY[w].readings(sel.chain[w], sig, root, sel.chain)]
    if len(starts) == 1:
        return False
    coarse = _subsample(folds.train, START_ROWS)
    ranked = [(refine_jointly(pair, ch, root, sig, folds, coarse, held), held) for ch, held in starts]
    best, held = min(ranked, key=lambda r: _chain_sse(pair[0], r[0], root, sig, folds))
    new = _tied_chain(pair, [sel.chain, refine_jointly(pair, best, root, sig, folds, held=held)], root, sig, folds)
    return _kept(pair, new, sel, sig, folds)


def _kept(words: list, new: dict, sel: Selection, sig: Signals, folds: Folds) -> bool:
    """``new`` (``sel.chain`` with ``words`` set otherwise) made the chain of ``sel`` if it differs and every
    law of ``words`` stays physical and resolved in it; returns whether it was."""
    if new is sel.chain:
        return False
    root = sel.reference
    d, b = design(words[0], root, sig, new, folds)
    theta = fit_final(d, sig.flow_lpm, folds.train)
    fitted = d.predict(theta)
    for w in words:
        word, others = VOCABULARY[w], {k: p for k, p in new.items() if k != w}
        phys = word.physical(new[w], _coef(w, d, theta), sig, b, fitted)
        if (word.implausible(phys) or word.not_resolved(new[w], sig, b) or _at_upper_bound(word, new[w], sig, b)
                or _beyond_physics(word, new[w], others)):
            return False
    sel.chain = new
    for step in sel.steps:
        step.params = sel.chain[step.word]
    return True


def refine_jointly(words: list, chain: dict, root: Base, sig: Signals, folds: Folds,
                   rows: np.ndarray | None = None, held: tuple = (), screened: tuple = (),
                   static: bool = False) -> dict:
    """``chain`` with the exact-law parameters of ``words`` (:meth:`Word.bounds`; but those ``held``,
    ``(word, parameter)`` pairs), and the screened parameters ``screened`` (``(word, parameter, lo,
    hi)``, :func:`_screened_range`), refined together by bounded nonlinear least squares in log scale
    on ``rows`` (by default a subsample of the training rows, :func:`_subsample`), the PI refitted from
    ``root`` at each evaluation; ``static``: beside a model file's free static curve of the duty
    (:func:`models.diagnose.design.static_curve`)."""
    rows = _subsample(folds.train) if rows is None else rows
    keys, lo, hi = [], [], []
    for w in words:
        for k, (a, b) in VOCABULARY[w].bounds(sig, root).items():
            if k in chain[w] and (w, k) not in held:
                keys.append((w, k))
                lo.append(np.log(a))
                hi.append(np.log(b))
    for w, k, a, b in screened:
        keys.append((w, k))
        lo.append(np.log(a))
        hi.append(np.log(b))
    lo, hi = np.array(lo), np.array(hi)
    x0 = np.clip(np.log([max(chain[w][k], 1e-12) for w, k in keys]), lo + 1e-9, hi - 1e-9)

    def at(x):
        out = {w: dict(p) for w, p in chain.items()}
        for (w, k), v in zip(keys, np.exp(x).tolist()):
            out[w][k] = v
        return out

    def resid(x):
        d = (build(root, sig, carried(words[0], sig, at(x)), static=True) if static
             else design(words[0], root, sig, at(x), folds, rows)[0])
        return train_residual(d, sig.flow_lpm, rows)

    res = least_squares(resid, x0, bounds=(lo, hi), diff_step=REFINE_DIFF_STEP, max_nfev=REFINE_EVALS, xtol=1e-3,
                        ftol=1e-6)
    return at(res.x)


def _chain_sse(word: str, chain: dict, root: Base, sig: Signals, folds: Folds) -> float:
    """Training error of ``chain`` on a subsample of the training rows, the PI refitted from ``root``."""
    rows = _subsample(folds.train)
    return train_sse(design(word, root, sig, chain, folds, rows)[0], sig.flow_lpm, rows)


def _tied_chain(words: list, chains: list, root: Base, sig: Signals, folds: Folds) -> dict:
    """Of ``chains`` (the same words, ``words`` set differently), the one of least training error, unless
    others tie with it: among those whose error is higher by at most :data:`PHYSICS_TIE` of the error the
    best explains (against the chain without ``words``), the first whose laws all stay within their words'
    physics, then by the words' preferences (:meth:`Word.tie_rank`: a coil cold at the start), as
    :func:`_tied_choice` chooses for one word."""
    err = [_chain_sse(words[0], ch, root, sig, folds) for ch in chains]
    best = min(err)
    rest = {k: p for k, p in chains[0].items() if k not in words}
    rows = _subsample(folds.train)
    none = train_sse(build(unbend(root, sig, rest, rows), sig, rest), sig.flow_lpm, rows)
    near = [i for i, e in enumerate(err) if e - best <= PHYSICS_TIE * max(none - best, 0.0)]
    return chains[min(near, key=lambda i: (not all(VOCABULARY[w].within_physics(chains[i][w]) for w in words),
                                           sum(VOCABULARY[w].tie_rank(chains[i][w]) for w in words), err[i]))]


def chain_params(chain: dict, d: Design, theta: np.ndarray, sig: Signals, base: Base) -> dict:
    """Word -> its parameters in physical units from the fit ``theta`` of the whole ``chain``'s
    design ``d`` on ``base`` (a linear column's coefficient, a creep's amplitude or a supply's
    exponent, is the whole chain's, not that of the round its word was named in)."""
    fitted = d.predict(theta)
    return {w: VOCABULARY[w].physical(p, _coef(w, d, theta), sig, base, fitted) for w, p in chain.items()}


def _gross_exact(cands: dict, words: list, sel: Selection, before: CVResult, cur: Base, sig: Signals, folds: Folds,
                 margins: Margins, noise: float) -> None:
    """When what the screens found leaves a gross held-out misfit (over :data:`GROSS` x the noise),
    test the exact law of every word that has one whatever its screen said (in place in ``cands``):
    a coil 90 K warm shifts the effective duty by a third, and its first-order column says nothing."""
    found = [c.gain for c in cands.values() if c.gain > _need(c, sel, margins) and c.majority(margins.min_wins)]
    if misfit(before) * np.sqrt(max(0.0, 1.0 - max(found, default=0.0))) <= GROSS * noise:
        return
    for w in words:
        if cands[w].refined or type(VOCABULARY[w]).exact_starts is Word.exact_starts:
            continue
        c = test_effect(w, sel.chain, before, cur, sig, folds, margins.gain[w], gross=True)
        if c.refined:
            cands[w] = c


def misfit(cv: CVResult) -> float:
    """RMS (L/min) of the pooled held-out residual of a cross-validated design."""
    return float(np.sqrt(cv.test.sum() / cv.n.sum()))


def _need(c: Candidate, sel: Selection, margins: Margins) -> float:
    need = margins.gain[c.word]
    first = next((s for s in sel.steps if s is not c), None)
    # the law of a named effect leaves part of it for other detectors to take up; a static law at a
    # range end is asserted only where the recording shows it (rows where the flow really stops or
    # flattens, :meth:`Word.support`), which that misfit does not
    if first is not None and not VOCABULARY[c.word].static:
        need = max(need, SECONDARY * first.gain)
    return need


def _passing(cands: dict, sel: Selection, margins: Margins, rnd: int) -> list:
    """Candidates that beat their margin in a fold majority, strongest first (the others traced)."""
    passing = []
    for c in cands.values():
        need = _need(c, sel, margins)
        if c.gain > need and c.majority(margins.min_wins):
            passing.append(c)
        else:
            sel.trace.append(_decision(c, rnd, need, margins, BELOW_MARGIN))
    return sorted(passing, key=lambda c: -c.gain)


def _first_acceptable(passing: list, chain: dict, cur: Base, sig: Signals, folds: Folds, noise: float,
                      margins: Margins):
    """The strongest passing candidate whose refined law is physical, resolved and supported:
    ``((candidate, chain, physical params), refused)`` with ``refused`` the ``(candidate, outcome,
    why)`` of the stronger ones that were not."""
    refused = []
    for c in passing:
        found = _accept(c, chain, cur, sig, folds, noise, margins)
        if found[0] == UNSUPPORTED and VOCABULARY[c.word].residual_support:
            found = _beside_resized(c, chain, cur, sig, folds, noise, margins) or found
        if isinstance(found[0], str):
            refused.append((c, *found))
            continue
        return found, refused
    return None, refused


def _beside_resized(c: Candidate, chain: dict, cur: Base, sig: Signals, folds: Folds, noise: float,
                    margins: Margins) -> tuple | None:
    """The law of ``c``, refused as unsupported on ``chain``, accepted (:func:`_accept`) beside the
    chain's laws refined again with it in place (:func:`_refined_beside`, from their whole range), as
    :func:`_accept` returns; ``None`` where none of them moves or it is refused again.

    A law named before it took up part of its residual, and leaves its own misfit where the law's
    correction is largest (:attr:`.words.Word.residual_support`): beside a coil 42 K warm and a dead
    zone on triangles, the heating named first read 10 K on 40 s, and an asymmetry x4.7 explained
    none of the residual where it widens the loop most; with the heating refined beside it (42 K on
    161 s), the asymmetry is named at x4.0."""
    resized = dict(chain)
    for k in chain:
        if not VOCABULARY[k].static:
            found = _refined_beside(k, {**resized, c.word: c.params}, cur, sig, folds, restart=True)
            if found is not None:
                resized[k] = found[0]
    if resized == chain:
        return None
    b = unbend(cur, sig, resized, folds.train)
    before = cross_validate(build(b, sig, resized), sig.flow_lpm, folds)
    found = _accept(test_effect(c.word, resized, before, b, sig, folds, margins.gain[c.word], gross=True), resized, b,
                    sig, folds, noise, margins)
    return None if isinstance(found[0], str) else found


def _with_companion(refused: list, accepted, passing: list, cands: dict, words: list, sel: Selection, cur: Base,
                    sig: Signals, folds: Folds, noise: float, margins: Margins) -> tuple | None:
    """A law named together with a companion law, when one of the two was refused and gained more than the
    law ``accepted`` (or than none): ``((candidate, chain, physical params by word), companion candidate)``,
    or ``None``. The companion is a range-end law placed where the recording shows it beside the law
    (:meth:`Word.placed`: a cracking duty where the flow at the valve leaves zero on the duty the magnetics
    see under a warm coil), or, when no law was accepted alone, another law refused this round at its
    screened setting, or a law of ``cands`` (this round's screen) that beat its margin short of a fold
    majority beside any other word at its screened setting.

    Each law alone can be the other's misfit. A coil 33 K warm on breaths resting just below a cracking
    duty was refused, its floor's seat line passing flow where the valve measured shut, and the dead
    zone alone gained 0.2 %: its jump, at a rest the warming coil moves, explains little without the
    warming. A coil 35 K warm with a dead zone at 46 % on a mixed excitation: the dead zone, refused as
    a misfit at the valve's rest, gained most, and an asymmetry was named on the loop the warming
    smeared. A coil 29 K warm beside a sensor offset of 2.3 L/min held against its model file: the
    heating's time constant ran to its bound and the offset's constant took up the warming, each
    refused; beside the offset the heating reads 28.7 K over 183 s. The pair is named where the law is
    accepted beside the companion (physical, resolved, supported), the companion beside it
    (:func:`_companion_beside`), each earns its place beside the other (:func:`earns`), and the two
    explain the recording better (held-out) than the law accepted alone.
    """
    if len(sel.chain) + 2 > MAX_EFFECTS:
        return None
    beats = [(c, VOCABULARY[c.word].static) for c, outcome, _ in refused
             if outcome == UNSUPPORTED and (accepted is None or c.gain > accepted[0].gain)]
    laws = [c for c, static in beats if not static]
    if any(static for _, static in beats):
        # a range-end law refused: tried beside each law that moves the duty the magnetics see, where it acts
        laws += [c for c in passing if VOCABULARY[c.word].input_side == "duty" and c not in laws]
    tries = [(c, s, p) for c in laws for s in words
             if VOCABULARY[s].static and s not in sel.chain and s != c.word
             for p in VOCABULARY[s].placed(sig, {**sel.chain, c.word: c.params})]
    if accepted is None:
        # (the strongest law first, each beside each other one refused)
        stuck = [c for c, outcome, _ in refused if outcome in (UNSUPPORTED, NOT_PHYSICAL)]
        tries += [(c, o.word, o.params) for c in stuck for o in stuck if o is not c]
        # a law that beats its margin on the whole but not fold by fold, beside each other word: a
        # supply wandering 0.14 bar, held against its model file on triangles beside a sensor offset of
        # 2.3 L/min, gained 18 % held-out in 3/6 folds, the offset alone none; together 53 and 63 % each
        # beside the other, in every fold (offset 2.19 L/min)
        short = sorted((c for c in cands.values()
                        if c.gain > _need(c, sel, margins) and not c.majority(margins.min_wins)), key=lambda c: -c.gain)
        tries += [(c, s, p) for c in short for s in words if s != c.word and s not in sel.chain
                  for p in (VOCABULARY[s].placed(sig, {**sel.chain, c.word: c.params}) if VOCABULARY[s].static
                            else [cands[s].params])]
    y = sig.flow_lpm

    def held_out_sse(chain: dict) -> float:
        return float(cross_validate(build(unbend(sel.reference, sig, chain, folds.train), sig, chain), y,
                                    folds).test.sum())

    bar = held_out_sse(accepted[1]) if accepted is not None else np.inf
    for c, s, p in tries:
        found = _companion_beside(c, s, p, sel, cur, sig, folds, noise, margins)
        if found is not None and held_out_sse(found[0][1]) < bar:
            return found
    return None


def _companion_beside(c: Candidate, s: str, params: dict, sel: Selection, cur: Base, sig: Signals, folds: Folds,
                      noise: float, margins: Margins) -> tuple | None:
    """The law of ``c`` accepted (:func:`_accept`) beside the companion law ``s`` at ``params``, and ``s``
    then set again beside it: a range-end law placed again (:func:`_placed_beside`, it was placed on the
    law's screened setting) and the law accepted once more there; another law refined and accepted beside
    it. As :func:`_with_companion` returns, or ``None`` where either is refused or does not earn its place
    beside the other."""
    y = sig.flow_lpm
    static = VOCABULARY[s].static
    for _ in range(2 if static else 1):
        beside = {**sel.chain, s: params}
        b = unbend(cur, sig, beside, folds.train)
        before = cross_validate(build(b, sig, beside), y, folds)
        found = _accept(test_effect(c.word, beside, before, b, sig, folds, margins.gain[c.word], gross=True),
                        beside, b, sig, folds, noise, margins)
        if isinstance(found[0], str):
            return None
        placed = _placed_beside(s, found[1], sel.reference, sig, folds) if static else None
        if placed is None:
            break
        params = placed[0]
    full = found[1]
    if not static:
        # the companion set again beside the law, as the law would be named after it
        law = {k: v for k, v in full.items() if k != s}
        b = unbend(sel.reference, sig, law, folds.train)
        before = cross_validate(build(b, sig, law), y, folds)
        again = _accept(test_effect(s, law, before, b, sig, folds, margins.gain[s], gross=True),
                        law, b, sig, folds, noise, margins)
        if isinstance(again[0], str):
            return None
        full = {**law, s: again[1][s]}
    earned = [earns(w, full, sel.reference, sig, folds, margins) for w in (c.word, s)]
    if any(why for _, why in earned):
        return None
    others = {k: v for k, v in full.items() if k != s}
    b1 = unbend(sel.reference, sig, full, folds.train)
    d = build(b1, sig, full)
    theta = fit_final(d, y, folds.train)
    if static and _unsupported(VOCABULARY[s], full[s], others, unbend(sel.reference, sig, others, folds.train),
                               b1, d, theta, sig, folds, noise):
        return None
    phys = chain_params(full, d, theta, sig, b1)
    if any(VOCABULARY[w].implausible(phys[w]) for w in full):
        return None
    companion = earned[1][0]
    companion.params = full[s]
    return (found[0], full, phys), companion


def _masking(refused: list, accepted) -> tuple | None:
    """``(candidate, why)`` of the strongest range-end law refused as unsupported (the recording lacks
    the rows that would show it, or shows no more of it than the valve resting shut) that gains more
    than the ``accepted`` one, or None. A law refused
    because the residual where it is largest is not its own (an asymmetry's) masks nothing: the
    residual is another law's, which the accepted one may be."""
    if accepted is None:
        return None
    over = [(c, why) for c, outcome, why in refused
            if outcome == UNSUPPORTED and VOCABULARY[c.word].static and c.gain > accepted[0].gain]
    return max(over, key=lambda cw: cw[0].gain) if over else None


def _independent(accepted: tuple, rival: Candidate, root: Base, sig: Signals, folds: Folds,
                 margins: Margins) -> bool:
    """Whether the ``accepted`` law, ``(candidate, chain, physical params)``, still earns its place
    (:func:`earns`) beside the stronger ``rival`` the recording cannot show: then the two do not
    explain the same residual, and the rival masks nothing."""
    c, full, _ = accepted
    return earns(c.word, {**full, rival.word: rival.params}, root, sig, folds, margins)[1] is None


def _lag_or_delay(accepted: tuple, cands: dict, passing: list, chain: dict, cur: Base, sig: Signals, folds: Folds,
                  noise: float, margins: Margins) -> tuple:
    """When the recording cannot tell a lag from a delay, both: ``(named, alternative)``, each
    ``(candidate, chain, physical params)`` as :func:`_accept` gives it, the named one the law whose
    exact form has the lower held-out error, each with the words named before it refined beside it
    (:func:`_beside`); else ``(accepted, None)``.

    Their screens rank them by their linearized columns, which are one column to first order
    (``-tau dq/dt``): only the exact laws (a lag's smoothing, a delay's shift of the steps) tell them
    apart, and the one reported is the one that explains the recording better.
    """
    c, full, phys = accepted
    if c.word not in DYNAMIC:
        return accepted, None
    other = cands.get(DYNAMIC[1 - DYNAMIC.index(c.word)])
    # within a sample a lag and a delay are one thing: how late the sample is depends on
    # when in the period the flow was read (a lag whose command moves between samples
    # answers as an interpolated delay)
    sub_sample = phys[TIME_PARAM[c.word]] * sig.rate_hz < 1.0
    # a static law placed before either was known (a cracking duty where the lagged openings and
    # closings average out) ranks their screens by which takes up its misplaced jump better: a lag's
    # smoothing did, by 5 % of the held-out error, beside a cracking duty 1.1 % low behind a delay
    placed = any(VOCABULARY[w].static for w in chain)
    if other is None or not any(o is other for o in passing):
        return accepted, None
    tied = c.gain - other.gain < AMBIGUOUS or sub_sample or placed
    if not (tied or c.gain - other.gain < COMPARED):
        return accepted, None
    alt = _accept(other, chain, cur, sig, folds, noise, margins)
    if isinstance(alt[0], str):
        return accepted, None
    accepted, alt = (_beside(found, cur, sig, folds, noise, margins) for found in (accepted, alt))
    y = sig.flow_lpm

    def held_out_sse(named: dict) -> float:
        return float(cross_validate(build(unbend(cur, sig, named, folds.train), sig, named), y, folds).test.sum())

    (sse_a, sse_b) = (held_out_sse(f[1]) for f in (accepted, alt))
    (best, first), (worse, second) = (((sse_a, accepted), (sse_b, alt))
                                      if _named_before(accepted, sse_a, alt, sse_b, sig.rate_hz)
                                      else ((sse_b, alt), (sse_a, accepted)))
    # screens apart by more than AMBIGUOUS (one screened at a grid setting, the other refined) are
    # both refined: the alternative is reported when their exact laws' held-out errors are as close
    # (a 27 ms delay at 50 Hz screened at 18 ms, 2.9 % behind a lag with the command held two thirds
    # of a sample; refined, both explain the recording to the noise)
    if tied or worse - best < AMBIGUOUS * float(np.sum(c.test_before)):
        return first, second
    return first, None


def _named_before(a: tuple, sse_a: float, b: tuple, sse_b: float, rate_hz: float) -> bool:
    """Whether of a lag and a delay ``a`` and ``b`` (each ``(candidate, chain, physical params)``, with its
    chain's held-out error), ``a`` is the one named: the lower held-out error, but a lag settled within a
    sample (:data:`SETTLED_SAMPLES`) gives way to a delay within :data:`AMBIGUOUS` of it.

    A 21 ms delay at 50 Hz was named as a lag of 4 ms with its command 95 % a sample late, its held-out
    error 1e-5 below the delay's: the lag's smoothing is gone by the next sample, all it carries is
    the lateness."""
    def settled(f: tuple) -> bool:
        return f[0].word == "valve_dynamics" and f[2]["tau_s"] * rate_hz < SETTLED_SAMPLES

    if settled(a) != settled(b) and max(sse_a, sse_b) <= (1.0 + AMBIGUOUS) * min(sse_a, sse_b):
        return settled(b)
    return sse_a <= sse_b


def _beside(found: tuple, cur: Base, sig: Signals, folds: Folds, noise: float, margins: Margins) -> tuple:
    """A lag or delay ``found`` as :func:`_accept` gives it, with the words named before it refined beside
    it (:func:`_refined_beside`) and it accepted again on the chain so refined; ``found`` as it was
    when nothing moves or the word is then refused.

    Those words were sized without a time response, and took up the part of it their laws can carry:
    on a chirp, whose frequency rises as the coil warms, a heating reads a lag's growing attenuation
    as a warming (24 K sized 39 K beside a 51 ms lag), and what is left of the lag is a phase alone,
    which a delay fits better than the lag. Each of the two is judged with its own share given back.
    """
    c, full, _ = found
    chain = {w: p for w, p in full.items() if w != c.word}
    if not chain:
        return found
    moved, params = dict(chain), full[c.word]
    # in turn with the time response itself refined beside them as moved (its screen sized it on their
    # old places), until neither moves: a delay sized beside a cracking duty placed 1.1 % low stopped
    # at 17.7 ms for 26.3, and the cracking duty placed beside that delay was still 0.1 % low
    for _ in range(3):
        was = (dict(moved), params)
        for w in chain:
            refined = _refined_beside(w, {**moved, c.word: params}, cur, sig, folds)
            if refined is not None:
                moved[w] = refined[0]
        # (its search places them again at each of its settings, :func:`_placed_sse`)
        params = refine(c.word, moved, params, cur, sig, folds)
        if (moved, params) == was:
            break
    if moved == chain and params == full[c.word]:
        return found
    c = replace(c, params=params)
    again = _accept(replace(c, chain=None), moved, unbend(cur, sig, moved, folds.train), sig, folds, noise, margins)
    return found if isinstance(again[0], str) else again


def _refined_beside(word: str, chain: dict, root: Base, sig: Signals, folds: Folds,
                    restart: bool = False) -> tuple | None:
    """The parameters of ``word`` in ``chain`` refined with every other word of it in place (:func:`refine`,
    and with ``restart`` also from its whole range, :meth:`Word.restarts`), the PI refitted from
    ``root``: ``(params, physical params)``, or ``None`` when the word has none to refine (a static law
    at a range end is placed again where the rows that show it place it, :func:`_placed_beside`), or
    they do not lower the training error or are not physical."""
    w = VOCABULARY[word]
    params = chain[word]
    if w.static:
        return _placed_beside(word, chain, root, sig, folds)
    if not params:
        return None
    others = {k: p for k, p in chain.items() if k != word}
    rows = _subsample(folds.train)
    old = train_sse(design(word, root, sig, chain, folds, rows)[0], sig.flow_lpm, rows)
    new = refine(word, others, params, root, sig, folds)
    choices = w.choices(new, sig, others)
    if choices:
        # the settings a refinement keeps fixed that the other words now tell apart (a creep's
        # reversals on the commanded duty or on the one the magnetics see, once a heating is named)
        new = _tied_choice(w, others, [new, *(refine(word, others, c, root, sig, folds) for c in choices)],
                           root, sig, folds)
    starts = w.restarts(sig, root) if restart else []
    if starts:
        # a law named before the others took up part of their misfit in a basin of its valley that
        # a local refinement does not leave (a coil heating named before a creep: 88 K for 38 K):
        # it is refined again from its whole range with them in place (a law named by its linearized
        # column too: a heating on a foreign chirp read 11 K for 24 K), and so is the setting of what
        # is not refined, a coil warm or cold from the start (named before a clip, the breaths'
        # clipped tops read as a warm start; beside a cracking duty carried along with it, each
        # breath's opening is a thermometer along the recording: warm 40 K for a cold 30 K); the
        # lowest training error is kept unless another setting ties with it (:func:`_tied_choice`)
        again = _multistart(w, others, starts, root, sig, folds)
        new = _tied_choice(w, others, [params, new, again], root, sig, folds)
        if new is params:
            return None
    d, b = design(word, root, sig, {**others, word: new}, folds, rows)
    if not starts and train_sse(d, sig.flow_lpm, rows) >= old:
        return None
    d, b = design(word, root, sig, {**others, word: new}, folds)
    theta = fit_final(d, sig.flow_lpm, folds.train)
    phys = w.physical(new, _coef(word, d, theta), sig, b, d.predict(theta))
    if (w.implausible(phys) or w.not_resolved(new, sig, b) or _at_upper_bound(w, new, sig, b)
            or _beyond_physics(w, new, others) or _within_phase(word, new, others, sig)):
        return None
    return new, phys


def _midway(word: str, chain: dict, params: dict, base: Base, sig: Signals, folds: Folds) -> dict:
    """``params`` of ``word`` beside ``chain`` moved to the middle of the settings that treat the
    training rows alike (:meth:`Word.midway`), when that fits them as well: the search's final chain
    as the holdout judges it and the report gives it.

    A cracking duty refined between two breath-rise rows 1.6 % apart was set 0.01 % above a holdout
    row the valve passed 50 L/min at, and the dead zone was refused on the holdout. Behind a time
    response the rows after each crossing do place it (the lagged flow of the row opened one
    sample later), and there it stays where the fit put it. The search itself keeps the setting
    the rows place (a dead zone's support is read on the rows just above its last shut row).
    """
    if has_dynamics(chain):
        return params
    w = VOCABULARY[word]
    mid = w.midway(sig, params, chain, folds.train)
    if mid == params:
        return params
    rows = _subsample(folds.train)

    def cost(p):
        if base.refit:
            return unbent_sse(word, chain, p, base, sig, rows)
        return train_sse(design(word, base, sig, {**chain, word: p}, folds)[0], sig.flow_lpm, rows)

    return mid if cost(mid) <= cost(params) * (1.0 + 1e-9) else params


def _placed_again(named: str, sel: Selection, sig: Signals, folds: Folds) -> bool:
    """The static laws of ``sel``'s chain placed again (:func:`_placed_beside`) once ``named`` joins it,
    before the next round's tests; whether one moved.

    A cracking duty placed before the time response was known sits where the lagged flow's openings
    and closings average out (44.2 % on a chirp behind a 26 ms delay, for 45.3): named beside it, the
    lag leaves a misfit 25 times the noise at each crossing, and the next round's words are tested on
    it (a coil 6.5 K warm from the start, whose effective duty moved the misplaced cracking duty onto
    the valve's, was named and survived every later check).
    """
    moved = False
    for word in [k for k in sel.chain if k != named and VOCABULARY[k].static]:
        placed = _placed_beside(word, sel.chain, sel.reference, sig, folds)
        if placed is None:
            continue
        sel.chain = {**sel.chain, word: placed[0]}
        sel.params[word] = placed[1]
        moved = True
    if moved:
        for s in sel.steps:
            s.params = sel.chain[s.word]
    return moved


def _placed_beside(word: str, chain: dict, root: Base, sig: Signals, folds: Folds) -> tuple | None:
    """A static law the recording itself places (:meth:`Word.placed`: a cracking duty where the flow at
    the valve leaves zero) placed again with every other word of ``chain`` in place, the PI refitted
    from ``root`` without the rows it explains: ``(params, physical params)``, or ``None`` when it has
    no placement, stays where it is, or the new place does not lower the training error or is not
    physical.

    Its screen chose among the grid and the placement with the other words as they were then: beside
    a lag sized before the cracking duty was known (its sampling phase half a sample off, taking up
    the unmodelled jump at each opening), a cracking duty 1.1 % above the valve's fitted the
    misplaced timing better than the true one, and the lag refined beside it then kept both off.
    """
    w = VOCABULARY[word]
    params = chain[word]
    if not w.resolution:
        return None
    others = {k: p for k, p in chain.items() if k != word}
    leads = [p for p in (w.settle(sig, q, others) for q in w.placed(sig, others)) if p != params]
    if not leads:
        return None
    rows = _subsample(folds.train)
    sse = [unbent_sse(word, others, p, root, sig, rows) for p in leads]
    i = int(np.argmin(sse))
    if sse[i] >= unbent_sse(word, others, params, root, sig, rows):
        return None
    new = leads[i]
    d, b = design(word, root, sig, {**others, word: new}, folds)
    theta = fit_final(d, sig.flow_lpm, folds.train)
    phys = w.physical(new, _coef(word, d, theta), sig, b, d.predict(theta))
    if w.implausible(phys) or _beyond_physics(w, new, others):
        return None
    return new, phys


def _memory_steps(word: str, chain: dict, full: dict, cur: Base, b: Base, sig: Signals, folds: Folds,
                  margins: Margins) -> str | None:
    """Why a slow drift's law (:meth:`Word.beside_memory`) explains no more than a staircase at the
    valve's memory epochs (:func:`models.diagnose.design.memory_epochs`), or ``None``: with a free
    offset per epoch in the model with and without it (``chain``, on ``cur``; ``full``, on ``b``),
    it must still lower the held-out error by its margin in a fold majority. The epochs whose fitted
    rows lie in one fold only are neither fitted nor scored (:func:`models.diagnose.design.unplaced_epochs`):
    held out, no offset can be placed for them, and a drift steepest there took up their step."""
    w = VOCABULARY[word]
    epochs = memory_epochs(sig).shape[1] if w.beside_memory(sig) and cur.refit else 0
    if not epochs:
        return None
    y = sig.flow_lpm
    skip = unplaced_epochs(sig, folds)
    c = _candidate(word, full[word], cross_validate(build(b, sig, full, memory=True), y, folds, skip),
                   cross_validate(build(cur, sig, chain, memory=True), y, folds, skip), b,
                   "exact" if w.is_exact(full[word]) else "linearized")
    need = margins.gain[word]
    if c.gain > need and c.majority(margins.min_wins):
        return None
    return (f"with a free offset per memory epoch of the valve (each growth of the duty's range, "
            f"{epochs} here) its held-out error changes by {-100 * c.gain:+.2f} % (needs "
            f"below -{100 * need:.2f} %), lower in {c.wins}/{len(c.test_after)} folds: a drift in steps at the "
            f"growths of the duty's range, the valve's hysteresis memory, not a thermal one")


def _drift_unseen(word: str, full: dict, b: Base, sig: Signals, folds: Folds, margins: Margins) -> str | None:
    """Why a law that drifts in time (:meth:`Word.instant`: a creep) shows no drift, or ``None``: against
    the same law settled within a sample (``full`` with it so, the PI refitted under each), it must lower
    the held-out error by its margin in a fold majority.

    Settled at once, a creep is a level set by the last reversal step, rate-independent as a loop is:
    breaths whose rest flow follows the peak before it (a foreign valve's asymmetric loop, which breaths
    cannot show, beside a warm coil and a clip) were named a creep of 0.0044 over 0.5 s."""
    w = VOCABULARY[word]
    settled = w.instant(full[word], sig)
    if settled is None:
        return None
    y = sig.flow_lpm
    at = {**full, word: settled}
    c = _candidate(word, full[word], cross_validate(build(b, sig, full), y, folds),
                   cross_validate(build(unbend(b, sig, at, folds.train) if b.refit else b, sig, at), y, folds), b,
                   "linearized")
    need = margins.gain[word]
    if c.gain > need and c.majority(margins.min_wins):
        return None
    return (f"against the same law settled within a sample (a level set by each reversal step, as a loop's shape "
            f"is) its held-out error changes by {-100 * c.gain:+.2f} % (needs below -{100 * need:.2f} %), lower in "
            f"{c.wins}/{len(c.test_after)} folds: its drift in time is not seen")


def _static_misfit(word: str, chain: dict, full: dict, cur: Base, b: Base, sig: Signals, folds: Folds,
                   margins: Margins) -> str | None:
    """Why a law in time held against a model file (:attr:`Word.beyond_loop`: a creep's drift, a lag or
    a delay) explains no more than the model's own misfit of the valve's loading curve and loop, or
    ``None``: with a free curve of the duty on each branch (:func:`models.diagnose.design.loop_curves`:
    a free loop, rate-independent) in the model with and without it (``chain``, on ``cur``; ``full``, on
    ``b``), it must still lower the held-out error by its margin in a fold majority.

    A lag's or delay's time is refined again beside the loop: refined without it, it has taken up part
    of the loop's misfit too (a foreign valve's 54 ms lag, on triangles beside a sensor offset against
    the model file, refined to 62 ms with the command held, lost 6 % held-out beyond the loop)."""
    w = VOCABULARY[word]
    if not (w.beyond_loop or w.beyond_curve) or cur.refit:
        return None
    y = sig.flow_lpm
    loop = w.beyond_loop
    if word in DYNAMIC:
        others, params = refine_time(word, chain, full[word], b, sig, folds, loop=True)
        full = {**others, word: params}
    c = _candidate(word, full[word], cross_validate(build(b, sig, full, static=True, branches=loop), y, folds),
                   cross_validate(build(cur, sig, chain, static=True, branches=loop), y, folds), b,
                   "exact" if w.is_exact(full[word]) else "linearized")
    need = margins.gain[word]
    if c.gain > need and c.majority(margins.min_wins):
        return None
    return (f"with a free curve of the duty{' on each branch' if loop else ''} beside the model file ({STATIC_KNOTS} "
            f"knots over its range{', rising and falling' if loop else ''}) its held-out error changes by "
            f"{-100 * c.gain:+.2f} % (needs below -{100 * need:.2f} %), lower in {c.wins}/{len(c.test_after)} folds: "
            f"the model's misfit of the valve's loading curve{' and loop' if loop else ''}, a function of the "
            f"duty{chr(39) + 's history' if loop else ''} alone, not a law in time")


def _symmetric_misfit(word: str, chain: dict, full: dict, sig: Signals, folds: Folds, margins: Margins) -> str | None:
    """Why a law held against a model file (:attr:`Word.beyond_symmetric`: an asymmetry) is the file's
    misfit of a symmetric loop, or ``None``: beside the paper's PI fitted on the recording (symmetric by
    construction, refitted under the chain as every test refits it), the chain ``full`` must still lower
    the held-out error of ``chain`` by the word's margin in a fold majority, with the law as found or
    linearized (the found setting is placed on the model file's thresholds). The level words of the
    chain are left out: that PI's constant takes them up."""
    w = VOCABULARY[word]
    if not w.beyond_symmetric:
        return None
    own = reference(fit_baseline(sig, folds), sig, folds)[0]
    others = {k: p for k, p in chain.items() if not VOCABULARY[k].shifts_level}
    y = sig.flow_lpm
    before = cross_validate(design(word, own, sig, others, folds)[0], y, folds)
    tried = []
    for params in (full[word], {}):
        d, b = design(word, own, sig, {**others, word: params}, folds)
        tried.append(_candidate(word, params, cross_validate(d, y, folds), before, b,
                                "exact" if w.is_exact(params) else "linearized"))
    c = max(tried, key=lambda t: t.gain)
    need = margins.gain[word]
    if c.gain > need and c.majority(margins.min_wins):
        return None
    return (f"beside the paper's PI fitted on the recording (symmetric, as the model file is) its held-out error "
            f"changes by {-100 * c.gain:+.2f} % (needs below -{100 * need:.2f} %), lower in {c.wins}/{len(c.test_after)} "
            f"folds: the model file's misfit of the valve's loop, which a symmetric PI takes up, not an asymmetry")


def _beyond_rest(word: str, chain: dict, full: dict, cur: Base, b: Base, sig: Signals, folds: Folds,
                 margins: Margins) -> str | None:
    """Why a law explains no more than its setting at the valve's rest (:meth:`Word.at_rest`), or
    ``None``: against the chain with that setting (``chain``, on ``cur``, the PI refitted under it),
    the law (``full``, on ``b``) must still lower the pooled held-out error by its margin.

    A valve resting shut at the recording's lowest duty passes nothing there whatever its PI says,
    and a law that closes it there frees the PI of those rows: on breaths resting at 30 % below
    plant_sim's seat (38 %), the PI pulled under zero flow at the rest fell 3 L/min short at the
    plateaus of the first breaths (their peak held in its widest operators), and a dead zone at
    34.8 % took that misfit of the baseline for its own; the same law at the rest explains all of it.
    """
    w = VOCABULARY[word]
    rest = w.at_rest(sig, full[word], cur)
    if rest is None:
        return None
    y = sig.flow_lpm
    seated = {**chain, word: rest}
    c = _candidate(word, full[word], cross_validate(build(b, sig, full), y, folds),
                   cross_validate(build(unbend(cur, sig, seated, folds.train), sig, seated), y, folds), b,
                   "exact" if w.is_exact(full[word]) else "linearized")
    need = margins.gain[word]
    # no fold majority: the law has earned one against the baseline, and what it adds to the same law
    # at the rest lies in the few rows between the two (a breath's rise crosses a cracking duty 1.6 %
    # above a 42 % rest in a sample or two, and those rows fall into one or two folds)
    if c.gain > need:
        return None
    return (f"against its setting at the valve's rest ({', '.join(f'{k} = {v:.4g}' for k, v in rest.items())}: "
            f"the valve shut or seated there by itself) its held-out error changes by {-100 * c.gain:+.2f} % "
            f"(needs below -{100 * need:.2f} %): a misfit of the baseline at the rest, not the law's")


def _within_phase(word: str, params: dict, chain: dict, sig: Signals) -> str | None:
    """A lag or delay shorter than one sample on top of the other word of :data:`DYNAMIC`: within a
    sample the two are one thing (the named one's sampling phase), so it is not resolved."""
    if word not in DYNAMIC or DYNAMIC[1 - DYNAMIC.index(word)] not in chain:
        return None
    key = TIME_PARAM[word]
    if params[key] * sig.rate_hz < 1.0:
        return (f"{key} = {params[key]:.4g} s, less than one sample on top of the named "
                f"{DYNAMIC[1 - DYNAMIC.index(word)]}: within a sample a lag and a delay are one thing")
    return None


def _unsupported(w: Word, params: dict, chain: dict, cur: Base, b: Base, d: Design, theta: np.ndarray,
                 sig: Signals, folds: Folds, noise: float) -> str | None:
    """Why the recording does not show the law of ``w`` at ``params`` on top of ``chain`` (:meth:`Word.support`),
    or ``None``: against the chain's model without it (``cur``, its PI refitted under ``chain``), and, for
    a static law on a refitted PI, against its own model (``d`` on ``b``, fitted as ``theta``) without it."""
    d0 = build(cur, sig, chain)
    before = d0.predict(fit_final(d0, sig.flow_lpm, folds.train))
    why = w.support(sig, params, before, noise, chain, after_lpm=d.predict(theta), fixed=not cur.refit)
    if why and w.static and cur.refit:
        # a PI fitted through a dead zone's shut rows bends to reach zero there and predicts no flow
        # either: what its law's own model (the PI fitted on the rows the law leaves open, its
        # coefficients) predicts there without the law, no reverse flow, is the model it corrects
        without = np.clip(build(b, sig, chain).predict(theta), 0.0, None)
        why = w.support(sig, params, without, noise, chain, extrapolated=True) and why
    return why


def _unsupported_after_drop(sel: Selection, sig: Signals, folds: Folds, margins: Margins, noise: float,
                            gone: set, rnd: int) -> str | None:
    """The support of each static law of ``sel`` read again on the final chain, after the backward
    check dropped ``gone``: a law whose support no longer holds is dropped as the backward check drops
    a word (traced as :data:`DROPPED`). Returns the word dropped, or ``None``.

    A static law is supported by the rows the chain as it was accepted in shows it at (on the duty the
    magnetics see, at the valve): a dead zone at the breaths' rest accepted beside a coil heating had
    each breath's rise open just above it on the heating's effective duty, and without the heating
    the valve is not seen opening there at all.
    """
    for step in sel.steps:
        w = VOCABULARY[step.word]
        if not w.static:
            continue
        others = {k: p for k, p in sel.chain.items() if k != step.word}
        cur = unbend(sel.reference, sig, others, folds.train)
        b = unbend(sel.reference, sig, sel.chain, folds.train)
        d = build(b, sig, sel.chain)
        theta = fit_final(d, sig.flow_lpm, folds.train)
        why = _unsupported(w, sel.chain[step.word], others, cur, b, d, theta, sig, folds, noise)
        if why is None:
            continue
        sel.trace.append(_decision(step, rnd, margins.gain[step.word], margins, DROPPED,
                                   f"with {', '.join(sorted(gone))} dropped, the recording no longer shows its "
                                   f"law: {why}"))
        sel.steps = [s for s in sel.steps if s.word != step.word]
        sel.chain = others
        del sel.params[step.word]
        sel.alternatives.pop(step.word, None)
        if sel.steps:
            _backfit(sel, sig, folds, dropped=True)
        return step.word
    return None


def _static_after_search(sel: Selection, sig: Signals, folds: Folds, margins: Margins, rnd: int) -> str | None:
    """The final chain's laws in time held against a model file (:attr:`Word.beyond_loop`: a creep, a lag,
    a delay), checked beyond the model's own misfit of the valve's loading curve and loop
    (:func:`_static_misfit`): one that explains no more is dropped as the backward check drops a word
    (traced as :data:`DROPPED`). Returns the word dropped, or ``None``.

    Checked on the final chain, not as the creep is named: a spurious creep named early can carry the
    search to the words that explain the recording (a coil 24 K warm beside a clip and a sensor offset,
    each refused alone in the first round, held-out 1470), and is dropped once they are in place.
    """
    for step in sel.steps:
        if sel.reference.refit:
            break
        others = {k: p for k, p in sel.chain.items() if k != step.word}
        why = (_static_misfit(step.word, others, sel.chain, sel.reference, sel.reference, sig, folds, margins)
               or _symmetric_misfit(step.word, others, sel.chain, sig, folds, margins))
        if why is None:
            continue
        why = f"with {', '.join(others) or 'nothing else'} in place, {why}"
        sel.trace.append(_decision(step, rnd, margins.gain[step.word], margins, DROPPED, why))
        sel.loop_misfit[step.word] = why
        sel.steps = [s for s in sel.steps if s.word != step.word]
        sel.chain = others
        del sel.params[step.word]
        sel.alternatives.pop(step.word, None)
        if sel.steps:
            _backfit(sel, sig, folds, dropped=True)
        return step.word
    return None


def _loop_masked(sel: Selection) -> None:
    """The words neither named nor another's alternative whose last test held against a model file
    refused or dropped them for explaining no more than the model's misfit of the valve's loop
    (:attr:`Selection.loop_misfit`): not identifiable against that model file. Updates ``sel``.

    An asymmetry dropped because the paper's symmetric PI fitted on the recording takes up the loop as
    well (:func:`_symmetric_misfit`) is the same: the recording shows a loop the model file misses (x7.8
    on a foreign valve's breaths explained 94 % of the held-out error against the file), not whether
    the valve's own loop is asymmetric.

    They fit the model's residual better than the model does, and so would a lateness of the valve: a
    lag shifts a ramp's flow by ``tau dq/dt``, a level on each branch, and only the spread of the
    ramps' rates and the holds tell it from a loop a little wider or narrower than the model's. Where
    those show nothing beyond the loop (triangles, ramps at 2-8 %/s: a foreign valve's 40 ms lag gained
    1.4 % held-out beyond the model file's loop, its misfit there 2.8 x the noise), the recording cannot
    say whether the valve is late: said, rather than the lag named or called absent.
    """
    alternative = {a[0].word for a in sel.alternatives.values()}
    for w, why in sel.loop_misfit.items():
        if w in sel.chain or w in alternative or w in sel.not_identifiable:
            continue
        last = sel.last().get(w)
        if last is None or last.why != why:
            continue  # refused for another reason in a later round
        sel.not_identifiable[w] = f"not identifiable against this model file: {why}"


#: Once the named words are in place, a misfit (RMS) within this factor of the sensor noise leaves
#: nothing for another law to explain.
EXPLAINED = 1.1


def _level_after_search(sel: Selection, sig: Signals, folds: Folds, margins: Margins, noise: float,
                        rnd: int) -> str | None:
    """A level word (:attr:`Word.shifts_level`: a sensor offset) held against a model file beside an
    exact law on the valve's input (a coil's effective duty, an asymmetry's widened thresholds), on a
    recording with no rows that read its level by themselves (:meth:`Word.pinned`: a shut valve's
    zero): said to be not identifiable when the constant it reads trades against that law's
    parameters by more than the sensor noise. Named, it is dropped as the backward check drops a word
    (traced as :data:`DROPPED`); returns the word dropped, or ``None``.

    The constant is read twice: with the input-side laws refined jointly with it (what the search
    does), and with them placed by their own signature, beside a free static curve of the duty
    (:func:`models.diagnose.design.static_curve`: the model file's misfit of the valve's loading
    curve, and any constant), the constant then fitted beside them. A valve the model file describes
    reads the same constant both ways (plant_sim's, a 30 K coil with a -1.6 L/min offset on breaths:
    -1.61 and -1.61). On a valve it does not quite describe (a foreign valve's loop held against a PI
    fitted on its staircase: 0.8 L/min low over the breaths' tops, 0.5 high at rest), the heating's
    rise and time constant or the asymmetry's widening take up that misfit together with the constant:
    a coil 24 K warm with an offset of +2.0 L/min read the constant +0.5 jointly, +1.6 so placed, and
    the same coil with no offset at all -1.5 and -0.5 (named, a false offset); its time signature, a
    constant from the first row where the heating starts cold, is traded for the model file's misfit.
    """
    ref = sel.reference
    if ref.refit:
        return None
    for word, w in VOCABULARY.items():
        if not w.shifts_level or word in sel.not_identifiable:
            continue
        others = {k: p for k, p in sel.chain.items() if k != word}
        inside = [k for k, p in others.items() if VOCABULARY[k].input_side and VOCABULARY[k].is_exact(p)
                  and any(q in p for q in VOCABULARY[k].bounds(sig, ref))]
        y = sig.flow_lpm
        if word not in sel.chain:
            why = _level_unexplained(word, sel, sig, folds, noise)
            if why is not None:
                sel.not_identifiable[word] = why
                continue
        if not inside:
            if word not in sel.chain:
                continue
            why = _level_within_misfit(word, others, sel, sig, folds)
            if why is not None:
                sel.not_identifiable[word] = why
                sel.nuisance.add(word)
            continue

        def level(chain: dict) -> tuple:
            d = build(ref, sig, carried(inside[0], sig, {**chain, word: {}}))
            theta = fit_final(d, y, folds.train)
            fitted = d.predict(theta)
            coef = _coef(word, d, theta)
            return coef, fitted - coef * d.X[:, d.names.index(word)], fitted

        joint = refine_jointly(inside, {**others, word: sel.chain.get(word, {})}, ref, sig, folds)
        c_joint, before, after = level({k: p for k, p in joint.items() if k != word})
        if w.pinned(sig, before, after):
            continue
        c_own = level(refine_jointly(inside, others, ref, sig, folds, static=True))[0]
        if abs(c_joint - c_own) <= noise:
            continue
        why = (f"not identifiable beside {', '.join(inside)} against this model file: no rows read its level by "
               f"themselves (a shut valve's zero), and it reads {c_joint:.3g} {next(iter(w.units.values()))} "
               f"with {', '.join(inside)} refined jointly with it, {c_own:.3g} with them placed by their own "
               f"signature beside a free static curve of the duty (the model file's misfit of the valve's "
               f"loading curve): it trades against their parameters by more than the noise ({noise:.3g})")
        sel.not_identifiable[word] = why
        if word not in sel.chain:
            continue
        return _drop_level(word, others, sel, sig, folds, margins, rnd, why)
    return None


def _drop_level(word: str, others: dict, sel: Selection, sig: Signals, folds: Folds, margins: Margins, rnd: int,
                why: str) -> str:
    """Drop the named level ``word`` from ``sel`` as the backward check drops a word (traced as
    :data:`DROPPED`, the others refined again without it); returns ``word``."""
    step = next(s for s in sel.steps if s.word == word)
    sel.trace.append(_decision(step, rnd, margins.gain[word], margins, DROPPED, why))
    sel.steps = [s for s in sel.steps if s.word != word]
    sel.chain = others
    del sel.params[word]
    sel.alternatives.pop(word, None)
    if sel.steps:
        _backfit(sel, sig, folds, dropped=True)
    return word


def _level_unexplained(word: str, sel: Selection, sig: Signals, folds: Folds, noise: float) -> str | None:
    """Why the level ``word`` (a sensor offset) not named, held against a model file, cannot be said to
    be absent, or ``None``: no rows read its level by themselves (:meth:`Word.pinned`: a shut valve's
    zero), and the model file with the named words still misses the recording beyond the noise
    (:data:`EXPLAINED`) where a free static curve of the duty and a constant are fitted beside them
    (:func:`models.diagnose.design.static_curve`): a misfit no level explains, which the named words'
    parameters trade a constant against.

    A foreign valve's loop held against a PI fitted on its staircase, widened x5.4 with an offset of
    -1.0 L/min on triangles never shut: the model file's thresholds widened in proportion miss the
    valve's by 1.5 L/min for 0.46 of noise, the asymmetry's lift took the offset up, and the constant
    then read +0.11 (+0.79 with the widening alone): no offset named, and none could have been sized.
    """
    ref, y, rows = sel.reference, sig.flow_lpm, folds.train
    d = build(ref, sig, {**sel.chain, word: {}})
    theta = fit_final(d, y, rows)
    level = _coef(word, d, theta)
    if level is None:
        return None
    fitted = d.predict(theta)
    if VOCABULARY[word].pinned(sig, fitted - level * d.X[:, d.names.index(word)], fitted):
        return None
    s = build(ref, sig, sel.chain, static=True)
    ok = rows & s.fit_ok
    misfit = float(np.sqrt(np.mean((y - s.predict(fit_final(s, y, rows)))[ok] ** 2)))
    if misfit <= EXPLAINED * noise:
        return None
    unit = next(iter(VOCABULARY[word].units.values()))
    return (f"not identifiable against this model file: no rows read its level by themselves (a shut valve's zero), "
            f"and with {', '.join(sel.chain) or 'no word'} in place the model misses the recording by {misfit:.3g} "
            f"{unit} RMS beside a free static curve of the duty and a constant, beyond the noise ({noise:.3g} {unit}): "
            f"a misfit no level explains, which a constant trades against (it reads {level:.3g} {unit} here)")


def _level_within_misfit(word: str, others: dict, sel: Selection, sig: Signals, folds: Folds) -> str | None:
    """Why the named level ``word`` (a sensor offset) held against a model file, on a recording with no
    rows that read its level by themselves (:meth:`Word.pinned`: a shut valve's zero), cannot be told
    from the model file's own misfit of the valve's loading curve, or ``None``.

    A free static curve of the duty beside the other words (:func:`models.diagnose.design.static_curve`)
    is the model's misfit of the loading curve, a constant included: its spread over the training rows
    (standard deviation, L/min) is how far the model file misses the valve at one duty against another,
    and a constant no larger than that is within what the model gets wrong; its mean cannot be told
    from a zero offset. A valve the model file describes shows next to no spread (plant_sim against its
    model file: 0.01 L/min, an offset of 1.0 read 1.00); a foreign valve held against a PI fitted on
    its staircase, effect free on triangles never shut, spreads 1.01 L/min and read a constant of 0.49
    (named a sensor offset, 3.2 % held-out against a 3 % margin), with an offset of -1.0 on a chirp
    read -1.05 beside a spread of 1.26, and with +1.5 on triangles +1.89 beside 1.04.
    """
    ref, y, rows = sel.reference, sig.flow_lpm, folds.train
    d = build(ref, sig, {**others, word: {}})
    theta = fit_final(d, y, rows)
    level = _coef(word, d, theta)
    if level is None:
        return None
    fitted = d.predict(theta)
    if VOCABULARY[word].pinned(sig, fitted - level * d.X[:, d.names.index(word)], fitted):
        return None
    s = build(ref, sig, others, static=True)
    theta = fit_final(s, y, rows)
    cols = [i for i, n in enumerate(s.names) if n == "static"]
    spread = float(np.std((s.X[:, cols] @ theta[cols])[rows & s.fit_ok]))
    if abs(level) > spread:
        return None
    unit = next(iter(VOCABULARY[word].units.values()))
    return (f"not identifiable against this model file: no rows read its level by themselves (a shut valve's zero), "
            f"and the constant it reads ({level:.3g} {unit}) is no larger than the model file's own misfit of the "
            f"valve's loading curve (a free static curve of the duty beside the other words spreads {spread:.3g} "
            f"{unit} over the rows): a level within what the model gets wrong from one duty to another, kept as a "
            f"free constant of the baseline and not reported")


def _accept(c: Candidate, chain: dict, cur: Base, sig: Signals, folds: Folds, noise: float,
            margins: Margins) -> tuple:
    """Polish a passing candidate's parameters and check them: ``(c, chain, physical params)``, or
    ``(outcome, why)`` when they are not physical, not resolved, the recording does not show the law,
    or a slow drift's law explains no more than the valve's memory steps (:func:`_memory_steps`)."""
    w = VOCABULARY[c.word]
    b = cur if w.joint_with_pi else c.base or cur
    if c.word in DYNAMIC and not c.refined:
        chain, params = refine_time(c.word, chain if c.chain is None else c.chain, c.params, b, sig, folds)
    else:
        chain = chain if c.chain is None else c.chain
        params = c.params if c.refined else refine(c.word, beside_recorded(c.word, sig, chain), c.params, b, sig, folds)
    params = w.settle(sig, params, chain)
    full = carried(c.word, sig, {**chain, c.word: params})
    d, b = design(c.word, b, sig, full, folds)
    theta = fit_final(d, sig.flow_lpm, folds.train)
    phys = w.physical(params, _coef(c.word, d, theta), sig, b, d.predict(theta))
    why = (w.implausible(phys) or w.not_resolved(params, sig, b) or _at_upper_bound(w, params, sig, b)
           or _beyond_physics(w, params, chain) or _within_phase(c.word, params, chain, sig))
    if why:
        return NOT_PHYSICAL, why
    why = _unsupported(w, params, chain, cur, b, d, theta, sig, folds, noise)
    if why:
        return UNSUPPORTED, why
    why = _beyond_rest(c.word, chain, full, cur, b, sig, folds, margins)
    if why:
        # the recording shows no more of it than the valve resting shut: what it explains is the
        # baseline's misfit at the rest, which a weaker word may be taking up too (:func:`_masking`: a
        # creep beside a heating oversized on breaths resting below the seat)
        return UNSUPPORTED, why
    why = _memory_steps(c.word, chain, full, cur, b, sig, folds, margins) or _drift_unseen(c.word, full, b, sig, folds,
                                                                                         margins)
    if why:
        return NOT_PHYSICAL, why
    if c.word in DYNAMIC:
        # a lateness beside a model file is held beyond its loop as it is named, not only on the final
        # chain as a creep is (:func:`_static_after_search`): a time response delays every column behind
        # it, and one named on the model's loop misfit shifts the branches the words after it are fitted on
        why = _static_misfit(c.word, chain, full, cur, b, sig, folds, margins)
        if why:
            return MASKED, why
    c.params = params
    if w.joint_with_pi:
        c.base = b
    return c, full, phys
