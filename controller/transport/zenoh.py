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
sample (the field notes' GIL trap). Commands go out with priority
``REAL_TIME``, ``express`` (no batching) and congestion control ``DROP``: a
late command is worth less than the next one.
"""
from __future__ import annotations

import json
import os

import zenoh

RING = 256  # samples kept per subscriber between two loop steps (a flood beyond is dropped unseen)


def session_config(cfg, listen: list[str] | None, connect: list[str] | None, role: str) -> zenoh.Config:
    """Zenoh configuration for ``role`` (``controller`` or ``valve``).

    ``config/zenoh.json5`` (``[zenoh] config``) is loaded when present; the
    session is a peer with multicast scouting off either way. Endpoints:
    ``--listen``/``--connect`` if given, else the controller listens on
    ``[zenoh] listen`` and connects to ``[zenoh] connect``, and any other
    party connects to the controller's listen endpoints (or to ``[zenoh]
    connect`` when a router is configured there).
    """
    z = cfg["zenoh"]
    path = cfg.resolve(z["config"])
    conf = zenoh.Config.from_file(path) if os.path.exists(path) else zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if role == "controller":
        lis = z["listen"] if listen is None else listen
        con = z["connect"] if connect is None else connect
    else:
        lis = [] if listen is None else listen
        con = (z["connect"] or z["listen"]) if connect is None else connect
    conf.insert_json5("listen/endpoints", json.dumps(lis))
    conf.insert_json5("connect/endpoints", json.dumps(con))
    if not os.path.exists(path):  # the retry settings of zenoh.json5, so any party may start first
        conf.insert_json5("connect/timeout_ms", "-1")
        conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def open_session(cfg, listen, connect, role: str):
    """Open the Zenoh session; a bad endpoint or a taken port is bad input."""
    from models.recording import InputError

    try:
        return zenoh.open(session_config(cfg, listen, connect, role))
    except Exception as exc:  # the binding raises ZError for bad locators and bind failures
        raise InputError(f"zenoh: cannot open a session ({exc})") from None


def payload(t_s: float, seq: int, value, **extra) -> bytes:
    return json.dumps({"t": t_s, "seq": seq, "value": value, **extra}).encode()


def parse(sample) -> tuple[float | None, int | None]:
    """``(value, seq)`` of a payload; value None if the payload is malformed (seq None if absent)."""
    try:
        d = json.loads(sample.payload.to_bytes())
        v = d["value"]
    except (ValueError, TypeError, KeyError, UnicodeDecodeError):
        return None, None
    seq = d.get("seq")
    seq = seq if isinstance(seq, int) else None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None, seq
    return float(v), seq


def drain(sub, accept) -> tuple[float | None, int, int | None]:
    """Newest accepted value among the queued samples, how many were rejected, and its seq."""
    latest, bad, latest_seq = None, 0, None
    while True:
        s = sub.try_recv()
        if s is None:
            return latest, bad, latest_seq
        v, seq = parse(s)
        if v is not None and accept(v):
            latest, latest_seq = v, seq
        else:
            bad += 1


class _Publisher:
    def __init__(self, session, key: str, **qos):
        self.pub = session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON, **qos)
        self.seq = 0

    def put(self, t_s: float, value, **extra) -> None:
        self.pub.put(payload(t_s, self.seq, value, **extra))
        self.seq += 1

    def undeclare(self) -> None:
        self.pub.undeclare()


class ZenohReference:
    """``…/ref/flow`` as the loop's reference: the newest value, stale after ``ref_stale_ms``."""

    can_go_stale = True
    preview_s = 0.0

    def __init__(self, sub):
        self.sub = sub

    def poll(self, t_s: float, accept) -> tuple[float | None, int]:
        return drain(self.sub, accept)[:2]


class ZenohTransport:
    """The controller's side: measurements and references in, commands, error and status out."""

    def __init__(self, session, valve_id: str = "insp"):
        k = f"vent/valve/{valve_id}"
        self.session = session
        self.sub_meas = session.declare_subscriber(f"{k}/meas/flow", zenoh.handlers.RingChannel(RING))
        self.sub_ref = session.declare_subscriber(f"{k}/ref/flow", zenoh.handlers.RingChannel(RING))
        rt = {"priority": zenoh.Priority.REAL_TIME, "express": True, "congestion_control": zenoh.CongestionControl.DROP}
        self.cmd = _Publisher(session, f"{k}/cmd/duty", **rt)
        self.err = _Publisher(session, f"{k}/ctrl/error", express=True, congestion_control=zenoh.CongestionControl.DROP)
        self.status = _Publisher(session, f"{k}/ctrl/status")
        self.token = session.liveliness().declare_token(f"{k}/alive/controller")
        self.meas_seq: int | None = None

    def reference(self) -> ZenohReference:
        return ZenohReference(self.sub_ref)

    def poll_measurement(self, accept) -> tuple[float | None, int]:
        v, bad, seq = drain(self.sub_meas, accept)
        if v is not None:
            self.meas_seq = seq
        return v, bad

    def command(self, duty_pct: float, t_s: float) -> None:
        # meas_seq: the newest measurement this command was computed from (round-trip timing).
        self.cmd.put(t_s, duty_pct, meas_seq=self.meas_seq)

    def publish_error(self, t_s: float, error_lpm: float) -> None:
        self.err.put(t_s, error_lpm)

    def publish_status(self, t_s: float, status: dict) -> None:
        self.status.put(t_s, status)

    def close(self) -> None:
        self.token.undeclare()
        for p in (self.cmd, self.err, self.status):
            p.undeclare()
        for s in (self.sub_meas, self.sub_ref):
            s.undeclare()


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

    def publish_status(self, t_s: float, status: dict) -> None:
        self.zt.publish_status(t_s, status)


class ValveNodeTransport:
    """The valve's side (``valvectl valve-node``): commands in, measured flow out, ``alive/valve``."""

    def __init__(self, session, valve_id: str = "insp"):
        k = f"vent/valve/{valve_id}"
        self.sub_cmd = session.declare_subscriber(f"{k}/cmd/duty", zenoh.handlers.RingChannel(RING))
        self.meas = _Publisher(session, f"{k}/meas/flow", priority=zenoh.Priority.REAL_TIME, express=True,
                               congestion_control=zenoh.CongestionControl.DROP)
        self.token = session.liveliness().declare_token(f"{k}/alive/valve")

    def poll_command(self, accept) -> tuple[float | None, int]:
        return drain(self.sub_cmd, accept)[:2]

    def publish_flow(self, t_s: float, flow_lpm: float) -> None:
        self.meas.put(t_s, flow_lpm)

    def close(self) -> None:
        self.token.undeclare()
        self.meas.undeclare()
        self.sub_cmd.undeclare()
