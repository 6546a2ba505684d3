"""The augmented model: baseline plus a chain of effects, as a linear regression.

For fixed nonlinear parameters every word of :mod:`models.diagnose.words`
keeps the model linear in its remaining unknowns, so the augmented model is::

    q(t) = D[clip(F_v(t) + X_v(t) theta_v)] + X_s(t) theta_s

with ``D`` the chain's time response (delay, lag), ``clip`` the valve's
full-open flow (saturation) and its no-reverse-flow floor, both at the valve
as the valve clips, and ``X_s`` the columns at the sensor; without a time
response it is ``clip(F + X theta)``.

:func:`build` asks each word in the chain for its part: the duty the
hysteresis core sees (a warm coil's effective duty) and the lift of its
descending thresholds (the exact laws, which refit the PI on them), linear
columns at the valve (first-order asymmetry and heating, the supply
exponent), a pointwise gain (a dead zone), a time response (delay, lag;
the hysteresis is time invariant and causal, so delaying its input and
delaying its output are the same), columns at the sensor (creep, offset)
and a clip (saturation).

The hysteresis core's weights are fitted once on all training rows, under
the effects named so far and jointly with an effect under test that it absorbs
(:func:`unbend`), never per fold: a PI of 50 operators refitted on 5/6 of the
training blocks is far less stable on the sixth (rare excursions set the
states of the wide operators) than the effects it is meant to reveal; the
leak this leaves is measured by the calibration on effect-free recordings.
With a baseline fitted on the recording its prediction enters with a free
*gain*, *offset*, *loop width* and *duty scale* (``x dq/dx``: the response
to a constant change of the coil current), the ways a baseline fitted with
an effect present has bent to absorb it on average; with a model file the
model's prediction, run as the simulated valve runs it, is held fixed in ``F``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .. import play
from ..model import FittedModel
from ..pi import PIModel, SlopeRows, fit_pi, fit_weights, fit_weights_on, thresholds
from ..preprocess import Scaling
from . import effects as fx
from .folds import Folds
from .residuals import branch
from .signals import Signals, noise_lpm
from .words import VOCABULARY, Columns, Word

#: Relative ridge on the normal equations (keeps a column that is all zero harmless).
RIDGE = 1e-10
#: Operators of the paper's symmetric PI baseline (Eq. 2).
BASELINE_N = 50
#: Most play operators a model file's own PI brings into the refits: each refit builds rows x
#: operators outputs and an operators-squared system (25 000 operators: 16 GB and 96 s on 2000
#: rows). A larger PI enters them as a model of another kind does, through a BASELINE_N-operator
#: PI fitted to its prediction; its own prediction stays the baseline.
SHAPE_MAX_OPERATORS = 1000
#: A measured flow within this many times the sensor noise of zero is a valve shut by itself.
SHUT_NOISE = 3.0
#: Ridge per fitted row on a refitted PI's steps of its loading-curve slope (the weights of the
#: operators with a threshold; normalized units; :func:`unbend`), towards zero: a step of 1 costs as much
#: as a 0.03 % misfit of the range on every row. The steps the rows tell are fitted as without it; the
#: opposite steps of operators the rows do not tell apart stay near zero, the slope going on as the rows
#: below tell (towards the root baseline's steps instead, the refit kept the root's bends that took up
#: the effect: a clip's flattened top, an asymmetry's).
STEP_RIDGE = 1e-7
#: For the holdout check (:func:`unbend` with ``untold``): a further ridge per fitted row on the step of
#: each operator of a PI refitted under a saturation, in proportion to the square of the share of its
#: movement that falls on the rows left to the clip (:func:`clip_share`): the widest operators, which
#: only the clipped tops of the highest breaths move, keep the loading curve's slope instead of taking
#: opposite steps that the training breaths' memory alone sets. Free, they predicted a shut valve at
#: rest passing 5-7 L/min after a breath that first reached a new top inside a holdout block (a memory
#: no training row shows; breaths on a valve clipped at 142 L/min, seed 10143: held-out error 0.98
#: L/min against 0.34 with the ridge, the noise 0.3). The search keeps them free: on the rows it fits
#: they take up the valve's own staircase between its memory epochs, which the clip's test needs.
CLIP_STEP_RIDGE = 1e-5
#: A flow within this many times the sensor noise of the full-open flow, or above it, is at the
#: plateau: the flow the valve would pass there is only known to be at least the full-open flow.
PLATEAU_NOISE = 3.0
#: Knots of the static curve of the duty beside a model file (:func:`static_curve`), evenly over the
#: duty's range: a model's misfit of a valve's loading curve is smooth across it.
STATIC_KNOTS = 8
#: Growths of the duty's running range closer than this (s) to the last one share one memory epoch
#: (a breath's 0.2 s rise grows it over many samples).
EPOCH_S = 5.0


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
        is a PI; for ``refit``, the PI with the weights of this base).
    shape_scale : Scaling
        Duty scaling of ``shape``'s input.
    lift_w : ndarray
        Non-negative weights over ``shape``'s thresholds (normalized output) that shape the
        asymmetric-branch column: a fitted PI's weights alternate in sign, and a column that
        weights each operator's own lift by them is erratic wherever operators part ways
        (random holds).
    parent : Base, optional
        For a PI refitted jointly with an effect (:func:`unbend`): the baseline whose loop
        offset, descending lift and slope the effect columns were fitted with.
    seat : tuple, optional
        For a PI fitted on the recording: ``(seat_pct, gain_lpm_per_pct)``, the duty below which
        the valve's plunger sits on its seat (the PI's input is held there) and the slope of the
        line the flow closes along below it (:func:`fit_baseline`); ``None``: the PI spans the
        recording's whole duty range.
    """

    refit: bool
    model: FittedModel
    shape: PIModel
    shape_scale: Scaling
    lift_w: np.ndarray
    parent: "Base | None" = None
    seat: tuple | None = None
    cache: dict = field(default_factory=dict, repr=False)

    @property
    def y_half(self) -> float:
        return self.model.y_scale.half_range

    @property
    def root(self) -> "Base":
        return self.parent or self

    @property
    def supply_ref_bar(self) -> float | None:
        """The supply (bar gauge) a model file was identified at: as it records it
        (:func:`models.fitting.fit_recording`), else the reference hardware's
        (:data:`.effects.REFERENCE_SUPPLY_BAR`); ``None`` for a refitted PI, whose gain is refitted.

        Not the recording's mean supply: a supply that droops with the flow averages below the
        regulator's setting, and the model file's flow scaled to that mean reads the droop's share of
        the flow as a constant (a foreign valve identified at 3.0 bar, held against a recording
        drooping to a mean of 2.97: a 1.8 L/min offset read 1.12)."""
        if self.refit:
            return None
        return float(self.root.model.meta.get("supply_bar", fx.REFERENCE_SUPPLY_BAR))

    def _cached(self, key, make, keep: int = 4):
        """``make()`` cached under ``key``; at most ``keep`` entries of its kind (``key[0]``) besides
        those of the raw duty (an entry of operator outputs is N x m)."""
        hit = self.cache.get(key)
        if hit is None:
            same = [k for k in self.cache if k[0] == key[0] and k[2:] != ((),)]
            for old in same[:max(0, len(same) - keep + 1)]:
                del self.cache[old]
            hit = self.cache[key] = make()
        return hit

    def predict(self, sig: Signals, chain: dict) -> np.ndarray:
        """Prediction (L/min) on ``sig`` under the input-side laws of ``chain`` (effective duty,
        lifted descending thresholds), cached."""
        x, a, key = inputs(sig, chain)
        if self.refit:
            return self._cached(("q", id(sig), key), lambda: self.model.y_scale.from_unit(
                self.regressors(sig, chain) @ self.shape.w + self.shape.offset)
                + (0.0 if self.seat is None else self.seat[1] * seat_line(seated_input(sig, chain), self.seat[0])))
        if any(a[:2]) and isinstance(self.model.core, PIModel):
            # the model file run as the simulated valve runs it (its input held to the identified
            # range, closing below it, no reverse flow), plus what the lifted descending thresholds
            # change in its own operators on that held input: a PI's output is linear in them
            duty_only = {w: p for w, p in chain.items() if VOCABULARY[w].input_side == "duty"}
            return self._cached(("q", id(sig), key), lambda: simulated(self.model, x, sig.rate_hz, sig.rest_pct)
                                + self.y_half * ((self.regressors(sig, chain) - self.regressors(sig, duty_only))
                                                 @ self.model.core.w))
        return self._cached(("q", id(sig), key), lambda: simulated(self.model, x, sig.rate_hz, sig.rest_pct))

    def unit_input(self, duty_pct: np.ndarray) -> np.ndarray:
        """A duty (%) as the hysteresis core's normalized input: a model file's valve holds it to the
        identified range [-1, 1] (seated below it, fully open above it, as the simulated valve runs
        it); a PI fitted on the recording spans the recording's own range above its seat duty, and
        holds its input there below it (:attr:`seat`)."""
        if self.refit:
            return self.shape_scale.to_unit(duty_pct if self.seat is None else np.maximum(duty_pct, self.seat[0]))
        return np.clip(self.shape_scale.to_unit(duty_pct), -1.0, 1.0)

    def shut(self, sig: Signals) -> np.ndarray:
        """Rows where a PI fitted on the recording is left to the valve's no-reverse-flow floor: the
        measured flow is zero within :data:`SHUT_NOISE` x the noise (none for a model file, whose
        simulation closes by itself; cached)."""
        if not self.refit:
            return np.zeros(len(sig), dtype=bool)
        return self.root._cached(("shut", id(sig)), lambda: shut_rows(sig.flow_lpm))

    def plateau(self, sig: Signals, chain: dict, valve: bool = True) -> tuple:
        """The rows whose flow, as measured, is at the plateau of the chain's saturation, and the flow
        (L/min) a prediction must reach on each for the row to be left to the clip:
        ``(plateau, reach_lpm)``; no rows without a saturation.

        ``valve``: the flow at the valve, recovered from the measured flow through the chain's time
        response (its noise with it), else the flow at the sensor. A plateau row only says that the
        valve would pass at least the full-open flow: a fit that falls short of it there is pulled up
        by the row, one that reaches it leaves the row to the clip, and a row measured below the
        plateau is always fitted (chosen by a prediction, the rows left to the clip moved with a
        heating's rise and time constant, and its refinement stalled on a rugged training error).
        Where the root baseline (the PI fitted through the plateau, or the model file's simulation)
        reaches the full-open flow, a prediction within the plateau's noise band below it counts as
        reaching it: a PI fitted without the plateau runs on flat just below it (breaths that hold
        their top duties clipped), and rows fitted there bend it flat into the plateau.
        """
        c = clip_of(chain)
        if c is None:
            return np.zeros(len(sig), dtype=bool), np.full(len(sig), np.inf)
        flow = sig.flow_lpm
        noise = noise_lpm(flow)
        if valve:
            for w, p in reversed(chain.items()):
                flow = VOCABULARY[w].undo(flow, sig.rate_hz, p)
            # the sensor's noise as the undoing passes it on, not as read off the flow it gives: a
            # delay between samples interpolates two rows, which correlates neighbours, and the
            # second differences then read half the noise each row keeps (a 50 ms delay at 50 Hz:
            # plateau rows dipping below a band so narrowed were fitted as open, and the delay and
            # clip at their true settings fitted 1.3 x the noise where 40 or 60 ms fitted 1.09 x)
            noise *= undo_gain(chain, sig.rate_hz)
        band = PLATEAU_NOISE * noise
        reach = np.where(self.root.predict(sig, {}) >= c, c - band, c)
        return flow >= c - band, reach

    def bends(self, sig: Signals) -> tuple:
        """Loop offset, descending lift and ``x dq/dx`` (all L/min) of the root baseline on ``sig``'s duty:
        the ways a PI fitted with an effect present bends (cached)."""
        root = self.root
        if root is not self:
            return root.bends(sig)

        def make():
            x = sig.duty_pct
            x_unit = self.unit_input(x)
            ops = self.regressors(sig, {})
            loop = fx.loop_offset(ops, x_unit, self.shape.w) * self.y_half
            lift = fx.descending_lift(ops, x_unit, self.shape.r) @ self.lift_w * self.y_half
            # relative duty step of the central difference: a few threshold spacings of a 50-operator
            # PI (a fitted PI's slope within one segment is its noisiest feature), about the current
            # change of a coil some ten kelvin warm (0.393 %/K)
            eps = 0.05
            slope = (simulated(self.model, x * (1 + eps), sig.rate_hz, sig.rest_pct)
                     - simulated(self.model, x * (1 - eps), sig.rate_hz, sig.rest_pct)) / (2 * eps)
            return loop, lift, slope

        return self._cached(("B", id(sig)), make)

    def regressors(self, sig: Signals, chain: dict) -> np.ndarray:
        """The baseline PI's play operator outputs on the effective duty of ``chain``, with its
        descending thresholds lifted by the chain's asymmetry (cached)."""
        x, a, key = inputs(sig, chain)

        def make():
            x_unit = self.unit_input(x)
            y0 = self.shape.y0
            if sig.rest_pct is not None:  # at rest at the duty before the first row, within the input range
                y0 = np.full_like(self.shape.r, np.clip(self.shape_scale.to_unit(sig.rest_pct), -1.0, 1.0))
            if any(a[:2]):
                return fx.generalized_play(self.shape.r, x_unit, *a, y0=y0)
            return pi_columns(self.shape.r, x_unit, y0)

        # every base refitted from one root shares its thresholds: the operator outputs are the root's
        return self.root._cached(("P", id(sig), key), make, keep=2)

    def regressors_at_sensor(self, sig: Signals, chain: dict) -> np.ndarray:
        """:meth:`regressors` through the dead zone, delay and lag of ``chain`` (cached: a joint test
        refits the PI under the same chain at every grid point of the effect it tests)."""
        rest = passed(chain)
        k = ("S", *self._at_sensor_key(sig, chain))
        cache = self.root.cache
        hit = cache.get(k)
        if hit is None:
            for old in [key for key in cache if isinstance(key, tuple) and key[0] in ("S", "D")]:
                del cache[old]  # one chain at a time: each entry is N x m (its slope rows with it)
            hit = cache[k] = at_sensor(self.regressors(sig, chain), sig, rest)
        return hit

    def slope_rows(self, sig: Signals, chain: dict, rows: np.ndarray) -> SlopeRows:
        """The operator part of a PI refit's normal equations (:class:`models.pi.SlopeRows`) of
        :meth:`regressors_at_sensor` on ``rows`` (cached with it: every grid point of a joint screen
        refits the PI on the same operators and rows, with another effect column)."""
        Y = self.regressors_at_sensor(sig, chain)
        key = ("D", *self._at_sensor_key(sig, chain), rows.tobytes())
        return self.root._cached(key, lambda: SlopeRows.of(Y[rows]), keep=2)

    @staticmethod
    def _at_sensor_key(sig: Signals, chain: dict) -> tuple:
        """What :meth:`regressors_at_sensor` depends on: the signals, the input-side laws and the
        words the operators pass through (:func:`passed`)."""
        rest = passed(chain)
        return id(sig), inputs(sig, chain)[2], repr(sorted(rest.items()))


