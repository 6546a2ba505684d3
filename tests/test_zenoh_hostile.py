"""Hostile payloads and floods against the running controller and valve node (real processes).

Hypothesis draws payloads (tests.test_payload's strategy: binary noise, JSON
of any shape, deep nesting, 400-digit and non-finite numbers, megabyte
strings) and a client puts them on ``ref/flow``, ``meas/flow``, ``cmd/duty``
and ``ctrl/mode``; then floods of 1 MB payloads as fast as Python publishes
and a 10 kHz reference flood. Both processes must live through all of it,
count what they dropped, and the controller must be running again after.
Rates are asserted only as "every deadline is a step or a counted overrun":
the figures under flood are bench/bench_load.py's job.
"""
from __future__ import annotations

import json
import re
import signal
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

zenoh = pytest.importorskip("zenoh")

from tests.test_payload import hostile  # noqa: E402
from tests.zenoh_helpers import client_session, free_port, rows, valvectl, wait_for  # noqa: E402

P = "vent/valve/insp"
KEYS = ("ref/flow", "meas/flow", "cmd/duty", "ctrl/mode")


def node_stats(out: str) -> dict:
    """The valve node's exit line: steps, overruns, commands, bad, command timeouts."""
    m = re.search(r"(\d+) steps, (\d+) overruns, (\d+) commands, (\d+) bad, (\d+) command timeouts", out)
    assert m, out
    return dict(zip(("steps", "overruns", "commands", "bad_commands", "command_timeouts"), map(int, m.groups())))


def stop(p) -> str:
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert "Traceback" not in err, err
    return out


def flood(pubs, payload: bytes, seconds: float) -> int:
    n, t_end = 0, time.monotonic() + seconds
    while time.monotonic() < t_end:
        for pub in pubs:
            pub.put(payload)
        n += 1
    return n


@pytest.mark.slow
def test_hostile_payloads_and_floods_on_every_key(tmp_path):
    ep_ctrl, ep_node = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    rec, summ = tmp_path / "run.csv", tmp_path / "s.json"
    ctrl = valvectl("run", "--plant", "zenoh", "--reference", "zenoh", "--controller", "ff+kf", "--listen", ep_ctrl,
                    "--duration", "0", "--record", str(rec), "--json", str(summ))
    node = valvectl("valve-node", "--connect", ep_ctrl, "--listen", ep_node)
    procs = (ctrl, node)
    try:
        with client_session(ep_ctrl) as s_ctrl, client_session(ep_node) as s_node:
            # cmd/duty straight to the node (peers do not route for each other); the rest to the controller
            pubs = {k: (s_node if k == "cmd/duty" else s_ctrl).declare_publisher(f"{P}/{k}") for k in KEYS}
            ref_ok = pubs["ref/flow"]
            ref_ok.put(json.dumps({"t": 0, "seq": 0, "value": 40.0}).encode())
            wait_for(lambda: any(r[6] == "running" for r in rows(rec)[-50:]), "the controller running", procs)

            @settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck),
                      database=None)
            @given(st.lists(hostile, min_size=1, max_size=12))
            def put_batches(batch):
                for data in batch:
                    for pub in pubs.values():
                        pub.put(data)
                assert ctrl.poll() is None and node.poll() is None

            put_batches()
            k = 0
            for _ in range(300):  # well formed, but from a second source: spoofed, never believed
                pubs["meas/flow"].put(json.dumps({"t": 0, "seq": k, "value": 123.25}).encode())
                k += 1
            big = b'{"value": 1, "pad": "' + b"x" * 2 ** 20 + b'"}'
            flood(list(pubs.values()), big, 1.0)
            assert ctrl.poll() is None and node.poll() is None
            t_end, k = time.monotonic() + 1.0, 0
            while time.monotonic() < t_end:  # 10 kHz of valid references
                ref_ok.put(json.dumps({"t": k * 1e-4, "seq": k, "value": 40.0 + k % 2}).encode())
                k += 1
                while time.monotonic() < t_end and time.monotonic() < t_end - 1.0 + k * 1e-4:
                    pass
            n_before = len(rows(rec))
            wait_for(lambda: len(rows(rec)) > n_before + 300 and rows(rec)[-1][6] == "running",
                     "the controller running after the floods", procs)
        out_node = stop(node)
        stop(ctrl)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()

    faults = {f["kind"]: f["count"] for f in json.loads(summ.read_text())["faults"]}
    assert faults["bad_reference"] > 0 and faults["bad_measurement"] > 0
    assert faults["spoofed_measurement"] > 0
    assert node_stats(out_node)["bad_commands"] > 0
    table = rows(rec)
    flow = np.array([float(r[2]) for r in table])
    assert not np.any(flow == 123.25)  # the second source's value never reached the loop
    s = json.loads(summ.read_text())
    span = float(table[-1][0]) - float(table[0][0])
    assert s["steps"] + s["overruns"] == pytest.approx(span * 1000.0 + 1, abs=2)


