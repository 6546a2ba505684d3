"""The identification protocol: what duty to command, step by step, within the time available.

Four phases, in order, every one fitted to the duration asked for:

1. ``range``: a ramp up from the lowest allowed duty, turning back at the
   highest allowed duty or as soon as the flow reaches the ceiling (a
   fraction of the flow limit), then down again. The ramps give the working
   range: ``lo`` where the valve passes flow on either ramp (cracking on the
   way up, or closing on the way down: a hysteretic valve closes well below
   the duty it cracked at, and a controller asking for no flow must know
   where), ``hi`` where the flow stops rising (fully open) or the ceiling was met.
   It is the one adaptive phase; the rest is planned once it ends.
2. ``sweep``: the paper's identification signal (§2.2, Fig. 2), swings of
   growing amplitude about the middle of [lo, hi]
   (:func:`plant_sim.protocols.paper_identification`), its peak rate chosen so
   that a number of swings that grows with the time available fits.
3. ``reversals``: decaying swings about two levels (first-order reversal
   curves and nested minor loops), at the sweep's rate.
4. ``steps``: held levels, alternately up and down, of random sizes at
   random places in the range: the lag and the delay are read from them and
   they are never fitted (the model is validated on them).

A hysteretic valve is rate-independent, so the sweep may run faster than the
paper's 0.4 %/s when time is short; what a faster sweep adds (the valve's
lag seen as a shift) is taken out with the lag and delay the steps give.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.recording import InputError
from plant_sim.protocols import paper_identification, swings

PHASES = ("range", "sweep", "reversals", "steps")
#: Share of the time after the range phase given to each planned phase.
SHARES = {"sweep": 0.55, "reversals": 0.15, "steps": 0.30}
#: Each way of the range ramp takes this share of the duration.
RANGE_SHARE = 0.04
#: Cracking and full-open thresholds of the range finding, fractions of the largest flow seen.
CRACK_FRACTION, OPEN_FRACTION = 0.03, 0.98
#: Step holds, s: long enough for a lag of up to a tenth of the shortest (short protocols get more steps,
#: so more chances of one a stall of a busy machine does not fall into).
HOLD_S = (0.3, 2.5)


@dataclass(frozen=True)
class ProtocolParams:
    """What the protocol may do.

    Attributes
    ----------
    duration_s : float
        Valve time for the whole protocol, s.
    rate_hz : float
        Command rate, Hz.
    duty_min_pct, duty_max_pct : float
        Allowed duty range, %.
    flow_ceiling_lpm : float
        The range ramp turns back when the measured flow reaches this, L/min.
    seed : int
        Step levels and sizes.
    """

    duration_s: float
    rate_hz: float
    duty_min_pct: float = 0.0
    duty_max_pct: float = 100.0
    flow_ceiling_lpm: float = math.inf
    seed: int = 0

    def __post_init__(self):
        if not (math.isfinite(self.duration_s) and 10.0 <= self.duration_s <= 86400.0):  # as [identify] duration_s
            raise InputError(f"--duration: 10 s to one day (86400 s) of valve time, got {self.duration_s:g}")
        if not self.duty_min_pct < self.duty_max_pct:
            raise InputError(f"limits: duty_min_pct {self.duty_min_pct:g} must be below duty_max_pct {self.duty_max_pct:g}")


@dataclass(frozen=True)
class WorkingRange:
    """The valve's working range from the range ramp.

    Attributes
    ----------
    lo_pct : float
        Lowest duty with a flow above :data:`CRACK_FRACTION` of its largest value: on the way up
        (cracking) or on the way down (closing), %.
    hi_pct : float
        Duty at which it first reaches :data:`OPEN_FRACTION` of it, %.
    flow_max_lpm : float
        Largest (smoothed) flow on the ramp, L/min.
    """

    lo_pct: float
    hi_pct: float
    flow_max_lpm: float

    @property
    def span_pct(self) -> float:
        return self.hi_pct - self.lo_pct


def working_range(duty_pct: np.ndarray, flow_lpm: np.ndarray, rate_hz: float, down_duty_pct: np.ndarray | None = None,
                  down_flow_lpm: np.ndarray | None = None) -> WorkingRange:
    """Working range from an ascending ramp and, when given, the descending one after it
    (flow smoothed over 50 ms against the noise).

    Raises
    ------
    InputError
        When the flow never rises: no working range to identify.
    """
    w = max(1, int(round(0.05 * rate_hz)))

    def smoothed(f):
        return np.convolve(f, np.ones(w) / w, mode="same") if len(f) > w else np.asarray(f, dtype=np.float64)

    smooth = smoothed(flow_lpm)
    top = float(np.max(smooth)) if len(smooth) else 0.0
    if not top > 1.0:
        raise InputError(f"identify: the flow never exceeded 1 L/min on the range ramp (largest {top:.2f} L/min): "
                         "is the valve supplied and the duty range right?")
    i_lo = int(np.argmax(smooth > CRACK_FRACTION * top))
    i_hi = int(np.argmax(smooth >= OPEN_FRACTION * top))
    lo, hi = float(duty_pct[max(i_lo - 1, 0)]), float(duty_pct[i_hi])
    if down_duty_pct is not None and len(down_duty_pct):
        passing = np.flatnonzero(smoothed(down_flow_lpm) > CRACK_FRACTION * top)
        if len(passing):  # the last duty on the way down that still passed flow, one row on
            lo = min(lo, float(down_duty_pct[min(passing[-1] + 1, len(down_duty_pct) - 1)]))
    if not hi - lo > 1.0:
        raise InputError(f"identify: working range {lo:.1f}..{hi:.1f} % is too narrow to identify")
    return WorkingRange(lo, hi, top)


def sweep_duty(r: WorkingRange, duration_s: float, rate_hz: float) -> np.ndarray:
    """The paper's growing sweep over ``r`` in ``duration_s``: 7 to 21 swings (one per ~25 s)."""
    half = r.span_pct / 2.0
    a0 = 0.08 * half
    k = int(np.clip(round(duration_s / 25.0), 7, 21)) | 1
    # paper_identification fits k swings of ~(a0 + half) each plus the last full swing at this peak rate
    rate = 1.01 * math.pi * (k * (a0 + half) + 2.0 * half) / (2.0 * duration_s)
    return paper_identification(rate_hz, duration_s, lo_pct=r.lo_pct, hi_pct=r.hi_pct, max_rate_pct_s=max(rate, 0.4),
                                start_amplitude_pct=a0)