def shut_rows(flow_lpm: np.ndarray) -> np.ndarray:
    """Rows where the measured flow is zero within :data:`SHUT_NOISE` x the sensor noise."""
    return flow_lpm <= SHUT_NOISE * noise_lpm(flow_lpm) + 1e-9


def simulated(model: FittedModel, duty_pct: np.ndarray, rate_hz: float, rest_pct: float | None = None) -> np.ndarray:
    """Flow (L/min) of a model file run as the simulated valve runs it: a PI-family model through
    plant_sim without effects or sensor errors (its input held to the identified range, closing
    below it, no reverse flow), from rest at ``rest_pct`` (default: the first duty), any other
    kind by its own prediction. A recording is held against the simulation, and a closed-loop
    run drives its valve far outside the identified range."""
    from plant_sim.plant import PLANT_KINDS, BatchPlant, PlantParams

    if model.kind not in PLANT_KINDS:
        return model.predict(duty_pct)[0]
    valve = BatchPlant(PlantParams(model, noise_lpm=0.0, scale_factor=0.0, range_lpm=(-1e9, 1e9)), rate_hz)
    duty = np.clip(duty_pct, 0.0, 100.0)
    state = valve.init(duty[0] if rest_pct is None else rest_pct)  # at rest before the first row
    return valve.run(state, duty[None, :])[1]["true_flow_lpm"][0]


