"""The recording as the valve lived it: on the session's even time grid, with what a busy machine lost.

A session on a loaded machine misses periods. While it is descheduled no
command goes out, so the valve holds the duty it last got, and of the
readings its bridge published meanwhile the session sees the newest only.
The recording's rows are then unevenly spaced (``t_s`` says when each was
made), and whatever counts row ``k`` as time ``k / rate`` — a lag, a delay,
a lowpass, a derivative — reads the valve's dynamics wrong: a fit smears its
loops, and a validation through the lag and delay scores the wrong kind
best. So the identification works on the even grid of the session's rate:

- ``duty_pct``: the command in force at each grid time (zero-order hold: what
  the valve was actually driven with, held through every missed period);
- ``flow_lpm``: the fresh readings at their rows' times, linear between them;
- ``fresh``: grid times with a reading received in that step;
- ``observed``: grid times not inside a reading gap longer than
  :data:`STALL_PERIODS` periods (what a figure may be scored on: inside a
  longer gap the interpolated flow is a guess);
- ``phase``: the protocol phase of the command in force.

A recording without a missed period maps onto the grid row for row.

How damaged the recording is (:class:`Damage`) is counted on the grid:
missed periods, the stalls they came in, and the share of the fitted
phases' and of the steps' time not observed. :func:`verdict` turns it into
``ok``, ``degraded`` (said, the identification made) or ``damaged``
(refused: no model from it). Hysteresis is rate independent and the duty
the valve held is known through every stall, so an identification on the
timeline survives a lot (``bench/bench_identify_load.py``: 2 minutes in-process,
stalls at random, the valve running on through them): held-out RMSE against
the bench twin 1.38 L/min with 47 % of the periods missed in 8 ms stalls,
2.10 and 1.49 with 53 % and 78 % missed in 60 ms stalls, 1.39 from a clean
session (PVP twin: 0.48, 0.51, 0.52; clean 0.46); the rows taken as evenly
spaced instead gave 2.57, 2.06, 6.42 (PVP 5.09, 1.66, 3.50).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A row made up to this share of a period before a deadline belongs to that deadline's period.
EARLY_PERIODS = 0.25
#: A reading gap longer than this many periods is a stall (as :data:`.dynamics.CLEAN_GAP_PERIODS`).
STALL_PERIODS = 2.5
#: Missed share of the session's periods from which the identification says it was disturbed.
DEGRADED_MISSED = 0.10
#: Unobserved share of the fitted phases' (or of the steps') time above which nothing is identified: beyond
#: the 78 % measured to still identify both twins (module docstring), there is little left to fit on.
DAMAGED_UNOBSERVED = 0.85


@dataclass(frozen=True)
class Timeline:
    """The recording on the session's even grid (see the module's docstring); arrays of one length."""

    t_s: np.ndarray
    duty_pct: np.ndarray
    flow_lpm: np.ndarray
    fresh: np.ndarray
    observed: np.ndarray
    phase: np.ndarray
    row: np.ndarray  # grid index of every recording row
    rate_hz: float


@dataclass(frozen=True)
class Damage:
    """What a busy machine cost the recording.

    Attributes
    ----------
    periods : int
        Grid periods the session spanned.
    missed : int
        Periods with no command sent (the valve held the duty before).
    stalls : int
        Runs of consecutive missed periods.
    longest_stall_ms : float
        Longest of them, ms.
    unobserved_share : float
        Share of the periods inside a reading gap longer than :data:`STALL_PERIODS` periods.
    unobserved_fit_share, unobserved_steps_share : float
        The same share over the fitted phases and over the steps.
    longest_gap_ms : float
        Longest time between two fresh readings (or from the start to the first, or from the last to
        the end), ms.
    """

    periods: int
    missed: int
    stalls: int
    longest_stall_ms: float
    unobserved_share: float
    unobserved_fit_share: float
    unobserved_steps_share: float
    longest_gap_ms: float

    @property
    def missed_share(self) -> float:
        return self.missed / max(self.periods, 1)

    def to_json(self) -> dict:
        return {"periods": self.periods, "missed": self.missed, "missed_share": self.missed_share,
                "stalls": self.stalls, "longest_stall_ms": self.longest_stall_ms,
                "unobserved_share": self.unobserved_share, "unobserved_fit_share": self.unobserved_fit_share,
                "unobserved_steps_share": self.unobserved_steps_share, "longest_gap_ms": self.longest_gap_ms,
                "verdict": verdict(self)[0]}


def timeline(t_s: np.ndarray, duty_pct: np.ndarray, flow_lpm: np.ndarray, fresh: np.ndarray, phase: np.ndarray,
             rate_hz: float) -> Timeline:
    """The recording's rows (times ``t_s`` from its first row, s) on the even grid of ``rate_hz``.

    Each row goes to the grid period it was made in: a loop wakes at or a little after each
    deadline, so a row belongs to the last period started by its time (up to :data:`EARLY_PERIODS`
    earlier: a clock that woke a hair early). Rows never share a period: one that would takes the
    next free one.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    k = np.floor((t_s - t_s[0]) * rate_hz + EARLY_PERIODS).astype(np.int64)
    for i in np.flatnonzero(np.diff(k) <= 0):  # a row woke late in its period, the next on time: it keeps its own
        if i == 0 or k[i] - 1 > k[i - 1]:
            k[i] -= 1
    k = np.maximum.accumulate(k - np.arange(len(k))) + np.arange(len(k))  # strictly increasing
    n = int(k[-1]) + 1
    held = np.searchsorted(k, np.arange(n), side="right") - 1  # the row whose command is in force
    fresh = np.asarray(fresh, dtype=bool)
    kf = k[fresh]
    grid_fresh = np.zeros(n, dtype=bool)
    grid_fresh[kf] = True
    grid_s = t_s[0] + np.arange(n) / rate_hz
    flow = np.interp(grid_s, t_s[fresh], np.asarray(flow_lpm, dtype=np.float64)[fresh]) if len(kf) else np.zeros(n)
    return Timeline(grid_s, np.asarray(duty_pct, dtype=np.float64)[held], flow, grid_fresh,
                    ~in_gaps(kf, n, STALL_PERIODS), np.asarray(phase)[held], k, rate_hz)


