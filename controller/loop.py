"""The fixed-rate control loop: inputs, watchdog, control law, command, record.

Scheduling: absolute deadlines ``next += period`` on ``time.perf_counter``,
slept to ``spin_s`` before the deadline and spun from there (sleep alone wakes
~0.1-0.2 ms late with a long tail; the spin costs about spin/period of a
core). A deadline whose whole period passed before a step could start for it
is skipped and counted as an overrun; a step that ends after the next deadline
but within its period lets that deadline's step start at once, late
(``catch_up``, :func:`deadlines_missed`: a POSIX timer's overrun count), so the
loop never runs a burst of steps to catch up, and never drops a period it can
still serve. Each step's lateness (start - deadline) is recorded. The garbage
collector is frozen and disabled while the loop runs (:func:`gc_paused`).

Trigger (``[loop] trigger``): ``period`` steps at every deadline, as above;
``measurement`` steps as each measurement arrives, on the transport's own
thread: the transport calls the loop's hook (``on_measurement``) right after
it keeps the measurement, and the hook runs the step there, so no thread
hand-off (an event's wake-up and the GIL's, 50-150 µs) lies between the
measurement and its command. The loop's thread only sleeps, as the watchdog:
when no measurement came for :data:`WATCHDOG_PERIODS` periods it steps itself
(stale check, safe state, status); a lock keeps the two from stepping at
once; it also rehearses the step just before the next measurement is due
(``rehearse``). Then lateness is step start - arrival (the lock's wait; start -
watchdog deadline on a watchdog step) and an overrun is a measurement that
got no step of its own: a step that started after it came took it along,
or the steps were rationed (:data:`BURST_STEPS`: a flood of measurements never steps the
laws faster than twice the rate on average; the next step takes it).

Per step (one period):

1. wake at the deadline (or the measurement); lateness = wake - deadline (or arrival);
2. take the newest measurement and reference from the transport (already
   received, never waited for); reject and count non-finite or out-of-range
   values (``bad_measurement`` / ``bad_reference``); clamp the reference to
   the valve's range;
3. watchdog: no fresh measurement for ``stale_ms`` -> ``safe`` (command
   ``safe_duty_pct``, fault ``stale``, or ``no_measurement`` if none ever
   came since the start); fresh data -> ``running`` again, resumed
   bumplessly (:func:`controller.laws.control.resume`);
4. the control law of the word in force, through the
   :class:`controller.supervisor.Supervisor` (a word asked for on the
   transport's ``poll_mode`` takes over bumplessly; a failing law falls back
   to ``ff+pid``, then to the fault state), or the safe duty;
5. command, tracking error, alarms (:mod:`controller.alarms`), status at
   ``status_hz``, record row;
6. compute time (``compute_us``) = end of the step - wake: all of 2.-5., the
   payloads parsed and the command sent included (with the embedded valve,
   its simulated step too); beside it the thread's CPU time over the same
   step (``compute_cpu_us``: ``CLOCK_THREAD_CPUTIME_ID``, read just before
   the step's first clock read and just after its last), which leaves out
   the time the thread stood off its CPU: the hypervisor running something
   else (host steal: this guest's kernel subtracts it from the tasks' clock,
   ``CONFIG_PARAVIRT_TIME_ACCOUNTING``), or another thread of the guest
   running on it (README: A step in microseconds).

Status (``ctrl/status``, every ``rate_hz / status_hz`` steps): the faults' and the alarms' counts are taken
anew only when they changed (:attr:`controller.watchdog.Faults.changes`, :attr:`controller.alarms.Alarms.view`),
and the status is a :class:`Status` (a msgspec Struct: made without a hash table; its payload is the dict's,
byte for byte, encoded in the same time), so a status step fills one record of numbers and reuses the lists
and dicts it built before (README: A step in microseconds).

Allocation: the loop's per-step records are preallocated arrays; the law of
the word in force advances in place in one compiled call
(:class:`controller.laws.control.Live`), the simulated valve
(:class:`plant_sim.plant.RunningPlant`) and the alarms
(:class:`controller.alarms.Alarms`) likewise, each on buffers passed by
address, so a step allocates no arrays.

The clock is injectable: :class:`RealClock` for the live loop,
:class:`SimClock` for tests and fast simulations (time jumps to each deadline).
"""
from __future__ import annotations

import contextlib
import gc
import math
import os
import struct
import sys
import threading
import time
from dataclasses import dataclass

import msgspec
import numpy as np