def inputs(sig: Signals, chain: dict) -> tuple:
    """The duty the hysteresis core sees under ``chain`` (%), the ``(widen, lift, start)`` of its
    descending thresholds (:func:`effects.generalized_play`), and a hashable key of the two."""
    key, a, warm = [], (0.0, 0.0, 0.0), None
    for w, p in chain.items():
        word = VOCABULARY[w]
        if word.input_side and word.is_exact(p):
            key.append((w, tuple(sorted(p.items()))))
            a = tuple(u + v for u, v in zip(a, word.threshold_widening(p)))
            warm = (word, p) if word.input_side == "duty" else warm
    key = tuple(key)
    x = sig.duty_pct
    if warm is not None:
        # the last two effective duties are kept (the chain's, and the same before its input floor,
        # :func:`seated_input`): an exact-law refinement asks for them several times per evaluation
        x = sig.cache.get(key)
        if x is None:
            while len(sig.cache) >= 2:
                del sig.cache[next(iter(sig.cache))]
            x = sig.cache[key] = warm[0].effective_duty(sig, warm[1])
    return x, a, key


def input_floor(chain: dict) -> tuple:
    """``(floor_pct, chain without it)``: the duty (%) below which a law of ``chain`` holds the
    hysteresis core's input (:meth:`Word.floor`: a warm coil's valve seated on the duty the magnetics
    see), ``None`` and ``chain`` when none does."""
    for w, p in chain.items():
        floor, rest = VOCABULARY[w].floor(p)
        if floor is not None:
            return floor, {**chain, w: rest}
    return None, chain


def seated_input(sig: Signals, chain: dict) -> np.ndarray:
    """The duty the magnetics see under ``chain`` (%) before any input floor: what a seat's line
    (:func:`seat_line`) closes along below it."""
    return inputs(sig, input_floor(chain)[1])[0]


def major_loop_half_width(r: np.ndarray, w: np.ndarray, n: int = 2001) -> float:
    """Half the input distance between the branches of a PI's major loop (normalized input), averaged
    over the middle half of its output range (a fitted PI's branches may touch at a single level)."""
    up = np.linspace(-1.0, 1.0, n)
    # one cycle closes the loop (the first ascent starts below it), the second is measured
    q = pi_columns(r, np.concatenate([up, up[::-1], up]), -np.inf)[n:] @ w
    desc, asc = np.maximum.accumulate(q[:n][::-1]), np.maximum.accumulate(q[n:])
    levels = np.linspace(0.25, 0.75, 51) * (q.max() - q.min()) + q.min()
    return float(np.mean(np.interp(levels, asc, up) - np.interp(levels, desc, up))) / 2.0


def memory_start_s(sig: Signals, n: int = BASELINE_N) -> float:
    """Time (s) of the end of the initial loading curve out of a shut valve: the duty first turns
    back, by more than twice the smallest threshold of an ``n``-operator PI over its range (a turn
    that wipes an operator out), from an excursion as large. ``t_s[0]`` when the valve passes flow at
    the first row (or the duty never turns).

    Along the first excursion every operator it moves runs from the memory the valve had before the
    recording, which Eq. (3) sets at rest at the first duty. Where the valve passes flow there, the
    recording's own start is that rest (the paper's protocol); a valve shut at its rest duty shows
    nothing of its memory there, and a valve whose plunger sits seated below its cracking duty holds
    it at the cracking duty, not at a rest far below it (plant_sim and the foreign suite's valve hold
    their input at 38 %). No later row repeats that curve (the first descent wipes both memories out
    alike), so no fit learns it: on breaths resting at 30 % (a clip at 130 L/min) the first 0.2 s
    rise missed by up to 73 L/min, and the baseline's cross-validated misfit was 1.77 L/min against
    0.52 on the holdout (0.53 without those rows).
    """
    x, flow = sig.duty_pct, sig.flow_lpm
    if not shut_rows(flow)[0]:
        return float(sig.t_s[0])
    x0 = x[0] if sig.rest_pct is None else sig.rest_pct
    step = float(np.ptp(np.append(x, x0))) / (n + 1)
    hi, lo = np.maximum.accumulate(np.maximum(x, x0)), np.minimum.accumulate(np.minimum(x, x0))
    turned = ((hi - x > step) & (hi - x0 > step)) | ((x - lo > step) & (x0 - lo > step))
    return float(sig.t_s[np.argmax(turned)]) if turned.any() else float(sig.t_s[0])


def memory_epochs(sig: Signals) -> np.ndarray:
    """Step columns, shape (N, e): one from each growth of the duty's running range after the initial
    loading curve of a recording whose valve is shut at its first row (:func:`memory_start_s`), at
    most one every :data:`EPOCH_S`; none otherwise.

    An operator the running range has not yet wiped out (twice its threshold wider than the range)
    holds the highest (or lowest) duty so far, and only a growth of the range moves it: between two
    growths those operators add a constant, which a fitted PI, its thresholds elsewhere than the
    valve's, gets wrong by a different amount in each epoch. plant_sim's valve (weights of +-0.8 side
    by side among its widest operators) steps its flow at every later breath by 1.2 L/min while its
    highest breath is 70.65 % and by 0.23 L/min while it is 71.4 % (effect-free breaths resting at
    30 %, seed 2011): a staircase in time that a slow drift's law takes up.
    """
    x = sig.duty_pct
    start = memory_start_s(sig)
    if start <= sig.t_s[0]:
        return np.zeros((len(x), 0))
    span = np.maximum.accumulate(x) - np.minimum.accumulate(x)
    cols, last = [], -np.inf
    for k in np.flatnonzero(np.diff(span) > 0) + 1:
        if sig.t_s[k] > start and sig.t_s[k] - last >= EPOCH_S:
            cols.append(np.arange(len(x)) >= k)
            last = sig.t_s[k]
    return np.column_stack(cols).astype(float) if cols else np.zeros((len(x), 0))


def unplaced_epochs(sig: Signals, folds: Folds) -> np.ndarray:
    """Rows of the memory epochs (:func:`memory_epochs`) whose fitted rows all lie in one
    cross-validation fold: held out, no fit places their offset.

    The epoch before the first growth of the duty's range is a few breaths long, and a blocked fold
    can hold it out whole (breaths resting at 30 % on a valve clipped at 139 L/min: its first 5 s,
    up to 5 L/min above the later breaths at the same duty while the valve's widest operators still
    hold the first breath's top, all in the first block; another epoch of 12 s between the holdout
    and one fold). Scored there, both models miss by its whole step (that fold's held-out squared
    error tens of times the noise's), and a cold coil's warming, steepest at the start, took up part
    of it: the pooled held-out gain was that fold's, the other folds gained a few per cent."""
    epoch = memory_epochs(sig).sum(axis=1).astype(int)
    fitted = (folds.fold >= 0) & folds.fit_ok
    out = np.zeros(len(epoch), dtype=bool)
    for e in np.unique(epoch):
        rows = epoch == e
        if len(np.unique(folds.fold[rows & fitted])) <= 1:
            out |= rows
    return out


def static_curve(sig: Signals) -> np.ndarray:
    """Hat columns, shape (N, :data:`STATIC_KNOTS`), of a piecewise-linear curve of the duty over its
    range (0.5th to 99.5th percentile; flat beyond): a free function of the duty alone.

    Beside a model file it is the model's own misfit of the valve's loading curve, which a drift in
    time must explain beyond (:attr:`Word.drifts`): breaths on a valve the model file does not quite
    describe (0.5 L/min low over their top, 0.2 high at rest) are matched by a creep of a small
    fraction with a time constant longer than the breath, its state following the reversals up and
    down each breath as a static curve would.
    """
    lo, hi = np.percentile(sig.duty_pct, [0.5, 99.5])
    knots = np.linspace(lo, hi, STATIC_KNOTS)
    if not hi > lo:
        return np.ones((len(sig.duty_pct), 1))
    return np.column_stack([np.interp(sig.duty_pct, knots, e) for e in np.eye(STATIC_KNOTS)])


