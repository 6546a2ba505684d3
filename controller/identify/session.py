"""The open-loop identification session: command the protocol, record, and stop safely.

Scheduling is the control loop's (:class:`controller.loop.RealClock`,
absolute deadlines, :class:`controller.loop.Deadlines`): a deadline whose
whole period passed without a step is skipped and counted as an overrun; with
``catch_up`` (``[loop] catch_up``) a step that ends past the next deadline, or
a wake within the period of the newest one passed, serves it at once, late.
Per step:

1. take the newest measured flow (and supply pressure and coil temperature
   when the valve publishes them); malformed or out-of-range values are
   counted and ignored;
2. safety, before anything is commanded:
   ``stop()`` true (Ctrl-C, SIGTERM) -> ``interrupted``; the session itself
   stalled (no command sent) for longer than ``stale_s`` -> ``stalled`` (the
   valve went uncommanded: its bridge may have closed it, and the recording
   no longer says what it did); no measurement for ``stale_s`` -> ``stale``;
   measured flow above ``flow_limit_lpm`` -> ``flow_limit``. Any of them
   commands the safe duty in this same step and ends the session, ``aborted``;
3. the protocol's duty for this step, clamped to the allowed duty range;
4. command it and write the row (flushed: a killed session leaves every row
   before the kill).

A row holds the duty commanded at ``t_s`` and the newest flow measured by
then, as the run recording does, so the lag and delay read from it are the
ones a controller on the same transport sees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controller.loop import Deadlines
from controller.watchdog import Faults, Watchdog, in_range
from models.recording import InputError

from .protocol import Program, WorkingRange

#: Columns of the identification recording; ``supply_bar`` and ``coil_temp_c`` follow ``flow_lpm`` when published.
BASE_COLUMNS = ("t_s", "duty_pct", "flow_lpm")
TAIL_COLUMNS = ("phase", "meas_age_ms")
AUX_COLUMNS = ("supply_bar", "coil_temp_c")


@dataclass(frozen=True)
class Safety:
    """The session's safety rules.

    Attributes
    ----------
    duty_min_pct, duty_max_pct : float
        Commanded duty is clamped to this range, %.
    safe_duty_pct : float
        Duty commanded when the session stops for any reason, %.
    stale_s : float
        A measurement older than this aborts the session, s. Open loop, the command never
        depends on the measurement: a stale one only blinds the flow limit, so this may be
        longer than the loop's ``stale_ms`` and ride out a busy machine's stalls.
    flow_limit_lpm : float
        A measured flow above this aborts the session, L/min.
    sensor_range_lpm : tuple of float
        Plausible readings; anything outside is a bad measurement.
    """

    duty_min_pct: float = 0.0
    duty_max_pct: float = 100.0
    safe_duty_pct: float = 0.0
    stale_s: float = 0.25
    flow_limit_lpm: float = 200.0
    sensor_range_lpm: tuple[float, float] = (-250.0, 250.0)


@dataclass
class SessionResult:
    """What a session leaves.

    Attributes
    ----------
    columns : dict of ndarray
        ``t_s, duty_pct, flow_lpm``, the auxiliary measurements recorded and ``meas_age_ms``
        (0 on the rows whose flow was received in that step).
    phase : ndarray of str
        Protocol phase per row (``safe`` for the row that stopped it).
    aborted : bool
    reason : str or None
        ``interrupted``, ``stalled``, ``stale``, ``no_measurement``, ``flow_limit`` or ``no_working_range``
        when aborted.
    duration_s : float
        Valve time, s.
    working_range : WorkingRange or None
        From the range ramp, once it ended.
    steps, overruns : int
    faults : list of dict
        ``{"kind", "first_s", "count"}`` (bad measurements, the abort's cause).
    """

    columns: dict
    phase: np.ndarray
    aborted: bool
    reason: str | None
    duration_s: float
    working_range: WorkingRange | None
    steps: int
    overruns: int
    faults: list = field(default_factory=list)
    message: str | None = None  # why, in words, when the reason needs them


def record_columns(aux: tuple[str, ...]) -> tuple[str, ...]:
    """The recording's header for the auxiliary measurements present."""
    return BASE_COLUMNS + tuple(a for a in AUX_COLUMNS if a in aux) + TAIL_COLUMNS


def run_session(program: Program, transport, safety: Safety, rate_hz: float, clock, writer=None, stop=None,
                progress=None, aux: tuple[str, ...] = (), catch_up: bool = True) -> SessionResult:
    """Run ``program`` against ``transport`` until it ends or a safety rule stops it.

    Parameters
    ----------
    program : Program
    transport : object
        ``poll_measurement(accept) -> (flow | None, n_bad or {fault kind: n})``, ``command(duty_pct, t_s)``
        and, with ``aux``, ``poll_aux() -> {column: value}``.
    safety : Safety
    rate_hz : float
        Step rate, Hz.
    clock : RealClock or SimClock
    writer : RecordingWriter, optional
        Columns :func:`record_columns` of ``aux``.
    stop : callable, optional
        True when the session must stop (a signal arrived).
    progress : callable, optional
        ``progress(fraction, phase)`` about ten times a second.
    aux : tuple of str
        Auxiliary columns to record (of :data:`AUX_COLUMNS`).
    catch_up : bool
        The loop's rule for late steps (:attr:`controller.loop.LoopSettings.catch_up`).
    """
    period = 1.0 / rate_hz
    aux = tuple(a for a in AUX_COLUMNS if a in aux)
    accept = in_range(*safety.sensor_range_lpm)
    cap = int(program.p.duration_s * rate_hz) + 16
    cols = {c: np.empty(cap) for c in BASE_COLUMNS + aux + ("meas_age_ms",)}
    phases: list[str] = []
    aux_now = {a: math.nan for a in aux}
    if aux:
        aux_now.update(transport.poll_aux())  # the values seen before the start
    faults = Faults()
    every = max(1, int(rate_hz / 10))
    dog = Watchdog(safety.stale_s, 0.0)
    meas = math.nan
    reason = message = None
    steps = overruns = 0
    t0 = clock.now()
    deadlines = Deadlines(t0, period, catch_up)
    t = t_sent = 0.0
    while True:
        now = clock.wait_until(deadlines.next)
        overruns += deadlines.woken(now)
        t = now - t0
        v, rejects = transport.poll_measurement(accept)
        for kind, n in (rejects.items() if isinstance(rejects, dict) else (("bad_measurement", rejects),)):
            faults.add(kind, t, n)
        if v is not None:
            meas = v
            dog.fresh(t)
        if aux:
            aux_now.update(transport.poll_aux())

        if stop is not None and stop():
            reason = "interrupted"
        elif t - t_sent > safety.stale_s:
            reason = "stalled"
        elif dog.stale(t):
            reason = "stale" if meas == meas else "no_measurement"
        elif meas > safety.flow_limit_lpm:
            reason = "flow_limit"
        nxt = None
        if not reason:
            try:
                nxt = program.next(meas, t)
            except InputError as exc:  # the range ramp found no working range: nothing to identify
                reason, message = "no_working_range", str(exc)
        if nxt is None:
            duty, phase = safety.safe_duty_pct, "safe"
        else:
            duty = min(max(nxt[0], safety.duty_min_pct), safety.duty_max_pct)
            phase = nxt[1]
        transport.command(duty, t)
        t_sent = t

        if steps == cap:
            for c in cols:
                cols[c] = np.resize(cols[c], 2 * cap)
            cap *= 2
        flow = 0.0 if meas != meas else meas
        cols["t_s"][steps], cols["duty_pct"][steps], cols["flow_lpm"][steps] = t, duty, flow
        for a in aux:
            cols[a][steps] = aux_now[a]
        age_ms = cols["meas_age_ms"][steps] = dog.age(t) * 1e3
        phases.append(phase)
        if writer is not None:
            writer.write((t, duty, flow, *(aux_now[a] for a in aux), phase, age_ms))
        steps += 1
        if progress is not None and steps % every == 0:
            progress(program.fraction, phase)
        if nxt is None:
            break
        overruns += deadlines.ended(clock.now())
    if reason:
        faults.add(reason, t)
    return SessionResult({c: v[:steps].copy() for c, v in cols.items()}, np.array(phases), reason is not None, reason,
                         t, program.range, steps, overruns, faults.to_list(), message)
