"""The vocabulary of the diagnosis: one object per effect word of DESIGN.md.

Each object carries everything the diagnosis knows of its word: the law (in
:mod:`.effects`), the linearized columns it screens with and where in the
chain they enter, the grid of its nonlinear parameters, its exact nonlinear
law and the bounds its physical parameters are refined within, the
parameters it reports with their units, their plausible ranges, and whether
the excitation can show it at all. :mod:`.design` builds the augmented model,
:mod:`.detectors` searches and confirms, and :mod:`.report` draws, by
iterating over :data:`VOCABULARY`: adding a word is one new object here.

The augmented model chains the words around the hysteresis core::

    duty -> coil heating (effective duty) -> hysteresis (asymmetric branch)
         -> dead zone (on the effective duty) -> supply pressure gain -> transport delay, lag
         -> creep -> saturation -> + sensor offset
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import effects as fx
from .residuals import branch
from . import signals
from .signals import Signals


@dataclass(frozen=True)
class Columns:
    """What a word's columns are built from (all on one sample grid, L/min).

    Attributes
    ----------
    sig : Signals
        The signals.
    flow_lpm : ndarray
        The baseline's prediction at the valve (before dead zone, dynamics and sensor).
    lift_lpm : ndarray
        Descending-threshold lift column of the baseline (:func:`effects.descending_lift`).
    slope_lpm : ndarray
        ``x dq/dx`` of the baseline along the input history.
    at_sensor_lpm : ndarray
        ``flow_lpm`` through the dead zone, delay and lag of the chain (for sensor-side columns).
    supply_ref_bar : float, optional
        The supply (bar gauge) the baseline's flow is at: a model file's identification supply, if it
        records one (:attr:`.design.Base.supply_ref_bar`).
    core_input : ndarray, optional
        The hysteresis core's normalized input under the chain: the duty the magnetics see (a warm
        coil's effective duty, held at the valve's input floor), held to a model file's identified
        range (:meth:`.design.Base.unit_input`).
    """

    sig: Signals
    flow_lpm: np.ndarray
    lift_lpm: np.ndarray
    slope_lpm: np.ndarray
    at_sensor_lpm: np.ndarray | None = None
    supply_ref_bar: float | None = None
    core_input: np.ndarray | None = None


@dataclass(frozen=True)
class Word:
    """One effect word: its law, columns, grid, refinement, parameters, plausibility, visibility.

    Attributes
    ----------
    word : str
        The DESIGN.md effect word.
    physics : str
        One line: the law modelled.
    units : dict
        Reported parameter -> unit.
    plausible : dict
        Reported parameter -> (lo, hi) physically plausible range.
    joint_with_pi : bool
        A PI fitted with the effect present bends its weights to absorb it, so the word's test
        refits the weights jointly with it (:func:`models.diagnose.design.unbend`).
    static : bool
        A static nonlinearity at a range end: the baseline is refitted without the rows it explains.
    unresolved : tuple or None
        ``(parameter, "low" | "high")``: the end of its search range where the law cannot be told
        from a static one.
    whole_plot : bool
        The finding's plot shows the whole recording (slow effects) rather than around its peak.
    probe : dict
        A plausible size of the effect (its nonlinear parameters) used to say whether the
        excitation can show it at all; empty: not probed.
    ratio_of : dict
        Exact-law parameter -> the parameter it is refined as a ratio to (see
        :func:`models.diagnose.detectors.refine`).
    input_side : str or None
        What the exact law changes at the hysteresis core's input: ``"duty"`` (the effective
        duty, :meth:`effective_duty`) or ``"thresholds"`` (:meth:`threshold_widening`).
    resolution : dict
        Screened parameter -> the step (in its unit) to which the refinement places it between its
        grid neighbours, on a linear scale (else 2 % of a positive parameter, on a log scale: a
        time constant).
    settled_ends : tuple
        Exact-law parameters whose box ends are settings of the law itself (a valve's input floor
        at the lowest commanded duty, or below every effective duty), not a refinement that ran off
        its range (:func:`models.diagnose.detectors._inside`); ``(name, "low")``: its lower end only
        (an asymmetry's widening in proportion at its least, all of the extra width in the lift).
    shifts_level : bool
        Its column moves the flow's level along the whole recording, as the size and time constant
        of an input-side exact law do (a heating lowers the flow more the warmer the coil): tested
        with those laws refined jointly with it (:func:`models.diagnose.detectors.test_effect`).
    before_floor : bool
        Its valve columns move the plunger before the no-reverse-flow floor: they open a valve the
        reference has shut (a PI fitted on the recording, running on below zero flow), but not one
        measured shut (:func:`models.diagnose.design.build`).
    drifts : bool
        Its law is a drift in time that follows the duty's reversals (a creep): held against a model
        file it must explain the recording beyond a free curve of the duty on each branch, the model's
        own misfit of the valve's loading curve and loop (:attr:`beyond_loop`):
        settled after each reversal, a creep is a level on each branch, as a loop's misfit is. Not a coil
        warming: its drift is a gain over the whole duty range, which the curve takes up in part (a coil
        24 K warm beside a clip at 125 L/min against the model file, held-out 1470, was refused by it
        while the clip was not yet named, and dropped). Its slow drift is also what a coil's warming
        named before it takes up in its size and time constant: it is tested with the chain's exact
        laws on the duty refined jointly with it, as a word that :attr:`shifts_level` is
        (:func:`models.diagnose.detectors.test_effect`).
    beyond_loop : bool
        Held against a model file, its law must explain the recording beyond a free curve of the duty
        on each branch (:func:`models.diagnose.design.loop_curves`): the model's own misfit of the
        valve's loading curve and loop, a function of the duty's history alone, which its law can take
        up in part (:func:`models.diagnose.detectors._static_misfit`). A creep (:attr:`drifts`) settles
        after each reversal at a level on each branch. A lag or a delay moves the flow by about
        ``-lateness dq/dt``: on a ramp, a level on each branch too (dq/dt has the branch's sign), so a loop
        a little wider or narrower than the model's is read as a lateness (a foreign valve, effect free,
        on triangles against its model file, misfit 3.9 x the noise: a lag of 30 ms gaining 4.3 %
        held-out, margin 3 %). A time response's own signature is what the loop cannot take: it scales
        with the duty's rate of change, ramp by ramp, is zero on holds and relaxes into them.
    beyond_curve : bool
        Held against a model file, its law must explain the recording beyond a free static curve of the
        duty (:func:`models.diagnose.design.static_curve`, a constant included), on the final chain
        (:func:`models.diagnose.detectors._static_after_search`): a coil warm from the first row whose
        temperature the duty's mean holds is a scale of the duty, a static misfit of the loading curve. A
        sensor offset of -1.0 L/min on a chirp that a foreign valve's model file misses by 1.26 L/min RMS
        is not identifiable (:func:`models.diagnose.detectors._level_within_misfit`); left out of the
        chain, its constant was named a coil 0.9 K warm from the start. A warming's drift from a cold start is what
        the curve cannot take.
    beyond_symmetric : bool
        Held against a model file, its law must also explain the recording beside the paper's PI fitted
        on it (:func:`models.diagnose.detectors._symmetric_misfit`), on the final chain: that PI is
        symmetric by construction (Eq. 1-4), so it shows a valve's asymmetric loop as the model file
        does, and takes up what the file merely misses of a symmetric loop. A foreign valve's loop held
        against a PI fitted on its staircase was named an asymmetry (lift 0.4-1.3 % duty) on triangles
        and chirps with no asymmetry in it, each gaining at most 0.1 % beside the PI fitted on the
        recording, where a true one (x3-9) gains 27-91 %.
    residual_support : bool
        Its support reads the residual where its correction is largest (:func:`explained_where_largest`):
        a named law mis-sized beside it leaves its own misfit there and refutes it, so a refusal is
        read again with the named laws refined beside it (:func:`models.diagnose.detectors._beside_resized`).
    """

    word: str
    physics: str
    units: dict
    plausible: dict
    joint_with_pi: bool = False
    static: bool = False
    unresolved: tuple | None = None
    whole_plot: bool = False
    probe: dict = field(default_factory=dict)
    input_side: str | None = None
    ratio_of: dict = field(default_factory=dict)
    resolution: dict = field(default_factory=dict)
    settled_ends: tuple = ()
    shifts_level: bool = False
    before_floor: bool = False
    drifts: bool = False
    beyond_loop: bool = False
    beyond_curve: bool = False
    beyond_symmetric: bool = False
    residual_support: bool = False

    # -- search --
    def grid(self, sig: Signals, base) -> dict:
        """``{parameter: values}`` of the nonlinear parameters screened (empty: linear only)."""
        return {}

    def placed(self, sig: Signals, chain: dict) -> list:
        """Settings of the nonlinear parameters the recording itself places (``chain``: the named
        words it joins), screened with the grid; empty by default."""
        return []

    def sized(self, sig: Signals, base, chain: dict) -> list:
        """Settings of the exact law at gross sizes, screened beside the linearized columns (``base``:
        the PI the screen refits, ``chain``: the named words it joins), where a first-order column
        under-explains a large effect and the screen would not pick or size the word; empty by default."""
        return []

    def applicable(self, sig: Signals, base) -> str | None:
        """``None``, or why the word cannot be tested on this recording with this baseline."""
        return None

    def recorded(self, sig: Signals) -> bool:
        """Whether a state the recording measures drives the law, linear in it (no nonlinear
        parameter): it is then in place, as a nuisance, where another word's screened parameters are
        refined on its acceptance (:func:`models.diagnose.detectors.beside_recorded`)."""
        return False

    def exact_starts(self, params: dict, coef: float, sig: Signals, base, chain: dict) -> list:
        """Starts of the exact law's refinement from a screen (its grid point and column
        coefficient) joining the named words of ``chain``; empty when the linearized law is the law."""
        return []

    def basin(self, params: dict):
        """Which of the exact law's valleys a start of its refinement lies in (hashable): the best start
        of each is refined (:func:`models.diagnose.detectors._multistart`), as of each setting of the
        parameters the refinement keeps fixed; ``None`` by default: one valley."""
        return None

    def between(self, params: dict, starts: list) -> list:
        """Starts of valleys (:meth:`basin`) halfway between the one ``params`` was refined in and its
        neighbours among ``starts``, to refine when the recording refutes it; empty by default."""
        return []

    def restarts(self, sig: Signals, base) -> list:
        """Starts of the exact law's refinement over its whole range, independent of a screen, from
        which it is refined again once the other words are named (:func:`models.diagnose.detectors._backfit`);
        empty: refined from where it was named."""
        return []

    def readings(self, params: dict, sig: Signals, base, chain: dict) -> list:
        """Other readings of the exact law at ``params`` of the same size (``base``: the search's
        reference, whose PI was fitted without it; ``chain``: the laws beside it), each ``(params, held)`` with ``held`` the
        parameters it keeps at their setting, from which it is refined once more jointly with the
        other law on the valve's input (:func:`models.diagnose.detectors._joint_restart`); empty by
        default."""
        return []

    def bounds(self, sig: Signals, base) -> dict:
        """``{parameter: (lo, hi)}`` of the exact law's parameters refined by least squares (log scale)."""
        return {}

    def is_exact(self, params: dict) -> bool:
        """Whether ``params`` select the exact nonlinear law (else the linearized columns)."""
        return False

    def at_rest(self, sig: Signals, params: dict, base) -> dict | None:
        """The setting of the law that acts only where the valve rests shut by itself at the
        recording's lowest duty (``base.shut``: none for a model file), or only as the valve's own seat
        does (a heating's input floor with the coil cold), or ``None`` (the law does not act there, or
        the valve is open at its rest): ``params`` must explain more than it
        (:func:`models.diagnose.detectors._beyond_rest`)."""
        return None

    def settle(self, sig: Signals, params: dict, chain: dict) -> dict:
        """``params`` moved to where the recording itself places them among settings the fit cannot
        tell apart (``chain``: the named words it joins); ``params`` by default."""
        return params

    def midway(self, sig: Signals, params: dict, chain: dict, rows: np.ndarray) -> dict:
        """``params`` moved to the middle of the settings that treat the training ``rows`` alike
        beside ``chain`` (a threshold between two rows), which their error cannot tell apart;
        ``params`` by default (a law whose error places it)."""
        return params

    def undecided(self, sig: Signals, params: dict, chain: dict, rows: np.ndarray, at: Signals) -> np.ndarray | None:
        """Rows of the signals ``at`` that the settings the training ``rows`` of ``sig`` cannot tell
        apart beside ``chain`` (:meth:`midway`) treat differently: neither evidence for the law nor
        against it. ``None`` by default (a law whose error places it)."""
        return None

    def carried(self, sig: Signals, params: dict, chain: dict) -> dict:
        """``params`` moved along with the duty the magnetics see under ``chain`` (its input-side law
        refined or named beside them): where the recording places them on that duty; ``params`` by
        default (a law that does not read it)."""
        return params

    def choices(self, params: dict, sig: Signals, chain: dict) -> list:
        """Other settings of what the refinement keeps fixed, distinct beside ``chain`` (the named words
        the law joins), each refined and compared with ``params`` once the other words are named
        (:func:`models.diagnose.detectors._refined_beside`); empty by default."""
        return []

    def floor(self, params: dict) -> tuple:
        """``(floor_pct, params without it)``: the duty (%) below which the law holds the hysteresis
        core's input (a seat on the duty the magnetics see, :func:`models.diagnose.design.unbend`),
        ``None`` and ``params`` (default) when it holds none."""
        return None, params

    def smoothed(self, sig: Signals, params: dict) -> dict:
        """``params`` with the law's hard edge smoothed, for the search of a law on the duty the
        magnetics see beside it (:func:`models.diagnose.detectors.smoothed`); ``params`` itself when
        it has none."""
        return params

    def held(self, sig: Signals, params: dict, base) -> tuple | None:
        """``(rest, rows)``: the rows a part of the law fitted to the recording holds at a setting of
        its own (a valve's input floor) and ``params`` without that part, which must fit those rows
        better than ``rest`` (:func:`models.diagnose.detectors._holds`); ``None`` (default): no such
        part."""
        return None

    # -- the law in the chain --
    def effective_duty(self, sig: Signals, params: dict) -> np.ndarray | None:
        """The duty the magnetics see under this word (input-side words), or ``None``."""
        return None

    def threshold_widening(self, params: dict) -> tuple:
        """``(widen, lift, start)`` of the descending thresholds: their widening at the top of the
        range and where in it the widening starts (exact asymmetry, :func:`effects.generalized_play`)."""
        return 0.0, 0.0, 0.0

    def valve_columns(self, ctx: Columns, params: dict) -> list:
        """Linear columns at the valve, before the dead zone and the dynamics."""
        return []

    def flow_gain(self, sig: Signals, params: dict, duty_pct: np.ndarray) -> np.ndarray | None:
        """Pointwise factor on the whole flow at the valve, or ``None`` (``duty_pct``: the duty the
        magnetics see, :func:`magnetic_duty`)."""
        return None

    def dynamics(self, v: np.ndarray, rate_hz: float, params: dict) -> np.ndarray:
        """The flow (or every column) through the word's time response."""
        return v

    def undo(self, y: np.ndarray, rate_hz: float, params: dict) -> np.ndarray:
        """The flow before the word's time response, recovered from the flow after it (the inverse
        of :meth:`dynamics`; noisier than its input)."""
        return y

    def bracket(self, params: dict, rate_hz: float) -> list:
        """The settings of the law between whose responses a sampled reading of it falls (a delay
        between whole samples interpolates the two whole-sample delays around it); ``[params]``
        when it has none."""
        return [params]

    def pieces(self, key: str, lo: float, hi: float, rate_hz: float) -> list:
        """The intervals of ``[lo, hi]`` of the screened parameter ``key`` on which the training error
        is smooth, each searched on its own by the refinement (:func:`models.diagnose.detectors.refine`)."""
        return [(lo, hi)]

    def lateness_s(self, params: dict, rate_hz: float) -> float | None:
        """How late (s) the word's time response makes the flow on average (the first moment of its
        impulse response: what a smooth excitation sees of it, ``-lateness dq/dt`` to first order), or
        ``None``: no time response."""
        return None

    def with_lateness(self, params: dict, lateness_s: float, rate_hz: float) -> dict | None:
        """``params`` with the time parameter set so that :meth:`lateness_s` is ``lateness_s``, or
        ``None`` when the law cannot be that late (or early)."""
        return None

    def sensor_columns(self, ctx: Columns, params: dict) -> list:
        """Linear columns at the sensor, after the dynamics."""
        return []

    def clip_lpm(self, params: dict) -> float | None:
        """Full-open flow the prediction is clipped to, or ``None``."""
        return None

    # -- report and checks --
    def physical(self, params: dict, coef: float | None, sig: Signals, base,
                 fitted_lpm: np.ndarray | None = None) -> dict:
        """The parameters in the units of :attr:`units` (``coef``: the column's fitted coefficient;
        ``fitted_lpm``: the fitted prediction of the chain the word is in, at the sensor)."""
        return {k: float(v) for k, v in params.items()}

    def support(self, sig: Signals, params: dict, before_lpm: np.ndarray, noise_lpm: float,
                chain: dict | None = None, extrapolated: bool = False,
                after_lpm: np.ndarray | None = None, fixed: bool = False) -> str | None:
        """``None``, or why the recording does not show this law where it should (the rows a
        range-end law needs; where a law's correction is largest);
        ``chain``: the named words it joins (their time response delays where the law shows);
        ``extrapolated``: ``before_lpm`` is a model fitted without the rows the law explains, run on
        past them; ``after_lpm``: the model with the law (its correction is ``after - before``);
        ``fixed``: ``before_lpm`` is a model file held fixed, whose prediction is its own claim, not a
        fit's residual."""
        return None

    def pinned(self, sig: Signals, before_lpm: np.ndarray, after_lpm: np.ndarray) -> bool:
        """Whether rows of the recording read the law's level by themselves (``before_lpm``, ``after_lpm``:
        the fitted chain without and with it), whatever the other words of the chain make of the rest: a
        sensor's zero read where the valve is shut. ``False`` by default."""
        return False

    def beside_memory(self, sig: Signals) -> bool:
        """Whether the word's law is a slow drift along the recording that must explain it beyond a
        free offset per memory epoch (:func:`models.diagnose.design.memory_epochs`): the steps a
        valve's hysteresis memory takes at each growth of the duty's range, which a fitted PI gets
        wrong by a different amount in each epoch, are a staircase in time, not the word's physics."""
        return False

    def instant(self, params: dict, sig: Signals) -> dict | None:
        """The law's setting with its drift in time made instantaneous (a time constant of one sample),
        which a drift must explain beyond (:func:`models.diagnose.detectors._drift_unseen`), or
        ``None``: the law does not drift."""
        return None

    def absorbed(self, sig: Signals, chain: dict) -> str | None:
        """Why the word, not named, cannot be told apart from a baseline fitted on the recording
        although the recording shows its law's signature (asked only when ``chain``, the named
        words, already explains the recording to within the noise), or ``None``."""
        return None

    def implausible(self, phys: dict) -> str | None:
        """Why the reported parameters are not physical, or ``None``."""
        bad = [f"{k} = {phys[k]:.4g} outside {lo:g}..{hi:g} {self.units[k]}"
               for k, (lo, hi) in self.plausible.items() if k in phys and not lo <= phys[k] <= hi]
        return "; ".join(bad) or None

    def within_physics(self, params: dict) -> bool:
        """Whether the exact law's ``params`` stay where the word's physics alone reaches (else it is
        named with :meth:`caveat`, when no setting within it explains nearly as much)."""
        return True

    def extent(self, params: dict) -> float:
        """How much effect ``params`` make, to prefer the least among settings a fit cannot tell apart
        (:func:`models.diagnose.detectors._tied_choice`); 0: no preference."""
        return 0.0

    def tie_rank(self, params: dict) -> int:
        """The word's preference (lowest first) among settings of its law that the fit cannot tell
        apart (:func:`models.diagnose.detectors._tied_choice`); 0 by default: none."""
        return 0

    def caveat(self, phys: dict) -> str | None:
        """What a user should know of a plausible finding's size (beyond what the word's physics
        alone can reach), or ``None``."""
        return None

    def not_resolved(self, params: dict, sig: Signals, base) -> str | None:
        """Why the time constant is not resolved (at the end of its search range), or ``None``."""
        if self.unresolved is None:
            return None
        key, side = self.unresolved
        grid = self.grid(sig, base).get(key)
        if grid is None or key not in params:
            return None
        lo, hi = float(np.min(grid)), float(np.max(grid))
        v = params[key]
        if (side == "low" and v <= lo * 1.05) or (side == "high" and v >= hi / 1.05):
            return f"{key} = {v:.4g} at the {side} end of its search range ({lo:.4g}..{hi:.4g}): not resolved"
        return None