from .alarms import AlarmSettings, Alarms
from .laws import control
from .supervisor import Supervisor, SupervisorSettings
from .watchdog import FAULT, RUNNING, SAFE, STATES, Faults, in_range

#: Columns of the run recording (DESIGN.md), then what the rate limit and the clamp changed
#: (``duty = ff + fb + limit``) and the age of the newest measurement.
RECORD_COLUMNS = ("t_s", "ref_lpm", "flow_lpm", "duty_pct", "ff_duty_pct", "fb_duty_pct", "state", "controller",
                  "limit_duty_pct", "meas_age_ms")


@dataclass(frozen=True)
class LoopSettings:
    """Loop rate, watchdog and input limits.

    Attributes
    ----------
    rate_hz : float
        Step rate, Hz.
    stale_ms : float
        Measurement age that triggers the safe state, ms.
    ref_stale_ms : float
        Age after which a received reference drops to 0 L/min, ms (references that can go stale).
    safe_duty_pct : float
        Duty commanded in the safe state, % (0 = valve closed).
    flow_max_lpm : float
        The valve's flow range is [0, flow_max_lpm]; references are clamped to it.
    sensor_range_lpm : tuple of float
        Plausible readings; measurements and references outside are rejected.
    status_hz : float
        Rate of ``ctrl/status``, Hz.
    spin_s : float
        Spin margin before each deadline, s.
    rt_priority : int
        ``SCHED_FIFO`` priority of the loop thread while it runs (1-99), so
        that other processes on the machine cannot delay its wake-ups; 0 keeps
        the normal scheduler. Without the permission (root or CAP_SYS_NICE)
        the loop runs with the normal scheduler and says so on stderr.
    trigger : str
        ``period``: a step at every deadline (the loop samples the sensor);
        ``measurement``: a step as soon as a measurement arrives, and at
        :data:`WATCHDOG_PERIODS` periods after the previous step when none came
        (the sensor samples on its own clock; the transport must call the
        loop at each arrival: ``on_measurement(hook)``).
    cpu : int
        On the real clock: the CPU the loop's thread runs on while the loop runs, so that each step finds
        the caches of the CPU the previous one warmed (the scheduler otherwise wakes the thread wherever a
        CPU is free); -1: wherever the scheduler puts it.
    catch_up : bool
        When a step ends past the next deadline: True, that deadline's step
        starts at once, late, and only deadlines whose whole period passed
        without a step are skipped and counted as overruns (a POSIX timer's
        overrun count, ``timer_getoverrun``); False, the next deadline is
        skipped and counted too (ros2_control's controller manager). On this
        VM the host freezes it ~1 ms at a time: a step woken 0.9 ms late then
        ends just past the next deadline, which False drops (bench_load.py).
        Lateness, steps and overruns are recorded as they happen either way.
    rehearse : bool
        On the real clock: rehearse the step's compiled calls on scratch
        copies just before the step is due, so that the step itself runs on
        warm caches (:meth:`Loop.run`): the law, the valve, the alarms, the
        reference and the record's next row. ``trigger = "period"``:
        :data:`REHEARSAL_S` before each deadline; ``"measurement"``: on the
        watchdog's thread, :data:`MEASUREMENT_REHEARSAL_S` before the next
        measurement is due (the last one's arrival plus a period).
    alarms : AlarmSettings
        Thresholds and hold times of the online alarms.
    fallback : SupervisorSettings
        When a Kalman-corrected law counts as failed.
    """

    rate_hz: float = 1000.0
    stale_ms: float = 50.0
    ref_stale_ms: float = 500.0
    safe_duty_pct: float = 0.0
    flow_max_lpm: float = 200.0
    sensor_range_lpm: tuple[float, float] = (-250.0, 250.0)
    status_hz: float = 10.0
    spin_s: float = 300e-6
    rt_priority: int = 0
    cpu: int = -1
    trigger: str = "period"
    rehearse: bool = True
    catch_up: bool = True
    alarms: AlarmSettings = AlarmSettings()
    fallback: SupervisorSettings = SupervisorSettings()


