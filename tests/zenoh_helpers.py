"""Helpers of the cross-process Zenoh tests: free ports, valvectl processes, waiting, reading recordings.

Free ports on 127.0.0.1, peer mode, multicast scouting off: other
engineers run Zenoh tests on the same machine at the same time.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time

import zenoh

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
START_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def valvectl(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "controller.cli", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def wait_for(pred, what: str, procs=()) -> None:
    t0 = time.monotonic()
    while not pred():
        for p in procs:
            if p.poll() is not None:
                raise AssertionError(f"{what}: a process ended early: {p.communicate()}")
        if time.monotonic() - t0 > START_TIMEOUT_S:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def rows(path) -> list[list[str]]:
    try:
        with open(path) as fh:
            return [line.rstrip("\n").split(",") for line in fh.readlines()[1:] if line.endswith("\n")]
    except FileNotFoundError:
        return []


def client_session(ep: str):
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([ep]))
    c.insert_json5("connect/timeout_ms", "-1")
    c.insert_json5("connect/exit_on_failure", "false")  # keep retrying in the background
    c.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 500}')
    return zenoh.open(c)




def kill_valve_then_stop(ctrl, node, rec, steps_after: int) -> None:
    """SIGKILL the valve node, wait for ``steps_after`` more controller steps in ``rec``, then SIGTERM the
    controller and check it ended cleanly (its summary written)."""
    import signal

    n_before = len(rows(rec))
    node.send_signal(signal.SIGKILL)
    node.wait(10)
    wait_for(lambda: len(rows(rec)) > n_before + steps_after, "steps after the kill", (ctrl,))
    ctrl.send_signal(signal.SIGTERM)
    out, err = ctrl.communicate(timeout=30)
    assert ctrl.returncode == 0, err


def reap(*procs) -> None:
    """Kill whichever of ``procs`` still runs."""
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait()