#: Largest steady coil rise at 55 % duty (K) a coil's copper can show: the rise goes with duty squared,
#: so at the full duty a proportional valve is rated to hold continuously the coil would be
#: (100/55)^2 = 3.3 x as warm, 200 K above a 25 C ambient at this bound, the hot-spot limit of class R
#: insulation (220 C). A finding above it is named with that caveat (:meth:`Word.caveat`): the valve's
#: gain drifts along the duty's thermal history by more than its copper's resistance explains.
MAX_RISE55_K = 60.0
#: Largest steady rise at 55 % duty (K) the heating law is refined to and named at: there the coil's
#: current at a fixed duty is half its cold value (1 + 0.00393 x 250 = 2); a larger drift is no longer
#: a resistance change of the coil (every law beyond halves the flow), and a rise refined onto this bound
#: has not found the law's minimum (:func:`models.diagnose.detectors._exact`).
LAW_RISE55_K = 250.0
#: Duty band (%, 5th to 95th percentile) over which the highest flows must sit at one level (within the
#: plateau's noise band) to show a full-open flow's signature: a valve's own loading curve rises some
#: 5 L/min per % there, so a band this wide is a plateau of ten times the noise or more.
PLATEAU_SPAN_PCT = 2.0
#: ... held by at least this share of the rows (twice the top percent the level is taken from: a coil
#: warming along breaths passes the same top flow at a few duties, on under 1 % of the rows).
PLATEAU_SHARE = 0.02
#: Share of the rows a coil as warm as copper can be takes below the lowest commanded duty that must be
#: shut for the valve to count as seated there (:meth:`CoilHeating._seated`).
SEATED_SHARE = 0.9
#: Share of the rows, those the law's correction moves most, where an asymmetry must be seen ...
LARGEST_SHARE = 0.1
#: ... explaining at least this share of the residual's mean square beyond the noise there.
MIN_EXPLAINED_SHARE = 0.6
#: Box (position in the input range, 0..1) where an asymmetry's widening may start on a recording
#: resting below the valve's opening.
START_BOUNDS = (1e-3, 0.5)
#: A widening's start this far (share of the input range) from where the valve opens is read again
#: from the opening (:meth:`AsymmetricHysteresis.readings`).
START_MOVED = 0.02
#: Box of an asymmetric hysteresis's relative widening of each descending threshold at the top.
WIDEN_BOUNDS = (1e-3, 40.0)
#: Lifts of every descending threshold (in half-widths of the PI's major loop) at which an asymmetry's
#: exact law is screened (:meth:`AsymmetricHysteresis.sized`): the lift column is first order, and
#: the PI refitted with it bends its own loop towards a gross one (x9.75 beside a clip at 148 L/min
#: on the paper sweep: the column gained 2.9 % of the training error, under its 3 % margin, and the
#: exact law was never refined). Two sizes, a loop twice and four times as wide at the top, from which
#: the refinement reached x8-10 on that probe and its variants; not tuned further.
GROSS_LIFTS = (1.0, 3.0)


