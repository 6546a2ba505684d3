"""`valvectl monitor`: the view on plain statuses, and live in a pseudo-terminal against a real controller and valve."""
from __future__ import annotations

import json
import os
import pty
import select
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.monitor import BARS, MONITOR_COLUMNS, MonitorState, parse_status, render, sparkline
from controller.transport.payload import PayloadError

zenoh = pytest.importorskip("zenoh")

from tests.zenoh_helpers import ROOT, client_session, free_port, rows, valvectl, wait_for  # noqa: E402


def status(i, state="running", word="ff+kf", alarms=()):
    return {"state": state, "controller": word, "ref_lpm": 60.0, "flow_lpm": 60.0 - i % 3, "duty_pct": 44.0 + i,
            "error_lpm": i % 3, "iae": 0.01 * i, "steps": 100 * i, "overruns": 1, "lateness_us_max": 12.0,
            "compute_us_max": 80.0, "faults": {"stale": 1}, "alarms": list(alarms),
            "alarm_counts": {a: 1 for a in alarms}}


@given(st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=80), st.integers(1, 80))
def test_sparkline_spans_its_glyphs_in_order(values, width):
    s = sparkline(values, width)
    tail = values[-width:]
    assert len(s) == len(tail)
    if max(tail) > min(tail):  # the extremes get the lowest and highest glyph, and order is kept
        assert s[int(np.argmin(tail))] == BARS[0] and s[int(np.argmax(tail))] == BARS[-1]
        levels = [BARS.index(c) for c in s]
        order = np.argsort(tail, kind="stable")
        assert all(levels[a] <= levels[b] for a, b in zip(order, order[1:]))


def test_view_shows_state_controller_signals_timing_faults_and_alarms():
    from rich.console import Console

    m = MonitorState(window=20)
    for i in range(30):
        row = m.add(0.1 * i, status(i, alarms=("supply_low",) if i == 29 else ()))
    assert len(row) == len(MONITOR_COLUMNS) and row[-1] == "supply_low" and row[1] == "running"
    c = Console(record=True, width=140, color_system=None)
    c.print(render(m, "tcp/127.0.0.1:1"))
    text = c.export_text()
    for word in ("running", "ff+kf", "flow L/min", "duty %", "error L/min", "overruns 1", "stale x1",
                 "ACTIVE supply_low", "compute max 80 us"):
        assert word in text, word
    assert sparkline(m.history["duty_pct"], 20) in text


@pytest.mark.parametrize("data", [b"{}", b'{"value": 1}', b'{"value": {"state": 3}}', b"[", b"x" * 5000])
def test_malformed_status_is_a_payload_error(data):
    with pytest.raises(PayloadError):
        parse_status(data)


class PtyReader(threading.Thread):
    """Drains the terminal's master side as the child writes (a full pty would block the child)."""

    def __init__(self, fd):
        super().__init__(daemon=True)
        self.fd, self.out, self.done = fd, bytearray(), threading.Event()

    def run(self):
        while not self.done.is_set():
            r, _, _ = select.select([self.fd], [], [], 0.2)
            if r:
                try:
                    chunk = os.read(self.fd, 65536)
                except OSError:  # the child closed the terminal
                    return
                if not chunk:
                    return
                self.out += chunk

    def text(self) -> str:
        return self.out.decode("utf-8", "replace")