def in_gaps(fresh_k: np.ndarray, n: int, min_periods: float) -> np.ndarray:
    """Grid periods strictly inside a gap of more than ``min_periods`` periods between fresh readings
    (``fresh_k``, their grid indices; before the first and after the last count as gaps too)."""
    edges = np.concatenate([[-1], np.asarray(fresh_k, dtype=np.int64), [n]])
    big = np.flatnonzero(np.diff(edges) > min_periods)
    marks = np.zeros(n + 1, dtype=np.int64)
    np.add.at(marks, edges[big] + 1, 1)
    np.add.at(marks, edges[big + 1], -1)
    return np.cumsum(marks)[:n] > 0


def damage(tl: Timeline, fit_phases: tuple[str, ...], steps_phase: str) -> Damage:
    """Count what the machine cost :class:`Timeline` ``tl`` (see :class:`Damage`)."""
    n = len(tl.t_s)
    sent = np.zeros(n, dtype=bool)
    sent[tl.row] = True
    missed = ~sent
    starts = np.flatnonzero(missed & ~np.r_[False, missed[:-1]])
    ends = np.flatnonzero(missed & ~np.r_[missed[1:], False])
    unseen = ~tl.observed

    def share(of):
        return float(np.mean(unseen[of])) if of.any() else 0.0

    gaps = np.diff(np.r_[0, np.flatnonzero(tl.fresh), n - 1])  # from the start and to the end too
    return Damage(n, int(missed.sum()), len(starts),
                  float(np.max(ends - starts + 1)) * 1e3 / tl.rate_hz if len(starts) else 0.0,
                  float(np.mean(unseen)), share(np.isin(tl.phase, fit_phases)), share(tl.phase == steps_phase),
                  float(gaps.max()) * 1e3 / tl.rate_hz)


def verdict(d: Damage) -> tuple[str, str | None]:
    """``("ok" | "degraded" | "damaged", why in words or None)``.

    ``damaged``: more than :data:`DAMAGED_UNOBSERVED` of the fitted phases' or of the steps' time
    unobserved: no model is made from it. ``degraded``: more than :data:`DEGRADED_MISSED` of the
    periods missed: the identification is made on the timeline the valve lived, and says so.
    """
    gaps = (f"{d.missed_share:.0%} of the periods missed in {d.stalls} stalls (longest {d.longest_stall_ms:.0f} ms), "
            f"no reading for {d.unobserved_fit_share:.0%} of the fitted phases and {d.unobserved_steps_share:.0%} of "
            f"the steps (longest gap {d.longest_gap_ms:.0f} ms)")
    if max(d.unobserved_fit_share, d.unobserved_steps_share) > DAMAGED_UNOBSERVED:
        return "damaged", (f"the recording is too damaged to identify from: {gaps}; identify again on a quieter "
                           "machine (or with the session at real-time priority)")
    if d.missed_share > DEGRADED_MISSED:
        return "degraded", f"a busy machine: {gaps}; the fits and figures are from the timeline the valve lived"
    return "ok", None
