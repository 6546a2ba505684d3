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
   feedforward's kind chosen.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Sequence

from models.fitting import KINDS

from .dynamics import Dynamics, dynamics_from_steps
from .estimate import FIT_PHASES, VALIDATION_PHASE, Estimate, estimate
from .session import SessionResult
from .timeline import Damage, Timeline, damage, timeline, verdict


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
    """

    timeline: Timeline
    damage: Damage
    verdict: str
    warning: str | None
    dynamics: Dynamics
    estimate: Estimate


def session_timeline(res: SessionResult, rate_hz: float) -> Timeline:
    """The session's recording on the even grid of ``rate_hz``."""
    c = res.columns
    return timeline(c["t_s"], c["duty_pct"], c["flow_lpm"], c["meas_age_ms"] == 0.0, res.phase, rate_hz)


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
    tl = session_timeline(res, rate_hz)
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
    return Identification(tl, dmg, word, why, dyn, est)


def damage_of(res: SessionResult, rate_hz: float) -> Damage:
    """What the machine cost a session's recording (an aborted one too)."""
    return damage(session_timeline(res, rate_hz), FIT_PHASES, VALIDATION_PHASE)