def loop_curves(sig: Signals) -> np.ndarray:
    """The columns of :func:`static_curve`, and the same hat columns again on the rows of an ascending
    branch (the sign of the duty's last motion, :func:`.residuals.branch`): a free curve of the duty on
    each branch, a free loop of the duty, which depends on the duty's history but not on time.

    Beside a model file it is the model's own misfit of the valve's loop (a loop wider, or wider at the
    top, than the model's), which a drift in time must explain beyond (:attr:`Word.drifts`). A creep
    whose time constant is short beside the time between reversals has settled after each of them at a
    fraction of the last step, up after a rise and down after a fall: a level on each branch, as a
    loop's misfit is. A foreign valve's loop, x8 wider at the top, held against the model file beside
    the exact asymmetry and a sensor offset on a chirp (a sine of one amplitude, the same loop each
    cycle) gained 14 % held-out as a creep of 0.019 over 1.8 s beyond a static curve, and nothing beyond
    this loop. A creep's drift in time is what the loop cannot take: its relaxation through each hold,
    and how far it gets between reversals that come faster or slower.
    """
    curve = static_curve(sig)
    return np.hstack([curve, curve * (branch(sig.duty_pct) > 0)[:, None]])


def pi_columns(r: np.ndarray, x_unit: np.ndarray, y0=np.nan) -> np.ndarray:
    """Play operator outputs, Eq. (1), started by Eq. (3) at the first input (``y0`` NaN: at rest there)."""
    Y, _ = play.play_response(r, x_unit, play.init(r, x_unit[0], y0))
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
        Column names: ``gain``, ``offset``, ``loop_width``, ``duty_scale`` and, when asked for, a
        ``memory`` offset per memory epoch (:func:`memory_epochs`) (refitted baseline), then effect
        words.
    fit_ok : ndarray of bool
        Rows the fit may use (rows at the plateau the prediction reaches are left to the clip
        (:meth:`Base.plateau`), shut rows to the floor; all, with :attr:`valve`, whose linearized
        columns leave them there).
    clip_hi : float or None
        Full-open flow (L/min) the prediction is clipped to.
    floor : bool
        No reverse flow: the prediction is clipped at zero (a PI fitted on a recording where the
        valve shuts by itself; its loading curve runs on below zero where the valve closes).
    valve : Valve or None
        The flow at the valve, where a clipped chain with a time response clips it; ``F`` and the
        first ``valve.X.shape[1]`` columns of ``X`` are then that flow linearized at the clip's and
        the floor's active set, seen at the sensor (:func:`build`). ``None``: the clip acts on
        ``F + X theta`` (no time response, or nothing clipped).
    plateau : tuple or None
        With a clip: the rows measured at its plateau that the fit still fits, and the flow (L/min) a
        prediction must reach on each to leave it to the clip (:meth:`Base.plateau`); behind a time
        response also the active set at the valve, ``(held, free)``. A fit (:func:`fit_final`,
        :func:`cross_validate`) leaves to the clip those its own prediction reaches (:func:`censored`).
    """

    F: np.ndarray
    X: np.ndarray
    names: tuple
    fit_ok: np.ndarray
    clip_hi: float | None = None
    floor: bool = False
    valve: "Valve | None" = None
    plateau: "tuple | None" = None

    @property
    def clipped(self) -> bool:
        """Whether the prediction is clipped at either end."""
        return self.clip_hi is not None or self.floor

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """``min(F + X theta, clip_hi)``, at least 0 with the floor, for one ``theta`` (p,) or several
        (p, K) -> (N,) or (N, K); with :attr:`valve`, the flow at the valve clipped so, then through
        the chain's time response, plus the sensor-side columns."""
        if self.valve is None:
            q = (self.F if theta.ndim == 1 else self.F[:, None]) + self.X @ theta
            return clip(q, self.clip_hi, self.floor)
        v = self.valve
        pv = v.X.shape[1]
        q = (v.F if theta.ndim == 1 else v.F[:, None]) + v.X @ theta[:pv]
        return v.dynamics(clip(q, self.clip_hi, self.floor)) + self.X[:, pv:] @ theta[pv:]


@dataclass(frozen=True, eq=False)
class Valve:
    """The flow at the valve of a :class:`Design`: after the dead zone, before the time response.

    Attributes
    ----------
    F : ndarray, shape (N,)
        Fixed part (L/min).
    X : ndarray, shape (N, p_v)
        The design's columns at the valve (its first ``p_v``).
    dynamics : callable
        The chain's time response (delay, lag), on a flow (N,) or several (N, K).
    """

    F: np.ndarray
    X: np.ndarray
    dynamics: object


def clip(q: np.ndarray, clip_hi: float | None, floor: bool) -> np.ndarray:
    """``q`` clipped at the full-open flow ``clip_hi`` and, with ``floor``, at zero flow."""
    if clip_hi is not None:
        q = np.minimum(q, clip_hi)
    return np.maximum(q, 0.0) if floor else q


def undo_gain(chain: dict, rate_hz: float) -> float:
    """RMS gain of white noise through the undoing of ``chain``'s time response (each word's
    :meth:`Word.undo` in reverse order, all linear): the norm of its impulse response."""
    half = int(np.ceil(rate_hz * max([VOCABULARY[w].lateness_s(p, rate_hz) or 0.0 for w, p in chain.items()], default=0.0))) + 8
    h = np.zeros(2 * half + 1)
    h[half] = 1.0
    for w, p in reversed(chain.items()):
        h = VOCABULARY[w].undo(h, rate_hz, p)
    return float(np.sqrt(np.sum(h ** 2)))


