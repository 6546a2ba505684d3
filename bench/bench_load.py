"""The Zenoh pair (controller and valve node, real processes) under CPU hogs on every core, with and without
the real-time measures, in one run.

Cases, each a `valvectl run --plant zenoh` against a `valvectl valve-node` for DURATION seconds:

* ``idle, loop FIFO + io FIFO``: no hogs, the shipped settings (the reference);
* ``hogs, nothing``: both loops and Zenoh's threads under the normal scheduler;
* ``hogs, loop FIFO``: the loops under SCHED_FIFO (``[loop] rt_priority``), Zenoh's threads normal;
* ``hogs, loop FIFO + io FIFO``: Zenoh's I/O threads under SCHED_FIFO too, below the loops
  (``[zenoh] io_priority = 10``, shipped);
* ``hogs, loop FIFO + io nice``: Zenoh's I/O threads at nice -20 instead (``[zenoh] io_nice``);
* with ``--flood``: a Zenoh reference at 100 Hz and a flood on ``ref/flow`` or ``meas/flow``
  (1 MB payloads as fast as Python publishes, small ones as fast as it publishes, 10 kHz),
  with Zenoh's threads under FIFO or at nice -20, no hogs.

Hogs: per core, one pure-Python spin and one numpy matrix product (compute and memory traffic).
Printed per case: controller steps, overruns (and their share), stale faults during the run,
valve-node steps, commands received per node step, command timeouts, round trip p50/p99 (node
side: measurement published -> the command computed from it received). The node is stopped
just before the controller's last step so that neither sees the other's end as a fault; stale
faults are counted from the controller's recording (running -> safe transitions).

Usage: ``nice -n 10 .venv/bin/python bench/bench_load.py [--duration 20] [--hogs-per-core 2]``.
Needs root (or CAP_SYS_NICE) for SCHED_FIFO; without it the FIFO cases run under the normal
scheduler (the processes say so) and the comparison shows nothing.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Flooders (a Zenoh peer connected to the controller): valid references at 100 Hz and a flood on KEY.
FLOOD = """
import json, sys, time, zenoh
ep, key, kind, seconds = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
c = zenoh.Config()
c.insert_json5("mode", '"peer"'); c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("connect/endpoints", json.dumps([ep])); c.insert_json5("connect/timeout_ms", "-1")
c.insert_json5("connect/exit_on_failure", "false")
s = zenoh.open(c)
ref, pub = s.declare_publisher("vent/valve/insp/ref/flow"), s.declare_publisher("vent/valve/insp/" + key)
big = b'{"value": 1, "pad": "' + b"x" * 2 ** 20 + b'"}'
t0 = time.monotonic(); k = 0; next_ref = t0
while time.monotonic() - t0 < seconds:
    now = time.monotonic()
    if now >= next_ref:
        ref.put(json.dumps({"t": now - t0, "seq": k, "value": 40.0 + 20.0 * (int(now - t0) % 2)}).encode())
        next_ref += 0.01
    if kind == "1MB":
        pub.put(big)
    elif kind == "max":
        pub.put(json.dumps({"t": now - t0, "seq": 10 ** 9 + k, "value": 50.0}).encode())
    else:  # 10 kHz
        pub.put(json.dumps({"t": now - t0, "seq": 10 ** 9 + k, "value": 50.0}).encode())
        while time.monotonic() < t0 + k * 1e-4:
            pass
    k += 1
"""
HOGS = {
    "python": "while True: pass",
    "numpy": "import numpy as np\na = np.random.rand(700, 700)\nwhile True: b = a @ a; c = a.copy()",
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(rt: int, io: int, nice: int) -> str:
    """config/run.toml with the loop's and Zenoh's scheduling set; written beside it (relative paths)."""
    with open(os.path.join(ROOT, "config", "run.toml")) as fh:
        text = fh.read()
    text = re.sub(r"(?m)^rt_priority = \d+", f"rt_priority = {rt}", text)
    text = re.sub(r"(?m)^io_priority = \d+", f"io_priority = {io}", text)
    text = re.sub(r"(?m)^io_nice = -?\d+", f"io_nice = {nice}", text)
    fd, path = tempfile.mkstemp(prefix=".bench_load_", suffix=".toml", dir=os.path.join(ROOT, "config"))
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    return path


def last_t(path: str) -> float:
    try:
        with open(path, "rb") as fh:
            fh.seek(max(0, os.path.getsize(path) - 400))
            lines = fh.read().decode(errors="replace").splitlines()
        for line in reversed(lines[1:] if len(lines) > 1 else []):
            head = line.split(",", 1)[0]
            if head.replace(".", "", 1).isdigit():
                return float(head)
    except OSError:
        pass
    return -1.0


def node_line(out: str) -> dict:
    """The valve node's exit line, where it writes no N.json."""
    m = re.search(r"(\d+) steps, (\d+) overruns, (\d+) commands, (\d+) bad, (\d+) command timeouts", out)
    return dict(zip(("steps", "overruns", "commands", "bad_commands", "command_timeouts"), map(int, m.groups())))


def stale_during(rec: str, end_s: float) -> int:
    """running -> safe transitions before the last 0.1 s of the run."""
    n, prev = 0, None
    with open(rec) as fh:
        for row in csv.DictReader(fh):
            if prev == "running" and row["state"] == "safe" and float(row["t_s"]) < end_s - 0.1:
                n += 1
            prev = row["state"]
    return n