def reversal_duty(r: WorkingRange, start_pct: float, duration_s: float, rate_hz: float) -> np.ndarray:
    """Decaying swings about 30 % and 70 % of the range: reversal curves and nested minor loops."""
    a = 0.25 * r.span_pct
    decay = np.array([1.0, -0.7, 0.45, -0.25, 0.1])
    c1, c2 = r.lo_pct + 0.3 * r.span_pct, r.lo_pct + 0.7 * r.span_pct
    ext = np.concatenate([[start_pct], c1 + a * decay, c2 - a * decay])
    span = float(np.sum(np.abs(np.diff(ext))))
    rate = math.pi * span / (2.0 * duration_s)
    x = swings(ext, rate * 1.02, rate_hz)
    n = max(1, int(round(duration_s * rate_hz)))
    return np.concatenate([x, np.full(max(0, n - len(x)), x[-1])])[:n]


def step_duty(r: WorkingRange, start_pct: float, duration_s: float, rate_hz: float, seed: int = 0) -> np.ndarray:
    """Held levels, alternately up and down by 8-90 % of the range, held for ``duration_s / 40`` (0.3-2.5 s)."""
    rng = np.random.default_rng(seed)
    hold = float(np.clip(duration_s / 40.0, *HOLD_S))
    n_hold = max(1, int(round(hold * rate_hz)))
    n = max(1, int(round(duration_s * rate_hz)))
    lo_f, hi_f, gap = 0.05, 0.95, 0.08
    f = float(np.clip((start_pct - r.lo_pct) / r.span_pct, lo_f, hi_f))
    up = f < 0.5
    levels = []
    for _ in range(math.ceil(n / n_hold)):
        if up and f + gap > hi_f or not up and f - gap < lo_f:
            up = not up
        f = rng.uniform(f + gap, hi_f) if up else rng.uniform(lo_f, f - gap)
        levels.append(r.lo_pct + f * r.span_pct)
        up = not up
    return np.repeat(levels, n_hold)[:n]


