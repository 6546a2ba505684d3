"""Zenoh transport (eclipse-zenoh 1.x): keys and payloads of DESIGN.md.

Keys under ``vent/valve/{id}``: ``ref/flow`` and ``meas/flow`` in,
``cmd/duty``, ``ctrl/error`` (every step) and ``ctrl/status`` (10 Hz) out,
liveliness tokens ``alive/controller`` and ``alive/valve``. Payloads are
UTF-8 JSON ``{"t": s, "seq": n, "value": x}`` with encoding
``application/json``; ``cmd/duty`` adds ``meas_seq``, the ``seq`` of the
newest measurement the command was computed from.

The loop thread receives: subscribers hand samples to a
``zenoh.handlers.RingChannel`` (the newest samples, never blocking Zenoh's
threads) and the loop drains it with ``try_recv()`` once per step. A Python
callback instead would wait for the GIL while the loop spins, ~5 ms a
sample (the field notes' GIL trap). With ``trigger = "measurement"`` the
samples of every key come through callbacks instead, and a measurement's
runs the loop's step itself on Zenoh's thread
(:meth:`ZenohTransport.on_measurement`): the loop's own thread then only
sleeps, as the watchdog, and the step's polls are ``deque`` pops. Commands go out with priority
``REAL_TIME``, ``express`` (no batching) and congestion control ``DROP``: a
late command is worth less than the next one.
"""
from __future__ import annotations

import collections
import contextlib
import json
import os
import sys
import time

import zenoh

from .guard import SourceGuard
from .payload import MAX_PAYLOAD_BYTES, Message, PayloadError, encode, parse_command, parse_number, parse_word

#: Samples Zenoh keeps per subscribed key between two polls, and the most one poll takes.
RING = 16
#: Samples the valve node keeps of ``cmd/duty`` between two polls (read newest first: :class:`Inbox`).
CMD_RING = 64
#: Time one poll of one key may spend on its samples, s (a 1 kHz step has 1000 us; the law needs ~100).
DRAIN_BUDGET_S = 150e-6
#: Largest Zenoh message a session takes in, bytes (a payload of MAX_PAYLOAD_BYTES plus key and headers, with room):
#: Zenoh drops a larger one in its receive path, before assembling or delivering it.
MAX_MESSAGE_BYTES = 4 * MAX_PAYLOAD_BYTES
#: Auxiliary measurements a valve may publish, recording column -> key under ``vent/valve/{id}``
#: (payloads as ``meas/flow``; ``value`` in the column's unit: supply pressure in bar gauge, coil temperature in °C).
AUX_KEYS = {"supply_bar": "meas/supply", "coil_temp_c": "meas/coil_temp"}


def _plausible_supply(bar: float) -> bool:
    """A supply reading a valve could report, bar gauge (anything else is dropped unseen)."""
    return -1.0 <= bar <= 100.0


