"""Event-driven stepping (``[loop] trigger = "measurement"``) over Zenoh, and its doorbell.

Free ports on 127.0.0.1, peer mode, multicast scouting off.
"""
from __future__ import annotations

import json
import threading
import time

import pytest

zenoh = pytest.importorskip("zenoh")

from controller.transport.zenoh import Doorbell  # noqa: E402
from tests.zenoh_helpers import free_port, kill_valve_then_stop, reap, rows, valvectl, wait_for  # noqa: E402


def test_doorbell_wakes_at_a_ring_counts_the_superseded_and_times_out_at_the_deadline():
    bell = Doorbell()
    assert bell.wait(time.perf_counter() + 0.01) == (None, 0)  # nothing rang: back at the deadline
    bell.ring()
    bell.ring()
    arrival, superseded = bell.wait(time.perf_counter() + 10.0)  # rang before the wait: at once
    assert arrival is not None and arrival <= time.perf_counter() and superseded == 1
    t_ring = []

    def later():
        time.sleep(0.05)
        t_ring.append(time.perf_counter())
        bell.ring()

    threading.Thread(target=later).start()
    arrival, superseded = bell.wait(time.perf_counter() + 30.0)
    assert superseded == 0 and arrival >= t_ring[0]  # woken by the ring, long before the deadline
    assert bell.wait(time.perf_counter()) == (None, 0)  # each ring wakes one wait


def test_controller_triggered_by_measurements_drives_the_valve_node_and_goes_safe_when_it_dies(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, summ = tmp_path / "run.csv", tmp_path / "s.json"
    ctrl = valvectl("run", "--plant", "zenoh", "--trigger", "measurement", "--listen", ep, "--duration", "0",
                    "--record", str(rec), "--json", str(summ))
    node = valvectl("valve-node", "--connect", ep)
    try:
        wait_for(lambda: sum(r[6] == "running" for r in rows(rec)[-300:]) > 200, "the controller running",
                 (ctrl, node))
        kill_valve_then_stop(ctrl, node, rec, 100)  # the watchdog's steps go on without measurements
    finally:
        reap(ctrl, node)
    s = json.loads(summ.read_text())
    faults = {f["kind"] for f in s["faults"]}
    assert "stale" in faults  # the measurements stopped: the watchdog's steps took the loop to safe
    last = rows(rec)[-1]
    assert last[6] == "safe" and float(last[3]) == 0.0  # safe duty: valve closed
    assert s["steps"] > 300