def plan(r: WorkingRange, start_pct: float, duration_s: float, rate_hz: float, seed: int = 0):
    """The phases after the range ramp: ``(duty (N,), [(phase, start, stop), ...])`` in ``duration_s``."""
    parts, out, k = [], [], 0
    t = {p: SHARES[p] * duration_s for p in SHARES}
    sweep = sweep_duty(r, t["sweep"], rate_hz)
    # from where the range ramp left the valve to the sweep's start, at the sweep's pace, within its share
    lead = swings([start_pct, sweep[0]], max(abs(sweep[0] - start_pct) / 2.0, 1.0), rate_hz)
    sweep = np.concatenate([lead, sweep])[: len(sweep)]
    rev = reversal_duty(r, float(sweep[-1]), t["reversals"], rate_hz)
    steps = step_duty(r, float(rev[-1]), t["steps"], rate_hz, seed)
    for name, x in (("sweep", sweep), ("reversals", rev), ("steps", steps)):
        parts.append(x)
        out.append((name, k, k + len(x)))
        k += len(x)
    return np.concatenate(parts), out


class Program:
    """The protocol as a state machine in valve time: :meth:`next` gives the duty and phase at ``t_s``.

    The range ramp runs first; when it is back at the bottom, the rest is
    planned (:func:`plan`) for the time left. Steps a busy machine missed
    are skipped, so the protocol keeps to its duration.
    """

    def __init__(self, p: ProtocolParams):
        self.p = p
        self.ramp_rate = (p.duty_max_pct - p.duty_min_pct) / (RANGE_SHARE * p.duration_s)  # %/s
        self.t_s = 0.0
        self.duty = p.duty_min_pct
        self.phase = "range"
        self.turn: tuple[float, float] | None = None  # (time, duty) the ramp turned back at
        self.up_duty: list[float] = []
        self.up_flow: list[float] = []
        self.down_duty: list[float] = []
        self.down_flow: list[float] = []
        self.range: WorkingRange | None = None
        self.rest: np.ndarray | None = None
        self.rest_phases: list = []
        self.rest_t0 = 0.0

    @property
    def fraction(self) -> float:
        """Share of the protocol's duration done, 0..1."""
        return min(1.0, self.t_s / self.p.duration_s)

    def next(self, flow_lpm: float, t_s: float) -> tuple[float, str] | None:
        """Duty (%) and phase at ``t_s`` (s since the start), given the newest measured flow; None when done."""
        p = self.p
        self.t_s = t_s
        if self.phase == "range":
            if self.turn is None:
                self.up_duty.append(self.duty)
                self.up_flow.append(flow_lpm)
                if self.duty >= p.duty_max_pct or flow_lpm >= p.flow_ceiling_lpm:
                    self.turn = (t_s, self.duty)
                else:
                    self.duty = min(p.duty_min_pct + self.ramp_rate * t_s, p.duty_max_pct)
            else:
                self.down_duty.append(self.duty)
                self.down_flow.append(flow_lpm)
            if self.turn is not None:
                self.duty = max(self.turn[1] - self.ramp_rate * (t_s - self.turn[0]), p.duty_min_pct)
                if self.duty <= p.duty_min_pct:
                    self._plan_rest(t_s)
        if self.phase != "range":
            i = int(round((t_s - self.rest_t0) * p.rate_hz))
            if i >= len(self.rest):
                return None
            self.duty = float(self.rest[i])
            self.phase = next(name for name, a, b in self.rest_phases if a <= i < b)
        return self.duty, self.phase

    def _plan_rest(self, t_s: float) -> None:
        self.range = working_range(np.asarray(self.up_duty), np.asarray(self.up_flow), self.p.rate_hz,
                                   np.asarray(self.down_duty), np.asarray(self.down_flow))
        left_s = max(self.p.duration_s - t_s, 1.0)
        self.rest, self.rest_phases = plan(self.range, self.duty, left_s, self.p.rate_hz, self.p.seed)
        self.rest = np.clip(self.rest, self.p.duty_min_pct, self.p.duty_max_pct)
        self.rest_t0 = t_s
        self.phase = "sweep"