def build(base: Base, sig: Signals, chain: dict, memory: bool = False, static: bool = False,
          branches: bool = False) -> Design:
    """Columns of baseline + the effects in ``chain`` on the grid of ``sig``.

    Parameters
    ----------
    base : Base
        The baseline.
    sig : Signals
        Signals on the grid to build on.
    chain : dict
        ``{effect word: {parameter: value}}`` with the nonlinear parameters of each word
        (:data:`models.diagnose.words.VOCABULARY`); linear effects have ``{}``.
    memory : bool
        A refitted baseline also has a free offset per memory epoch (:func:`memory_epochs`), named
        ``memory``: what a slow drift must explain beyond (:meth:`Word.beside_memory`).
    static : bool
        A fixed baseline (a model file) also has a free static curve of the duty
        (:func:`static_curve`), named ``static``: what a drift in time must explain beyond
        (:attr:`Word.drifts`).
    branches : bool
        With ``static``, the curve on each branch of the duty (:func:`loop_curves`): the model's misfit
        of the valve's loop too.
    """
    n = len(sig.t_s)
    F = base.predict(sig, chain)
    loop, lift, slope = base.bends(sig)
    ref = F
    names: list[str] = []
    cols = []
    if base.refit:
        epochs = memory_epochs(sig) if memory else np.zeros((n, 0))
        cols += [F, np.ones(n), loop, slope, *epochs.T]
        names += ["gain", "offset", "loop_width", "duty_scale"] + ["memory"] * epochs.shape[1]
        F = np.zeros(n)
    elif static:
        curve = loop_curves(sig) if branches else static_curve(sig)
        cols += list(curve.T)
        names += ["static"] * curve.shape[1]
    valve_ctx = Columns(sig, ref, lift, slope, supply_ref_bar=base.supply_ref_bar,
                        core_input=core_input(base, sig, chain))
    for w, p in chain.items():
        for col in VOCABULARY[w].valve_columns(valve_ctx, p):
            cols.append(col)
            names.append(w)
    Xv = at_valve(np.column_stack(cols) if cols else np.zeros((n, 0)), sig, chain)
    ref_v = Xv[:, 0] if base.refit else at_valve(ref, sig, chain)
    # an effect at the valve moves no flow where the reference has the valve shut (the floor's
    # active set): a warm coil does not open a closed valve. But a law that moves the plunger before
    # the floor (:attr:`Word.before_floor`: a creep) does, where the valve is not measured shut and
    # the reference runs on below zero flow (a PI fitted on the recording, down its loading curve:
    # how far the valve is from opening); behind a time response every column is linearized at the
    # reference's active set (breaths resting at 30 % with a creep of 0.2: the chain's training
    # error 1.40 x the noise floor with the column on every shut row, 1.10 x zeroed on them, 1.08 x
    # zeroed on those measured shut)
    # the baseline's own columns are not zeroed there: the offset and the memory epochs' offsets are
    # the flow the fitted PI passes on any row (zeroed on shut rows, an epoch's column was a step on
    # the open rows only, near-collinear with the offset and a warm coil's slow rise: cond 2e8, and a
    # coil 34.5 K warm on breaths was missed (plant_sim, seed 10226; found at 34.6 K now))
    first = 4 + epochs.shape[1] if base.refit else 0
    clip_hi = clip_of(chain)
    shut = base.shut(sig)
    floor = bool(shut.any())
    at_set = (clip_hi is not None or floor) and has_dynamics(chain)
    shut_v = ref_v <= 0.0
    for i in range(first, Xv.shape[1]):
        word = VOCABULARY.get(names[i])
        if at_set or not (base.refit and word is not None and word.before_floor):
            Xv[shut_v, i] = 0.0
        else:
            Xv[shut_v & shut, i] = 0.0
    F_v = F if base.refit else ref_v
    if at_set:
        # the valve's full-open stop and its no-reverse-flow floor act on the flow at the valve, and
        # the sensor sees the clipped flow through the delay and lag: a lagged flow rises to the
        # plateau from below and leaves a shut valve from zero, not from where a PI's loading curve
        # runs on below it. Linearized at the reference's active set: rows where the reference reaches
        # the full-open flow hold it, rows where it has the valve closed hold zero (the sensor cannot
        # say which valve rows were shut: it sees a closing valve's flow decay for several time
        # constants), the others are free; every row at the sensor is fitted on the free rows' columns
        # through the time response. The rows held at the plateau are those measured there
        # (:meth:`Base.plateau`, at the valve)
        top, reach = base.plateau(sig, chain)
        held = top & (ref_v >= reach)
        free = ~(held | (floor & (ref_v <= 0.0)))
        valve = Valve(F_v, Xv, lambda v: through_dynamics(v, sig, chain))
        X, F = _at_active_set(valve, free, held, clip_hi)
        ref = through_dynamics(ref_v, sig, chain)
    else:
        valve = None
        X = through_dynamics(Xv, sig, chain)
        # one pass through the dynamics each: with a refitted baseline the reference is the gain
        # column and the fixed part stays zero (zero flow through a dead zone, delay and lag); a
        # fixed baseline's prediction is both the fixed part and the reference
        ref = X[:, 0] if base.refit else through_dynamics(ref_v, sig, chain)
        if not base.refit:
            F = ref
    sensor_ctx = Columns(sig, valve_ctx.flow_lpm, lift, slope, ref, base.supply_ref_bar, valve_ctx.core_input)
    extra = []
    for w, p in chain.items():
        for col in VOCABULARY[w].sensor_columns(sensor_ctx, p):
            extra.append(col)
            names.append(w)
    if extra:
        X = np.hstack([X, np.column_stack(extra)])
    if valve is not None:
        return Design(F, X, tuple(names), np.ones(n, dtype=bool), clip_hi, floor, valve,
                      plateau=(top & free, reach, held, free) if clip_hi is not None else None)
    # a censored row, whose measured flow only bounds the flow the valve would pass, is left to the
    # floor or the clip where the baseline reaches that bound too, and fitted where it does not (unless
    # the chain's own fit reaches it: :func:`censored`)
    top, reach = base.plateau(sig, chain)
    kept = ~(shut & (ref <= 0.0))
    return Design(F, X, tuple(names), kept & ~(top & (ref >= reach)), clip_hi, floor,
                  plateau=(top & kept, reach) if clip_hi is not None else None)


def _at_active_set(valve: Valve, free: np.ndarray, held: np.ndarray, clip_hi: float | None) -> tuple:
    """The columns and the fixed part at the sensor of a design linearized at an active set at the
    valve: ``free`` rows follow its columns, ``held`` rows hold the full-open flow, the others zero."""
    X = valve.dynamics(valve.X * free[:, None])
    F = valve.dynamics(np.where(free, valve.F, np.where(held, clip_hi or 0.0, 0.0)))
    return X, F


def censored(d: Design, y: np.ndarray, rows: np.ndarray) -> Design:
    """``d`` with the plateau rows its own fit reaches left to the clip (one step of a Tobit
    regression, as :func:`censored_fit` does for the PI): fitted on ``rows`` without the plateau, then
    each plateau row the fit so made reaches is left to the clip, as well as those the reference
    reaches.

    A plateau row says only that the valve would pass at least the full-open flow. Fitted where the
    reference falls short of it but the chain with its effects does not, it pulls the effects down as
    if the flow were exactly there: a creep after the paper sweep's reversal at the top, which rises
    under the clip and holds the flow on the plateau after the valve without it has left, was fitted
    too small and too slow (plant_sim, creep 0.12 beside a clip at 140 L/min: 75 s at the end of its
    range, refused, and a coil 3.8 K warm from the first second named in its place; now 0.13, 33 s)."""
    if d.plateau is None or d.X.shape[1] == 0:
        return d
    top, reach = d.plateau[:2]
    fitted = top & d.fit_ok
    if not (fitted & rows).any():
        return d
    fr = rows & d.fit_ok & ~top
    X = d.X[fr]
    theta = solve(X.T @ X, X.T @ (y - d.F)[fr])
    left = np.zeros(len(y), dtype=bool)
    if d.valve is None:
        left[fitted] = d.F[fitted] + d.X[fitted] @ theta >= reach[fitted]
        return replace(d, fit_ok=d.fit_ok & ~left) if left.any() else d
    # behind a time response, at the valve: the rows the fit reaches are held at the full-open flow too
    v = d.valve
    pv = v.X.shape[1]
    left[fitted] = v.F[fitted] + v.X[fitted] @ theta[:pv] >= reach[fitted]
    if not left.any():
        return d
    held, free = d.plateau[2] | left, d.plateau[3] & ~left
    Xs, F = _at_active_set(v, free, held, d.clip_hi)
    return replace(d, F=F, X=np.hstack([Xs, d.X[:, pv:]]), plateau=(top & free, reach, held, free))


def core_input(base: Base, sig: Signals, chain: dict) -> np.ndarray:
    """The hysteresis core's normalized input under ``chain``: the duty the magnetics see
    (:func:`inputs`, a warm coil's effective duty held at the valve's input floor), held to a model
    file's identified range (:meth:`Base.unit_input`)."""
    return base.unit_input(inputs(sig, chain)[0])


def clip_of(chain: dict) -> float | None:
    """The full-open flow the chain clips to, or ``None``."""
    clips = [c for c in (VOCABULARY[w].clip_lpm(p) for w, p in chain.items()) if c is not None]
    return min(clips) if clips else None


def _fit_rows(base: Base, sig: Signals, chain: dict) -> np.ndarray:
    """Rows a PI refitted under ``chain`` may fit on: all but the shut rows where the base has its
    valve closed too (by the base's own prediction at the sensor); behind a time response, less the
    rows whose flow at the sensor carries the clip or the floor at the valve (the PI's operators are
    not clipped). The plateau rows of a saturation are chosen within the PI's own fit
    (:func:`censored_fit`).

    The same rows whether or not a column is fitted jointly with the PI: a test's gain is then its
    column's, not that of a PI fitted on other rows (on breaths resting below the valve's opening,
    two thirds of the rows are shut, and which of them a fit keeps moved the held-out error by 10 %).
    """
    ref_v = at_valve(base.predict(sig, chain), sig, chain)
    ref = through_dynamics(ref_v, sig, chain)
    c = clip_of(chain)
    shut = base.shut(sig)
    ok = ~(shut & (ref <= 0.0))
    if (c is not None or shut.any()) and has_dynamics(chain):
        # the PI's operators run on unclipped through the time response: not the rows whose flow at
        # the sensor still carries, by more than the noise, the valve's clip or floor (the lagged
        # descent from the plateau, the onset from a closed valve)
        clipped = through_dynamics(clip(ref_v, c, bool(shut.any())), sig, chain)
        ok &= np.abs(clipped - ref) <= noise_lpm(sig.flow_lpm)
    return ok


def passed(chain: dict) -> dict:
    """The part of ``chain`` a PI refitted under it passes its operators through on their way to the
    sensor: the words not fitted jointly with it (dead zone, delay, lag), with the exact laws that set
    the duty the magnetics see (a warm coil's), on which a dead zone opens.

    A heating is fitted jointly with the PI (its exact law in the operators' input, its linearized
    column beside them), but its effective duty is also where the plunger cracks: with the dead zone
    on the commanded duty, the refitted PI's operators passed on rows the design had shut (a coil
    40 K warm beside a 43 % cracking duty and a 30 ms lag, all at their true settings: held-out error
    1.64 x the noise, now 1.09 x)."""
    return {w: p for w, p in chain.items()
            if not VOCABULARY[w].joint_with_pi or (VOCABULARY[w].input_side == "duty" and VOCABULARY[w].is_exact(p))}


