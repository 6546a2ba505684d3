"""The identification's side of Zenoh: the valve's measurements in, duty out, one commander per valve.

Keys under ``vent/valve/{id}`` (DESIGN.md): ``meas/flow`` in, ``cmd/duty``
out (with ``meas_seq``, as the controller sends it), and the auxiliary
measurements a bridge may publish, :data:`controller.transport.zenoh.AUX_KEYS`
(``meas/supply``: supply pressure, bar gauge; ``meas/coil_temp``: coil
temperature, °C). The session commands the valve, so it holds
``alive/controller`` while it runs, and it refuses to start while another
session holds it: two commanders on one valve are a hazard.
"""
from __future__ import annotations

import time

import zenoh

from controller.transport.guard import SourceGuard
from controller.transport.zenoh import AUX_KEYS, Inbox, _Publisher
from controller.watchdog import in_range
from models.recording import InputError


class Link:
    """Subscriptions and the command publisher for one valve; the liveliness token once :meth:`claim` ed.

    Measurements pass a :class:`~controller.transport.guard.SourceGuard`
    (one publisher of ``meas/flow`` believed; a second is ``spoofed_measurement``).
    """

    def __init__(self, session, valve_id: str = "insp", stale_s: float = 0.25):
        self.key = f"vent/valve/{valve_id}"
        k = self.key
        self.session = session
        self.meas_in = Inbox(session, f"{k}/meas/flow", guard=SourceGuard(stale_s))
        self.aux_in = {col: Inbox(session, f"{k}/{key}") for col, key in AUX_KEYS.items()}
        self.sub_alive = session.liveliness().declare_subscriber(f"{k}/alive/controller",
                                                                 zenoh.handlers.RingChannel(16), history=True)
        self.cmd = _Publisher(session, f"{k}/cmd/duty", priority=zenoh.Priority.REAL_TIME, express=True,
                              congestion_control=zenoh.CongestionControl.DROP)
        self.token = None
        self.meas_seq: int | None = None
        self.aux: dict[str, float] = {}
        self._pending: float | None = None  # a measurement taken while waiting, handed to the first poll
        self._accept_aux = in_range(-1e6, 1e6)

    def _controller_seen(self) -> bool:
        seen = False
        while True:
            s = self.sub_alive.try_recv()
            if s is None:
                return seen
            seen = seen or s.kind == zenoh.SampleKind.PUT

    def _refuse(self) -> None:
        raise InputError(f"zenoh: a controller is alive on {self.key}/alive/controller: refusing to command "
                         "the valve (two commanders on one valve); stop it first")

    def wait_for_valve(self, timeout_s: float, grace_s: float = 0.3) -> tuple[str, ...]:
        """Wait for measurements; refuse if a controller is alive. Returns the auxiliary columns published.

        Raises
        ------
        InputError
            A controller's token is alive, or no measurement came within ``timeout_s``.
        """
        end = time.monotonic() + timeout_s
        first = None
        while True:
            if self._controller_seen():
                self._refuse()
            m, _, _ = self.meas_in.poll(self._accept_aux)
            if m is not None:
                self._pending, self.meas_seq = m.value, m.seq
                first = first or time.monotonic()
            self.poll_aux()
            now = time.monotonic()
            if first is not None and now - first >= grace_s:
                break
            if first is None and now > end:
                raise InputError(f"zenoh: no measurement on {self.key}/meas/flow within {timeout_s:g} s "
                                 "(is the valve connected? see --listen/--connect)")
            time.sleep(0.005)
        replies = self.session.liveliness().get(f"{self.key}/alive/controller", timeout=grace_s)
        for r in replies:
            if r.ok is not None:
                self._refuse()
        if self._controller_seen():
            self._refuse()
        return tuple(self.aux)

    def claim(self) -> None:
        """Declare ``alive/controller``: this session commands the valve now."""
        self.token = self.session.liveliness().declare_token(f"{self.key}/alive/controller")

    def poll_measurement(self, accept) -> tuple[float | None, dict]:
        """Newest believed measurement (or None) and the rejected ones by fault kind."""
        m, bad, spoofed = self.meas_in.poll(accept)
        rejects = {"bad_measurement": bad, "spoofed_measurement": spoofed}
        if m is None:
            v, self._pending = self._pending, None
            return (v if v is not None and accept(v) else None), rejects
        self._pending, self.meas_seq = None, m.seq
        return m.value, rejects

    def poll_aux(self) -> dict[str, float]:
        """The newest value of every auxiliary measurement seen so far."""
        for col, inbox in self.aux_in.items():
            m, _, _ = inbox.poll(self._accept_aux)
            if m is not None:
                self.aux[col] = m.value
        return dict(self.aux)

    def command(self, duty_pct: float, t_s: float) -> None:
        self.cmd.put(t_s, duty_pct, meas_seq=self.meas_seq)

    def close(self) -> None:
        if self.token is not None:
            self.token.undeclare()
        self.cmd.undeclare()
        self.sub_alive.undeclare()
        for inbox in (self.meas_in, *self.aux_in.values()):
            inbox.undeclare()