def session_config(cfg, listen: list[str] | None, connect: list[str] | None, role: str,
                   certs: str | None = None) -> zenoh.Config:
    """Zenoh configuration for ``role`` (``controller``, ``valve``, ``stack`` or ``monitor``).

    ``config/zenoh.json5`` (``[zenoh] config``) is loaded when present; the
    session is a peer with multicast scouting off either way. Endpoints:
    ``--listen``/``--connect`` if given, else the controller listens on
    ``[zenoh] listen`` and connects to ``[zenoh] connect``, and any other
    party connects to the controller's listen endpoints (or to ``[zenoh]
    connect`` when a router is configured there). Every session takes in
    messages of at most :data:`MAX_MESSAGE_BYTES` (Zenoh drops larger ones
    unassembled) and no shared memory.
    """
    from models.recording import InputError, check_input_file

    z = cfg["zenoh"]
    path = cfg.resolve(z["config"])
    if os.path.lexists(path):  # Zenoh's own reader would block on a FIFO and never end on /dev/zero
        check_input_file(path, "a Zenoh configuration", 16 << 20)
    try:
        conf = zenoh.Config.from_file(path) if os.path.exists(path) else zenoh.Config()
    except zenoh.ZError as exc:
        raise InputError(f"{path}: not a Zenoh configuration ({str(exc).splitlines()[0][:120]})") from None
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if role == "controller":
        lis = z["listen"] if listen is None else listen
        con = z["connect"] if connect is None else connect
    else:
        lis = [] if listen is None else listen
        con = (z["connect"] or z["listen"]) if connect is None else connect
    for key, eps, given in (("listen", lis, listen), ("connect", con, connect)):
        try:
            conf.insert_json5(f"{key}/endpoints", json.dumps(eps))
        except zenoh.ZError:
            where = f"--{key}" if given is not None else f"{cfg.path}: zenoh.{key}"
            raise InputError(f"{where}: {eps} are not Zenoh endpoints (<protocol>/<address>, "
                             f"e.g. tcp/127.0.0.1:7447)") from None
    # A flood of large payloads costs the receiving thread only the socket reads: Zenoh drops a message past
    # max_message_size instead of assembling it (1 MB each) and queueing it for the loop. Shared memory
    # would hand large payloads over outside that limit, and no DESIGN.md payload needs it (3 kB threshold).
    conf.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_BYTES))
    with contextlib.suppress(zenoh.ZError):  # a build without shared memory has nothing to turn off
        conf.insert_json5("transport/shared_memory/enabled", "false")
    if not os.path.exists(path):  # the retry settings of zenoh.json5, so any party may start first
        conf.insert_json5("connect/timeout_ms", "-1")
        conf.insert_json5("connect/exit_on_failure", "false")
    if certs is not None:
        from .security import secure

        secure(conf, certs, role, z["id"])
    return conf


@contextlib.contextmanager
def _nice(nice: int):
    """The calling thread at nice value ``nice`` (Linux: per thread), restored after; unchanged without the permission."""
    if nice == 0 or not hasattr(os, "setpriority"):
        yield
        return
    old = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except PermissionError:
        sys.stderr.write(f"zenoh: no permission for nice {nice}; its threads run at nice {old}\n")
        yield
        return
    try:
        yield
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, old)


def open_session(cfg, listen, connect, role: str, certs: str | None = None):
    """Open the Zenoh session of ``role``; with ``certs`` (a ``valvectl certs`` folder) the secure one
    (:func:`controller.transport.security.secure`). A bad endpoint, a taken port or a missing
    certificate is bad input (:class:`models.recording.InputError`).

    Zenoh's I/O threads (its runtimes ``app``, ``net``, ``acc``, ``rx``,
    ``tx``: process-wide, started by the first session) get a scheduling of
    their own: the session is opened while the calling thread has it, and
    Linux gives a new thread its creator's policy and nice value, so every
    thread Zenoh starts then or later (``rx``/``tx`` when links come up)
    inherits it. ``[zenoh] io_priority`` > 0: ``SCHED_FIFO`` below the
    loop's ``rt_priority``, so CPU-bound processes cannot delay a measurement
    or a command and the loop is never delayed by them (bench/bench_load.py,
    one CPU hog per core, 20 s: 9 overruns in 20 000 steps, against 91 with
    Zenoh's threads under the normal scheduler and 3349 with nothing).
    ``io_priority = 0`` and ``io_nice`` < 0: the normal scheduler with a
    larger share (weaker: it counts only within the login session's
    autogroup).
    """
    from models.recording import InputError

    from controller.loop import realtime

    conf = session_config(cfg, listen, connect, role, certs)
    z = cfg["zenoh"]
    try:
        with realtime(z["io_priority"]), _nice(z["io_nice"]):
            return zenoh.open(conf)
    except Exception as exc:  # the binding raises ZError for bad locators and bind failures
        raise InputError(f"zenoh: cannot open a session ({exc})") from None


def raw_payload(sample, max_bytes: int = MAX_PAYLOAD_BYTES) -> bytes:
    """The payload's bytes, refused (:class:`PayloadError`) before the copy out of Zenoh when oversized."""
    zb = sample.payload
    n = len(zb)
    if n > max_bytes:
        raise PayloadError(f"payload of {n} bytes (limit {max_bytes})")
    return zb.to_bytes()