def at_sensor(v: np.ndarray, sig: Signals, chain: dict) -> np.ndarray:
    """A flow at the valve (or every column of one) as the sensor sees it: dead zone, then
    transport delay and lag."""
    return through_dynamics(at_valve(v, sig, chain), sig, chain)


def at_valve(v: np.ndarray, sig: Signals, chain: dict) -> np.ndarray:
    """A flow (or every column of one) through the chain's dead zone: the flow the valve passes."""
    gain = flow_gain(sig, chain)
    if gain is not None:
        v = v * (gain if v.ndim == 1 else gain[:, None])
    return v


def through_dynamics(v: np.ndarray, sig: Signals, chain: dict) -> np.ndarray:
    """A flow at the valve (N,), or several (N, K), through the chain's transport delay and lag."""
    for w, p in chain.items():
        v = VOCABULARY[w].dynamics(v, sig.rate_hz, p)
    return v


def has_dynamics(chain: dict) -> bool:
    """Whether a word of ``chain`` has a time response (delay, lag)."""
    return any(type(VOCABULARY[w]).dynamics is not Word.dynamics for w in chain)


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


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normal equations ``A x = b`` with a relative ridge (:data:`RIDGE`), one system or a stack.

    Parameters
    ----------
    A : ndarray, shape (p, p) or (K, p, p)
        Gram matrices (symmetric, positive semi-definite).
    b : ndarray, shape (p,) or (K, p)
        Right-hand sides.

    Returns
    -------
    ndarray, shape (p,) or (K, p)
        Solutions, in ``b``'s unit per ``A``'s.
    """
    p = A.shape[-1]
    lam = RIDGE * np.maximum(np.trace(A, axis1=-2, axis2=-1) / p, 1e-12)
    M = A + lam[..., None, None] * np.eye(p)
    try:
        # a stack in one call: a fold's system is a few columns, so scipy's per-call checks cost
        # more than the factorization
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        if M.ndim == 3:  # the systems one by one, each its own way
            return np.stack([solve(a, c) for a, c in zip(A, b)])
        # two columns equal to rounding (a fold's Gram matrix subtracted from the whole leaves a
        # difference of near-equal sums): the minimum-norm solution
        return np.linalg.lstsq(M, b, rcond=1e-12)[0]
    z = np.linalg.solve(L, b[..., None])
    return np.linalg.solve(np.swapaxes(L, -1, -2), z)[..., 0]


def _grams(X: np.ndarray, r: np.ndarray, parts: list, k: int) -> np.ndarray:
    """Gram matrix of ``[X, r]`` over the rows of each fold.

    Parameters
    ----------
    X : ndarray, shape (N, p)
        Free columns (L/min per column unit).
    r : ndarray, shape (N,)
        ``y - F`` (L/min).
    parts : list of (rows, fold)
        Rows (a slice or an index array) and the fold they belong to; a fold's rows may come in
        several parts.
    k : int
        Number of folds.

    Returns
    -------
    ndarray, shape (k, p + 1, p + 1)
        ``[X, r]^T [X, r]`` per fold (L/min squared per column unit squared).
    """
    p = X.shape[1]
    G = np.zeros((k, p + 1, p + 1))
    for rows, j in parts:
        # three BLAS products on the part's rows (one BLAS thread, as the CLI runs): stacking
        # [X, r] first cost a copy of the design, and einsum's loops were three times slower
        Xb, rb = X[rows], r[rows]
        xr = Xb.T @ rb
        G[j, :p, :p] += Xb.T @ Xb
        G[j, :p, p] += xr
        G[j, p, :p] += xr
        G[j, p, p] += rb @ rb
    return G


def cross_validate(design: Design, y: np.ndarray, folds: Folds, skip: np.ndarray | None = None) -> CVResult:
    """Fit on all folds but one (least squares), predict every fold; for each left-out fold.

    Each fold's normal equations are sums over its blocks, each a contiguous run of rows (no
    gather). Without a clip the squared errors follow from them too
    (``e^T e = c - 2 theta^T b + theta^T A theta``), so no prediction is formed. Rows in ``skip``
    are neither fitted nor scored.
    """
    K = folds.k
    blocks = folds.cv_blocks()
    design = censored(design, y, folds.train if skip is None else folds.train & ~skip)
    X = design.X
    p = X.shape[1]
    r = y - design.F
    # the normal equations and the squared residual together; the rows a fit may not use (guards,
    # clipped rows) are few, so their Gram matrix is subtracted rather than the fitted rows' formed anew
    G = _grams(X, r, blocks, K)
    if skip is not None:
        gone = np.flatnonzero((folds.fold >= 0) & skip)
        G = G - _grams(X, r, [(gone[folds.fold[gone] == j], j) for j in range(K)], K)
    out = np.flatnonzero((folds.fold >= 0) & ~(folds.fit_ok & design.fit_ok) & (True if skip is None else ~skip))
    Gw = G - _grams(X, r, [(out[folds.fold[out] == j], j) for j in range(K)], K)
    if p:
        A, b = Gw[:, :p, :p], Gw[:, :p, p]
        At, bt = A.sum(axis=0), b.sum(axis=0)
        theta = solve(At - A, bt - b).T
    else:
        theta = np.zeros((0, K))
    if not design.clipped:
        Aa, ba, ca = G[:, :p, :p], G[:, :p, p], G[:, p, p]
        # sse[k, j] for theta_k on fold j
        sse = ca[None, :] - 2.0 * (theta.T @ ba.T) + np.einsum("pk,jpq,qk->kj", theta, Aa, theta)
    elif design.valve is None:
        sse = np.zeros((K, K))
        for rows, j in blocks:
            q = clip(design.F[rows, None] + X[rows] @ theta, design.clip_hi, design.floor)
            e2 = (q - y[rows, None]) ** 2
            sse[:, j] += (e2 if skip is None else e2[~skip[rows]]).sum(axis=0)
    else:  # every fold's model through the time response at once, over the whole recording
        e2 = (design.predict(theta) - y[:, None]) ** 2
        if skip is not None:
            e2[skip] = 0.0
        sse = np.zeros((K, K))
        for rows, j in blocks:
            sse[:, j] += e2[rows].sum(axis=0)
    return CVResult(sse, folds.cv_rows())


def fit_final(design: Design, y: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Least-squares ``theta`` on ``rows`` (the rows the design may fit on)."""
    design = censored(design, y, rows)
    fr = rows & design.fit_ok
    if design.X.shape[1] == 0:
        return np.zeros(0)
    X = design.X[fr]
    return solve(X.T @ X, X.T @ (y - design.F)[fr])


def fit_baseline(sig: Signals, folds: Folds, n: int = BASELINE_N) -> Base:
    """The paper's symmetric PI (Eq. 2-4, ``n`` operators, constrained) fitted on the training rows only,
    but those where the valve is shut by itself (:meth:`Base.shut`: left to the no-reverse-flow floor).

    Where the valve shuts by itself, the PI may hold its input at a seat duty and the flow close
    below it along a line of its own (:func:`seat_duties`, :attr:`Base.seat`): the seat duty of
    those tried whose fit leaves the least training error, or none."""
    shut = shut_rows(sig.flow_lpm)
    best = _seated_fit(sig, folds, n, shut, None)
    seats = seat_duties(sig, shut)
    noise = noise_lpm(sig.flow_lpm)
    unseated = best
    for h in seats:
        fit = _seated_fit(sig, folds, n, shut, h)
        if fit[0] < best[0] and _closes_where_it_opens(fit, seats, noise):
            best = fit
    # the seat is placed from the rows the duty crosses on its way up from shut (a breath's rise): a
    # recording that dwells below it with the valve open (a sweep turning back there, holds between
    # a cracking duty and the seat) shows there what a static line would flatten (a coil 30 K warm on
    # the paper sweep, 5 % of its rows open below a seat at 44 %, read as a clip); a seat moved down
    # to leave them out mimics a cracking duty just below it
    if best[4] is not None and np.sum(folds.train & ~shut & (sig.duty_pct < best[4][0])) > SEAT_TRANSIT * np.sum(folds.train):
        best = unseated
    _, core, xs, ys, seat, rows = best
    model = FittedModel("pi", core, xs, ys, meta={"source": "fitted on the training rows", "n": n,
                                                  **({"seat_pct": seat[0], "seat_gain_lpm_per_pct": seat[1]}
                                                     if seat else {})})
    held = sig.duty_pct if seat is None else np.maximum(sig.duty_pct, seat[0])
    y_pi = ys.to_unit(sig.flow_lpm - (0.0 if seat is None else seat[1] * seat_line(sig.duty_pct, seat[0])))
    return Base(True, model, core, xs, density(core, xs, sig, y_pi, rows, held), seat=seat)


