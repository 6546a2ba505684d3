"""The Zenoh pair (controller and valve node, real processes) under CPU hogs on every core, with and without
the real-time measures, in one run.

Cases, each a `valvectl run --plant zenoh` against a `valvectl valve-node` for DURATION seconds:

* ``idle, loop FIFO + io FIFO``: no hogs, the shipped settings (the reference);
* ``hogs, nothing``: both loops and Zenoh's threads under the normal scheduler, and a step that ends past the
  next deadline skips it (``[loop] catch_up = false``);
* ``hogs, loop FIFO``: the loops under SCHED_FIFO (``[loop] rt_priority``), Zenoh's threads normal;
* ``hogs, loop FIFO + io FIFO``: Zenoh's I/O threads under SCHED_FIFO too, below the loops
  (``[zenoh] io_priority = 10``, shipped);
* ``hogs, loop FIFO + io nice``: Zenoh's I/O threads at nice -20 instead (``[zenoh] io_nice``);
* ``hogs, loop FIFO + io FIFO, skip late``: the shipped measures but ``catch_up = false``: a step that ends past
  the next deadline skips it and counts it (ros2_control's rule) instead of letting it start at once, late;
* ``hogs, loop FIFO + io FIFO, mlockall``: the shipped measures with both processes' memory locked from their
  start (``mlockall(MCL_CURRENT | MCL_FUTURE)``): whether page faults cost the loops any deadline;
* with ``--flood``: a Zenoh reference at 100 Hz and a flood on one key, the shipped measures, no
  hogs: ``ref/flow``, ``meas/flow``, ``ctrl/mode``, ``meas/supply`` (the controller's keys) and
  ``cmd/duty`` (the valve node's, the flooder connected to the node), each with 1 MB payloads as
  fast as Python publishes, small ones as fast as it publishes, and small ones at 10 kHz. The
  rate and longest step are then those of the flooded process.

Hogs: per core, a pure-Python spin, then a numpy matrix product (compute and memory traffic),
alternating; each under the normal scheduler at nice 0 (set explicitly and checked, whatever
the bench runs under), as are the controller and the node before they raise their own threads.
Printed per case: controller steps, overruns (and their share), stale faults during the run,
valve-node steps, commands received per node step, command timeouts, round trip p50/p99 (node
side: measurement published -> the command computed from it received), the node's longest gap between two
published measurements, and the hypervisor's steal during the case (/proc/stat: time the VM's CPUs were
frozen by the host; every loop misses its deadlines then). The steal is set beside the controller's missed
deadlines, each located in the recording (with ``catch_up`` a step starts within its own deadline's period, so
a row's deadline is the period it started in, and the deadlines between two rows' are the missed ones): the
overruns in a window where the steal counter rose (sampled every 2 ms), those outside any (the issue's figure
with the host's steal set aside), and those in whole seconds when the counter did not move at all; the same for
steps that started late. Per loop thread: page faults, involuntary switches, the time it waited for a CPU. The
node is stopped
just before the controller's last step so that neither sees the other's end as a fault; stale
faults are counted from the controller's recording (running -> safe transitions). The load
average before and after is printed: other work on the machine shows there.

The default run is issue 11's condition (20 s, one hog per core) with and without the measures, and says
whether it is met; ``--repeat N`` runs the cases N times, interleaved, with each case's median and worst.

Usage: ``.venv/bin/python bench/bench_load.py [--duration 20] [--hogs-per-core 1] [--repeat 1] [--flood]
[--cases WORDS...] [--keep DIR]``.
Needs root (or CAP_SYS_NICE) for SCHED_FIFO; without it the FIFO cases run under the normal
scheduler (the processes say so) and the comparison shows nothing.
"""
from __future__ import annotations