class Inbox:
    """One subscribed key: Zenoh keeps its newest ``ring`` samples, the loop drains them with a bound.

    Zenoh's thread drops whatever a flood pushes past the ring (a
    ``RingChannel``, never blocking Zenoh and never growing). :meth:`poll`
    takes at most ``ring`` samples and spends at most ``budget_s`` (checked
    after each sample), so a flood of any size or rate costs a step a fixed
    budget; what it leaves waits for the next step, where the ring has kept
    only the newest. Each sample goes through the payload parser (size
    before the copy, then depth, numbers, shape) and, if given, a
    :class:`~controller.transport.guard.SourceGuard`.

    Parameters
    ----------
    session : zenoh.Session
    key : str
    parse : callable
        ``parse(bytes) -> Message`` or :class:`PayloadError` (:func:`payload.parse_number`, ``parse_word``).
    guard : SourceGuard, optional
    ring : int
        Samples kept by Zenoh and drained per step at most.
    budget_s : float
        Time one poll may spend, s.
    max_bytes : int
        Largest payload parsed, bytes.
    newest_first : bool
        Parse from the newest sample back and stop at the first valid one (no guard): the samples
        older than it are superseded and dropped unread, so a flood of garbage costs a step the
        parses of the garbage newer than the newest valid message, and a valid one that a flood
        would leave unreached at the end of the budget (oldest first) is found first. For a key
        where only the newest value counts (``cmd/duty`` at the valve node).
    on_sample : callable, optional
        ``on_sample(arrival_s)``, called on Zenoh's thread after each sample is kept (``arrival_s``:
        ``time.perf_counter`` when it came); implies ``by_callback``.
    by_callback : bool
        The samples kept by a Python callback on Zenoh's thread in a ring of ``ring`` (a ``deque``), not
        by a ``RingChannel``: a poll is then a ``deque`` pop, no call into Zenoh (a cold
        ``RingChannel.try_recv`` cost a measurement's step ~5 µs). Only for a process whose loop
        does not spin (trigger ``measurement``): the callback needs the GIL.
    """

    def __init__(self, session, key: str, parse=parse_number, guard: SourceGuard | None = None, ring: int = RING,
                 budget_s: float = DRAIN_BUDGET_S, max_bytes: int = MAX_PAYLOAD_BYTES, on_sample=None,
                 by_callback: bool = False, newest_first: bool = False):
        if newest_first and guard is not None:
            raise ValueError("a guard must see every sample in order: no newest_first with a guard")
        if on_sample is None and not by_callback:
            self.sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(ring))
            self._try_recv = self.sub.try_recv
        else:  # a callback keeps the ring (and signals each sample: for a loop that steps at each one)
            kept = collections.deque(maxlen=ring)
            pc = time.perf_counter
            keep = kept.append

            def take(sample):
                arrival_s = pc()
                keep(sample)
                if on_sample is not None:
                    on_sample(arrival_s)

            def try_recv():
                return kept.popleft() if kept else None

            self.sub = session.declare_subscriber(key, take)
            self._try_recv = try_recv
        self.parse, self.guard, self.ring, self.budget_s, self.max_bytes = parse, guard, ring, budget_s, max_bytes
        self.on_sample, self.newest_first = on_sample, newest_first

    def poll(self, accept=None) -> tuple[Message | None, int, int]:
        """``(newest accepted message or None, bad, spoofed)`` of the samples received since the last poll.

        Bad: not a DESIGN.md payload, or a value ``accept`` rejects; spoofed:
        well formed but refused by the guard. Never raises for a payload.
        """
        pc = time.perf_counter
        end = pc() + self.budget_s
        if self.newest_first:
            return self._poll_newest_first(accept, end)
        latest, bad, spoofed = None, 0, 0
        try_recv, parse, guard = self._try_recv, self.parse, self.guard
        for _ in range(self.ring):
            s = try_recv()
            if s is None:
                break
            try:
                m = parse(raw_payload(s, self.max_bytes))
            except PayloadError:
                bad += 1
            else:
                if accept is not None and not accept(m.value):
                    bad += 1
                elif guard is not None and not guard.believe(m.src, m.seq):
                    spoofed += 1
                else:
                    latest = m
            if pc() > end:
                break
        return latest, bad, spoofed

    def _poll_newest_first(self, accept, end: float) -> tuple[Message | None, int, int]:
        """Take every kept sample (no parsing), then parse from the newest back to the first valid one."""
        samples = []
        try_recv = self._try_recv
        for _ in range(self.ring):
            s = try_recv()
            if s is None:
                break
            samples.append(s)
        bad = 0
        pc, parse = time.perf_counter, self.parse
        for s in reversed(samples):
            try:
                m = parse(raw_payload(s, self.max_bytes))
            except PayloadError:
                bad += 1
            else:
                if accept is None or accept(m.value):
                    return m, bad, 0
                bad += 1
            if pc() > end:
                break
        return None, bad, 0

    def undeclare(self) -> None:
        self.sub.undeclare()