#: With ``trigger = "measurement"``: a step this many periods after the previous one when no measurement
#: came (the watchdog's own steps: stale check, safe state, status). Above 1, so that a sensor whose
#: clock runs slightly slower than the loop's never meets a watchdog step just before its measurement.
WATCHDOG_PERIODS = 1.5
#: With ``trigger = "measurement"``: the measurements' steps are rationed by a token bucket of this many steps,
#: refilled at twice the rate. The laws step by one period, so a flood of measurements (a faulty or hostile
#: publisher) must not step them faster than twice the rate on average; a few bunched ones (transport jitter, a
#: sensor catching up) each still get their step at once. A measurement that finds the bucket empty gets none
#: (an overrun); the next step takes it.
BURST_STEPS = 4.0
#: The triggers of a step (:attr:`LoopSettings.trigger`).
TRIGGERS = ("period", "measurement")
#: With :attr:`LoopSettings.rehearse`: the loop wakes this much earlier than its spin, for the rehearsal (~20-30 us
#: cold), so that the rehearsal ends before the deadline and the step is not made late by it.
REHEARSAL_S = 50e-6
#: With trigger ``measurement`` and :attr:`LoopSettings.rehearse`: the watchdog's thread rehearses the law's step this
#: long before the next measurement is due (the last one's arrival plus a period): early enough that a measurement
#: a little early rarely waits for it (~10-20 us), late enough that the caches are still warm when it comes.
MEASUREMENT_REHEARSAL_S = 150e-6


class Status(msgspec.Struct, gc=False):
    """A ``ctrl/status`` value (DESIGN.md): encoded by msgspec as the JSON object of these fields, in this order,
    and read by key like the dict it replaces (``status["state"]``). ``faults``: counts by kind; ``alarms``: the
    alarms raised now; ``alarm_counts``: how many times each was raised."""

    state: str
    controller: str
    ref_lpm: float
    flow_lpm: float | None
    duty_pct: float
    error_lpm: float | None
    iae: float
    steps: int
    overruns: int
    lateness_us_max: float
    compute_us_max: float
    faults: dict
    alarms: list
    alarm_counts: dict

    def __getitem__(self, key: str):
        return getattr(self, key)

    def get(self, key: str, default=None):
        return getattr(self, key, default)


def deadlines_missed(late_s: float, period_s: float, catch_up: bool) -> int:
    """Deadlines a fixed-rate loop skips and counts as overruns when it is ``late_s`` > 0 past a deadline it has
    not started a step for (:attr:`LoopSettings.catch_up`): with ``catch_up``, those whose whole period has passed
    (the step for the newest one starts at once, late); without, that newest one too."""
    return int(late_s / period_s) + (0 if catch_up else 1)


class Deadlines:
    """A fixed-rate loop's absolute deadlines (``next``), moved past the missed ones by :func:`deadlines_missed`.

    The one rule for the loops that keep their own schedule (the valve node, the identification session; the
    control loop applies the same function itself): :meth:`woken` at each wake, :meth:`ended` after each step;
    each returns the deadlines it skipped, to be counted as overruns. Every deadline is then a step or an overrun.
    """

    __slots__ = ("next", "period", "catch_up")

    def __init__(self, t0: float, period_s: float, catch_up: bool = True):
        self.next, self.period, self.catch_up = t0, period_s, catch_up

    def woken(self, now: float) -> int:
        """Woken at ``now`` for ``next``: with ``catch_up``, the deadlines whose whole period passed are missed and
        the step serves the newest, late by less than a period; without, none (the step serves ``next``, late)."""
        late = now - self.next
        if not self.catch_up or late < self.period:
            return 0
        missed = deadlines_missed(late, self.period, True)
        self.next += missed * self.period
        return missed

    def ended(self, now: float) -> int:
        """The step for ``next`` ended at ``now``: on to the following deadline, past those already missed."""
        self.next += self.period
        late = now - self.next
        if late <= 0:
            return 0
        missed = deadlines_missed(late, self.period, self.catch_up)
        self.next += missed * self.period
        return missed