import argparse
import bisect
import csv
import json
import os
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Flooders (a Zenoh peer connected to the flooded process): valid references at 100 Hz when REF, and a flood on
#: KEY. Small payloads are well formed; on cmd/duty their value is out of range (counted, not obeyed), on ctrl/mode
#: not a controller word.
FLOOD = """
import json, sys, time, zenoh
ep, key, kind, seconds, with_ref = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), sys.argv[5] == "ref"
c = zenoh.Config()
c.insert_json5("mode", '"peer"'); c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("connect/endpoints", json.dumps([ep])); c.insert_json5("connect/timeout_ms", "-1")
c.insert_json5("connect/exit_on_failure", "false")
s = zenoh.open(c)
ref, pub = s.declare_publisher("vent/valve/insp/ref/flow"), s.declare_publisher("vent/valve/insp/" + key)
big = b'{"value": 1, "pad": "' + b"x" * 2 ** 20 + b'"}'
value = {"cmd/duty": 500.0, "ctrl/mode": "no-such-law"}.get(key, 50.0)
t0 = time.monotonic(); k = 0; next_ref = t0
while time.monotonic() - t0 < seconds:
    now = time.monotonic()
    if with_ref and now >= next_ref:
        ref.put(json.dumps({"t": now - t0, "seq": k, "value": 40.0 + 20.0 * (int(now - t0) % 2)}).encode())
        next_ref += 0.01
    if kind == "1MB":
        pub.put(big)
    else:
        pub.put(json.dumps({"t": now - t0, "seq": 10 ** 9 + k, "value": value}).encode())
        if kind == "10kHz":
            while time.monotonic() < t0 + k * 1e-4:
                pass
    k += 1
"""
#: ``valvectl`` with all its memory locked (``mlockall(MCL_CURRENT | MCL_FUTURE)``) before anything is imported: no
#: page of it is ever reclaimed, and every page it maps later is faulted in when mapped, not when first touched.
MLOCKALL = """
import ctypes, os, sys
if ctypes.CDLL(None, use_errno=True).mlockall(3) != 0:
    raise SystemExit("mlockall: " + os.strerror(ctypes.get_errno()))
from controller.cli import main
sys.exit(main(sys.argv[1:]))
"""
HOGS = {
    "python": "while True: pass",
    "numpy": "import numpy as np\na = np.random.rand(700, 700)\nwhile True: b = a @ a; c = a.copy()",
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(rt: int, io: int, nice: int, catch_up: bool = True) -> str:
    """config/run.toml with the loop's and Zenoh's scheduling set; written beside it (relative paths)."""
    with open(os.path.join(ROOT, "config", "run.toml")) as fh:
        text = fh.read()
    text = re.sub(r"(?m)^rt_priority = \d+", f"rt_priority = {rt}", text)
    text = re.sub(r"(?m)^io_priority = \d+", f"io_priority = {io}", text)
    text = re.sub(r"(?m)^io_nice = -?\d+", f"io_nice = {nice}", text)
    text = re.sub(r"(?m)^catch_up = \w+", f"catch_up = {'true' if catch_up else 'false'}", text)
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


def step_times(rec: str) -> list[float]:
    """The controller's recorded steps, ``t_s`` (s from its first deadline)."""
    t = []
    with open(rec) as fh:
        next(fh)
        for line in fh:
            head = line.split(",", 1)[0]
            try:
                t.append(float(head))
            except ValueError:
                continue
    return t


def missed_deadlines(t: list[float], period_s: float, catch_up: bool) -> tuple[list[float], list[float]]:
    """(the deadlines that got no step, each its time in the controller's ``t_s``; each step's lateness, s).

    With ``catch_up`` a step starts within its own deadline's period (a later start is counted as missed
    deadlines, and the step serves the newest), so a row's deadline is ``floor(t_s / period)``, its lateness the
    rest, and the deadlines between two rows' are exactly the missed ones. Without, a step may start periods
    late: the missed deadlines are read from the gaps of more than 1.5 periods between rows (``round(gap) - 1``
    after the earlier row) and the lateness is not known (empty)."""
    if not catch_up:
        return [a + i * period_s for a, b in zip(t, t[1:]) if b - a > 1.5 * period_s
                for i in range(1, int(round((b - a) / period_s)))], []
    k = [int(x / period_s + 1e-3) for x in t]  # t_s is written to 9 digits: a step on time may read up to 0.05 us early
    missed = [j * period_s for a, b in zip(k, k[1:]) for j in range(a + 1, b)]
    return missed, [x - j * period_s for x, j in zip(t, k)]


#: /proc/stat counts steal in 1/USER_HZ units (10 ms): a steal shows when its sum crosses a multiple of that,
#: up to this long after it happened. A window of steal is widened back by it (and by the clock offset's slack).
STEAL_TICK_S = 0.010
CLOCK_SLACK_S = 0.003
#: A step that started this long after its deadline is counted as late (``late steps``).
LATE_STEP_S = 300e-6


def stolen_windows(samples: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Intervals of the bench's clock in which the host's steal counter rose (``samples``: (monotonic s, steal
    ms) every poll), each widened back by :data:`STEAL_TICK_S` and both ways by :data:`CLOCK_SLACK_S`."""
    return [(m0 - STEAL_TICK_S - CLOCK_SLACK_S, m1 + CLOCK_SLACK_S)
            for (m0, s0), (m1, s1) in zip(samples, samples[1:]) if s1 > s0]


def in_windows(times: list[float], width_s: float, windows: list[tuple[float, float]], offset_s: float) -> int:
    """How many of the intervals ``[t, t + width_s)`` (controller's ``t_s``; plus ``offset_s``: the bench's
    monotonic clock) overlap a window of host steal."""
    ws = sorted(windows)
    starts = [a for a, _ in ws]
    reach, hi = [], -float("inf")  # the latest end of the windows up to each one (they may overlap)
    for _, b in ws:
        hi = max(hi, b)
        reach.append(hi)
    n = 0
    for t in times:
        lo, up = t + offset_s, t + offset_s + width_s
        i = bisect.bisect_left(starts, up) - 1  # the last window starting before the interval ends
        n += i >= 0 and reach[i] > lo
    return n


def quiet_seconds(times: list[float], samples: list[tuple[float, float]], offset_s: float,
                  bin_s: float = 1.0) -> tuple[int, int]:
    """(whole bins of ``bin_s`` in which the host's steal counter did not move at all, of the ``times``
    (controller's ``t_s``) those bins hold). Over a second the counter's unit is small: a bin where it stood
    still had less than one unit (10 ms) of steal, on both vCPUs together, and an overrun there is hard to lay
    on the host."""
    if len(samples) < 2:
        return 0, 0
    clock = [m for m, _ in samples]
    t0, n = clock[0], int((clock[-1] - clock[0]) / bin_s)
    quiet = []
    for b in range(n):
        i = bisect.bisect_right(clock, t0 + b * bin_s) - 1
        j = bisect.bisect_left(clock, t0 + (b + 1) * bin_s)  # the first sample at or past the bin's end
        quiet.append(samples[min(j, len(samples) - 1)][1] == samples[i][1])
    held = sum(1 for t in times if 0 <= (b := int((t + offset_s - t0) / bin_s)) < n and quiet[b])
    return sum(quiet), held


def steal_cover(windows: list[tuple[float, float]], span: tuple[float, float]) -> float:
    """Share of the run (``span``, the bench's monotonic clock) the windows of host steal span, %."""
    lo, hi = span
    covered, end = 0.0, lo
    for a, b in sorted(windows):
        a, b = max(a, end), min(b, hi)
        if b > a:
            covered += b - a
            end = b
    return 100.0 * covered / max(1e-9, hi - lo)


def proc_counters(pid: int) -> tuple[int, int, float, int]:
    """(major page faults of process ``pid``, involuntary context switches of its main thread, where the loop
    runs, that thread's time runnable but waiting for a CPU, ms: schedstat's run delay, and its minor page
    faults); -1s once gone."""
    try:
        majflt = int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[9])
        minflt = int(open(f"/proc/{pid}/task/{pid}/stat").read().rsplit(")", 1)[1].split()[7])
        status = open(f"/proc/{pid}/task/{pid}/status").read()
        nvcs = int(re.search(r"nonvoluntary_ctxt_switches:\s+(\d+)", status).group(1))
        wait_ms = int(open(f"/proc/{pid}/task/{pid}/schedstat").read().split()[1]) * 1e-6
        return majflt, nvcs, wait_ms, minflt
    except (OSError, AttributeError, IndexError, ValueError):
        return -1, -1, -1.0, -1


def locked_mb(pid: int) -> float | None:
    """Memory locked by process ``pid`` (``VmLck``), MB; None once gone."""
    try:
        return int(re.search(r"VmLck:\s+(\d+) kB", open(f"/proc/{pid}/status").read()).group(1)) / 1024
    except (OSError, AttributeError):
        return None


def host_steal_ms() -> float:
    """Time the hypervisor kept this VM's CPUs from running although they had work, summed over CPUs, ms
    (``steal`` of /proc/stat, in clock ticks; 0 on bare metal)."""
    with open("/proc/stat") as fh:
        fields = fh.readline().split()
    return int(fields[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")


def kernel_facts() -> str:
    """What bounds a real-time thread's latency on this kernel: preemption model, transparent huge pages."""
    version = os.uname().version
    model = next((m for m in ("PREEMPT_RT", "PREEMPT_DYNAMIC", "PREEMPT") if m in version), "no preemption")
    try:
        cmdline = open("/proc/cmdline").read().split()
        chosen = next((a for a in cmdline if a.startswith("preempt=")), None)
    except OSError:
        chosen = None
    if model == "PREEMPT_DYNAMIC":
        model += f" ({chosen})" if chosen else " (no preempt= on the command line: the build's default)"
    try:
        thp = re.search(r"\[(\w+)\]", open("/sys/kernel/mm/transparent_hugepage/enabled").read()).group(1)
    except (OSError, AttributeError):
        thp = "?"
    return f"kernel {os.uname().release}, {model}, transparent huge pages {thp}"


def normal() -> None:
    """In a child before exec: the normal scheduler at nice 0, whatever the bench runs under (nice, FIFO)."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.setpriority(os.PRIO_PROCESS, 0, 0)


def scheduling(pid: int) -> tuple[int, int]:
    """(policy, nice) of process ``pid``, from /proc (fields 41 and 19 of stat)."""
    st = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return int(st[38]), int(st[16])


def foreign_realtime() -> list[str]:
    """User processes outside this bench with a real-time thread (another 1 kHz loop shares the cores)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                cmd = fh.read().split(b"\0")[:4]
            ppid = int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[1])
            if not cmd[0] or int(pid) == os.getpid() or ppid == os.getpid():
                continue  # kernel threads have no command line
            if any(scheduling_task(f"/proc/{pid}/task/{t}") in (os.SCHED_FIFO, os.SCHED_RR)
                   for t in os.listdir(f"/proc/{pid}/task")):
                found.append(f"{pid} {b' '.join(cmd).decode(errors='replace')[:80]}")
        except (OSError, ValueError, IndexError):
            continue  # gone meanwhile
    return found


def scheduling_task(task_dir: str) -> int:
    return int(open(f"{task_dir}/stat").read().rsplit(")", 1)[1].split()[38])


def case(name: str, sched: tuple, hogs: int, duration: float, tmp: str, flood=None) -> dict:
    cfg = config(*sched[:4])
    catch_up = sched[3] if len(sched) > 3 else True
    lock = len(sched) > 4 and sched[4]  # both processes' memory locked (mlockall) from their start
    with open(cfg, "rb") as fh:
        period_s = 1.0 / tomllib.load(fh)["loop"]["rate_hz"]
    ep, node_ep = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    rec, summ, nj = (os.path.join(tmp, f"{name}.{x}") for x in ("csv", "s.json", "n.json"))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    start = dict(env=env, preexec_fn=normal)
    hog_procs = [subprocess.Popen([sys.executable, "-c", HOGS[list(HOGS)[i % len(HOGS)]]], **start)
                 for i in range(hogs)]
    hog_sched = {scheduling(p.pid) for p in hog_procs}
    if hog_sched - {(os.SCHED_OTHER, 0)}:
        raise SystemExit(f"{name}: hogs not at SCHED_OTHER nice 0: {hog_sched}")
    vc = [sys.executable, "-c", MLOCKALL] if lock else [sys.executable, "-m", "controller.cli"]
    node_json = ["--json", nj] if NODE_JSON else []
    at_node = flood is not None and flood[0] == "cmd/duty"
    try:
        node = subprocess.Popen([*vc, "valve-node", "--config", cfg, "--connect", ep, "--listen", node_ep,
                                 *node_json], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                **start)
        ref = ["--reference", "zenoh"] if flood and not at_node else []
        ctrl = subprocess.Popen([*vc, "run", "--config", cfg, "--plant", "zenoh", "--listen", ep, "--duration",
                                 str(duration), "--record", rec, "--json", summ, *ref], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **start)
        if flood:
            hog_procs.append(subprocess.Popen([sys.executable, "-c", FLOOD, node_ep if at_node else ep, *flood,
                                               str(duration + 30), "-" if at_node else "ref"], **start))
        steal0, samples, offset_s, counters0 = None, [], None, None
        while (t_rec := last_t(rec)) < duration - 0.03 and ctrl.poll() is None:
            now = time.monotonic()
            if steal0 is None and t_rec >= 0:  # the controller's first step
                steal0 = host_steal_ms()
                counters0 = proc_counters(ctrl.pid), proc_counters(node.pid)
            if t_rec >= 0:  # the newest row was flushed at most a poll (2 ms) before; the closest poll counts
                offset_s = now - t_rec if offset_s is None else min(offset_s, now - t_rec)
            if steal0 is not None:
                samples.append((now, host_steal_ms()))
            time.sleep(0.002)
        steal_ms = host_steal_ms() - steal0 if steal0 is not None else None
        counters1 = proc_counters(ctrl.pid), proc_counters(node.pid)
        locked = [None if (m := locked_mb(p.pid)) is None else round(m) for p in (ctrl, node)]
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
    row = {"case": name, "pids": {"controller": ctrl.pid, "node": node.pid}, "steps": s["steps"], "overruns": s["overruns"],
           "overrun_pct": 100.0 * s["overruns"] / max(1, s["steps"] + s["overruns"]),
           "stale": stale_during(rec, duration), "node_steps": n.get("steps"), "node_overruns": n.get("overruns"),
           "fresh_cmd_pct": 100.0 * n["commands"] / n["steps"] if n.get("steps") else None,
           "delivered_pct": 100.0 * n["commands"] / max(1, s["steps"]),
           "cmd_timeouts": n.get("command_timeouts"), "rt_p50_us": rt_us.get("p50"), "rt_p99_us": rt_us.get("p99"),
           "compute_max_us": s["compute_us"]["max"], "lateness_max_us": s["lateness_us"]["max"],
           "rate_hz": s["rate_hz"], "faults": {f["kind"]: f["count"] for f in s["faults"]},
           "bad_commands": n.get("bad_commands"), "stalled": {f["kind"]: f["count"] for f in s["faults"]}.get("stalled", 0),
           "steal_ms": steal_ms, "node_gap_max_ms": n.get("publish_gap_ms", {}).get("max")}
    missed, late = missed_deadlines(step_times(rec), period_s, catch_up)
    late_steps = [t for t, x in zip(step_times(rec), late) if x > LATE_STEP_S] if late else []
    if samples and offset_s is not None:
        windows = stolen_windows(samples)
        stolen = in_windows(missed, period_s, windows, offset_s)  # a deadline's whole period against the windows
        late_stolen = in_windows(late_steps, 0.0, windows, offset_s)
        covered_pct = steal_cover(windows, (samples[0][0], samples[-1][0]))
        quiet_s, quiet_overruns = quiet_seconds(missed, samples, offset_s)
    else:
        stolen = late_stolen = quiet_s = quiet_overruns = 0
        covered_pct = 0.0
    total = max(1, s["steps"] + s["overruns"])
    row.update(stolen_overruns=stolen, steal_cover_pct=covered_pct, located_overruns=len(missed),
               quiet_s=quiet_s, quiet_overruns=quiet_overruns,
               adjusted_overrun_pct=100.0 * max(0, s["overruns"] - stolen) / total,
               late_steps=len(late_steps) if late else None, late_stolen=late_stolen if late else None,
               majflt=[b[0] - a[0] if counters0 else None for a, b in zip(counters0 or counters1, counters1)],
               preempted=[b[1] - a[1] if counters0 else None for a, b in zip(counters0 or counters1, counters1)],
               run_wait_ms=[round(b[2] - a[2], 1) if counters0 else None
                            for a, b in zip(counters0 or counters1, counters1)],
               minflt=[b[3] - a[3] if counters0 else None for a, b in zip(counters0 or counters1, counters1)],
               locked_mb=locked)
    if flood:  # the flooded process: its share of the configured rate and its longest step
        if at_node:
            row["flooded_rate_pct"] = 100.0 * n["steps"] / max(1, n["steps"] + n["overruns"])
            row["flooded_longest_us"] = n.get("compute_us", {}).get("max")
        else:
            row["flooded_rate_pct"] = 100.0 * s["steps"] / max(1, s["steps"] + s["overruns"])
            row["flooded_longest_us"] = s["compute_us"]["max"]
    row["trace"] = {"steal_samples": samples, "offset_s": offset_s, "period_s": period_s}  # for --keep
    return row


def enrichment(r: dict) -> str:
    """How much likelier an overrun was inside a window of host steal than the windows' share of time makes it."""
    if not r["overruns"] or not r["steal_cover_pct"]:
        return ""
    return f"; {r['stolen_overruns'] / r['overruns'] / (r['steal_cover_pct'] / 100.0):.0f}x their share of the time"


NODE_JSON = "--json" in subprocess.run([sys.executable, "-m", "controller.cli", "valve-node", "--help"], cwd=ROOT,
                                      capture_output=True, text=True).stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--hogs-per-core", type=int, default=1)
    ap.add_argument("--json", default=None, help="write the table as JSON")
    ap.add_argument("--keep", default=None, metavar="DIR",
                    help="keep each case's recording, run summary and steal samples (bench clock s, steal ms) in DIR")
    ap.add_argument("--cases", nargs="*", default=None, metavar="WORDS", help="only the cases whose name contains one")
    ap.add_argument("--flood", action="store_true",
                    help="also flood each key (1 MB payloads, small ones as fast as Python publishes, 10 kHz) "
                         "beside a Zenoh reference, the shipped measures, no hogs")
    ap.add_argument("--repeat", type=int, default=1, metavar="N",
                    help="run the cases N times, interleaved, and print each case's median and worst")
    a = ap.parse_args()
    try:  # the bench must stop the node on time, whatever the hogs do; its children start normal (normal())
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(1))
    except PermissionError:
        print("bench: no permission for SCHED_FIFO: the FIFO cases will run under the normal scheduler")
    cores = len(os.sched_getaffinity(0))
    hogs = a.hogs_per_core * cores
    none, loop, io_fifo, io_nice = (0, 0, 0, False), (20, 0, 0), (20, 10, 0), (20, 0, -20)
    cases = [("idle, loop FIFO + io FIFO", io_fifo, 0, None), ("hogs, nothing", none, hogs, None),
             ("hogs, loop FIFO", loop, hogs, None), ("hogs, loop FIFO + io FIFO", io_fifo, hogs, None),
             ("hogs, loop FIFO + io nice", io_nice, hogs, None),
             ("hogs, loop FIFO + io FIFO, skip late", (*io_fifo, False), hogs, None),
             ("hogs, loop FIFO + io FIFO, mlockall", (*io_fifo, True, True), hogs, None)]
    if a.flood:
        cases += [(f"flood {k} on {key}", io_fifo, 0, (key, k))
                  for key in ("ref/flow", "meas/flow", "ctrl/mode", "meas/supply", "cmd/duty")
                  for k in ("1MB", "max", "10kHz")]
    if a.cases:
        cases = [c for c in cases if any(w in c[0] for w in a.cases)]
    rows = []
    load_before = os.getloadavg()
    foreign = set()
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(1, a.repeat + 1):  # interleaved: each repetition sees every case under similar load
            for name, sched, h, flood in cases:
                foreign.update(foreign_realtime())
                tag = re.sub(r"\W+", "_", f"{name} {rep}")
                rows.append(case(tag, sched, h, a.duration, tmp, flood))
                trace = rows[-1].pop("trace")
                if a.keep:
                    os.makedirs(a.keep, exist_ok=True)
                    for x in ("csv", "s.json", "n.json"):
                        if os.path.exists(src := os.path.join(tmp, f"{tag}.{x}")):
                            shutil.copy(src, os.path.join(a.keep, f"{tag}.{x}"))
                    with open(os.path.join(a.keep, f"{tag}.steal.json"), "w") as fh:
                        json.dump(trace, fh)
                rows[-1].update(case=name, rep=rep)
                print(f"{name} ({rep}/{a.repeat}): done", file=sys.stderr)
    load_after = os.getloadavg()
    kinds = ", ".join(list(HOGS)[i % len(HOGS)] for i in range(hogs))
    if foreign:
        print("other processes with real-time threads during the bench (they share the cores at the loops' "
              "priorities):\n  " + "\n  ".join(sorted(foreign)))
    print(f"{cores} cores, {hogs} hogs ({kinds}; SCHED_OTHER, nice 0), "
          f"{a.duration:g} s per case; load average 1/5/15 min before {'/'.join(f'{x:.2f}' for x in load_before)}, "
          f"after {'/'.join(f'{x:.2f}' for x in load_after)}; {kernel_facts()}")
    print("stalled: controller steps that stood still past stale_ms; node gap: the longest time between two "
          "measurements the node published (a stale fault with a node gap as long is the node standing still)")
    print("host steal: CPU time the hypervisor withheld from this VM during the case (both vCPUs frozen: every "
          "loop misses its deadlines then, whatever its priority; 0 on bare metal)")
    print(f"stolen: overruns that fell in a window where the host's steal counter rose (/proc/stat counts steal in "
          f"{STEAL_TICK_S * 1e3:.0f} ms units, so each window reaches back that far); steal cover: the share of the "
          f"run those windows span (the adjustment means little when it is large); adjusted: overruns minus stolen "
          f"(the overruns outside host-steal windows). The raw figure is the one the issue counts. The counter is "
          f"cumulative: steal shorter than its unit shows only when the sum crosses one, so a window marks where "
          f"steal was booked, not every freeze (stolen is a lower bound of the overruns the host caused)")
    print("steal-free s: whole seconds of the run in which the host's steal counter did not move (under 10 ms of "
          "steal on both vCPUs together); overruns in them: the overruns those seconds hold (hard to lay on the host)")
    print(f"late steps: controller steps that started more than {LATE_STEP_S * 1e6:.0f} us after their deadline "
          f"(with catch_up, read from the recording: a step's deadline is the period it started in); late in steal: "
          f"those in a window of host steal")
    print("major faults: page faults that read from disk, controller/node; minor faults: the loop thread's page "
          "faults served from memory, controller/node; locked MB: memory locked (VmLck), controller/node; preempted: involuntary context switches "
          "of the loop's thread, controller/node (a SCHED_FIFO thread is preempted only by higher real-time "
          "priorities, the kernel's own work, or a wait it did not choose); run wait: the loop thread's time runnable "
          "but waiting for a CPU, controller/node (behind a real-time thread of equal or higher priority, ours or "
          "another process's, or the kernel)")
    hdr = ("case", "rep", "rate Hz", "steps", "overruns", "overrun %", "stale", "stalled", "node steps", "node overruns",
           "fresh cmd %", "cmd timeouts", "rt p50 us", "rt p99 us", "longest step us", "lateness max us",
           "node gap max ms", "host steal ms", "stolen", "steal cover %", "adjusted overrun %", "steal-free s",
           "overruns in them", "late steps", "late in steal", "major faults", "minor faults", "preempted",
           "run wait ms", "locked MB")
    keys = ("case", "rep", "rate_hz", "steps", "overruns", "overrun_pct", "stale", "stalled", "node_steps", "node_overruns",
            "fresh_cmd_pct", "cmd_timeouts", "rt_p50_us", "rt_p99_us", "compute_max_us", "lateness_max_us",
            "node_gap_max_ms", "steal_ms", "stolen_overruns", "steal_cover_pct", "adjusted_overrun_pct", "quiet_s",
            "quiet_overruns", "late_steps", "late_stolen", "majflt", "minflt", "preempted", "run_wait_ms", "locked_mb")
    assert len(hdr) == len(keys)
    print(" | ".join(hdr))
    for r in rows:
        cells = []
        for k in keys:
            v = r[k]
            if isinstance(v, list):
                v = "/".join("-" if x is None else str(x) for x in v)
            cells.append("-" if v is None else (f"{v:.2f}" if isinstance(v, float) and k in ("overrun_pct", "rate_hz", "steal_cover_pct",
                                                                                              "adjusted_overrun_pct")
                                                else f"{v:.0f}" if isinstance(v, float) else str(v)))
        print(" | ".join(cells))
    floods = [r for r in rows if "flooded_rate_pct" in r]
    if floods:
        print("commands delivered: node steps that took a new command, per controller step (each step sends one)")
        print("flood | rep | flooded process | rate % | longest step us | faults (controller) | bad commands (node) "
              "| commands delivered % | rt p50 us")
        for r in floods:
            who = "valve node" if r["case"].endswith("cmd/duty") else "controller"
            longest = "-" if r["flooded_longest_us"] is None else f"{r['flooded_longest_us']:.0f}"
            rt50 = "-" if r["rt_p50_us"] is None else f"{r['rt_p50_us']:.0f}"
            print(f"{r['case']} | {r['rep']} | {who} | {r['flooded_rate_pct']:.2f} | {longest} | {r['faults']} | "
                  f"{r['bad_commands']} | {r['delivered_pct']:.1f} | {rt50}")
    names = list(dict.fromkeys(r["case"] for r in rows))
    if a.repeat > 1:
        print(f"over {a.repeat} repetitions | overrun % median | overrun % worst | stale total | cmd timeouts total "
              f"| host steal ms median | adjusted overrun % median | adjusted overrun % worst | overruns in steal-free "
              f"seconds / those seconds, total")
        for name in names:
            rs = [r for r in rows if r["case"] == name]
            pct = sorted(r["overrun_pct"] for r in rs)
            steal = [r["steal_ms"] for r in rs if r["steal_ms"] is not None]
            adj = sorted(r["adjusted_overrun_pct"] for r in rs)
            print(f"{name} | {statistics.median(pct):.3f} | {pct[-1]:.3f} | {sum(r['stale'] for r in rs)} | "
                  f"{sum(r['cmd_timeouts'] or 0 for r in rs)} | "
                  f"{statistics.median(steal) if steal else float('nan'):.0f} | {statistics.median(adj):.3f} | "
                  f"{adj[-1]:.3f} | {sum(r['quiet_overruns'] for r in rs)} / {sum(r['quiet_s'] for r in rs)}")
    for rep in range(1, a.repeat + 1):
        of = {r["case"]: r for r in rows if r["rep"] == rep}
        idle, shipped, base = (of.get(k) for k in ("idle, loop FIFO + io FIFO", "hogs, loop FIFO + io FIFO",
                                                   "hogs, nothing"))
        if idle is not None and shipped is not None:  # what the hogs still cost, beside what the machine costs anyway
            print(f"[{rep}] overruns, hogs with the measures against no hogs: {shipped['overruns']} / "
                  f"{idle['overruns']} ({shipped['overrun_pct']:.2f} % / {idle['overrun_pct']:.2f} % of the steps)")
        for name, r in of.items():
            if base is not None and name.startswith("hogs, loop FIFO") and not name.endswith("skip late"):
                print(f"[{rep}] {name} against hogs, nothing: overruns {r['overruns']} / {base['overruns']}, "
                      f"stale {r['stale']} / {base['stale']}, command timeouts {r['cmd_timeouts']} / "
                      f"{base['cmd_timeouts']}")
        skip = of.get("hogs, loop FIFO + io FIFO, skip late")
        if shipped is not None and skip is not None:
            print(f"[{rep}] hogs, shipped (catch_up) against the same skipping late deadlines: overruns "
                  f"{shipped['overruns']} / {skip['overruns']} ({shipped['overrun_pct']:.3f} % / {skip['overrun_pct']:.3f} %), "
                  f"lateness max {shipped['lateness_max_us']:.0f} / {skip['lateness_max_us']:.0f} us, stale "
                  f"{shipped['stale']} / {skip['stale']}, command timeouts {shipped['cmd_timeouts']} / {skip['cmd_timeouts']}")
        locked = of.get("hogs, loop FIFO + io FIFO, mlockall")
        if shipped is not None and locked is not None:
            print(f"[{rep}] hogs, shipped against the same with all memory locked: overruns {shipped['overruns']} / "
                  f"{locked['overruns']} ({shipped['overrun_pct']:.3f} % / {locked['overrun_pct']:.3f} %), outside "
                  f"host-steal windows {shipped['adjusted_overrun_pct']:.3f} % / {locked['adjusted_overrun_pct']:.3f} %, "
                  f"loop threads' minor faults {shipped['minflt']} / {locked['minflt']}, host steal "
                  f"{shipped['steal_ms'] or 0:.0f} / {locked['steal_ms'] or 0:.0f} ms")
        if shipped is not None:  # issue 11's condition, with the shipped measures
            met = shipped["stale"] == 0 and shipped["cmd_timeouts"] == 0 and shipped["overrun_pct"] <= 0.1
            span = f"{a.duration:g} s" + ("" if a.duration == 20 else ", not the issue's 20 s")
            met_adj = shipped["stale"] == 0 and shipped["cmd_timeouts"] == 0 and shipped["adjusted_overrun_pct"] <= 0.1
            print(f"[{rep}] done when (hogs on every core, {span}, the shipped measures): stale "
                  f"{shipped['stale']} (0), command timeouts {shipped['cmd_timeouts']} (0), overruns "
                  f"{shipped['overrun_pct']:.3f} % (<= 0.1 %): {'met' if met else 'NOT met'} (raw); host steal "
                  f"{shipped['steal_ms'] if shipped['steal_ms'] is not None else float('nan'):.0f} ms, "
                  f"{shipped['stolen_overruns']} of {shipped['overruns']} overruns in its windows "
                  f"({shipped['steal_cover_pct']:.1f} % of the run{enrichment(shipped)}): overruns outside host-steal "
                  f"windows {shipped['adjusted_overrun_pct']:.3f} %: {'met' if met_adj else 'NOT met'} with the host's "
                  f"steal set aside")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