class _Publisher:
    def __init__(self, session, key: str, **qos):
        self.pub = session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON, **qos)
        self.seq = 0

    def put(self, t_s: float, value, **extra) -> None:
        self.pub.put(encode(t_s, self.seq, value, **extra))
        self.seq += 1

    def undeclare(self) -> None:
        self.pub.undeclare()


class ZenohReference:
    """``…/ref/flow`` as the loop's reference: the newest value, stale after ``ref_stale_ms``."""

    can_go_stale = True
    preview_s = 0.0

    def __init__(self, inbox: Inbox):
        self.inbox = inbox

    def poll(self, t_s: float, accept) -> tuple[float | None, int]:
        m, bad, _ = self.inbox.poll(accept)
        return (None if m is None else m.value), bad


class ZenohTransport:
    """The controller's side: measurements and references in, commands, error and status out.

    Measurements pass a :class:`SourceGuard` released after ``stale_s`` of
    silence: a second publisher of ``meas/flow`` is ``spoofed_measurement``.
    """

    def __init__(self, session, valve_id: str = "insp", stale_s: float = 0.05, trigger: str = "period"):
        k = f"vent/valve/{valve_id}"
        self.session = session
        # trigger "measurement": each measurement calls the loop's hook on Zenoh's thread (on_measurement)
        self._hook = None
        cb = trigger == "measurement"  # the loop's thread sleeps: every key kept by a callback (Inbox)
        self.meas_in = Inbox(session, f"{k}/meas/flow", guard=SourceGuard(stale_s),
                             on_sample=self._arrived if cb else None)
        self.ref_in = Inbox(session, f"{k}/ref/flow", by_callback=cb)
        self.mode_in = Inbox(session, f"{k}/ctrl/mode", parse=parse_word, by_callback=cb)
        self.supply_in = Inbox(session, f"{k}/{AUX_KEYS['supply_bar']}", by_callback=cb)
        self._supply_bar: float | None = None
        rt = {"priority": zenoh.Priority.REAL_TIME, "express": True, "congestion_control": zenoh.CongestionControl.DROP}
        self.cmd = _Publisher(session, f"{k}/cmd/duty", **rt)
        self.err = _Publisher(session, f"{k}/ctrl/error", express=True, congestion_control=zenoh.CongestionControl.DROP)
        self.status = _Publisher(session, f"{k}/ctrl/status")
        self.token = session.liveliness().declare_token(f"{k}/alive/controller")
        self.meas_seq: int | None = None

    def reference(self) -> ZenohReference:
        return ZenohReference(self.ref_in)

    def poll_measurement(self, accept) -> tuple[float | None, dict]:
        """Newest believed measurement (or None) and the rejected ones by fault kind."""
        m, bad, spoofed = self.meas_in.poll(accept)
        rejects = {"bad_measurement": bad, "spoofed_measurement": spoofed} if bad or spoofed else 0
        if m is None:
            return None, rejects
        self.meas_seq = m.seq
        return m.value, rejects

    def on_measurement(self, hook) -> None:
        """Call ``hook(arrival_s)`` (``time.perf_counter``) on Zenoh's thread as each measurement arrives, after
        it is kept for :meth:`poll_measurement`; None stops the calls (trigger ``measurement``)."""
        if self.meas_in.on_sample is None:
            raise ValueError("a transport opened with trigger 'period' signals no measurements")
        self._hook = hook

    def _arrived(self, arrival_s: float) -> None:
        hook = self._hook
        if hook is not None:
            hook(arrival_s)

    def poll_mode(self) -> tuple[str | None, int]:
        """The newest controller word asked for on ``ctrl/mode``, and how many requests were malformed."""
        m, bad, _ = self.mode_in.poll()
        return (None if m is None else m.value), bad

    def supply_bar(self) -> float | None:
        """The newest supply pressure the valve published (``meas/supply``, bar gauge), held; None before any."""
        m, _, _ = self.supply_in.poll(_plausible_supply)
        if m is not None:
            self._supply_bar = m.value
        return self._supply_bar

    def command(self, duty_pct: float, t_s: float) -> None:
        # meas_seq: the newest measurement this command was computed from (round-trip timing).
        self.cmd.put(t_s, duty_pct, meas_seq=self.meas_seq)

    def publish_error(self, t_s: float, error_lpm: float) -> None:
        self.err.put(t_s, error_lpm)

    def publish_status(self, t_s: float, status) -> None:
        self.status.put(t_s, status)

    def close(self) -> None:
        self.token.undeclare()
        for p in (self.cmd, self.err, self.status):
            p.undeclare()
        for i in (self.meas_in, self.ref_in, self.mode_in, self.supply_in):
            i.undeclare()