@contextlib.contextmanager
def realtime(priority: int):
    """Run the calling thread under ``SCHED_FIFO`` at ``priority`` (0: unchanged) and restore it after."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        yield False
        return
    old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        sys.stderr.write("loop: no permission for SCHED_FIFO; running with the normal scheduler\n")
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setscheduler(0, old_policy, old_param)


@contextlib.contextmanager
def pinned(cpu: int):
    """Run the calling thread on CPU ``cpu`` alone (-1: unchanged) and give it back its former CPUs after."""
    if cpu < 0 or not hasattr(os, "sched_setaffinity"):
        yield False
        return
    old = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError:  # no such CPU, or not one of this process's
        sys.stderr.write(f"loop: cannot run on CPU {cpu}; running on CPUs {sorted(old)}\n")
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setaffinity(0, old)


def _lift(priority: int):
    """The calling thread under ``SCHED_FIFO`` at ``priority`` for good: its former ``(policy, param)``, to
    restore by its native id, or None (unchanged: no permission, or no such scheduler)."""
    if priority <= 0 or not hasattr(os, "sched_setscheduler"):
        return None
    old = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        return None
    return old


@contextlib.contextmanager
def gc_paused():
    """Collect once, freeze what survives and keep the collector off until the block ends.

    A full collection of a process that has imported numpy, numba and zenoh
    walks ~130 000 objects: ~40-120 ms, more than ``stale_ms``, wherever an
    allocation happens to trigger it. A loop allocates no reference cycles
    per step (its arrays are preallocated), so nothing accumulates meanwhile.
    """
    gc.collect()
    gc.freeze()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
        gc.unfreeze()


class RealClock:
    """Wall clock: hybrid sleep-then-spin to absolute deadlines on ``time.perf_counter``."""

    def __init__(self, spin_s: float = 300e-6):
        self.spin_s = spin_s

    @staticmethod
    def now() -> float:
        return time.perf_counter()

    #: The calling thread's CPU time, ns (``CLOCK_THREAD_CPUTIME_ID``): a step's ``cpu_s``.
    cpu_ns = staticmethod(time.thread_time_ns)

    def wait_until(self, deadline: float, rehearse=None) -> float:
        """Sleep, then spin, to ``deadline``; ``rehearse()``, if given, runs between the two
        (:data:`REHEARSAL_S` earlier), unless the deadline has passed already."""
        pc = time.perf_counter
        rest = deadline - pc() - self.spin_s - (0.0 if rehearse is None else REHEARSAL_S)
        if rest > 0:
            time.sleep(rest)
        if rehearse is not None and pc() < deadline:
            rehearse()
        now = pc()
        while now < deadline:
            now = pc()
        return now

    @staticmethod
    def sleep_until(deadline: float) -> float:
        """Sleep (the GIL released) to ``deadline`` without the spin: a wait other threads may end early."""
        rest = deadline - time.perf_counter()
        if rest > 0:
            time.sleep(rest)
        return time.perf_counter()


class SimClock:
    """Simulated clock: waiting jumps to the deadline, so a loop runs as fast as it computes."""

    def __init__(self, t0_s: float = 0.0):
        self.t = t0_s

    def now(self) -> float:
        return self.t

    #: The calling thread's CPU time, ns: the step's work is real even when its time is simulated.
    cpu_ns = staticmethod(time.thread_time_ns)

    def wait_until(self, deadline: float, rehearse=None) -> float:
        """Jump to ``deadline``: simulated time costs nothing to wait and needs no rehearsal."""
        self.t = max(self.t, deadline)
        return self.t

    sleep_until = wait_until


class ProfileReference:
    """A reference that is a pure function of time (a breath profile): always fresh.

    Known in advance, it can be read ``preview_s`` ahead for the feedforward
    (:meth:`ahead`), so the valve's transport delay is acted early.
    """

    can_go_stale = False

    def __init__(self, value, preview_s: float = 0.0):
        self._value = value
        self.preview_s = preview_s

    def poll(self, t_s: float, accept) -> tuple[float | None, int]:
        v = float(self._value(t_s))
        return (v, 0) if accept(v) else (None, 1)

    def ahead(self, t_s: float, accept) -> float | None:
        """The reference ``preview_s`` ahead, or None (no preview, or a value ``accept`` rejects)."""
        if self.preview_s <= 0:
            return None
        v = float(self._value(t_s + self.preview_s))
        return v if accept(v) else None

    def rehearse(self, t_s: float) -> None:
        """Evaluate the reference at ``t_s`` (and ahead) for nothing: the loop's rehearsal (the value is pure)."""
        self._value(t_s)
        if self.preview_s > 0:
            self._value(t_s + self.preview_s)