def explained_where_largest(flow_lpm: np.ndarray, before_lpm: np.ndarray, after_lpm: np.ndarray,
                            noise_lpm: float) -> float:
    """Share of the residual's mean square beyond the noise that a law's correction (``after_lpm -
    before_lpm``) explains on the rows it moves most (:data:`LARGEST_SHARE`); 0 with no residual beyond
    the noise there. A law that follows another's residual over the recording gains held out, but is
    not that residual where its own correction is largest."""
    delta = after_lpm - before_lpm
    top = np.abs(delta) >= np.quantile(np.abs(delta), 1.0 - LARGEST_SHARE)
    resid = (flow_lpm - before_lpm)[top]
    excess = float(np.mean(resid ** 2)) - noise_lpm ** 2
    left = float(np.mean((resid - delta[top]) ** 2)) - noise_lpm ** 2
    return 1.0 - left / excess if excess > 0 else 0.0
#: A start placed near a bound of a refinement's box is placed this factor inside it.
AT_START = 1.05
#: Fewest rows at a range end that can show a dead zone or a saturation.
MIN_END_ROWS = 3
#: A saturation held against a model file must lower the model's flow by more than this many times the
#: noise on :data:`MIN_END_ROWS` rows: the clip, not a level at the top.
CLIP_CUT_NOISE = 2.0
#: Fewest rows where a fixed model file rises past a saturation's full-open flow below its own plateau
#: (its flow at the top of its identified range), where the clip must hold the measured flow.
MIN_RISING_ROWS = 20
#: Largest slope of the measured flow on the model file's flow on those rows: a clip holds it flat (0),
#: a level under the model's plateau follows it (1).
MAX_CLIPPED_SLOPE = 0.5
#: Fewest rows of a shut valve (and at least 1 % of the recording) that read a sensor's zero offset.
MIN_ZERO_ROWS = 20
#: Share of the rows a saturation clips beyond which rows measured above its full-open flow (by more
#: than the noise band) refute it (sensor spikes aside, a clipped valve passes no more).
OVER_CLIP_SHARE = 0.01
#: Duty band (%) above a cracking duty where the flow must have jumped.
JUMP_BAND_PCT = 2.0
#: Step (% duty) to which a cracking duty is refined: a breath's rise crosses a per cent of duty in a
#: few samples, and a cracking duty placed a fifth of a per cent low leaves those rows open at the
#: valve in the model where the valve passes nothing (2 % of the duty, a time constant's step, is a
#: whole per cent at 45 %).
CRACKING_STEP_PCT = 0.05


def _span(sig: Signals) -> float:
    return float(sig.t_s[-1] - sig.t_s[0])


#: Fewest consecutive rows at one duty that make a held level.
HOLD_ROWS = 10


def held_levels(duty_pct: np.ndarray, hi_pct: float) -> np.ndarray:
    """The duties (%) up to ``hi_pct`` held for at least :data:`HOLD_ROWS` consecutive rows."""
    change = np.flatnonzero(np.diff(duty_pct) != 0.0)
    starts = np.concatenate([[0], change + 1])
    runs = np.diff(np.concatenate([starts, [len(duty_pct)]]))
    levels = duty_pct[starts[runs >= HOLD_ROWS]]
    return np.unique(levels[levels <= hi_pct])


def _spread(x: np.ndarray) -> bool:
    """Whether duties (%) spread over the band above a cracking duty (:data:`JUMP_BAND_PCT`) enough for
    a parabola, not two held levels."""
    return len(np.unique(x)) >= 4 and float(np.ptp(x)) >= JUMP_BAND_PCT if len(x) else False


def _moves_core_input(chain: dict) -> bool:
    """Whether a word of ``chain`` moves the duty the magnetics see away from the commanded duty (an
    input-side exact law on the duty: a warm coil's)."""
    return any(VOCABULARY[w].input_side == "duty" and VOCABULARY[w].is_exact(p) for w, p in chain.items())


def bracketing(chain: dict, rate_hz: float) -> list:
    """``chain`` with each law at each setting of :meth:`Word.bracket`: every combination."""
    out = [{}]
    for w, p in chain.items():
        out = [{**c, w: q} for c in out for q in VOCABULARY[w].bracket(p, rate_hz)]
    return out


def magnetic_duty(sig: Signals, chain: dict) -> np.ndarray:
    """The duty the valve's magnetics see under ``chain`` (%): the effective duty of its input-side
    word (a warm coil's, :meth:`Word.effective_duty`), else the commanded duty."""
    from .design import inputs

    return inputs(sig, chain)[0]


@dataclass(frozen=True)
class AsymmetricHysteresis(Word):
    """Descending thresholds widened with the input level (generalized PI)."""

    def exact_starts(self, params, coef, sig, base, chain):
        from .design import major_loop_half_width

        # each operator widened in proportion to its threshold, or all lifted by one amount (the
        # zero-threshold operator too): the exact law has both, started on a coarse grid
        h = major_loop_half_width(base.shape.r, base.lift_w)
        first = float(np.clip(coef / h if h > 1e-3 else 0.1, 0.01, 20.0))
        at = {} if "dead_zone" in chain else self._opening(sig, base, chain)
        lifts = (1e-3, 0.3, 1.0, 3.0, 10.0)
        # and the lift alone (the widening at the lower bound of its box), a valley of its own
        # (:meth:`basin`): ranked among the widenings in proportion, whose unrefined starts fit
        # better, it was never refined (x3.18 alone on a mixed recording resting at 34 %: widen 2.32
        # refined from widen 2, more training error than the lift alone refined from a lift of the
        # loop's half-width, and 2.39 L/min held out against that law's 1.01 and the baseline's 1.75;
        # its correction largest where it ran off, it was refused as another law's residual)
        lo, hi = self.bounds(sig, base)["lift"]
        alone = [{"widen": WIDEN_BOUNDS[0], "lift": float(np.clip(c * h, lo * AT_START, hi / AT_START)), **at}
                 for c in lifts[1:]]
        return [{"widen": a, "lift": c * h, **at} for a in sorted({first, 0.1, 0.5, 2.0}) for c in lifts] + alone

    def basin(self, params):
        # a widening in proportion to each threshold and a lift of every threshold alone: the PI
        # refitted under the former shrinks its own loop into the widened one (:meth:`readings`), a
        # valley a refinement from there does not leave for the latter's, nor the reverse
        return bool(params.get("widen", 0.0) <= WIDEN_BOUNDS[0] * AT_START)

    def sized(self, sig, base, chain):
        from .design import major_loop_half_width

        # the widening at the lower bound of its box, all of the extra width in the lift: the reading a
        # refinement from a widening in proportion does not reach (:meth:`readings`)
        # not against a model file: the model's own misfit of a valve's loop is as gross (a foreign
        # valve's, on breaths beside a 44 K coil, was named an extra width of 2.35 from these sizes)
        h = major_loop_half_width(base.shape.r, base.lift_w)
        if h <= 1e-3 or not base.refit:
            return []
        box = self.bounds(sig, base)
        at = {} if "dead_zone" in chain else self._opening(sig, base, chain)
        return [{"widen": box["widen"][0], "lift": float(np.clip(c * h, box["lift"][0], box["lift"][1])), **at}
                for c in GROSS_LIFTS]

    @staticmethod
    def _opening(sig: Signals, base, chain: dict) -> dict:
        """``{"start": position}`` where the valve opens in the input range of a PI fitted on a
        recording that rests below the opening (the duty the magnetics see under ``chain`` that best
        splits its rows into shut below and open above), refined from there; empty when no row is
        shut: the widening starts at the bottom of the range.

        A widening counted from a rest below the opening lifts every descending threshold by a
        constant where the valve opens, which the PI refitted with it takes out of its own loop: the
        loop's half-width shrinks and the extra width relative to it doubles (x9.7 named 20.6 on a
        mixed recording resting at 34 %, the simulated valve's loop starting at 38 %). Not beside a
        named dead zone: it shuts the valve after the hysteresis core, whose own opening it hides
        (a start placed at a 44 % cracking duty named x8 as 3.6). On the duty the magnetics see: a warm
        coil's valve opens at a higher commanded duty, not a higher input of its core (a coil 44 K warm
        on the paper sweep: a start at 43.2 % commanded, where the core's input opens at 38 %, doubled the
        refitted PI's own loop and named x5.6 as 2.1)."""
        from .design import seated_input

        shut = base.shut(sig)
        if not shut.any() or shut.all():
            return {}
        duty = seated_input(sig, chain)
        order = np.argsort(duty, kind="stable")
        x, opened = duty[order], ~shut[order]
        # misplaced rows with the split after row i: open rows at or below it, shut rows above it
        wrong = np.cumsum(opened) + (np.sum(~opened) - np.cumsum(~opened))
        pos = (float(base.unit_input(x[int(np.argmin(wrong))])) + 1.0) / 2.0
        return {"start": float(np.clip(pos, START_BOUNDS[0] * 1.1, START_BOUNDS[1] / 1.1))}

    def readings(self, params, sig, base, chain):
        from .design import major_loop_half_width

        if not self.is_exact(params):
            return []
        out = []
        at = {} if "start" not in params or "dead_zone" in chain else self._opening(sig, base, chain)
        if at and abs(at["start"] - params["start"]) > START_MOVED:
            # the widening started where the valve opens on the duty the magnetics see, held there: a
            # heating named first beside it took up part of the widening, and the start refined above
            # the opening holds the heating in that basin (a coil 44 K warm with x5.6 on the paper
            # sweep: 54 K from a start at 43 %, the valve opening at 38 %; from 38 %, 44 K and x4)
            out.append(({**params, **at}, ("start",)))
        # the same extra width at the top as a lift of every descending threshold alone, each no wider
        # in proportion to its own threshold (held at the lower bound of the widening), on the loop of
        # the PI fitted without the law: a widening in proportion lets the PI refitted under it shrink
        # its own loop into the widened one, a basin a refinement from there does not leave (a coil
        # 32 K warm with x8 on a mixed recording: widen 1.96 on a loop shrunk to a few hundredths of
        # its width, read as x65, with 17 % more training error than the lift alone)
        h = major_loop_half_width(base.shape.r, base.lift_w)
        if h <= 1e-3:
            return out
        box = self.bounds(sig, base)
        extra = params["widen"] + params["lift"] / h
        lift = float(np.clip(extra * h, box["lift"][0] * AT_START, box["lift"][1] / AT_START))
        return out + [({**params, "widen": box["widen"][0], "lift": lift}, ("widen",))]

    def bounds(self, sig, base):
        return {"widen": WIDEN_BOUNDS, "lift": (1e-4, 4.0), "start": START_BOUNDS}

    def is_exact(self, params):
        return "widen" in params

    def threshold_widening(self, params):
        return float(params.get("widen", 0.0)), float(params.get("lift", 0.0)), float(params.get("start", 0.0))

    def valve_columns(self, ctx, params):
        return [] if self.is_exact(params) else [ctx.lift_lpm]

    def support(self, sig, params, before_lpm, noise_lpm, chain=None, extrapolated=False, after_lpm=None, fixed=False):
        if after_lpm is None:
            return None
        # the law widens the descending branch most at high flow: on the rows where its correction is
        # largest, the residual before it must be mostly the correction, beyond the noise. A residual
        # of another word (a coil's heating under-sized beside a supply and a creep) correlates with
        # the widening over a sweep's loops, and gains held out, but is not the widening where the
        # widening is largest
        share = explained_where_largest(sig.flow_lpm, before_lpm, after_lpm, noise_lpm)
        if share < MIN_EXPLAINED_SHARE:
            return (f"where its correction is largest (the {100 * LARGEST_SHARE:.0f} % of rows it moves most) it "
                    f"explains {100 * share:.0f} % of the residual beyond the noise (needs "
                    f"{100 * MIN_EXPLAINED_SHARE:.0f} %): the residual there is another law's")
        return None

    def physical(self, params, coef, sig, base, fitted_lpm=None):
        from .design import major_loop_half_width

        # relative to the half-width of the PI's own major loop (its fitted weights: the loop the
        # valve shows), as DESIGN.md's effect table measures the asymmetry
        h = major_loop_half_width(base.shape.r, base.shape.w)
        if self.is_exact(params):
            # descending thresholds r (1 + widen) + lift at the top: relative extra width over the
            # loop's half-width h
            out = {"extra_width": float(params["widen"] + params["lift"] / h), "widen": float(params["widen"]),
                   "lift_pct": float(params["lift"]) * base.shape_scale.half_range}
            if "start" in params:
                out["start_pct"] = float(base.shape_scale.from_unit(2.0 * params["start"] - 1.0))
            return out
        p = {"lift_pct": float(coef) * base.shape_scale.half_range}
        if h > 1e-3:
            p["extra_width"] = float(coef) / h
        return p


