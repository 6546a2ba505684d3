"""The controller word in force: runtime switching (``ctrl/mode``) and fallback.

As ros2_control's controller manager does, a switch takes effect within one
control step and a failing controller hands over to a fallback:

- a requested word takes over at the next step, bumplessly
  (:func:`controller.laws.control.transfer`): the new law starts from the
  duty last applied, so its first duty differs from the last one by at most
  the rate limit;
- a law fails when its duty is not finite, or (``ff+kf``) when its Kalman
  innovation (measured - predicted flow), low-passed over ``tau_s``, stays
  beyond ``innovation_limit_lpm`` for ``innovation_hold_s``: the filter no
  longer follows the valve (its flow estimate tracks the measurement, so
  even a large model error leaves an innovation of only ``(1 - a)`` times
  that error; an innovation beyond the bound is a filter that diverged).
  The law then hands over to :data:`FALLBACK` (``ff+pid``) in the same
  step, with the faults ``bad_command`` or ``innovation_diverged`` and
  ``fallback``; if the fallback fails too, the step returns no command and
  the loop goes to the fault state (safe duty).

For the alarms (:mod:`controller.alarms`) the supervisor also reports the
model's flow error, :attr:`Supervisor.mismatch_lpm`: the measured flow
minus the forward model's flow passed through the valve's identified lag
and delay (the filter's own ``a`` and ``d``), low-passed over ``tau_s``.
It is the error the Kalman bias converges to, seen at once rather than at
the bias's bandwidth; laws without the filter report nan.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .laws import control
from .watchdog import Faults

#: The controller a failing law hands over to: feedback on the measured flow around the feedforward.
FALLBACK = "ff+pid"
#: The fault of a live step's verdict (:meth:`controller.laws.control.Live.step`).
_VERDICT_FAULTS = {control.BAD_COMMAND: "bad_command", control.DIVERGED: "innovation_diverged"}


@dataclass(frozen=True)
class SupervisorSettings:
    """When a Kalman-corrected law counts as failed.

    Attributes
    ----------
    innovation_limit_lpm : float
        Bound on the low-passed innovation (measured - predicted flow), L/min.
    innovation_hold_s : float
        How long the innovation must stay beyond the bound, s.
    tau_s : float
        Time constant of the low-pass of the innovation and the model error, s
        (averages the sensor noise out).
    """

    innovation_limit_lpm: float = 10.0
    innovation_hold_s: float = 0.2
    tau_s: float = 0.02


class Supervisor:
    """Steps the law of the word in force, switching and falling back as above.

    Parameters
    ----------
    laws : dict of str to ControllerParams
        The words this run may switch to (batch of one each); a run that
        cannot fall back simply lacks :data:`FALLBACK`.
    word : str
        The word in force at the start.
    settings : SupervisorSettings
    """

    def __init__(self, laws: dict, word: str, settings: SupervisorSettings = SupervisorSettings()):
        if word not in laws:
            raise ValueError(f"controller {word!r} not among {', '.join(laws)}")
        self.laws, self.word, self.settings = dict(laws), word, settings
        # each law's step judges the filter's health itself (control.Live: one compiled call a step)
        self._live = {w: control.Live(p, settings) for w, p in self.laws.items()}
        self.pending: str | None = None
        self.mismatch_lpm = math.nan

    @classmethod
    def fixed(cls, params: control.ControllerParams) -> "Supervisor":
        """One word, no switching and no fallback."""
        return cls({params.mode: params}, params.mode)

    @property
    def params(self) -> control.ControllerParams:
        return self.laws[self.word]

    def warm_up(self, dt_s: float, duty_pct: float) -> None:
        """One throw-away pass of every law through the live path (step with the Kalman prediction and its
        health checks, resume, transfer), so that loading compiled kernels (numba's cache: milliseconds per
        kernel and signature) never stalls a live step. The supervisor is left as it was (the laws' states
        are set again by :meth:`init`)."""
        saved = (self.word, self.pending, self.mismatch_lpm)
        zero = np.zeros(1)
        try:
            for word, p in self.laws.items():
                self.word = word
                ctrl = self.init(0.0, duty_pct)
                self._law_step(0.0, 0.0, dt_s, 0.0, 0.0, Faults())
                control.resume(p, ctrl, 0.0, duty_pct)
                for other in self.laws.values():
                    control.transfer(other, ctrl, 0.0, zero)
        finally:
            self.word, self.pending, self.mismatch_lpm = saved

    def rehearse(self, dt_s: float) -> None:
        """The law in force's last step again on scratch copies (:meth:`control.Live.rehearse`): nothing changes."""
        self._live[self.word].rehearse(dt_s)

    def request(self, word: str) -> bool:
        """Ask for ``word`` from the next step on; False (nothing changes) for a word this run lacks."""
        if word not in self.laws:
            return False
        self.pending = word
        return True

    def init(self, meas_lpm: float, duty_pct: float) -> control.ControllerState:
        self._reset()
        return self._live[self.word].load(control.init(self.params, meas_lpm, duty_pct))

    def resume(self, ctrl, meas_lpm: float, duty_pct: float) -> control.ControllerState:
        self._reset()
        return self._live[self.word].load(control.resume(self.params, ctrl, meas_lpm, duty_pct))

    def _reset(self) -> None:
        self.mismatch_lpm = math.nan
        self._live[self.word].reset_health()

    def _switch(self, word: str, ctrl, ref_lpm: float, meas_lpm: float):
        old = self.params
        self.word = word
        self._reset()
        if old is self.params:
            return ctrl
        return self._live[word].load(control.transfer(self.params, ctrl, ref_lpm, np.array([meas_lpm])))

    def step(self, ctrl, ref_lpm: float, meas_lpm: float, dt_s: float, ref_ff_lpm: float, t_s: float, faults):
        """One period of the word in force: ``(state, (duty, ff, fb, limit))`` in %, or ``(state, None)``
        when no law could run (the state is then the one before the step)."""
        if self.pending is not None:
            ctrl = self._switch(self.pending, ctrl, ref_lpm, meas_lpm)
            self.pending = None
        cmd = self._law_step(ref_lpm, meas_lpm, dt_s, ref_ff_lpm, t_s, faults)
        live = self._live[self.word]
        if cmd is not None or self.word == FALLBACK or FALLBACK not in self.laws:
            return live.state, cmd
        faults.add("fallback", t_s)
        ctrl = self._switch(FALLBACK, live.state, ref_lpm, meas_lpm)
        cmd = self._law_step(ref_lpm, meas_lpm, dt_s, ref_ff_lpm, t_s, faults)
        return self._live[self.word].state, cmd

    def _law_step(self, ref_lpm, meas_lpm, dt_s, ref_ff_lpm, t_s, faults):
        """The law's step and its health (judged in the step itself, :meth:`control.Live.step`): the
        command, or None (with the fault counted and the step undone) when it failed."""
        live = self._live[self.word]
        duty, ff, fb, limit, verdict, self.mismatch_lpm = live.step(ref_lpm, meas_lpm, ref_ff_lpm, dt_s)
        if verdict != control.STEP_OK:
            faults.add(_VERDICT_FAULTS[verdict], t_s)
            live.rollback()
            return None
        return duty, ff, fb, limit