class _Columns:
    """The per-step record: one preallocated row of doubles per step, written by one ``struct`` call.

    One call per step instead of one numpy item assignment per column (~0.5 µs against ~2 µs warm,
    and fewer objects for a cold step to fetch). Zero-filled at creation (grown by doubling when a
    run has no set length), so that no step meets a page of it for the first time.
    """

    FIELDS = ("t_s", "ref_lpm", "flow_lpm", "duty_pct", "ff_duty_pct", "fb_duty_pct", "limit_duty_pct",
              "meas_age_ms", "lateness_s", "state", "word", "compute_s", "cpu_s")  # word: index into control.MODES
    ROW = struct.Struct(f"{len(FIELDS)}d")
    #: The row without ``compute_s`` and ``cpu_s`` (written at the step's very end), and those two alone.
    HEAD, LAST = struct.Struct(f"{len(FIELDS) - 2}d"), struct.Struct("2d")
    __slots__ = ("buf", "n", "capacity")

    def __init__(self, capacity: int):
        self.n, self.capacity = 0, capacity
        self.buf = bytearray(capacity * self.ROW.size)

    def grow(self) -> None:
        self.buf += bytes(len(self.buf))
        self.capacity *= 2

    def trimmed(self) -> dict[str, np.ndarray]:
        rows = np.frombuffer(self.buf, dtype=np.float64, count=self.n * len(self.FIELDS)).reshape(self.n, -1)
        out = {f: rows[:, j].copy() for j, f in enumerate(self.FIELDS) if f not in ("state", "word")}
        out["state"] = rows[:, self.FIELDS.index("state")].astype(np.int8)
        out["controller"] = np.asarray(control.MODES)[rows[:, self.FIELDS.index("word")].astype(np.intp)]
        return out


@dataclass
class LoopResult:
    """What a run leaves: per-step columns, faults, alarms, step and overrun counts."""

    columns: dict
    faults: Faults
    steps: int
    overruns: int
    settings: LoopSettings
    alarms: Alarms | None = None

    @property
    def rate_hz(self) -> float:
        """Achieved step rate: steps over the run's span."""
        t = self.columns["t_s"]
        if self.steps < 2:
            return float("nan")
        return (self.steps - 1) / float(t[-1] - t[0])