@pytest.mark.slow  # ~13 s: make test keeps the suite under 5 minutes
def test_monitor_in_a_pty_shows_a_live_run_of_another_process_and_records_it(tmp_path):
    """valvectl run --plant zenoh + valve-node; the monitor in a pseudo-terminal; a mode switch on ctrl/mode."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, mrec = tmp_path / "run.csv", tmp_path / "m.csv"
    ctrl = valvectl("run", "--plant", "zenoh", "--controller", "ff+kf", "--listen", ep, "--duration", "0",
                    "--record", str(rec))
    node = valvectl("valve-node", "--connect", ep)
    master, slave = pty.openpty()
    mon = None
    try:
        wait_for(lambda: any(r[6] == "running" for r in rows(rec)), "the controller running", (ctrl, node))
        env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "130", "LINES": "40"}
        mon = subprocess.Popen([sys.executable, "-m", "controller.cli", "monitor", "--connect", ep, "--duration", "8",
                                "--record", str(mrec)], cwd=ROOT, stdin=slave, stdout=slave, stderr=slave, env=env)
        os.close(slave)
        reader = PtyReader(master)
        reader.start()
        wait_for(lambda: len(rows(mrec)) >= 5, "the monitor receiving statuses", (mon, ctrl, node))
        with client_session(ep) as s:  # the ventilator stack switches the controller
            pub = s.declare_publisher("vent/valve/insp/ctrl/mode", encoding=zenoh.Encoding.APPLICATION_JSON)
            wait_for(lambda: (pub.put(json.dumps({"t": 0.0, "seq": 1, "value": "ff+pid"})) or True)
                     and any(r[2] == "ff+pid" for r in rows(mrec)), "the switch seen by the monitor", (mon,))
        assert mon.wait(60) == 0
        reader.done.set()
        reader.join(5)
        screen = reader.text()
    finally:
        for p in (mon, ctrl, node):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(30)
        os.close(master)
    # the view, as the terminal got it (with rich's cursor movements): the live run's words
    for word in ("valvectl monitor", "running", "ff+kf", "ff+pid", "flow L/min", "duty %", "overruns", "alarms:"):
        assert word in screen, word
    assert "\x1b[" in screen  # drawn for a terminal (colours, cursor moves), not plain text
    table = rows(mrec)
    assert open(mrec).readline().strip() == ",".join(MONITOR_COLUMNS)
    t = np.array([float(r[0]) for r in table])
    assert len(table) >= 10 and np.all(np.diff(t) > 0)
    assert {r[1] for r in table} <= {"running", "safe", "fault"} and "running" in {r[1] for r in table}
    words = [r[2] for r in table]
    assert words[0] == "ff+kf" and words[-1] == "ff+pid"
    # the controller's own recording agrees: the word in force changed to ff+pid without a duty jump
    run = rows(rec)
    duty = np.array([float(r[3]) for r in run])
    ctl = np.array([r[7] for r in run])
    i = int(np.flatnonzero(ctl == "ff+pid")[0])
    assert abs(duty[i] - duty[i - 1]) <= 10000.0 / 1000.0 + 1e-9


def test_secured_monitor_reads_the_status_of_a_secured_loop(tmp_path):
    """--certs: the monitor (role monitor) sees ctrl/status over TLS; a monitor without certificates sees nothing."""
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "controller.cli", "certs", str(site)], cwd=ROOT, capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, good, rogue = tmp_path / "run.csv", tmp_path / "m.csv", tmp_path / "rogue.csv"
    ctrl = valvectl("run", "--plant", "zenoh", "--listen", ep, "--certs", str(site), "--duration", "0",
                    "--record", str(rec))
    node = valvectl("valve-node", "--connect", ep, "--certs", str(site))
    mons = []
    try:
        wait_for(lambda: any(r[6] == "running" for r in rows(rec)), "the secured loop running", (ctrl, node))
        mons = [valvectl("monitor", "--connect", ep, "--certs", str(site), "--duration", "0", "--record", str(good)),
                valvectl("monitor", "--connect", ep, "--duration", "0", "--record", str(rogue))]
        # the rogue's recording opens once its session is up and subscribed: from then on the monitor with
        # certificates receives statuses while the rogue listens beside it
        wait_for(rogue.exists, "the rogue monitor listening", (*mons, ctrl, node))
        n0 = len(rows(good))
        wait_for(lambda: len(rows(good)) >= n0 + 5 and "running" in {r[1] for r in rows(good)[n0:]},
                 "statuses at the monitor with certificates", (*mons, ctrl, node))
        for m in mons:
            m.send_signal(signal.SIGTERM)
            _, err = m.communicate(timeout=90)
            assert m.returncode == 0, err
    finally:
        for p in (*mons, ctrl, node):
            if p.poll() is None:
                p.terminate()
                p.wait(30)
    # on a busy machine the loop may be safe at times (stale measurements); it ran and the monitor saw it
    assert len(rows(good)) >= 5 and "running" in {r[1] for r in rows(good)}
    assert rows(rogue) == []


def test_an_in_process_run_with_listen_publishes_its_status(tmp_path):
    """`valvectl run --listen EP` on the simulated valve publishes ctrl/status (with alarms) for a monitor."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    summ = tmp_path / "s.json"
    with client_session(ep) as s:
        sub = s.declare_subscriber("vent/valve/insp/ctrl/status", zenoh.handlers.RingChannel(1000))
        run = valvectl("run", "--listen", ep, "--duration", "2", "--inject", "supply_bar=0.3@1.2",
                       "--json", str(summ))
        _, err = run.communicate(timeout=180)
        assert run.returncode == 0, err
        got = []
        while (x := sub.try_recv()) is not None:
            got.append(parse_status(x.payload.to_bytes()).value)
    assert got and {"state", "controller", "ref_lpm", "flow_lpm", "duty_pct", "alarms", "faults"} <= set(got[-1])
    assert any("supply_low" in g["alarms"] for g in got)


def test_the_controller_reads_the_supply_the_valve_publishes():
    """meas/supply (bar gauge, as valve-node publishes it) reaches the loop's supply_low alarm; nonsense is dropped."""
    from controller.transport.zenoh import ZenohTransport

    ep = f"tcp/127.0.0.1:{free_port()}"
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps([ep]))
    with zenoh.open(c) as ctrl_session, client_session(ep) as valve:
        zt = ZenohTransport(ctrl_session)
        try:
            assert zt.supply_bar() is None  # nothing published yet: no supply_low either way
            pub = valve.declare_publisher("vent/valve/insp/meas/supply")

            def published(v, seq):
                pub.put(json.dumps({"t": 0.0, "seq": seq, "value": v}))
                return zt.supply_bar() == v

            wait_for(lambda: published(1.5, 1), "the supply reading")
            for seq, bad in enumerate((1e9, -50.0, "low"), start=2):  # implausible: the last good one holds
                pub.put(json.dumps({"t": 0.0, "seq": seq, "value": bad}))
            time.sleep(0.3)
            assert zt.supply_bar() == 1.5
        finally:
            zt.close()