def test_only_garbage_measurements_keep_the_valve_closed(tmp_path):
    """No valve node, only malformed meas/flow: the controller never runs, commands the safe duty, counts faults."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, summ = tmp_path / "run.csv", tmp_path / "s.json"
    ctrl = valvectl("run", "--plant", "zenoh", "--listen", ep, "--duration", "0", "--record", str(rec),
                    "--json", str(summ))
    try:
        wait_for(lambda: len(rows(rec)) > 100, "the controller stepping", (ctrl,))
        garbage = [b"[" * 5000, b'{"value": NaN}', b'{"value": ' + b"9" * 400 + b"}", b'{"value": "60"}', b"\xff",
                   b'{"seq": 1}', b'{"value": 1e999}', b'{"value": 100000.0}']
        with client_session(ep) as s:
            pub = s.declare_publisher(f"{P}/meas/flow")
            for k in range(3000):
                pub.put(garbage[k % len(garbage)])
                time.sleep(0.0005)
        stop(ctrl)
    finally:
        if ctrl.poll() is None:
            ctrl.kill()
            ctrl.wait()
    table = rows(rec)
    assert {r[6] for r in table} == {"safe"}
    assert all(float(r[3]) == 0.0 for r in table)
    faults = {f["kind"]: f["count"] for f in json.loads(summ.read_text())["faults"]}
    assert faults["bad_measurement"] > 0 and faults["no_measurement"] == 1


def test_a_third_publisher_neither_steers_nor_hides_a_dead_valve(tmp_path):
    """A process putting meas/flow beside the valve node is flagged and never believed; when the node
    dies, its measurements do not keep the controller running: stale, safe, valve closed."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, summ = tmp_path / "run.csv", tmp_path / "s.json"
    ctrl = valvectl("run", "--plant", "zenoh", "--listen", ep, "--duration", "0", "--record", str(rec),
                    "--json", str(summ))
    node = valvectl("valve-node", "--connect", ep)
    try:
        wait_for(lambda: any(r[6] == "running" for r in rows(rec)[-50:]), "the controller running", (ctrl, node))
        with client_session(ep) as s:
            pub = s.declare_publisher(f"{P}/meas/flow")

            def spoof(seconds, k0):
                t_end, k = time.monotonic() + seconds, k0
                while time.monotonic() < t_end:
                    pub.put(json.dumps({"t": 0.0, "seq": 10 ** 9 + k, "value": 123.25}).encode())
                    k += 1
                    time.sleep(0.001)
                return k

            k = spoof(1.0, 0)
            n_kill = len(rows(rec))
            node.send_signal(signal.SIGKILL)
            node.wait(10)
            spoof(1.0, k)
        stop(ctrl)
    finally:
        for p in (ctrl, node):
            if p.poll() is None:
                p.kill()
                p.wait()
    table = rows(rec)
    flow = np.array([float(r[2]) for r in table])
    state = np.array([r[6] for r in table])
    assert not np.any(flow == 123.25)
    last_run = np.flatnonzero(state == "running")[-1]
    assert last_run > n_kill - 100  # running up to the kill, beside the spoofer
    assert np.all(state[last_run + 1:] == "safe")  # then safe for good, while the spoofer went on for 1 s
    assert len(table) - last_run > 500
    faults = {f["kind"]: f["count"] for f in json.loads(summ.read_text())["faults"]}
    assert faults["spoofed_measurement"] > 0 and faults["stale"] >= 1


