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

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import carray, njit

from models.borrow import pointer
from models.direct import direct

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


#: The kernel's buffer (:class:`Alarms`): the settings, then the state, float64.
(_TAU, _DUTY_HI, _DUTY_LO, _SAT_ERR, _MISMATCH, _SUPPLY_LOW, _HOLD, N_SETTINGS) = (0, 1, 2, 3, 4, 5, 6, 9)  # _HOLD: one per kind
(_T_PREV, _ERR_LP, _SAT_ERR0, _HELD) = (N_SETTINGS, N_SETTINGS + 1, N_SETTINGS + 2, N_SETTINGS + 3)
#: Per kind (:data:`KINDS` order), from ``_HELD``: since when its condition holds (nan: it does not), whether it
#: is raised (0/1), when it was first raised (nan: never) and how many times.
(_SINCE, _ACTIVE, _FIRST, _COUNT, _N_HELD) = range(5)
#: After the kinds: how many times an alarm was raised or cleared, all kinds together (a reader that keeps
#: :meth:`Alarms.active` and :meth:`Alarms.counts` takes them anew only when it moved).
_CHANGES = _HELD + len(KINDS) * _N_HELD
N_BUFFER = _CHANGES + 1


@njit(cache=True, inline="always")
def _update_held(A, j, t_s, cond):
    """Kind ``j``'s condition, which must hold for its hold time before it is raised; counts raisings."""
    o = _HELD + j * _N_HELD
    if not cond:
        if A[o + _ACTIVE] != 0.0:
            A[_CHANGES] += 1.0
        A[o + _SINCE], A[o + _ACTIVE] = np.nan, 0.0
        return
    if A[o + _SINCE] != A[o + _SINCE]:
        A[o + _SINCE] = t_s
    if A[o + _ACTIVE] == 0.0 and t_s - A[o + _SINCE] >= A[_HOLD + j] - 1e-9:
        A[o + _ACTIVE] = 1.0
        A[o + _COUNT] += 1.0
        A[_CHANGES] += 1.0
        if A[o + _FIRST] != A[o + _FIRST]:
            A[o + _FIRST] = t_s


@njit(cache=True)
def _step(address, t_s, running, duty_pct, error_lpm, mismatch_lpm, supply_bar):
    # the buffer by address (models.borrow.pointer): a call of numbers alone, microseconds on cold caches
    A = carray(pointer(address, np.float64), N_BUFFER)
    dt = 0.0 if A[_T_PREV] != A[_T_PREV] else t_s - A[_T_PREV]
    A[_T_PREV] = t_s
    if running and math.isfinite(error_lpm):
        e = A[_ERR_LP] + (error_lpm - A[_ERR_LP]) * (1.0 - math.exp(-dt / A[_TAU]))
        A[_ERR_LP] = e
        at_limit = (duty_pct >= A[_DUTY_HI] and e > 0.0) or (duty_pct <= A[_DUTY_LO] and e < 0.0)
        sat = at_limit and abs(e) >= A[_SAT_ERR]
        if not sat:
            A[_SAT_ERR0] = math.inf
        elif A[_SAT_ERR0] == math.inf:
            A[_SAT_ERR0] = abs(e)
        _update_held(A, 0, t_s, sat and abs(e) >= A[_SAT_ERR0] - A[_SAT_ERR] * 0.1)
        _update_held(A, 1, t_s, abs(mismatch_lpm) > A[_MISMATCH])  # nan compares False
    else:
        A[_ERR_LP], A[_SAT_ERR0] = 0.0, math.inf
        _update_held(A, 0, t_s, False)
        _update_held(A, 1, t_s, False)
    _update_held(A, 2, t_s, supply_bar < A[_SUPPLY_LOW])  # nan (no reading) compares False


class Alarms:
    """The alarm conditions, evaluated once per loop step.

    ``step(t_s, running, duty_pct, error_lpm, mismatch_lpm, supply_bar)`` is one step:
    ``error_lpm`` = reference - flow; ``mismatch_lpm`` nan when the law has no model
    estimate; ``supply_bar`` nan without a supply reading. It is the compiled kernel's
    entry point itself, bound to this object's buffer (a loop step calls it directly).

    ``view[CHANGES_AT]`` (a float read without numpy) counts the raisings and clearings so far: a reader that
    keeps :meth:`active` and :meth:`counts` takes them anew only when it moved (the loop's status).

    Parameters
    ----------
    settings : AlarmSettings
    duty_min_pct, duty_max_pct : float
        The duty limits of the controller.
    """

    CHANGES_AT = _CHANGES

    def __init__(self, settings: AlarmSettings, duty_min_pct: float, duty_max_pct: float):
        self.s = settings
        self.duty_min_pct, self.duty_max_pct = duty_min_pct, duty_max_pct
        a = self._buf = np.full(N_BUFFER, np.nan)
        a[_TAU], a[_SAT_ERR], a[_MISMATCH] = settings.error_tau_s, settings.saturated_error_lpm, settings.mismatch_lpm
        a[_DUTY_HI] = duty_max_pct - settings.saturated_margin_pct
        a[_DUTY_LO] = duty_min_pct + settings.saturated_margin_pct
        a[_SUPPLY_LOW] = settings.supply_low_bar
        a[_HOLD:_HOLD + 3] = settings.saturated_hold_s, settings.mismatch_hold_s, settings.supply_hold_s
        a[_ERR_LP], a[_SAT_ERR0], a[_CHANGES] = 0.0, math.inf, 0.0
        self.view = memoryview(a)  # the buffer as Python floats
        held = a[_HELD:_CHANGES].reshape(len(KINDS), _N_HELD)
        held[:, _ACTIVE] = held[:, _COUNT] = 0.0
        self._held = held
        self._scratch = a.copy()  # rehearse()'s buffer
        # the kernel's machine code without numba's dispatcher (models.direct), its buffer by address
        entry = direct(_step, a.ctypes.data, 0.0, True, 0.0, 0.0, 0.0, 0.0)
        self.step = functools.partial(entry, a.ctypes.data)
        self._rehearse_step = functools.partial(entry, self._scratch.ctypes.data)

    def rehearse(self, t_s: float, running: bool, duty_pct: float, error_lpm: float, mismatch_lpm: float,
                 supply_bar: float) -> None:
        """A step on a scratch copy of the buffer: the kernel's machine code and the buffer pass through
        the caches, and the alarms are untouched (the loop's rehearsal before a step is due)."""
        np.copyto(self._scratch, self._buf)
        self._rehearse_step(t_s, running, duty_pct, error_lpm, mismatch_lpm, supply_bar)

    def active(self) -> list[str]:
        """The alarms raised now."""
        return [k for k, h in zip(KINDS, self._held) if h[_ACTIVE]]

    def counts(self) -> dict[str, int]:
        """How many times each alarm was raised (the ones raised at least once)."""
        return {k: int(h[_COUNT]) for k, h in zip(KINDS, self._held) if h[_COUNT]}

    def to_list(self) -> list[dict]:
        """``S.json`` ``alarms``: ``[{"kind", "first_s", "count"}]``, in the order first raised."""
        raised = [(float(h[_FIRST]), k, int(h[_COUNT])) for k, h in zip(KINDS, self._held) if h[_COUNT]]
        return [{"kind": k, "first_s": t, "count": n} for t, k, n in sorted(raised)]