class Loop:
    """The loop around one controller (the batch of one of :mod:`controller.laws.control`).

    Parameters
    ----------
    params : ControllerParams or Supervisor
        One controller (batch of one), or the words the run may switch between.
    transport : object
        ``poll_measurement(accept) -> (flow | None, n_bad)``, ``command(duty_pct, t_s)``,
        ``publish_error(t_s, error_lpm)``, ``publish_status(t_s, status)``; optionally
        ``poll_mode() -> (word | None, n_bad)`` (runtime switching),
        ``supply_bar() -> float | None`` (the supply pressure, for ``supply_low``) and
        ``on_measurement(hook | None)`` (trigger ``measurement``: ``hook(arrival_s)`` called on the
        transport's thread as each measurement arrives, ``arrival_s`` on the clock's time).
    reference : object
        ``poll(t_s, accept) -> (ref | None, n_bad)`` and ``can_go_stale``; with
        ``preview_s > 0`` also ``ahead(t_s, accept)``, the feedforward's reference.
    settings : LoopSettings
    clock : RealClock or SimClock
        ``now()``, ``wait_until(deadline)`` (trigger ``period``) and ``sleep_until(deadline)`` (the
        watchdog's wait with trigger ``measurement``).
    writer : RecordingWriter, optional
        Receives one row per step (:data:`RECORD_COLUMNS`), flushed as written.
    observer : callable, optional
        Called with each status (``ctrl/status``) the loop publishes, e.g. for a progress line.
    """

    def __init__(self, params, transport, reference, settings: LoopSettings, clock=None, writer=None,
                 observer=None):
        sup = params if isinstance(params, Supervisor) else Supervisor.fixed(params)
        if any(p.batch != 1 for p in sup.laws.values()):
            raise ValueError("the live loop runs one controller (batch of one)")
        self.supervisor = sup
        self.observer = observer
        self.transport = transport
        self.reference = reference
        self.settings = settings
        self.clock = clock if clock is not None else RealClock(settings.spin_s)
        self.writer = writer

    def run(self, duration_s: float | None = None, stop=None) -> LoopResult:
        """Run for ``duration_s`` seconds (or until ``stop()`` is true); returns the result."""
        cfg = self.settings
        period = 1.0 / cfg.rate_hz
        if cfg.trigger not in TRIGGERS:
            raise ValueError(f"trigger {cfg.trigger!r} (one of {', '.join(TRIGGERS)})")
        on_measurement = cfg.trigger == "measurement"
        serve = getattr(self.transport, "on_measurement", None)
        if on_measurement and serve is None:
            raise ValueError("trigger 'measurement' needs a transport that signals measurements (a valve over Zenoh)")
        n_steps = None if duration_s is None else max(1, int(round(duration_s * cfg.rate_hz)))
        # A set length is preallocated up to 2^20 rows (96 MiB) and grown beyond, as a run of no set length is:
        # a legal run of days must not ask for its whole record before the first step.
        cols = _Columns(min(n_steps, 1 << 20) if n_steps else 1 << 16)
        faults = Faults()
        accept_meas = in_range(*cfg.sensor_range_lpm)
        accept_ref = accept_meas
        status_every = max(1, int(round(cfg.rate_hz / cfg.status_hz)))
        sup, transport, reference, clock, writer = self.supervisor, self.transport, self.reference, self.clock, self.writer
        observer = self.observer
        # the step's callees bound once (a lookup less per call)
        poll_measurement, command = transport.poll_measurement, transport.command
        publish_error, publish_status = transport.publish_error, transport.publish_status
        poll_mode = getattr(transport, "poll_mode", None)
        supply_bar = getattr(transport, "supply_bar", None)
        poll_reference, ahead = reference.poll, reference.ahead if getattr(reference, "preview_s", 0.0) > 0 else None
        can_go_stale = reference.can_go_stale
        lim = sup.params.limits
        alarms = Alarms(cfg.alarms, float(lim.duty_min_pct[0]), float(lim.duty_max_pct[0]))
        alarm_step = alarms.step
        sup_step = sup.step
        word_index = {w: i for i, w in enumerate(control.MODES)}
        pc = time.perf_counter
        cpu_ns = getattr(clock, "cpu_ns", time.thread_time_ns)
        safe, flow_max = cfg.safe_duty_pct, cfg.flow_max_lpm
        stale_s, ref_stale_s = cfg.stale_ms * 1e-3, cfg.ref_stale_ms * 1e-3
        real_time = isinstance(clock, RealClock)  # a simulated clock does not stand still for the host
        pack_head, pack_last = _Columns.HEAD.pack_into, _Columns.LAST.pack_into
        row_bytes, last_at = _Columns.ROW.size, _Columns.HEAD.size

        # The loop's state, advanced by step() (on the loop's thread, or on the transport's with
        # trigger "measurement"; never by two at once).
        t0 = 0.0
        meas_t = ref_t = 0.0  # time of the newest fresh measurement and reference (the watchdogs)
        state, stale, ref_stale = SAFE, False, False
        ctrl = None
        meas = math.nan  # newest accepted measurement
        ref_in = 0.0
        duty = safe
        ff = fb = 0.0
        steps = overruns = 0
        iae = 0.0
        late_max = compute_max = 0.0  # since the last status
        last_wake = -math.inf
        # The status's counts, taken anew only when they changed (Faults.changes, the alarms' change count)
        faults_seen, fault_counts = -1, {}
        alarm_view, alarm_changes_at = alarms.view, alarms.CHANGES_AT
        alarms_seen, alarms_active, alarm_counts = -1.0, [], {}

        def step(now: float, due: float) -> None:
            """One step (1.-6. above): ``now`` its wake, ``due`` when it was due (deadline or arrival)."""
            nonlocal meas_t, ref_t, state, stale, ref_stale, ctrl, meas, ref_in, duty, ff, fb, steps, iae, late_max
            nonlocal compute_max, last_wake, faults_seen, fault_counts, alarms_seen, alarms_active, alarm_counts
            k0 = cpu_ns()
            c0 = pc()
            last_wake = now
            t = now - t0

            # 2. inputs
            v, bad = poll_measurement(accept_meas)
            if bad:
                faults.add_rejects(bad, t, "bad_measurement")
            fresh = v is not None
            if fresh:
                meas, meas_t = v, t
            r, bad = poll_reference(t, accept_ref)
            if bad:
                faults.add("bad_reference", t, bad)
            if r is not None:
                ref_in, ref_stale, ref_t = r, False, t
            elif can_go_stale and t - ref_t > ref_stale_s:
                if not ref_stale:
                    faults.add("stale_reference", t)
                    ref_stale = True
                ref_in = 0.0
            ref = min(max(ref_in, 0.0), flow_max)
            r_ff = ahead(t, accept_ref) if ahead is not None else None
            ref_ff = ref if r_ff is None else min(max(r_ff, 0.0), flow_max)

            if poll_mode is not None:
                w, bad = poll_mode()
                if w is not None and not sup.request(w):
                    bad += 1
                if bad:
                    faults.add("bad_mode", t, bad)

            # 3. watchdog
            if t - meas_t > stale_s:
                if not stale:
                    # Data that stopped is a stale valve; data that never came, a missing one.
                    faults.add("stale" if meas == meas else "no_measurement", t)
                    stale = True
                state = SAFE
            elif fresh and state != RUNNING:
                ctrl = sup.init(meas, duty) if ctrl is None else sup.resume(ctrl, meas, duty)
                state, stale = RUNNING, False

            # 4. law (switching, fallback) or safe duty
            if state == RUNNING:
                ctrl, cmd = sup_step(ctrl, ref, meas, period, ref_ff, t, faults)
                if cmd is None:  # no law could compute a duty: the fault state commands the safe duty
                    state, ctrl = FAULT, None
                else:
                    duty, ff, fb, _ = cmd
            if state != RUNNING:
                duty, ff, fb = safe, safe, 0.0

            # 5. outputs
            command(duty, t)
            err = ref - meas
            if state == RUNNING:
                publish_error(t, err)
                iae += abs(err) * period / 60.0
            supply = supply_bar() if supply_bar is not None else None
            alarm_step(t, state == RUNNING, duty, err, sup.mismatch_lpm, math.nan if supply is None else supply)
            if steps % status_every == 0:
                if faults.changes != faults_seen:
                    faults_seen, fault_counts = faults.changes, faults.counts()
                if alarm_view[alarm_changes_at] != alarms_seen:
                    alarms_seen, alarms_active, alarm_counts = alarm_view[alarm_changes_at], alarms.active(), alarms.counts()
                status = Status(STATES[state], sup.word, ref, meas if meas == meas else None, duty,
                                err if err == err else None, iae, steps, overruns, late_max * 1e6, compute_max * 1e6,
                                fault_counts, alarms_active, alarm_counts)
                late_max = compute_max = 0.0
                publish_status(t, status)
                if observer is not None:
                    observer(t, status)
            i = cols.n
            if i == cols.capacity:
                cols.grow()
            age_ms = (t - meas_t) * 1e3
            late = now - due
            limit = duty - ff - fb
            row = i * row_bytes
            pack_head(cols.buf, row, t, ref, meas, duty, ff, fb, limit, age_ms, late, state, word_index[sup.word])
            cols.n = i + 1
            if writer is not None:
                writer.write((t, ref, 0.0 if meas != meas else meas, duty, ff, fb, STATES[state], sup.word, limit,
                              age_ms))
            end = pc() - c0
            cpu = (cpu_ns() - k0) * 1e-9
            pack_last(cols.buf, row + last_at, end, cpu)
            if end > compute_max:
                compute_max = end
            if late > late_max:
                late_max = late
            if real_time and end + late > stale_s:  # stood still past its own watchdog
                faults.add("stalled", t)
            steps += 1

        transport_rehearse = getattr(transport, "rehearse", None)
        reference_rehearse = getattr(reference, "rehearse", None)
        alarm_rehearse, nan = alarms.rehearse, math.nan

        def rehearse(t: float) -> None:
            """The next step's compiled calls, reference and record row, for nothing, just before it is due at
            run time ``t`` (:attr:`LoopSettings.rehearse`): the law's last step, the valve's next one and the
            alarms' on scratch copies, the reference at ``t`` (and ahead), and the record's next row written
            ahead with the present values (past ``cols.n`` it is not part of the record; the step writes it
            again). A step after ~1 ms of sleep finds its code and data evicted (other processes, the
            hypervisor) and ran 2-3x slower than back to back; rehearsed, the step itself (all of its work,
            timed as ever) runs on warm caches."""
            sup.rehearse(period)
            if transport_rehearse is not None:
                transport_rehearse()
            if reference_rehearse is not None:
                reference_rehearse(t)
            alarm_rehearse(t, state == RUNNING, duty, ref_in - meas, sup.mismatch_lpm, nan)
            i = cols.n
            if i == cols.capacity:  # a run of no set length: grown here rather than in the step
                cols.grow()
            pack_head(cols.buf, i * row_bytes, t, ref_in, meas, duty, ff, fb, 0.0, 0.0, 0.0, state,
                      word_index[sup.word])

        # Warm-up: each law computes one throw-away step before the first deadline, so loading its
        # compiled kernels (numba's cache: tens to hundreds of ms on a busy host) never stalls a live
        # step, nor the valve, whose own command timeout would close it meanwhile.
        sup.warm_up(period, safe)

        rt = contextlib.ExitStack()
        rt.enter_context(gc_paused())
        rt.enter_context(realtime(cfg.rt_priority if real_time else 0))
        rt.enter_context(pinned(cfg.cpu if real_time else -1))
        t0 = clock.now()
        try:
            if on_measurement:
                # Each measurement's step runs at once on the transport's thread (arrived); this thread
                # is the watchdog: a step when none came for WATCHDOG_PERIODS periods, and the run's end.
                watch, refill = WATCHDOG_PERIODS * period, 2.0 / period
                lock = threading.Lock()  # one step at a time
                serving, failed = True, []
                last_wake = t0 - watch
                tokens, refilled = BURST_STEPS, t0  # the measurements' steps rationed (BURST_STEPS)
                # The transport's threads that step run at the loop's priority while it runs (Zenoh's own
                # are below it, [zenoh] io_priority): the step is the loop's work wherever it runs.
                lifted, priority = {}, cfg.rt_priority if real_time else 0

                last_arrival = -math.inf  # of the last measurement that got a step
                rehearse_law, lead = cfg.rehearse and real_time, MEASUREMENT_REHEARSAL_S
                native_id, now_s = threading.get_native_id, clock.now  # bound: the arrival's path is the command's

                def arrived(arrival_s: float) -> None:
                    nonlocal overruns, serving, tokens, refilled, last_arrival
                    with lock:
                        if not serving:
                            return
                        if priority:
                            tid = native_id()
                            if tid not in lifted:
                                lifted[tid] = _lift(priority)
                        if arrival_s > refilled:
                            tokens += (arrival_s - refilled) * refill
                            if tokens > BURST_STEPS:
                                tokens = BURST_STEPS
                            refilled = arrival_s
                        if last_wake >= arrival_s or tokens < 1.0:  # taken along by a step that came first, or rationed
                            overruns += 1
                            return
                        tokens -= 1.0
                        last_arrival = arrival_s
                        try:
                            step(now_s(), arrival_s)
                        except BaseException as exc:  # raised again on the loop's thread
                            failed.append(exc)
                            serving = False

                serve(arrived)
                rehearsed = -math.inf  # the arrival whose successor the law was rehearsed for
                try:
                    while True:
                        if rehearse_law and rehearsed < last_arrival and last_arrival + period - lead < last_wake + watch:
                            # the step rehearsed (rehearse()) just before the next measurement is due
                            expected = last_arrival
                            clock.sleep_until(expected + period - lead)
                            with lock:
                                if last_arrival == expected:  # no measurement came meanwhile
                                    rehearse(expected + period - t0)
                                rehearsed = expected
                            continue
                        clock.sleep_until(last_wake + watch)  # sleeps, never spins: the arrivals need the GIL
                        with lock:
                            if failed:
                                raise failed[0]
                            now = clock.now()
                            if now >= last_wake + watch:
                                step(now, last_wake + watch)
                            if (stop is not None and stop()) or (
                                    duration_s is not None and now - t0 >= duration_s - 0.5 * period):
                                serving = False
                                break
                finally:
                    serve(None)
                    with lock:
                        for tid, old in lifted.items():
                            if old is not None:
                                with contextlib.suppress(OSError):  # a thread that ended meanwhile
                                    os.sched_setscheduler(tid, *old)
            else:
                rehearse_next = None
                if cfg.rehearse and real_time:

                    def rehearse_next() -> None:  # in the spin before the deadline (RealClock.wait_until)
                        rehearse(deadline - t0)

                catch_up = cfg.catch_up
                deadline = t0

                def skip(missed: int) -> bool:
                    """Count ``missed`` deadlines as overruns and move past them; True when the run is over."""
                    nonlocal deadline, overruns, n_steps
                    if n_steps is not None:  # a run of n deadlines counts none past its end
                        missed = min(missed, n_steps - steps)
                        n_steps -= missed
                    deadline += missed * period
                    overruns += missed
                    return n_steps is not None and steps >= n_steps

                while True:
                    now = clock.wait_until(deadline, rehearse_next)
                    # woken (a frozen host) after whole periods: missed, the step serves the newest deadline
                    if catch_up and now - deadline >= period and skip(deadlines_missed(now - deadline, period, True)):
                        break
                    step(now, deadline)
                    if stop is not None and stop():
                        # the deadlines this last step woke past were missed too, though no step follows to count them
                        overruns += int((now - deadline) / period)
                        break
                    if n_steps is not None and steps >= n_steps:
                        break
                    deadline += period
                    behind = clock.now() - deadline
                    if behind > 0 and skip(deadlines_missed(behind, period, catch_up)):  # the deadlines missed
                        break
        finally:
            rt.close()
        return LoopResult(cols.trimmed(), faults, steps, overruns, cfg, alarms)