def test_a_stalled_step_shows_in_the_summary():
    """A step held up by its inputs (as a drain without a budget was by a 1 MB flood) is reported truthfully:
    as the longest step, its missed deadlines as overruns, and a `stalled` fault (the loop stood still
    longer than its own watchdog allows a measurement to)."""
    from controller.config import controller_params, load_run_config
    from controller.loop import Loop, LoopSettings, ProfileReference, RealClock
    from controller.run_summary import summary
    from controller.transport.sim import SimTransport
    from models.model import load_model
    from plant_sim.plant import Plant, load_plant

    stall_s, rate = 0.3, 1000.0
    cfg = load_run_config("config/run.toml")
    params = controller_params(cfg, "ff+pid", load_model(cfg.resolve(cfg[""]["model"])))

    class Stalling(SimTransport):
        n = 0

        def poll_measurement(self, accept):
            self.n += 1
            if self.n == 5:
                time.sleep(stall_s)
            return super().poll_measurement(accept)

    plant = Plant(load_plant(cfg.resolve(cfg[""]["plant_config"])), rate, seed=0)
    res = Loop(params, Stalling(plant), ProfileReference(lambda t: 40.0), LoopSettings(rate_hz=rate),
               clock=RealClock()).run(0.6)
    s = summary(res, "ff+pid", "sim")
    assert s["compute_us"]["max"] >= stall_s * 1e6
    assert s["compute_cpu_us"]["max"] < stall_s * 1e6 / 2 and s["steps_off_cpu"] >= 1  # asleep: off its CPU
    assert s["overruns"] >= int(stall_s * rate) - 1
    assert s["steps"] + s["overruns"] == int(0.6 * rate)
    assert {f["kind"]: f["count"] for f in s["faults"]}.get("stalled") == 1


def test_zenoh_drops_oversized_messages_before_they_reach_the_inbox():
    """A 1 MB payload is never assembled nor queued: the loop's inbox sees only the small ones (none counted bad)."""
    from controller.config import load_run_config
    from controller.transport.zenoh import Inbox, session_config
    from tests.zenoh_helpers import ROOT

    ep = f"tcp/127.0.0.1:{free_port()}"
    cfg = load_run_config(f"{ROOT}/config/run.toml")
    with zenoh.open(session_config(cfg, [ep], [], "controller")) as s, client_session(ep) as c:
        inbox = Inbox(s, f"{P}/ref/flow")
        pub = c.declare_publisher(f"{P}/ref/flow", congestion_control=zenoh.CongestionControl.BLOCK)
        seen: list = []

        def small_arrives(value: float) -> bool:
            pub.put(json.dumps({"value": value}).encode())
            t_end = time.monotonic() + 2.0
            while time.monotonic() < t_end:
                m, bad, _ = inbox.poll()
                seen.append(bad)
                if m is not None and m.value == value:
                    return True
                time.sleep(0.01)
            return False

        wait_for(lambda: small_arrives(1.0), "the client connected")
        big = b'{"value": 2, "pad": "' + b"x" * 2 ** 20 + b'"}'
        for _ in range(8):
            pub.put(big)
        assert small_arrives(3.0)  # sent after the big ones, on the same link: they were all handled before it
        assert sum(seen) == 0