def case(name: str, sched: tuple, hogs: int, duration: float, tmp: str, flood=None) -> dict:
    cfg = config(*sched)
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec, summ, nj = (os.path.join(tmp, f"{name}.{x}") for x in ("csv", "s.json", "n.json"))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    hog_procs = [subprocess.Popen([sys.executable, "-c", HOGS[list(HOGS)[i % len(HOGS)]]], env=env)
                 for i in range(hogs)]
    vc = [sys.executable, "-m", "controller.cli"]
    node_json = ["--json", nj] if NODE_JSON else []
    try:
        node = subprocess.Popen([*vc, "valve-node", "--config", cfg, "--connect", ep, *node_json], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        ref = ["--reference", "zenoh"] if flood else []
        ctrl = subprocess.Popen([*vc, "run", "--config", cfg, "--plant", "zenoh", "--listen", ep, "--duration",
                                 str(duration), "--record", rec, "--json", summ, *ref], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        if flood:
            hog_procs.append(subprocess.Popen([sys.executable, "-c", FLOOD, ep, *flood, str(duration + 30)],
                                              env=env))
        while last_t(rec) < duration - 0.03 and ctrl.poll() is None:
            time.sleep(0.002)
        node.send_signal(signal.SIGTERM)
        _, c_err = ctrl.communicate(timeout=120)
        n_out, n_err = node.communicate(timeout=120)
    finally:
        for p in hog_procs:
            p.kill()
            p.wait()
        os.remove(cfg)
    if ctrl.returncode != 0 or node.returncode != 0:
        raise SystemExit(f"{name}: controller {ctrl.returncode} {c_err[-300:]} / node {node.returncode} {n_err[-300:]}")
    s = json.load(open(summ))
    n = json.load(open(nj)) if os.path.exists(nj) else node_line(n_out)
    rt_us = n.get("round_trip_us", {})
    return {"case": name, "steps": s["steps"], "overruns": s["overruns"],
            "overrun_pct": 100.0 * s["overruns"] / max(1, s["steps"] + s["overruns"]),
            "stale": stale_during(rec, duration), "node_steps": n.get("steps"), "node_overruns": n.get("overruns"),
            "fresh_cmd_pct": 100.0 * n["commands"] / n["steps"] if n.get("steps") else None,
            "cmd_timeouts": n.get("command_timeouts"), "rt_p50_us": rt_us.get("p50"), "rt_p99_us": rt_us.get("p99"),
            "compute_max_us": s["compute_us"]["max"], "lateness_max_us": s["lateness_us"]["max"],
            "rate_hz": s["rate_hz"], "faults": {f["kind"]: f["count"] for f in s["faults"]}}


NODE_JSON = "--json" in subprocess.run([sys.executable, "-m", "controller.cli", "valve-node", "--help"], cwd=ROOT,
                                      capture_output=True, text=True).stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--hogs-per-core", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the table as JSON")
    ap.add_argument("--cases", nargs="*", default=None, metavar="WORDS", help="only the cases whose name contains one")
    ap.add_argument("--flood", action="store_true",
                    help="also flood ref/flow and meas/flow (1 MB payloads, small ones as fast as Python "
                         "publishes, 10 kHz) beside a Zenoh reference, all measures on, no hogs")
    a = ap.parse_args()
    try:  # the bench must stop the node on time, whatever the hogs do; its children start normal (RESET_ON_FORK)
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(1))
    except PermissionError:
        print("bench: no permission for SCHED_FIFO: the FIFO cases will run under the normal scheduler")
    cores = len(os.sched_getaffinity(0))
    hogs = a.hogs_per_core * cores
    none, loop, io_fifo, io_nice = (0, 0, 0), (20, 0, 0), (20, 10, 0), (20, 0, -20)
    cases = [("idle, loop FIFO + io FIFO", io_fifo, 0, None), ("hogs, nothing", none, hogs, None),
             ("hogs, loop FIFO", loop, hogs, None), ("hogs, loop FIFO + io FIFO", io_fifo, hogs, None),
             ("hogs, loop FIFO + io nice", io_nice, hogs, None)]
    if a.flood:
        cases += [(f"flood {k} on {key}, {io}", s, 0, (key, k)) for key in ("ref/flow", "meas/flow")
                  for k in ("1MB", "max", "10kHz") for io, s in (("io FIFO", io_fifo), ("io nice", io_nice))]
    if a.cases:
        cases = [c for c in cases if any(w in c[0] for w in a.cases)]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, sched, h, flood in cases:
            rows.append(case(re.sub(r"\W+", "_", name), sched, h, a.duration, tmp, flood))
            rows[-1]["case"] = name
            print(f"{name}: done", file=sys.stderr)
    print(f"{cores} cores, {hogs} hogs ({a.hogs_per_core} per core: python spin, numpy), {a.duration:g} s per case")
    hdr = ("case", "rate Hz", "steps", "overruns", "overrun %", "stale", "node steps", "fresh cmd %", "cmd timeouts",
           "rt p50 us", "rt p99 us", "longest step us", "lateness max us")
    keys = ("case", "rate_hz", "steps", "overruns", "overrun_pct", "stale", "node_steps", "fresh_cmd_pct",
            "cmd_timeouts", "rt_p50_us", "rt_p99_us", "compute_max_us", "lateness_max_us")
    print(" | ".join(hdr))
    for r in rows:
        cells = []
        for k in keys:
            v = r[k]
            cells.append("-" if v is None else (f"{v:.2f}" if isinstance(v, float) and k in ("overrun_pct", "rate_hz")
                                                else f"{v:.0f}" if isinstance(v, float) else str(v)))
        print(" | ".join(cells) + ("" if not r["case"].startswith("flood") else f"  faults {r['faults']}"))
    base = next((r for r in rows if r["case"] == "hogs, loop FIFO"), {"overruns": 0})
    for r in rows:
        if r["case"].startswith("hogs, loop FIFO +") and base["overruns"]:
            print(f"overruns, {r['case']} / hogs, loop FIFO: {r['overruns'] / base['overruns']:.3f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