#: Seat duties tried: this many, evenly from the duty where the valve opens from shut
#: (:func:`seat_duties`) up to :data:`SEAT_SPAN` of the way to the highest duty.
SEAT_POINTS = 12
SEAT_SPAN = 0.15
#: Steepest line a valve closes along below its seat, in multiples of its PI's mean gain (flow
#: range over duty range): a valve that opens with a jump (a cracking duty) is no seat.
SEAT_GAIN_MAX = 1.25
#: Most training rows open below a seat, as a share of all: the rows a duty crosses in transit.
SEAT_TRANSIT = 0.01
#: Fewest open rows below the seat for a refit to refit the line (else it keeps the baseline's).
MIN_SEAT_ROWS = 5


def seat_line(duty_pct: np.ndarray, seat_pct: float) -> np.ndarray:
    """The line (%, at most zero) a valve closes along below its seat duty: ``min(duty - seat, 0)``."""
    return np.minimum(duty_pct - seat_pct, 0.0)


def seat_duties(sig: Signals, shut: np.ndarray) -> np.ndarray:
    """Seat duties to try (%): none unless the valve shuts by itself on some rows; else
    :data:`SEAT_POINTS` from the duty that best splits the rows into shut below it and open above
    it, up :data:`SEAT_SPAN` of the way to the highest duty."""
    if not shut.any() or shut.all():
        return np.zeros(0)
    order = np.argsort(sig.duty_pct, kind="stable")
    xs, opened = sig.duty_pct[order], ~shut[order]
    wrong = np.cumsum(opened) + (np.sum(~opened) - np.cumsum(~opened))
    lo = float(xs[int(np.argmin(wrong))])
    hi = float(xs[-1])
    return np.linspace(lo, lo + SEAT_SPAN * (hi - lo), SEAT_POINTS)


def _closes_where_it_opens(fit: tuple, seats: np.ndarray, noise: float) -> bool:
    """Whether the line of a seated fit (:func:`_seated_fit`) comes to zero flow where the recording's
    valve opens from shut (``seats[0]``), within what the noise and the seat grid's step blur: a
    valve that opens with a jump (a cracking duty) is fitted by no line that does (its line runs on
    down through the shut rows below the jump)."""
    _, core, xs, ys, (h, g), _ = fit
    if g <= 0.0:
        return False
    bottom = float(ys.from_unit(core.w @ (core.r - 1.0) + core.offset))  # at the seat, after a descent to it
    zero = h - bottom / g
    step = float(seats[1] - seats[0]) if len(seats) > 1 else 0.0
    return seats[0] - zero <= SHUT_NOISE * noise / g + step


def _seated_fit(sig: Signals, folds: Folds, n: int, shut: np.ndarray, seat_pct: float | None) -> tuple:
    """The baseline PI with its input held at ``seat_pct`` (None: not held) and the line below it
    fitted jointly: ``(training squared error, core, duty scaling, flow scaling, seat, rows)``."""
    x = sig.duty_pct if seat_pct is None else np.maximum(sig.duty_pct, seat_pct)
    xs = Scaling.from_data(x)
    ys = Scaling.from_data(sig.flow_lpm[folds.train])
    x_unit, y_unit = xs.to_unit(x), ys.to_unit(sig.flow_lpm)
    r = thresholds(n, x_max=float(np.max(np.abs(x_unit))))
    Y = pi_columns(r, x_unit)
    line = np.zeros((len(x), 0)) if seat_pct is None else seat_line(sig.duty_pct, seat_pct)[:, None] / ys.half_range
    g_max = SEAT_GAIN_MAX * ys.half_range / xs.half_range

    def fit(rows):
        w, offset, c = fit_weights(Y[rows], y_unit[rows], extra=line[rows])
        g = float(c[0]) if line.shape[1] else 0.0
        if not 0.0 <= g <= g_max:  # held at the nearest physical slope
            g = min(max(g, 0.0), g_max)
            w, offset, _ = fit_weights(Y[rows], y_unit[rows] - g * line[rows, 0])
        return w, offset, g

    rows = folds.train & ~shut
    w, offset, g = fit(rows)
    q = Y @ w + offset + (g * line[:, 0] if line.shape[1] else 0.0)
    if shut.any():  # refitted with the shut rows where it has the valve open (censored rows)
        rows = folds.train & ~(shut & (q <= ys.to_unit(0.0)))
        w, offset, g = fit(rows)
        q = Y @ w + offset + (g * line[:, 0] if line.shape[1] else 0.0)
    pred = clip(ys.from_unit(q), None, bool(shut.any()))
    e = (sig.flow_lpm - pred)[folds.train]
    seat = None if seat_pct is None else (float(seat_pct), g)
    return float(e @ e), PIModel(r, w, offset), xs, ys, seat, rows


def censored_fit(Y: np.ndarray, y_unit: np.ndarray, H: np.ndarray, rows: np.ndarray, shut: np.ndarray,
                 zero_unit: float, open_rows: SlopeRows | None = None, plateau: np.ndarray | None = None,
                 reach_unit: np.ndarray | None = None, step_ridge: "float | np.ndarray" = 0.0) -> tuple:
    """:func:`models.pi.fit_weights` on ``rows`` where a valve shut by itself is censored at zero flow,
    and one at the plateau of a saturation at the full-open flow.

    A shut row only says that the flow the valve would pass is at most zero, a plateau row that it
    is at least the full-open flow: fitted first without them, then again with the shut rows where
    that fit has the valve open and the plateau rows where it falls short of the full-open flow
    (one step of a Tobit regression), so the loading curve may run on below zero where the valve
    closes and above the full-open flow where the valve is clipped.

    Parameters
    ----------
    Y : ndarray, shape (N, m)
        Play operator outputs (normalized input units).
    y_unit : ndarray, shape (N,)
        Measured flow, normalized.
    H : ndarray, shape (N, p)
        Columns fitted jointly (normalized output per column unit).
    rows, shut : ndarray of bool, shape (N,)
        Rows to fit on; rows where the valve is shut by itself.
    zero_unit : float
        Zero flow, normalized.
    open_rows : SlopeRows, optional
        ``SlopeRows.of(Y[rows & ~shut & ~plateau])`` when already formed (:meth:`Base.slope_rows`).
    plateau : ndarray of bool, shape (N,), optional
        Rows whose measured flow is at the full-open flow (:meth:`Base.plateau`).
    reach_unit : ndarray, shape (N,), optional
        With ``plateau``: the flow (normalized) the first fit must reach on a plateau row for it to
        be left to the clip (:meth:`Base.plateau`).
    step_ridge : float or ndarray
        A ridge on the steps of the loading-curve slope, one for all or one per operator with a
        threshold (:func:`models.pi.fit_weights_on`).
    """
    censored = shut if plateau is None else shut | plateau
    fr = rows & ~censored
    parts = [(open_rows or SlopeRows.of(Y[fr]), y_unit[fr], H[fr])]
    w, offset, coef = fit_weights_on(parts, step_ridge=step_ridge)
    back = rows & censored
    if not back.any():
        return w, offset, coef
    q = Y[back] @ w + offset + H[back] @ coef
    back[back] = np.where(shut[back], q > zero_unit, q < (np.inf if reach_unit is None else reach_unit[back]))
    if back.any():
        parts.append((SlopeRows.of(Y[back]), y_unit[back], H[back]))
        w, offset, coef = fit_weights_on(parts, step_ridge=step_ridge)
    return w, offset, coef


