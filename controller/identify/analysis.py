"""From a session's recording to the identified valve: timeline, damage, lag and delay, models.

The steps of :mod:`controller.identify` after the session, in order:

1. the recording on the even grid the valve lived (:func:`.timeline.timeline`:
   the duty held through missed periods, the readings at their times), and
   what the machine cost it (:func:`.timeline.damage`); a recording too
   damaged to identify from is refused (:class:`Damaged`);
2. the lag and delay from the steps (:func:`.dynamics.dynamics_from_steps`,
   on the rows' own times), the delay then in the loop's convention (one
   period less than command to reading);
3. every kind fitted and validated (:func:`.estimate.estimate`), the
   feedforward's kind chosen; when the valve publishes its coil temperature,
   on the duty its magnetics saw referred to the coil's temperature at the
   start (:func:`coil_referred_duty`).

A solenoid's coil warms as it works (minutes), and its resistance with it: at
a given PWM duty the current, the duty the magnetics see, falls by copper's
0.393 %/K. A valve identified while its coil warmed by 8 K is a model of no
temperature at all (its duty axis drifting 3 % over the protocol); referred to
the temperature it started at (the valve at rest, its coil at ambient) it is
the valve as a run starts it.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from models.fitting import KINDS

from .dynamics import Dynamics, dynamics_from_steps
from .estimate import FIT_PHASES, VALIDATION_PHASE, Estimate, estimate
from .session import SessionResult
from .timeline import Damage, Timeline, damage, timeline, verdict


#: Temperature coefficient of copper's resistance, /K (the coil's current at a given duty falls by it per K).
COPPER_ALPHA_PER_K = 0.00393
#: Coil temperatures believed, °C (a reading outside is a bad one, and left out).
COIL_RANGE_C = (-50.0, 250.0)


class Damaged(ValueError):
    """The recording lost too much to a busy machine to identify the valve from (the message says what)."""


@dataclass(frozen=True)
class Identification:
    """The identified valve and what it was identified from.

    Attributes
    ----------
    timeline : Timeline
    damage : Damage
    verdict : str
        ``ok`` or ``degraded`` (:func:`.timeline.verdict`).
    warning : str or None
        Why it is degraded, in words.
    dynamics : Dynamics
        ``delay_s`` in the loop's convention.
    estimate : Estimate
    coil_ref_c : float or None
        The coil temperature the models' duty is referred to, °C (None: no coil temperature published).
    """

    timeline: Timeline
    damage: Damage
    verdict: str
    warning: str | None
    dynamics: Dynamics
    estimate: Estimate
    coil_ref_c: float | None = None


def coil_referred_duty(duty_pct: np.ndarray, coil_temp_c: np.ndarray | None) -> tuple[np.ndarray, float | None]:
    """The duty the magnetics saw, referred to the coil's first reading: ``d (1 + a T0) / (1 + a T)``
    (``a``: :data:`COPPER_ALPHA_PER_K`; the current ``V d / R(T)``, ``R(T) = R0 (1 + a (T - T0))`` to first
    order), and ``T0`` (°C); the duty as commanded and None when no coil temperature was read."""
    if coil_temp_c is None:
        return duty_pct, None
    temp = np.asarray(coil_temp_c, dtype=np.float64)
    seen = (temp >= COIL_RANGE_C[0]) & (temp <= COIL_RANGE_C[1])  # NaN (not read yet) and implausible out
    if not seen.any():
        return duty_pct, None
    t0 = float(temp[seen][0])
    # rows without a reading: the coil as read before and after (before the first: as first read)
    temp = np.interp(np.arange(len(temp)), np.flatnonzero(seen), temp[seen])
    return duty_pct / (1.0 + COPPER_ALPHA_PER_K * (temp - t0)), t0


def session_timeline(res: SessionResult, rate_hz: float, duty_pct: np.ndarray | None = None) -> Timeline:
    """The session's recording on the even grid of ``rate_hz`` (``duty_pct``: another duty per row)."""
    c = res.columns
    duty = c["duty_pct"] if duty_pct is None else duty_pct
    return timeline(c["t_s"], duty, c["flow_lpm"], c["meas_age_ms"] == 0.0, res.phase, rate_hz)


def identify(res: SessionResult, rate_hz: float, kinds: Sequence[str] = KINDS,
             progress: Callable[[str], None] | None = None) -> Identification:
    """Identify the valve from a session that ran to its end.

    Raises
    ------
    Damaged
        Too much of the recording was lost to stalls of the machine.
    ValueError
        No step could be read (too small against the noise, or too short).
    """
    duty, coil_ref_c = coil_referred_duty(res.columns["duty_pct"], res.columns.get("coil_temp_c"))
    tl = session_timeline(res, rate_hz, duty)
    dmg = damage(tl, FIT_PHASES, VALIDATION_PHASE)
    word, why = verdict(dmg)
    if word == "damaged":
        raise Damaged(why)
    c = res.columns
    try:  # each step on the rows' own times (a step fit needs no even grid)
        dyn = dynamics_from_steps(c["t_s"], c["duty_pct"], c["flow_lpm"], res.phase == VALIDATION_PHASE,
                                  fresh=c["meas_age_ms"] == 0.0)
    except ValueError as exc:
        raise ValueError(f"cannot read the lag and delay: {exc}") from None
    dyn = dataclasses.replace(dyn, delay_s=max(dyn.delay_s - 1.0 / rate_hz, 0.0))
    r = res.working_range
    est = estimate(tl.t_s, tl.duty_pct, tl.flow_lpm, tl.phase, r.lo_pct, r.hi_pct, dyn, rate_hz, kinds, progress,
                   fresh=tl.fresh, observed=tl.observed)
    return Identification(tl, dmg, word, why, dyn, est, coil_ref_c)


def damage_of(res: SessionResult, rate_hz: float) -> Damage:
    """What the machine cost a session's recording (an aborted one too)."""
    return damage(session_timeline(res, rate_hz), FIT_PHASES, VALIDATION_PHASE)