@dataclass(frozen=True)
class CoilHeating(Word):
    """Coil resistance +0.393 %/K with a thermal state: effective duty = duty / (1 + alpha T)."""

    def grid(self, sig, base):
        if sig.coil_temp_c is not None:
            return {"copper_law_ratio": np.array([1.0])}
        tau = np.geomspace(20.0, 2000.0, 8)  # a solenoid coil warms over minutes
        # start: the coil's rise at the first sample as a fraction of the steady rise there (0 = cold start)
        return {"tau_s": tau[tau <= 2.0 * _span(sig)], "start": np.array([0.0, 1.0])}

    def exact_starts(self, params, coef, sig, base, chain):
        # the first-order column saturates on a large rise and biases the screen's time constant
        return [] if self.is_exact(params) else self.restarts(sig, base)

    def restarts(self, sig, base):
        if sig.coil_temp_c is not None:
            return []
        # rise and time constant trade off along a narrow valley: a grid of the exact law (and a warm
        # or a cold start: the screen's choice is unreliable when its column saturates)
        g = self.grid(sig, base)
        rises = (4.0, 10.0, 20.0, 35.0, 55.0, 100.0, 180.0)
        starts = [{"rise55_k": r, "tau_s": float(t), "start": float(s)}
                  for r in rises for t in g["tau_s"] for s in g["start"]]
        if not base.refit:
            return starts
        lowest = float(np.min(sig.duty_pct))
        if not self._seated(sig, base):
            # each also with the valve's input held at the lowest commanded duty, from where the
            # refinement places the floor (:meth:`effective_duty`, :meth:`bounds`)
            return starts + [{**p, "floor_pct": lowest} for p in starts]
        # a valve shut at the lowest commanded duty has its input held (:meth:`_seated`): there, and at
        # seats above it that a cold coil's lowest duty reaches and a warm one's effective duty falls
        # below (plant_sim's valve, seated at 38 %, on holds down to 34 %), each a valley of its own
        # (:meth:`basin`); a baseline's seat holds the input first, and a floor below it holds nothing
        # more (:func:`models.diagnose.design.unbend`)
        floors = np.linspace(lowest, self._top_floor(sig), FLOOR_STARTS)
        seat = base.root.seat
        floors = [lowest] + [float(f) for f in floors[1:] if seat is None or f > seat[0]]
        return [{**p, "floor_pct": f} for p in starts for f in floors]

    def basin(self, params):
        # the rows a floor holds change only where a held level's effective duty crosses it: the
        # training error is a staircase in the floor, on which a refinement stays where it starts
        return params.get("floor_pct")

    def between(self, params, starts):
        floors = sorted({p["floor_pct"] for p in starts if "floor_pct" in p})
        if "floor_pct" not in params or len(floors) < 2:
            return []
        i = int(np.argmin(np.abs(np.subtract(floors, params["floor_pct"]))))
        mids = [0.5 * (floors[i] + floors[j]) for j in (i - 1, i + 1) if 0 <= j < len(floors)]
        return [{**p, "floor_pct": m} for p in starts if p.get("floor_pct") == floors[i] for m in mids]

    @staticmethod
    def _seated(sig: Signals, base) -> bool:
        """Whether a PI fitted on the recording has its valve shut at the lowest commanded duty: its
        effective duty is then held there, a setting of the law, not refined.

        A seated plunger's memory does not follow a current below the one that seats it (plant_sim's
        valve holds its input at 38 %, seated at 34 %), and the recording shows no flow there to place
        a floor by (one placed at 34 % traded a warm start's rise). Run on below the lowest duty, the
        PI's input rests lower with every kelvin, each breath rising from another memory: beside a
        clip that hides the breaths' tops, a coil 30 K warm fitted best as 40 K (breaths resting at
        30 %, train error 1.16 x the noise at 30 K, 1.04 x with the input held at 30 %)."""
        if not base.refit:
            return False
        x, shut = sig.duty_pct, base.shut(sig)
        lowest = float(np.min(x))
        # and shut wherever a coil as warm as copper can be (MAX_RISE55_K) takes the effective duty
        # below it: a valve opening just above its lowest duty (the paper's sweep from 38 %) passes
        # flow that goes on falling with the effective duty below it (held, a coil 32 K warm beside
        # a clip was read as 23 K, train error 1.6 x that of the input run on)
        below = fx.effective_duty(x, MAX_RISE55_K * (x / fx.HEATING_REF_DUTY_PCT) ** 2) < lowest
        return bool(np.mean(shut[x <= np.percentile(x, 1.0)]) >= 0.5 and np.mean(shut[below]) >= SEATED_SHARE)

    def bounds(self, sig, base):
        if sig.coil_temp_c is not None:
            return {"copper_law_ratio": (0.2, 5.0)}
        # a time constant beyond twice the recording, as the screen's grid: the rise over the
        # recording is then close to a ramp in time, and a slow drift of anything fits it (a lag's
        # misfit on a mixed excitation, each third another, was read as a coil 11 K warm with a
        # 1130 s time constant on a 300 s recording)
        box = {"rise55_k": (0.2, LAW_RISE55_K), "tau_s": (10.0, 2.0 * _span(sig))}
        if self._seated(sig, base):
            return box
        lowest = float(np.min(sig.duty_pct))
        # the floor from the lowest commanded duty down to below every effective duty the law reaches: a
        # valve that passes flow at its lowest commanded duty is seated below it (a floor refined up to
        # 43 % on the paper's sweep from 38 % took up an asymmetry's widening there)
        return {**box, "floor_pct": (lowest / (1.0 + fx.ALPHA_CU_PER_K * LAW_RISE55_K), lowest)}

    @staticmethod
    def _top_floor(sig: Signals) -> float:
        """Highest input floor (%) a seated valve's law may hold (:meth:`restarts`):
        :data:`models.diagnose.design.SEAT_SPAN` of the way from the lowest commanded duty to the highest,
        as a baseline's seat is sought."""
        from .design import SEAT_SPAN

        lowest = float(np.min(sig.duty_pct))
        return lowest + SEAT_SPAN * (float(np.max(sig.duty_pct)) - lowest)

    def rise_k(self, sig: Signals, params: dict) -> np.ndarray:
        """Coil temperature rise since the first sample (K) times the copper-law ratio: measured or modelled."""
        if sig.coil_temp_c is not None:
            return params.get("copper_law_ratio", 1.0) * (sig.coil_temp_c - sig.coil_temp_c[0])
        x = sig.duty_pct
        steady0 = (x[0] / fx.HEATING_REF_DUTY_PCT) ** 2
        rise = fx.coil_temperature_rise(x, sig.rate_hz, params["tau_s"], params.get("rise55_k", 1.0),
                                        params.get("start", 1.0) * steady0 * params.get("rise55_k", 1.0))
        return rise

    def is_exact(self, params):
        return "rise55_k" in params or "copper_law_ratio" in params

    def effective_duty(self, sig, params):
        """The duty the coil's current gives at its reference temperature (%), held at the valve's
        input floor ``floor_pct`` when the law has one.

        A warm coil's effective duty runs below the lowest duty the recording commands, where a PI
        fitted on the recording has no row and runs on down its loading curve; a valve whose
        plunger is seated there holds its magnetic input, and its memory, at the bottom of its
        range (a valve identified over 38-72 % and driven over 40-70 %: a coil 25 K warm was read as
        31 K, beside a 39 ms lag as 40 K). A model file holds its input to its identified range
        itself (:meth:`models.diagnose.design.Base.unit_input`)."""
        if not self.is_exact(params):
            return None
        x = fx.effective_duty(sig.duty_pct, self.rise_k(sig, params))
        return np.maximum(x, params["floor_pct"]) if "floor_pct" in params else x

    def floor(self, params):
        if "floor_pct" not in params:
            return None, params
        return float(params["floor_pct"]), {k: v for k, v in params.items() if k != "floor_pct"}

    def at_rest(self, sig, params, base):
        # a floor above the lowest commanded duty holds rows a cold coil's duty reaches: the valve seated
        # there, a baseline's seat on the duty the magnetics see (:func:`models.diagnose.design.unbend`),
        # whatever the coil's warmth. The warming must explain more than the seat alone: a dead zone at
        # 36 % on ramps over 35.5-72 % was read as a coil 0.2 K warm held at 37.9 %, the seat's line
        # taking up the jump
        # (the seat where the warm coil's floor sits on the commanded duty on average: a coil warm from the
        # start is a scale of the duty the PI takes up, and a sines' jump at 36 % was read as 4.2 K warm
        # from the start held at 37.4 %, the commanded 38 %)
        if params.get("floor_pct", -np.inf) <= float(np.min(sig.duty_pct)) + 1e-6 or "rise55_k" not in params:
            return None
        warm = 1.0 + fx.ALPHA_CU_PER_K * float(np.mean(self.rise_k(sig, params)))
        return {**params, "rise55_k": 0.0, "start": 0.0, "floor_pct": params["floor_pct"] * warm}

    def support(self, sig, params, before_lpm, noise_lpm, chain=None, extrapolated=False, after_lpm=None, fixed=False):
        if sig.coil_temp_c is not None:
            r = params.get("copper_law_ratio", 1.0)
            if not 0.3 <= r <= 3.0:
                return f"the measured coil temperature explains it only at {r:.3g} x copper's 0.393 %/K"
            return None
        floor, rest = self.floor(params)
        if after_lpm is None or floor is None or floor <= float(np.min(sig.duty_pct)) + 1e-6:
            return None
        from .design import shut_rows

        # a floor above the lowest commanded duty is the valve's seat (:meth:`at_rest`), and below it the
        # flow closes along a line to where the valve really shuts: on the rows it holds where the model
        # passes flow, the valve must be open. A jump to zero flow (a dead zone) is not a seat: held at
        # 44.5 % beside a foreign valve's cracking duty of 46.6 %, a third of those rows measured shut
        # (a true seat's: 1 %)
        line = (self.effective_duty(sig, rest) < floor) & (after_lpm > 3.0 * noise_lpm)
        shut = float(np.mean(shut_rows(sig.flow_lpm)[line])) if line.any() else 0.0
        if shut > MAX_SHUT_ON_SEAT_LINE:
            return (f"held at {floor:.3g} % of effective duty, the valve closing below it along a seat's line, "
                    f"{100 * shut:.0f} % of the rows the line passes flow on measure it shut (at most "
                    f"{100 * MAX_SHUT_ON_SEAT_LINE:.0f} %): the flow stops with a jump there, not along a seat")
        return None

    def held(self, sig, params, base):
        if "floor_pct" not in params or self._seated(sig, base):
            return None
        rest = {k: v for k, v in params.items() if k != "floor_pct"}
        return rest, self.effective_duty(sig, rest) < params["floor_pct"]

    def valve_columns(self, ctx, params):
        if self.is_exact(params):
            return []
        # to first order in the resistance change: q(x (1 - a T)) ~ q(x) - a T x dq/dx, per kelvin of rise55
        return [-fx.ALPHA_CU_PER_K * self.rise_k(ctx.sig, params) * ctx.slope_lpm]

    def physical(self, params, coef, sig, base, fitted_lpm=None):
        p = {k: float(v) for k, v in params.items()}
        if sig.coil_temp_c is not None:
            p["coil_temp_span_k"] = float(np.ptp(sig.coil_temp_c))
            p.update(thermal_fit(sig))
        elif "rise55_k" not in p:
            p["rise55_k"] = float(coef)
        return p

    def within_physics(self, params):
        return params.get("rise55_k", 0.0) <= MAX_RISE55_K

    def tie_rank(self, params):
        # a coil warm from the start (at the steady rise of the first duty, rise55 (x0/55)^2) adds
        # a constant rise, a duty scale that a PI fitted on the recording takes up: along the
        # recording it warms by rise55 (m - m0) (1 - exp(-t/tau)), m and m0 the mean and the first
        # (duty/55)^2, where a cold one warms by rise55 m (1 - ...), the same curve to first order
        # (breaths resting at 30 %: a warm 59 K for a cold 30 K). The cold start is the simpler
        # reading (no warming before the recording that the recording cannot show)
        return int(params.get("start", 0.0) > 0.0)

    def extent(self, params):
        return params.get("rise55_k", 0.0)

    def beside_memory(self, sig):
        # a coil's temperature follows the power it dissipates through its thermal time constant, at
        # every row; a measured coil temperature drives the law directly
        return sig.coil_temp_c is None

    def caveat(self, phys):
        rise = phys.get("rise55_k")
        if rise is None or rise <= MAX_RISE55_K or "copper_law_ratio" in phys:
            return None
        return (f"a rise of {rise:.3g} K at 55 % duty is more than a coil's copper can show (at most "
                f"{MAX_RISE55_K:g} K: class R insulation at full duty on the duty-squared law): the valve's gain "
                f"drifts along the duty's thermal history by more than its coil resistance explains (a warmer "
                f"ambient, a magnet or spring that weakens with heat)")