def density(shape: PIModel, xs: Scaling, sig: Signals, y_unit: np.ndarray, rows: np.ndarray,
            duty_pct: np.ndarray | None = None) -> np.ndarray:
    """Non-negative play-operator weights over ``shape``'s thresholds fitted to ``y_unit`` on ``rows``
    (driven by ``duty_pct``, default the recording's duty)."""
    Y = pi_columns(shape.r, xs.to_unit(sig.duty_pct if duty_pct is None else duty_pct), shape.y0)
    return fit_weights(Y[rows], y_unit[rows], nonnegative=True)[0]


def fixed_base(model: FittedModel, sig: Signals) -> Base:
    """A model file as the fixed baseline; its loop shape from its own PI (of at most
    :data:`SHAPE_MAX_OPERATORS` operators), or a PI fitted to its prediction."""
    core = model.core
    y_model = model.y_scale.to_unit(model.predict(sig.duty_pct)[0])
    every = np.ones(len(sig), dtype=bool)  # the model's own prediction: no measurement is fitted
    if isinstance(core, PIModel) and len(core.r) <= SHAPE_MAX_OPERATORS:
        return Base(False, model, core, model.x_scale, density(core, model.x_scale, sig, y_model, every))
    xs = Scaling.from_data(sig.duty_pct)
    shape = fit_pi(xs.to_unit(sig.duty_pct), y_model, n=BASELINE_N)
    return Base(False, model, shape, xs, density(shape, xs, sig, y_model, every))


def flow_gain(sig: Signals, chain: dict) -> np.ndarray | None:
    """Pointwise factor on the whole flow at the valve (a dead zone's open mask, on the duty the
    magnetics see under ``chain``); ``None``: 1."""
    g, x = None, inputs(sig, chain)[0]
    for w, p in chain.items():
        f = VOCABULARY[w].flow_gain(sig, p, x)
        if f is not None:
            g = f if g is None else g * f
    return g


def is_open(sig: Signals, chain: dict) -> np.ndarray | bool:
    """Rows where the chain lets flow through (all when it has no dead zone)."""
    g = flow_gain(sig, chain)
    return True if g is None else g > 0.5


def clip_share(Y: np.ndarray, kept: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Share (0..1) of each play operator's movement (the sum of its output's changes into each row,
    ``Y`` of shape (N, m)) that falls on the rows ``left`` rather than on the rows ``kept`` (0 for an
    operator that moves on neither)."""
    dY = np.abs(np.diff(Y, axis=0, prepend=Y[:1]))
    a, b = dY[left].sum(axis=0), dY[kept].sum(axis=0)
    return np.where(a + b > 0, a / np.maximum(a + b, 1e-300), 0.0)


def unbend(base: Base, sig: Signals, chain: dict, rows: np.ndarray, untold: bool = False) -> Base:
    """The baseline PI with its weights refitted under ``chain``: on the chain's effective duty
    with its descending thresholds lifted, through its dead zone, delay and lag, jointly with the
    columns of the words a PI absorbs (``joint_with_pi``), without the rows a dead zone shuts or
    a saturation clips.

    Coil heating lowers the current the magnetics see along the thermal history;
    a PI fitted through it bends its weights to absorb what it can on average,
    and a heating column on top of that bent PI only sees what is left. The
    exact law refits the PI on the effective duty; the linearized column is
    fitted jointly with the PI's play operator outputs (Eq. 1, 4) and its
    offset, one least-squares problem on the training ``rows``, with the
    paper's constraint (every loading-curve slope positive): refitted freely,
    the weights of the wide operators, which rare excursions alone move,
    extrapolate wildly on held-out levels.
    Returns ``base`` itself for a model file (held fixed).

    ``untold``: the refit the holdout check judges (:class:`models.diagnose._ChainFits`): under a
    saturation, the steps of the operators that mostly the clipped rows move are also held near zero
    (:data:`CLIP_STEP_RIDGE`).
    """
    if not base.refit:
        return base
    if any(VOCABULARY[w].joint_with_pi and not VOCABULARY[w].is_exact(p) for w, p in chain.items()):
        d = build(base, sig, chain)
        joint = [i for i, w in enumerate(d.names) if w in chain and VOCABULARY[w].joint_with_pi]
        H = d.X[:, joint]
        if d.valve is not None:  # the PI's operators are not clipped at the valve: nor are its columns
            pv = d.valve.X.shape[1]
            H = np.column_stack([d.valve.dynamics(d.valve.X[:, i]) if i < pv else d.X[:, i] for i in joint])
    else:  # the exact laws are in the operators: no column to fit jointly
        H = np.zeros((len(sig), 0))
    fit_ok = _fit_rows(base, sig, chain)
    # the shut rows of a dead zone say nothing of the PI
    fr = rows & fit_ok & is_open(sig, chain)
    m = base.model
    ys = m.y_scale
    Y = base.regressors_at_sensor(sig, chain)
    y_unit = ys.to_unit(sig.flow_lpm)
    shut, (top, reach) = base.shut(sig), base.plateau(sig, chain, valve=False)
    H = H / ys.half_range
    rest = passed(chain)
    if flow_gain(sig, rest) is not None and has_dynamics(rest):
        # the PI's constant passes the dead zone and the time response as its operators do: a valve
        # opening from shut rises from zero flow along the lag, not from the constant. Its share at the
        # sensor less one (zero on the rows the valve has long been open), fitted jointly: its
        # coefficient is the constant's distance from zero flow (a fixed offset column left the
        # openings misfit by the whole flow there, and the PI bent to take that up held a 42.8 % cracking
        # duty behind a 48 ms lag, at their true settings, at 7.5 x the noise; now 1.07 x, as the model
        # file does)
        H = np.column_stack([H, at_sensor(np.ones(len(sig)), sig, rest) - 1.0])
    seat = base.root.seat
    floor = input_floor(chain)[0]
    if floor is not None and floor > float(np.min(sig.duty_pct)) + 1e-6 and (seat is None or floor > seat[0]):
        # a warm coil's valve held at an input floor above the lowest commanded duty, which a cold coil's
        # duty reaches, is seated there on the duty the magnetics see: below it the flow closes along a
        # line as a seated baseline's does (without it, the flow held at the floor's: plant_sim's valve,
        # seated at 38 %, 31 K warm on random holds down to 34 %, fitted at its true heating 7 x the
        # noise). A floor no cold duty reaches holds the warm coil's input only, the flow there as at the
        # floor. A baseline's seat above the floor holds the input first; one below it was placed on the
        # commanded duty under the warm coil (a creep beside that heating: a seat at 36 %, and the line
        # from there ran through the held rows)
        seat = (floor, 0.0 if seat is None else seat[1])
    line = None
    if seat is not None:
        # the line below the seat, refitted with the PI on the duty the magnetics see (where the rows
        # the fit may use reach below the seat; else kept)
        line = at_sensor(seat_line(seated_input(sig, chain), seat[0]), sig, rest)
        if np.count_nonzero(line[fr & ~shut]) >= MIN_SEAT_ROWS:
            H = np.column_stack([H, line / ys.half_range])
        else:
            line = None
    # the slope's steps held near zero where the rows do not tell them: operators that move together, or
    # only once, on the rows a refit has (the widest of a PI refitted under a warm coil's effective
    # duty, which the training rows kept near their thresholds, were weighted +-4000 against an offset
    # of 72: 5700 L/min on a held-out breath rising 0.4 % higher)
    ridge = STEP_RIDGE * int(fr.sum())
    if untold and (fr & top).any():
        # the steps of the operators only the rows left to the clip move (the held-out breaths that first
        # reach a new top set a memory of them no training row shows): held near zero too
        ridge = ridge + CLIP_STEP_RIDGE * int(fr.sum()) * clip_share(Y, fr & ~shut & ~top, rows & top)[1:] ** 2
    w, offset, coef = censored_fit(Y, y_unit, H, fr, shut, float(ys.to_unit(0.0)),
                                   base.slope_rows(sig, chain, fr & ~shut & ~top), top, ys.to_unit(reach), ridge)
    if line is not None:
        seat = (seat[0], float(np.clip(coef[-1], 0.0, SEAT_GAIN_MAX * ys.half_range / m.x_scale.half_range)))
    core = PIModel(base.shape.r, w, offset, base.shape.y0)
    model = FittedModel("pi", core, m.x_scale, ys, meta={**m.meta, "refitted": f"under {', '.join(chain) or 'nothing'}"})
    return Base(True, model, core, m.x_scale, base.lift_w, parent=base.root, seat=seat)
