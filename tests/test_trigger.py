"""Event-driven stepping (``[loop] trigger = "measurement"``) over Zenoh.

Free ports on 127.0.0.1, peer mode, multicast scouting off.
"""
from __future__ import annotations

import json

import pytest

zenoh = pytest.importorskip("zenoh")

from tests.zenoh_helpers import free_port, kill_valve_then_stop, reap, rows, valvectl, wait_for  # noqa: E402


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