def thermal_fit(sig: Signals) -> dict:
    """Steady rise at 55 % duty and time constant of a first-order thermal model fitted to the
    measured coil temperature (``tau dT/dt = rise55 (duty/55 %)^2 + T_amb - T``)."""
    from scipy.optimize import least_squares

    T = sig.coil_temp_c
    x = sig.duty_pct
    step = max(1, len(T) // 4000)
    Ts, xs = T[::step], x[::step]
    rate = sig.rate_hz / step
    dur = _span(sig)

    def model(u):
        rise55, tau, amb = np.exp(u[0]), np.exp(u[1]), u[2]
        drive = rise55 * (xs / fx.HEATING_REF_DUTY_PCT) ** 2
        return amb + fx.first_order_lag(drive, rate, tau, Ts[0] - amb)

    u0 = np.array([np.log(max(np.ptp(T), 0.5)), np.log(max(dur / 4, 10.0)), float(np.min(T))])
    res = least_squares(lambda u: model(u) - Ts, u0, bounds=([np.log(0.01), np.log(1.0), -50], [np.log(500), np.log(1e5), 200]),
                        max_nfev=60)
    return {"rise55_k": float(np.exp(res.x[0])), "tau_s": float(np.exp(res.x[1])), "ambient_c": float(res.x[2])}


@dataclass(frozen=True)
class SupplyPressure(Word):
    """Choked flow proportional to the upstream absolute pressure, from the supply_bar column."""

    def applicable(self, sig, base):
        return None if sig.supply_bar is not None else "no varying supply_bar column: the pressure cannot be seen"

    def recorded(self, sig):
        return sig.supply_bar is not None

    def valve_columns(self, ctx, params):
        # q ((p + p_atm) / (p_ref + p_atm))**n ~ q (1 + n ln(...)): the supply wanders by a few per cent
        # of the absolute pressure, so the exponent n enters linearly. p_ref is the supply the baseline's
        # flow is at: a model file's own (held fixed, the baseline cannot take up a mean supply that
        # droops below it); a refitted PI's gain takes up the mean, so there it is the mean
        sig = ctx.sig
        ref_bar = ctx.supply_ref_bar if ctx.supply_ref_bar is not None else float(np.mean(sig.supply_bar))
        gain = fx.pressure_gain(sig.supply_bar, ref_bar, 1.0)
        return [np.clip(ctx.flow_lpm, 0.0, None) * np.log(gain)]

    def physical(self, params, coef, sig, base, fitted_lpm=None):
        lo, hi = np.percentile(sig.supply_bar, [1, 99])
        return {"exponent": float(coef), "wander_bar": float(hi - lo) / 2.0}


@dataclass(frozen=True)
class ValveDynamics(Word):
    """First-order lag of the flow."""

    def grid(self, sig, base):
        return {"tau_s": np.geomspace(0.005 / sig.rate_hz, 1.5, 16), "phase": np.array([0.0, 0.5, 1.0])}

    def dynamics(self, v, rate_hz, params):
        return fx.first_order_lag(v, rate_hz, params["tau_s"], phase=params.get("phase", 1.0))

    def undo(self, y, rate_hz, params):
        return fx.lag_input(y, rate_hz, params["tau_s"], params.get("phase", 1.0))

    def lateness_s(self, params, rate_hz):
        if params["tau_s"] <= 0:
            return 0.0  # (the identity)
        # the recursion's pole a/(1 - a) samples, and the share of the previous sample's command
        a = np.exp(-1.0 / (rate_hz * params["tau_s"]))
        return float((a / (1.0 - a) + params.get("phase", 1.0)) / rate_hz)

    def with_lateness(self, params, lateness_s, rate_hz):
        pole = lateness_s * rate_hz - params.get("phase", 1.0)  # a / (1 - a), samples
        if pole <= 0:
            return None
        return {**params, "tau_s": float(-1.0 / (rate_hz * np.log(pole / (1.0 + pole))))}


@dataclass(frozen=True)
class TransportDelay(Word):
    """Pure delay from command to measured flow."""

    def grid(self, sig, base):
        return {"delay_s": np.geomspace(0.005 / sig.rate_hz, 0.8, 20)}

    def dynamics(self, v, rate_hz, params):
        return fx.delayed(v, rate_hz, params["delay_s"])

    def undo(self, y, rate_hz, params):
        return fx.advanced(y, rate_hz, params["delay_s"])

    def bracket(self, params, rate_hz):
        shift = params["delay_s"] * rate_hz
        if shift == np.floor(shift):
            return [params]
        return [{**params, "delay_s": float(np.floor(shift) / rate_hz)}, {**params, "delay_s": float(np.ceil(shift) / rate_hz)}]

    def pieces(self, key, lo, hi, rate_hz):
        # a delay between whole samples interpolates its neighbours, smoothing the flow most at half a
        # sample: the error has a kink at each whole sample, where a scalar search stops (17.7 ms beside
        # a cracking duty on a chirp, for 26.3 ms, at 50 Hz)
        cuts = np.arange(np.floor(lo * rate_hz) + 1, np.ceil(hi * rate_hz)) / rate_hz
        ends = [lo, *cuts[(cuts > lo) & (cuts < hi)], hi]
        return list(zip(ends[:-1], ends[1:]))

    def lateness_s(self, params, rate_hz):
        return float(params["delay_s"])

    def with_lateness(self, params, lateness_s, rate_hz):
        return {**params, "delay_s": float(lateness_s)} if lateness_s > 0 else None


#: Largest share of the rows a heating's seat line passes flow on (below its input floor) that may
#: measure the valve shut (:meth:`CoilHeating.support`): a dead zone's jump taken for a floor shuts
#: about a third of them, a true seat 1 %, and a floor a little above the seat of a coil 160 K warm on
#: breaths 13 %.
MAX_SHUT_ON_SEAT_LINE = 0.2
#: Input floors a heating's refinement starts from, from the lowest commanded duty up to a seat above
#: it (:meth:`CoilHeating.restarts`).
FLOOR_STARTS = 4


#: A dead zone's edge is smoothed, for the search of a heating beside it, over the duty a coil this
#: much warmer (K) moves its cracking duty by.
EDGE_K = 0.25


@dataclass(frozen=True)
class DeadZone(Word):
    """No flow while the duty is below the cracking duty."""

    def grid(self, sig, base):
        # cracking duties just above the lowest duty and the low duty quantiles (each masks the rows
        # at or below one of them, so a held level right at the cracking duty is either shut or open,
        # not both), and evenly over the lower 80 % of the duty span (a recording that rests at one
        # low level, as a ventilator's expiration does, has all its low quantiles at that level; a
        # gross dead zone shuts the valve over most of the holds of a random excitation)
        q = np.percentile(sig.duty_pct, [0, 0.5, 1, 2, 3, 4, 5, 7, 9, 12, 15, 20, 25, 30])
        span = np.linspace(q[0], q[0] + 0.8 * np.ptp(sig.duty_pct), 81)
        # (a cracking duty between two close held levels, which this grid may miss, is placed by
        # :meth:`settle`)
        c = np.unique(np.concatenate([q, span[1:]])) + 1e-6
        c = c[c <= self.plausible["cracking_pct"][1]]
        # one cracking duty of those that shut the same rows (a random excitation's held levels
        # leave many grid points between two of them)
        shut = np.searchsorted(np.sort(sig.duty_pct), c, side="right")
        return {"cracking_pct": c[np.unique(shut, return_index=True)[1]]}

    def applicable(self, sig, base):
        return None if len(self.grid(sig, base)["cracking_pct"]) else "the duty never goes low enough"

    def placed(self, sig, chain):
        # the duty where the flow at the valve leaves zero: the threshold that best splits the rows
        # into shut below it and open above it (over the plausible range). A grid a few tenths of a
        # per cent apart misses a cracking duty's narrow minimum, and a breath's rise crosses the gap
        # within a sample or two
        lo_hi = self.plausible["cracking_pct"]
        x = magnetic_duty(sig, chain)
        opened, decided = self._opened(sig, chain)
        rows = (x <= lo_hi[1]) & decided
        order = np.argsort(x[rows], kind="stable")
        xs = x[rows][order]
        opened = opened[rows][order]
        # misplaced rows with the threshold after row i: open rows at or below it, shut rows above it
        wrong = np.cumsum(opened) + (np.sum(~opened) - np.cumsum(~opened))
        i = int(np.argmin(wrong))
        c = float(xs[i]) + 1e-6
        if not (lo_hi[0] <= c < lo_hi[1] and i + 1 < len(xs)):
            return []
        # and the top of the gap up to the next row read, when rows left undecided lie in it (the rows
        # read place the cracking duty anywhere between)
        top = float(xs[i + 1]) - 1e-6
        between = np.any((x > c) & (x < top) & ~decided)
        return [{"cracking_pct": c}] + ([{"cracking_pct": top}] if between and top < lo_hi[1] else [])

    def flow_gain(self, sig, params, duty_pct):
        # the plunger lifts off its seat once the magnetic force beats the spring's preload: the
        # cracking duty is one of the coil's current, which a warm coil's resistance lowers at a
        # given commanded duty (a 46.5 % cracking duty held on the commanded duty beside a 26 K
        # heating left each breath's opening a few per cent late or early, read as a 97 K heating)
        return fx.open_mask(duty_pct, params["cracking_pct"], params.get("edge_pct", 0.0))

    def carried(self, sig, params, chain):
        # a warm coil lowers the current at every commanded duty, and a cracking duty is one of the
        # current: the rows where the flow leaves zero place it on the duty the magnetics see under
        # each setting of the heating (held where it was named, a 46.7 % cracking duty placed beside a
        # 97 K heating kept the heating refined beside it at 43 K for 26 K)
        placed = self.placed(sig, {w: p for w, p in chain.items() if w != self.word})
        if not placed:
            return params
        return {**placed[0], **{k: v for k, v in params.items() if k == "edge_pct"}}

    def smoothed(self, sig, params):
        # the edge over the duty a fraction of a kelvin moves the cracking duty by (EDGE_K): finer than
        # the rise a heating is sized to, wide enough to join the rows that cross it. A wider edge
        # (a 1 % duty band) passes flow below the cracking duty that the valve does not, and the
        # heating's valley floor then falls towards a slow warming (40 K on 600 s for 22.8 K on 180 s)
        return {**params, "edge_pct": EDGE_K * fx.ALPHA_CU_PER_K * params["cracking_pct"]}

    def at_rest(self, sig, params, base):
        rest = float(np.min(sig.duty_pct))
        if params["cracking_pct"] <= rest + 1e-6 or np.mean(base.shut(sig)[sig.duty_pct <= rest]) < 0.5:
            return None
        return {"cracking_pct": rest + 1e-6}

    def support(self, sig, params, before_lpm, noise_lpm, chain=None, extrapolated=False, after_lpm=None, fixed=False):
        x = magnetic_duty(sig, chain or {})
        below = int(np.sum(x <= params["cracking_pct"]))
        if below < MIN_END_ROWS:
            return f"only {below} rows below the cracking duty"
        lim = 3.0 * noise_lpm + 0.01 * float(np.ptp(sig.flow_lpm))
        why = None if fixed and self._open_at_rest(sig, before_lpm, lim) else \
            self._unopened_rest(sig, params, chain or {}, x)
        if why:
            return why
        # where the law says the valve is shut the measured flow must really stop (zero within the
        # noise) while the model before it predicted flow. Both are read at the sensor, so shut means
        # shut at the sensor: a lag or a delay of the chain carries the flow on past the closing, and
        # holds it off past the opening (a breath's duty has risen a few per cent above the cracking
        # duty before its flow arrives, and those rows are where a model without the law, its PI
        # smoothed through the jump, predicts flow)
        opened = self.flow_gain(sig, params, x)
        for w, p in (chain or {}).items():
            opened = VOCABULARY[w].dynamics(opened, sig.rate_hz, p)
        shut = opened < 0.02
        # either over the shut rows as a whole (a dead zone just above where the model closes by
        # itself), or where the model predicted clear flow (a deep dead zone, most of whose shut
        # rows lie below the model's own closing and say nothing either way) if the valve opens
        # with a jump there: a cracking duty holds the valve shut until the flow it would pass is
        # well above zero, where a valve closing by itself (a fitted PI smooths its kink) comes to
        # zero flow continuously
        jumps = self._jumps(sig, params, chain or {})
        if extrapolated and not jumps:
            # a PI run on below the rows it was fitted on predicts anything there: only a valve that
            # opens with a jump shows a cracking duty (a valve closing by itself comes to zero flow)
            return "the flow does not jump open above the cracking duty"
        for rows in (shut, shut & (np.abs(before_lpm) > lim) & jumps):
            if rows.sum() < MIN_END_ROWS:
                continue
            q = float(np.median(np.abs(sig.flow_lpm[rows])))
            if q <= lim and float(np.median(np.abs(before_lpm[rows]))) >= q + noise_lpm:
                return None
        q = float(np.median(np.abs(sig.flow_lpm[shut]))) if shut.any() else 0.0
        if q > lim:
            return (f"the flow does not stop below the cracking duty {params['cracking_pct']:.3g} %: median "
                    f"{q:.3g} L/min there (zero within {lim:.3g} L/min needed)")
        if self._opens_with_jump(sig, params, chain or {}):
            # a duty that crosses the cracking duty within a sample or two (a breath's rise) leaves
            # the jump between two samples, where a PI fitted without the law puts a steep opening of
            # its own: the model before it then predicts no flow where the law shuts the valve, and
            # the jump at the valve is the law's evidence
            return None
        return "the model before it already predicts no flow below the cracking duty"

    @staticmethod
    def _open_at_rest(sig: Signals, before_lpm: np.ndarray, lim: float) -> bool:
        """Whether the model before the law has the valve open at the recording's rest (its lowest
        commanded duty; median beyond ``lim``) where it measures shut (within ``lim``). Asked of a model
        file held fixed: its flow at the rest is the model's claim, not a misfit a fit left there, and
        the rest rows show a cracking duty by themselves. Breaths resting at 42 % held against a model
        file that passes 23 L/min there, the valve shut: a dead zone of 99.7 % held-out gain, refused for
        want of rows just above the rest (the breaths rise 1.6 % in a sample), left a sensor offset of
        -23 L/min to take it up."""
        rest = sig.duty_pct <= float(np.min(sig.duty_pct)) + 1e-6
        return (float(np.median(np.abs(before_lpm[rest]))) > lim
                and float(np.median(np.abs(sig.flow_lpm[rest]))) <= lim)

    def _unopened_rest(self, sig: Signals, params: dict, chain: dict, x: np.ndarray) -> str | None:
        """Why a cracking duty that shuts only the rows at the recording's lowest commanded duty (its
        rest) is not shown by it, or ``None``.

        A valve resting shut at the lowest duty passes no flow there whatever shuts it: its own closing
        below its identified range does, and a baseline that misfits the rest leaves a residual there
        that any law closing the valve at the rest takes up. Only the valve opening just above the
        cracking duty tells a cracking duty from a valve that rests shut: :data:`MIN_END_ROWS` rows
        reached opening from shut (:meth:`_opening`) within half of :data:`JUMP_BAND_PCT` above it
        whose flow at the valve (:meth:`_at_valve`) is clear of zero (its 10th percentile above the
        zero band). A breath rising from its rest crosses that band within a sample or two; a ramp,
        a sine or a random excitation holding levels there passes through it on many rows.
        """
        c = params["cracking_pct"]
        rest = float(np.min(sig.duty_pct))
        if np.any(sig.duty_pct[x <= c] > rest + 1e-6):
            return None
        q = self._at_valve(sig, chain)
        zero = self._zero_lpm(sig, q)
        near = (x > c) & (x <= c + JUMP_BAND_PCT / 2) & self._opening(sig, x, c)
        if near.sum() >= MIN_END_ROWS and float(np.percentile(q[near], 10)) > zero:
            return None
        shown = (f"{int(near.sum())} rows there on its way up from shut" if near.sum() < MIN_END_ROWS else
                 f"the flow at the valve there is {float(np.percentile(q[near], 10)):.3g} L/min at its 10th "
                 f"percentile, within the zero band of {zero:.3g} L/min")
        return (f"the cracking duty {c:.4g} % shuts only the rows at the recording's rest ({rest:.4g} % duty, where "
                f"a valve rests shut whatever shuts it) and the valve is not seen opening within "
                f"{JUMP_BAND_PCT / 2:g} % above it ({shown})")

    def settle(self, sig, params, chain):
        # a PI fitted on the rows the law leaves open is censored at zero flow, so it closes by
        # itself over shut held levels just above a cracking duty set too low (random holds), and
        # the fit cannot tell that cracking duty from the valve's own: the valve opens where its flow
        # leaves zero, so the cracking duty is raised over every held level above it whose flow (at
        # the valve) is zero, rows between included. Only over held levels: on a continuous
        # excitation the rows above a cracking duty place it, and a valve closing by itself there
        # comes to zero gradually (its last rows of zero flow are no cracking duty)
        q = self._at_valve(sig, chain)
        zero = self._zero_lpm(sig, q)
        x = magnetic_duty(sig, chain)
        c = params["cracking_pct"]
        for level in held_levels(sig.duty_pct, self.plausible["cracking_pct"][1]):
            # (the level as the magnetics see it: its highest, a warm coil's lowers it along the hold)
            at = sig.duty_pct == level
            top = float(np.max(x[at]))
            if top <= c:
                continue
            rows = (x > c) & (x <= top)
            if float(np.median(q[rows])) > zero or float(np.max(q[at])) > zero + zero:
                break
            c = top
        return {**params, "cracking_pct": c + 1e-6} if c != params["cracking_pct"] else params

    def midway(self, sig, params, chain, rows):
        # from the middle of the gap a row in it is most often shut or open right
        gap = self._gap(sig, params, chain, rows)
        return params if gap is None else {**params, "cracking_pct": 0.5 * (gap[0] + gap[1])}

    def undecided(self, sig, params, chain, rows, at):
        # a holdout row in the gap is shut or open as the setting within it happens to fall (a cracking
        # duty at 43.99985 % moved to the gap's middle, 44.0169 %, shut a holdout row at 44.017 % that
        # passed 35 L/min: a 35 L/min error on one row of 3750 turned the holdout against a dead zone
        # of 72 % held-out gain)
        gap = self._gap(sig, params, chain, rows)
        if gap is None:
            return None
        x = magnetic_duty(at, chain)
        return (x > gap[0]) & (x < gap[1])

    @staticmethod
    def _gap(sig: Signals, params: dict, chain: dict, rows: np.ndarray) -> tuple | None:
        """``(lo, hi)``: the highest duty of the training ``rows`` the cracking duty shuts and the
        lowest it leaves open (on the duty the magnetics see beside ``chain``); any cracking duty
        between them shuts the same training rows. ``None`` when it shuts all or none of them."""
        x = magnetic_duty(sig, chain)
        c = params["cracking_pct"]
        below, above = x[rows & (x <= c)], x[rows & (x > c)]
        if not (len(below) and len(above)):
            return None
        return float(np.max(below)), float(np.min(above))

    @staticmethod
    def _opening(sig: Signals, x: np.ndarray, c: float) -> np.ndarray:
        """Rows above the cracking duty ``c`` (on the duty the magnetics see, ``x``) that the valve
        reached opening from shut: the commanded duty has not fallen since it was last at or below
        ``c``, or, where the excitation never opens it so, every row above ``c``.

        A cracking duty's jump is the flow the valve passes on its loading curve from rest; above it,
        the branches the valve's memory holds after an excursion lie apart by the loop's width (a
        sweep turning back above the cracking duty passes 56 L/min at 2 % above it where a breath
        opening from shut passes 35, and a parabola over both dived to zero flow at the foot)."""
        idx = np.arange(len(x))
        fell = np.r_[False, np.diff(sig.duty_pct) < 0]
        last_shut = np.maximum.accumulate(np.where(x <= c, idx, -1))
        last_fall = np.maximum.accumulate(np.where(fell, idx, -1))
        opening = (x > c) & (last_shut >= 0) & (last_shut > last_fall)
        return opening if _spread(x[opening & (x <= c + 2.0 * JUMP_BAND_PCT)]) else x > c

    @staticmethod
    def _at_valve(sig: Signals, chain: dict) -> np.ndarray:
        """The measured flow taken back through the time response of ``chain`` (at the valve)."""
        q = sig.flow_lpm
        for w, p in reversed(list(chain.items())):
            q = VOCABULARY[w].undo(q, sig.rate_hz, p)
        return q

    def _opened(self, sig: Signals, chain: dict) -> tuple[np.ndarray, np.ndarray]:
        """The rows open at the valve, and the rows that reading decides: read back through a time
        response between two samples (:meth:`Word.bracket`: a delay of a fraction of a sample
        interpolates them), a row one sample reads shut and the other open is undecided (behind a
        26 ms delay at 50 Hz, a dozen rows at the jump read 12 L/min at the valve for 0 and 40, and
        placed the cracking duty among them, 0.02 % low)."""
        readings = [self._at_valve(sig, c) for c in bracketing(chain, sig.rate_hz)]
        zero = self._zero_lpm(sig, readings[0])
        opened = [q > zero for q in readings]
        return opened[0], np.logical_and.reduce([o == opened[0] for o in opened])

    @staticmethod
    def _zero_lpm(sig: Signals, q: np.ndarray) -> float:
        """A flow at the valve ``q`` at most this is zero within its noise (L/min)."""
        return 3.0 * signals.noise_lpm(q) + 0.01 * float(np.ptp(sig.flow_lpm))

    def absorbed(self, sig, chain):
        # a PI fitted on the recording that opens from zero flow steeply enough passes through the
        # jump as well as the law does (a breath's rise crosses it within a sample or two, and a
        # lag smooths it): the cracking duty is then seen only against a model of the valve
        jumps = [c for c in self.grid(sig, None)["cracking_pct"]
                 if self._opens_with_jump(sig, {"cracking_pct": c}, chain)]
        if not jumps:
            return None
        return (f"the flow at the valve is zero below {max(jumps):.3g} % duty and opens with a jump above it (a "
                f"cracking duty's signature), but a PI fitted on this recording opens as steeply and, with "
                f"{', '.join(chain) or 'no effect'}, explains the recording to within the noise; give the "
                f"simulation's model file (--model) to test it")

    def _opens_with_jump(self, sig: Signals, params: dict, chain: dict) -> bool:
        """Whether the flow at the valve is zero just below the cracking duty and opens with a jump
        just above it.

        Zero: 90 % of the rows within :data:`JUMP_BAND_PCT` below the cracking duty carry no flow
        (a valve closing by itself a little below it still passes flow there). The jump: 90 % of
        the rows within half that band above it carry flow, and the flow over twice the band above
        it, a parabola in the duty, extrapolated to the cracking duty is well above zero; both on
        the rows the valve reached opening from shut (:meth:`_opening`). A valve
        opening by itself rises from zero flow there, however steeply, and a coarse sampling of a
        fast rise does not move the intercept; a cracking duty opens onto the flow the valve would
        already pass. A parabola, because a valve's flow just above its own opening bends (a
        straight line through a steep start that flattens meets the cracking duty above zero).
        """
        q = self._at_valve(sig, chain)
        zero = self._zero_lpm(sig, q)
        x, c = magnetic_duty(sig, chain), params["cracking_pct"]
        below = (x > c - JUMP_BAND_PCT) & (x <= c)
        opening = self._opening(sig, x, c)
        above = (x > c) & (x <= c + 2.0 * JUMP_BAND_PCT) & opening
        # (a parabola needs duties spread over the band, not two held levels)
        if below.sum() < MIN_END_ROWS or not _spread(x[above]):
            return False
        if float(np.percentile(np.abs(q[below]), 90)) > zero:
            return False
        # (a parabola through a jump further up the band overshoots at its ends)
        near = (x > c) & (x <= c + JUMP_BAND_PCT / 2) & opening
        if near.sum() < MIN_END_ROWS or float(np.percentile(q[near], 10)) <= zero:
            return False
        return float(np.polynomial.polynomial.polyfit(x[above] - c, q[above], 2)[0]) > zero

    def _jumps(self, sig: Signals, params: dict, chain: dict) -> bool:
        """Whether the flow at the valve jumps open just above the cracking duty.

        Judged at the valve, the measured flow taken back through the time response of the
        chain (a lag smooths the jump over several samples, through which a breath's duty has
        long passed the band above the cracking duty), against that flow's own noise.
        """
        q = self._at_valve(sig, chain)
        x, c = magnetic_duty(sig, chain), params["cracking_pct"]
        opening = self._opening(sig, x, c)
        band = (x > c) & (x <= c + JUMP_BAND_PCT) & opening
        shut = x <= c
        if band.sum() < MIN_END_ROWS or shut.sum() < MIN_END_ROWS:
            return False
        opened = float(np.median(q[band]))
        above = (x > c) & (x <= c + 2.0 * JUMP_BAND_PCT) & opening
        if _spread(x[above]):
            # duties spread over the band: the flow taken down to the cracking duty itself (a valve
            # opening by itself from zero there rises through the band without a jump at its foot)
            opened = float(np.polynomial.polynomial.polyfit(x[above] - c, q[above], 2)[0])
        return opened - float(np.median(q[shut])) > self._zero_lpm(sig, q)


@dataclass(frozen=True)
class Saturation(Word):
    """Flow clipped at the full-open flow."""

    def grid(self, sig, base):
        q = np.percentile(sig.flow_lpm, [75, 82, 88, 92, 95, 97, 98.5, 99.3, 99.7, 99.9])
        return {"full_open_lpm": np.unique(np.round(q, 2))}

    def clip_lpm(self, params):
        return params["full_open_lpm"]

    def absorbed(self, sig, chain):
        # a valve at its full-open stop passes the same flow whatever the duty above the one that
        # reaches it: the highest flows pile up at one level over a band of duties. Breaths that rise
        # to it and step back down never sample the loop's descending branch there, so a PI fitted on
        # the recording flattens into the plateau as well as the clip does (beside a coil heating sized
        # right, a clip at 150 L/min gained nothing held out, its PI refitted either way)
        from .design import PLATEAU_NOISE

        flow, x = sig.flow_lpm, sig.duty_pct
        top = float(np.median(flow[flow >= np.percentile(flow, 99.0)]))
        rows = flow >= top - PLATEAU_NOISE * signals.noise_lpm(flow)
        lo, hi = np.percentile(x[rows], [5.0, 95.0]) if rows.mean() >= PLATEAU_SHARE else (0.0, 0.0)
        if hi - lo < PLATEAU_SPAN_PCT:
            return None
        level = float(np.median(flow[rows]))
        return (f"the flow flattens at {level:.4g} L/min over {lo:.3g}-{hi:.3g} % duty ({int(rows.sum())} rows: a "
                f"full-open flow's signature), but a PI fitted on this recording flattens as well and, with "
                f"{', '.join(chain) or 'no effect'}, explains the recording to within the noise; give the "
                f"simulation's model file (--model) to test it")

    def support(self, sig, params, before_lpm, noise_lpm, chain=None, extrapolated=False, after_lpm=None, fixed=False):
        top = before_lpm > params["full_open_lpm"]
        if top.sum() < MIN_END_ROWS:
            return f"only {int(top.sum())} rows where the model before it exceeds the full-open flow"
        if fixed:
            # a model file held fixed claims its own flow at the top, flat where its input is held at the
            # top of its identified range. A clip holds the measured flow at the full-open flow where the
            # model still rises past it; a flow measured under the model's own plateau that rises with
            # the model there is a level (a sensor offset read 2.3 L/min high beside a foreign valve's
            # asymmetric loop: a clip 2.5 L/min under the plateau took up the offset's error, its held-out
            # residual correlation 0.61), and one it lowers by no more than the noise cannot be told from
            # a misfit at the top (1.0 L/min under the plateau beside a dead zone, correlation 0.31)
            cut = before_lpm[top] - params["full_open_lpm"]
            if np.sum(cut > CLIP_CUT_NOISE * noise_lpm) < MIN_END_ROWS:
                return (f"it lowers the model file's flow by at most {float(np.max(cut)):.3g} L/min (needs more "
                        f"than {CLIP_CUT_NOISE:g} x the noise {noise_lpm:.3g} L/min on {MIN_END_ROWS} rows)")
            rising = top & (before_lpm < float(np.max(before_lpm)) - noise_lpm)
            if rising.sum() < MIN_RISING_ROWS:
                return (f"only {int(rising.sum())} of the rows it clips are below the model file's own plateau "
                        f"({float(np.max(before_lpm)):.4g} L/min, needs {MIN_RISING_ROWS}): it moves the model's "
                        f"full-open flow, not a clip of its rising flow")
            slope = float(np.polyfit(before_lpm[rising], sig.flow_lpm[rising], 1)[0])
            if slope > MAX_CLIPPED_SLOPE:
                return (f"where the model file rises past {params['full_open_lpm']:.4g} L/min below its own "
                        f"plateau, the measured flow rises with it (slope {slope:.2f}, a clip holds it: at most "
                        f"{MAX_CLIPPED_SLOPE:g})")
        # where the law clips, the measured flow must flatten at the full-open flow
        q = sig.flow_lpm[top]
        lim = 3.0 * noise_lpm + 0.01 * float(np.ptp(sig.flow_lpm))
        dev = float(np.median(np.abs(q - params["full_open_lpm"])))
        if dev > lim:
            return (f"the flow does not flatten at {params['full_open_lpm']:.4g} L/min where the model exceeds it "
                    f"(median distance {dev:.3g} L/min, within {lim:.3g} needed)")
        # and the full-open flow bounds the flow everywhere (a lag or a delay passes no more than it):
        # a clip placed just under the top of a loading curve the baseline cannot bend to (a PI of
        # 50 operators too steep over the last per cent of duty) leaves the highest rows measured
        # far above it (12x the noise, on a tenth of the rows it clips)
        over = int(np.sum(sig.flow_lpm > params["full_open_lpm"] + lim))
        if over > max(MIN_END_ROWS, OVER_CLIP_SHARE * top.sum()):
            return (f"the flow exceeds the full-open flow {params['full_open_lpm']:.4g} L/min by more than "
                    f"{lim:.3g} L/min on {over} rows (up to {float(np.max(sig.flow_lpm)):.4g} L/min)")
        return None


@dataclass(frozen=True)
class Creep(Word):
    """Slow drift after each reversal towards a fraction of the last reversal step."""

    def grid(self, sig, base):
        return {"tau_s": np.geomspace(0.5, min(400.0, _span(sig) / 4), 9)}

    def placed(self, sig, chain):
        # beside a law that moves the duty the magnetics see, the reversals are also read on that
        # duty (:meth:`valve_columns`)
        if not _moves_core_input(chain):
            return []
        return [{"tau_s": float(t), "magnetic": 1.0} for t in self.grid(sig, None)["tau_s"]]

    def choices(self, params, sig, chain):
        if not _moves_core_input(chain):
            return []
        if params.get("magnetic"):
            return [{k: v for k, v in params.items() if k != "magnetic"}]
        return [{**params, "magnetic": 1.0}]

    def valve_columns(self, ctx, params):
        # the plunger creeps, and the step it creeps after is one of the flow the valve passed. It
        # creeps before the no-reverse-flow floor (:attr:`Word.before_floor`): a valve the reference
        # has just shut passes the flow its plunger crept open (breaths resting just below the
        # valve's opening pass a few L/min at rest after each breath), one measured shut passes
        # nothing however far it has crept. It creeps on after each reversal of its motion: of the
        # commanded duty, or with ``magnetic`` of the duty the magnetics see (the hysteresis core's
        # input, :attr:`Columns.core_input`), the two apart only beside a law that moves it. A coil
        # warming through a commanded hold lowers its current, and a plunger driven by the current
        # turns back there (each step up of a random-hold sequence turns it back as the coil warms,
        # a step down as it cools; plant_sim's valve: a coil 30 K warm beside a creep of 0.15 on a
        # mixed excitation, the chain at its true settings fitted the creep as 0.20 on the commanded
        # duty, its training error 8 x the noise floor, and as 0.16 on the magnetic duty, 3.7 x, that
        # of the heating alone on the recording without creep 2.6 x)
        on = ctx.core_input if params.get("magnetic") and ctx.core_input is not None else ctx.sig.duty_pct
        q = np.clip(ctx.flow_lpm, 0.0, None)
        return [fx.creep(q, branch(on), ctx.sig.rate_hz, params["tau_s"])]

    def instant(self, params, sig):
        # settled within the sample after each reversal: a level that depends on the last reversal
        # step, which a loop's own shape makes too (an asymmetric loop on breaths, whose rest flow
        # follows the peak of the breath before)
        return {**params, "tau_s": 1.0 / sig.rate_hz}

    def physical(self, params, coef, sig, base, fitted_lpm=None):
        return {"tau_s": float(params["tau_s"]), "amplitude": float(coef)}


@dataclass(frozen=True)
class SensorOffset(Word):
    """Constant zero offset of the flow sensor."""

    def applicable(self, sig, base):
        if base.refit:
            return ("absorbed by the offset c of Eq. (4) of a baseline fitted on this recording; "
                    "give the simulation's model file (--model) to test it")
        return None

    def sensor_columns(self, ctx, params):
        return [np.ones(len(ctx.sig))]

    def support(self, sig, params, before_lpm, noise_lpm, chain=None, extrapolated=False, after_lpm=None, fixed=False):
        # a zero offset is what the sensor reads at zero flow: where the model with the other words
        # has the valve shut (seated at rest, or below a cracking duty) the fitted constant must be
        # of the flow read there, within a factor of two (over the open valve it also takes up the
        # model's mean misfit there, a few per cent of the flow). One the shut valve contradicts
        # takes up a misfit of the open valve (a 35 K heating's, refused beside a supply wander: a
        # constant of -9.2 L/min where the shut valve read +1.7)
        if after_lpm is None:
            return None
        read = self._at_zero_flow(sig, before_lpm, after_lpm)
        if read is None:
            return None
        read_lpm, fit_lpm, sd_lpm = read
        if not (read_lpm * fit_lpm > 0 and 0.5 * abs(read_lpm) - 3.0 * sd_lpm <= abs(fit_lpm) <= 2.0 * abs(read_lpm) + 3.0 * sd_lpm):
            return (f"the sensor reads {read_lpm:.3g} L/min where the valve is shut, not of the fitted offset "
                    f"{fit_lpm:.3g} L/min: the constant takes up a misfit of the open valve")
        return None

    def pinned(self, sig, before_lpm, after_lpm):
        return self._at_zero_flow(sig, before_lpm, after_lpm) is not None

    def physical(self, params, coef, sig, base, fitted_lpm=None):
        out = {"offset_lpm": float(coef)}
        read = None if fitted_lpm is None else self._at_zero_flow(sig, fitted_lpm - coef, fitted_lpm)
        if read is not None:
            # sized where it is the only flow the sensor sees: over the open valve the constant also
            # takes up the model's mean misfit (a foreign valve held against its model file: -1.70
            # L/min for -2.19, read -2.17 below a cracking duty)
            out = {"offset_lpm": read[0], "fit_offset_lpm": float(coef)}
        return out

    @staticmethod
    def _at_zero_flow(sig: Signals, before_lpm: np.ndarray, after_lpm: np.ndarray) -> tuple | None:
        """``(read, fitted, sd)`` (L/min): the median measured flow and the fitted offset over the rows
        where the prediction without the offset ``before_lpm`` is zero flow, and the read's standard
        error; ``None`` with fewer than :data:`MIN_ZERO_ROWS` such rows (and 1 % of the recording),
        or when the flow measured there spreads beyond the noise."""
        zero = np.abs(before_lpm) <= 1e-6
        n = int(zero.sum())
        if n < max(MIN_ZERO_ROWS, 0.01 * len(zero)):
            return None
        q = sig.flow_lpm[zero]
        noise = signals.noise_lpm(sig.flow_lpm)
        if np.subtract(*np.percentile(q, [75, 25])) > 2.0 * 1.349 * noise:
            # spread beyond the noise's: the valve passes flow on many of the rows its model shuts
            # (it opens lower than its model file), which say nothing of the zero
            return None
        return float(np.median(q)), float(np.median(after_lpm[zero])), float(1.25 * noise / np.sqrt(n))


#: The effect words, in the order the augmented model chains them.
VOCABULARY: dict[str, Word] = {w.word: w for w in (
    AsymmetricHysteresis(
        "asymmetric_hysteresis", "every play operator's descending threshold r widened to r (1 + a s) + c s with "
        "the input level s (generalized PI), the PI refitted with it",
        {"extra_width": "relative (1 = twice as wide) at full flow",
         "widen": "relative widening of each descending threshold at the top (a)",
         "lift_pct": "% duty (lift of every descending threshold at the top, c)",
         "start_pct": "% duty (where the widening starts, on a recording resting below the opening)"},
        {"extra_width": (0.003, 30.0)}, joint_with_pi=True, whole_plot=True, input_side="thresholds",
        probe={"widen": 1.0}, settled_ends=(("widen", "low"),), beyond_symmetric=True,
        residual_support=True),
    CoilHeating(
        "coil_heating", "tau dT/dt = rise55 (duty/55 %)^2 - T, or the measured coil_temp_c; effective duty = "
        "duty / (1 + 0.00393 T), the PI refitted on it",
        {"rise55_k": "K (steady rise at 55 % duty)", "tau_s": "s", "start": "fraction of the steady rise at t = 0",
         "copper_law_ratio": "- (measured temperature: 1 = copper's 0.393 %/K)", "coil_temp_span_k": "K",
         "ambient_c": "deg C"},
        {"rise55_k": (0.05, LAW_RISE55_K), "tau_s": (10.0, 1e4), "copper_law_ratio": (0.3, 3.0)},
        joint_with_pi=True, unresolved=("tau_s", "low"), whole_plot=True, input_side="duty",
        ratio_of={"rise55_k": "tau_s"}, settled_ends=("floor_pct",), beyond_curve=True),
    SupplyPressure(
        "supply_pressure", "flow x ((p + 1.013) / (p_mean + 1.013))^exponent from the supply_bar column, "
        "to first order, the PI refitted with it",
        {"exponent": "- (1 = choked flow)", "wander_bar": "bar (half the range of supply_bar)"},
        {"exponent": (0.3, 2.0)}, joint_with_pi=True, whole_plot=True),
    ValveDynamics(
        "valve_dynamics", "first-order lag of the flow: tau dq/dt = q_static - q, sampled with the command "
        "held (phase 1) or already seen within its sample (phase 0)",
        {"tau_s": "s", "phase": "- (share of the previous sample's command)"}, {"tau_s": (0.0, 2.0)},
        unresolved=("tau_s", "high"), probe={"tau_s": 0.02, "phase": 1.0}, beyond_loop=True),
    TransportDelay(
        "transport_delay", "pure delay from command to measured flow",
        {"delay_s": "s"}, {"delay_s": (0.0, 1.0)}, unresolved=("delay_s", "high"), probe={"delay_s": 0.01},
        beyond_loop=True),
    DeadZone(
        "dead_zone", "no flow while the duty the magnetics see (a warm coil's effective duty) is below the "
        "cracking duty",
        {"cracking_pct": "%"}, {"cracking_pct": (0.5, 65.0)}, static=True,
        resolution={"cracking_pct": CRACKING_STEP_PCT}),
    Saturation(
        "saturation", "flow clipped at the full-open flow",
        {"full_open_lpm": "L/min"}, {"full_open_lpm": (10.0, 400.0)}, static=True),
    Creep(
        "creep", "after each reversal the flow drifts on the way it went, to a fraction a of the last "
        "reversal-to-reversal step, first order with tau",
        {"amplitude": "fraction of the last reversal step", "tau_s": "s"},
        {"amplitude": (0.003, 1.0), "tau_s": (0.3, 1000.0)}, joint_with_pi=True, unresolved=("tau_s", "high"),
        whole_plot=True, before_floor=True, drifts=True, beyond_loop=True),
    SensorOffset(
        "sensor_offset", "constant zero offset of the flow sensor",
        {"offset_lpm": "L/min"}, {"offset_lpm": (-30.0, 30.0)}, shifts_level=True),
)}
#: The effect words of DESIGN.md.
WORDS = tuple(VOCABULARY)
#: The two words of the flow's time response, which a smooth excitation cannot tell apart.
DYNAMIC = ("valve_dynamics", "transport_delay")
