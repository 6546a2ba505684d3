"""Online alarms: what the loop's own estimates say about the valve and its gas supply.

Each alarm is a condition that must hold for a set time before it is raised
(so a breath's edges, where duty, error and innovation jump for a few
valve time constants, raise nothing) and clears as soon as it stops:

``saturated``
    The duty sits at its limit in the direction the error asks for, the
    low-passed error is beyond ``saturated_error_lpm`` and it does not
    shrink, for ``saturated_hold_s``: the valve cannot deliver the
    reference (supply failure, occlusion).
``model_mismatch``
    The model's flow error as the loop sees it (the Kalman bias plus the
    low-passed innovation, :attr:`controller.supervisor.Supervisor.mismatch_lpm`)
    stays beyond ``mismatch_lpm`` for ``mismatch_hold_s``.
``supply_low``
    A published (or simulated) supply pressure stays below
    ``supply_low_bar`` for ``supply_hold_s``. Without a supply reading the
    alarm is never raised.

Like the faults, each kind is reported once with the time it was first
raised and how many times it was raised (``S.json`` ``alarms``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

KINDS = ("saturated", "model_mismatch", "supply_low")


@dataclass(frozen=True)
class AlarmSettings:
    """Thresholds and hold times (units in the names).

    Attributes
    ----------
    error_tau_s : float
        Low-pass of the tracking error for ``saturated``, s.
    saturated_margin_pct : float
        Duty within this of its limit counts as at the limit, %.
    saturated_error_lpm : float
        Smallest low-passed error that counts for ``saturated``, L/min.
    saturated_hold_s : float
        How long the duty must stay at its limit with the error not shrinking, s.
    mismatch_lpm : float
        Bound on the model's flow error, L/min.
    mismatch_hold_s : float
        How long it must stay beyond the bound, s.
    supply_low_bar : float
        Supply pressure below which the supply is low, bar gauge.
    supply_hold_s : float
        How long it must stay below, s.
    """

    error_tau_s: float = 0.02
    saturated_margin_pct: float = 0.5
    saturated_error_lpm: float = 5.0
    saturated_hold_s: float = 0.1
    mismatch_lpm: float = 10.0
    mismatch_hold_s: float = 0.1
    supply_low_bar: float = 2.0
    supply_hold_s: float = 0.02


class _Held:
    """A condition that must hold for ``hold_s`` before it is raised; counts raisings."""

    def __init__(self, hold_s: float):
        self.hold_s, self.since, self.active = hold_s, None, False
        self.first_s, self.count = None, 0

    def update(self, t_s: float, cond: bool) -> None:
        if not cond:
            self.since, self.active = None, False
            return
        if self.since is None:
            self.since = t_s
        if not self.active and t_s - self.since >= self.hold_s - 1e-9:
            self.active = True
            self.count += 1
            if self.first_s is None:
                self.first_s = t_s


class Alarms:
    """The alarm conditions, evaluated once per loop step.

    Parameters
    ----------
    settings : AlarmSettings
    duty_min_pct, duty_max_pct : float
        The duty limits of the controller.
    """

    def __init__(self, settings: AlarmSettings, duty_min_pct: float, duty_max_pct: float):
        self.s = settings
        self.duty_min_pct, self.duty_max_pct = duty_min_pct, duty_max_pct
        self._held = {"saturated": _Held(settings.saturated_hold_s),
                      "model_mismatch": _Held(settings.mismatch_hold_s),
                      "supply_low": _Held(settings.supply_hold_s)}
        # bound once: the loop calls step() every period
        self._sat, self._mismatch, self._supply = (self._held[k].update for k in KINDS)
        self._duty_hi = duty_max_pct - settings.saturated_margin_pct
        self._duty_lo = duty_min_pct + settings.saturated_margin_pct
        self._err_lp = 0.0
        self._sat_err0 = math.inf  # |error| when the duty reached its limit
        self._t_prev: float | None = None

    def step(self, t_s: float, running: bool, duty_pct: float, error_lpm: float, mismatch_lpm: float,
             supply_bar: float | None) -> None:
        """One step: ``error_lpm`` = reference - flow; ``mismatch_lpm`` nan when the law has no model estimate."""
        s = self.s
        dt = 0.0 if self._t_prev is None else t_s - self._t_prev
        self._t_prev = t_s
        if running and math.isfinite(error_lpm):
            self._err_lp = e = self._err_lp + (error_lpm - self._err_lp) * (1.0 - math.exp(-dt / s.error_tau_s))
            at_limit = (duty_pct >= self._duty_hi and e > 0.0) or (duty_pct <= self._duty_lo and e < 0.0)
            sat = at_limit and abs(e) >= s.saturated_error_lpm
            if not sat:
                self._sat_err0 = math.inf
            elif self._sat_err0 == math.inf:
                self._sat_err0 = abs(e)
            self._sat(t_s, sat and abs(e) >= self._sat_err0 - s.saturated_error_lpm * 0.1)
            self._mismatch(t_s, abs(mismatch_lpm) > s.mismatch_lpm)  # nan compares False
        else:
            self._err_lp, self._sat_err0 = 0.0, math.inf
            self._sat(t_s, False)
            self._mismatch(t_s, False)
        self._supply(t_s, supply_bar is not None and supply_bar < s.supply_low_bar)

    def active(self) -> list[str]:
        """The alarms raised now."""
        return [k for k, v in self._held.items() if v.active]

    def counts(self) -> dict[str, int]:
        """How many times each alarm was raised (the ones raised at least once)."""
        return {k: v.count for k, v in self._held.items() if v.count}

    def to_list(self) -> list[dict]:
        """``S.json`` ``alarms``: ``[{"kind", "first_s", "count"}]``, in the order first raised."""
        raised = [(v.first_s, k, v.count) for k, v in self._held.items() if v.count]
        return [{"kind": k, "first_s": t, "count": n} for t, k, n in sorted(raised)]