class EmbeddedValve:
    """The embedded simulated valve with the controller's error and status published on Zenoh.

    For ``--plant sim --reference zenoh``: measurements and commands stay
    in-process, nothing is commanded over Zenoh.
    """

    def __init__(self, sim, zt: ZenohTransport):
        self.sim, self.zt = sim, zt

    def poll_measurement(self, accept):
        return self.sim.poll_measurement(accept)

    def command(self, duty_pct: float, t_s: float) -> None:
        self.sim.command(duty_pct, t_s)

    def publish_error(self, t_s: float, error_lpm: float) -> None:
        self.zt.publish_error(t_s, error_lpm)

    def publish_status(self, t_s: float, status) -> None:
        self.zt.publish_status(t_s, status)

    def poll_mode(self) -> tuple[str | None, int]:
        return self.zt.poll_mode()

    def supply_bar(self) -> float:
        return self.sim.supply_bar()


class ValveNodeTransport:
    """The valve's side (``valvectl valve-node``): commands in, measured flow out, ``alive/valve``.

    Its measurements carry ``src``, the session's Zenoh id, so that the
    controller's guard tells this node from any other publisher.
    """

    def __init__(self, session, valve_id: str = "insp"):
        k = f"vent/valve/{valve_id}"
        # newest first, with room: under a garbage flood the newest valid command is what counts
        self.cmd_in = Inbox(session, f"{k}/cmd/duty", parse=parse_command, ring=CMD_RING, newest_first=True)
        self.meas = _Publisher(session, f"{k}/meas/flow", priority=zenoh.Priority.REAL_TIME, express=True,
                               congestion_control=zenoh.CongestionControl.DROP)
        self.aux = {col: _Publisher(session, f"{k}/{key}", express=True, congestion_control=zenoh.CongestionControl.DROP)
                    for col, key in AUX_KEYS.items()}
        self.src = str(session.zid())
        self.token = session.liveliness().declare_token(f"{k}/alive/valve")

    def poll_command(self, accept) -> tuple[float | None, int, int | None]:
        """Newest accepted command, how many were rejected, and the ``meas_seq`` it carried (None if absent)."""
        m, bad, _ = self.cmd_in.poll(accept)
        return (None, bad, None) if m is None else (m.value, bad, m.meas_seq)

    def publish_flow(self, t_s: float, flow_lpm: float) -> int:
        """Publish a measurement; returns its ``seq``."""
        seq = self.meas.seq
        self.meas.put(t_s, flow_lpm, src=self.src)
        return seq

    def publish_aux(self, t_s: float, values: dict) -> None:
        """Publish auxiliary measurements (:data:`AUX_KEYS` columns), with this node's ``src``."""
        for col, v in values.items():
            self.aux[col].put(t_s, v, src=self.src)

    def close(self) -> None:
        self.token.undeclare()
        self.meas.undeclare()
        for p in self.aux.values():
            p.undeclare()
        self.cmd_in.undeclare()
