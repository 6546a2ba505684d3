"""Where a loop's missed deadlines come from under load: the shipped case of bench_load.py under ``perf``.

Runs the Zenoh pair with a CPU hog per core and the shipped measures (bench_load.py's ``hogs, loop FIFO + io
FIFO``) while ``perf`` records every scheduler switch and real-time wake-up on ``CLOCK_MONOTONIC``, then looks at
each time a loop thread (controller or valve node) was off schedule:

* a *late wake*: the thread slept longer than a period (it sleeps at most a period minus its step);
* a *long step*: it ran longer than a period without switching out.

A late wake is classified by the loop's own wake-up event (raised by its timer interrupt):

* ``timer interrupt late``: the interrupt itself came late. Inside a VM that is the hypervisor not running
  the vCPU (its steal time, /proc/stat, rises with these), or interrupts off for that long;
* ``woken on time, waited for the CPU``: the tasks that ran on that CPU meanwhile (a kernel thread in a
  non-preemptible section, another real-time thread, ...).

A long step is only counted: scheduler events cannot tell a frozen vCPU from slow code.

Needs root (or perf_event_paranoid <= -1) and ``perf`` with the sched tracepoints. Usage:
``.venv/bin/python bench/trace_load.py [--duration 20] [--keep DIR]``.
"""
from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_load  # noqa: E402  (the case runner, beside this file)

#: A loop period, s (the shipped rate_hz), and the lateness from which a wake-up is looked at, s.
PERIOD_S = 1e-3
LATE_S = 300e-6
LINE = re.compile(r"\s*(.+?)\s+(\d+)\s+\[(\d+)\]\s+([\d.]+):\s+sched:(\w+):\s+(.*)")


def events(perf_data: str):
    """Per CPU, the tasks switched in (time, name); per thread, its real-time wake-ups, switch-ins and
    switch-outs (from the run's first switch-out under a real-time policy: not its start-up)."""
    out = subprocess.run(["perf", "script", "-i", perf_data, "-F", "comm,tid,cpu,time,event,trace"],
                         capture_output=True, text=True, check=True).stdout
    per_cpu = collections.defaultdict(list)
    wakes, ins, outs = (collections.defaultdict(list) for _ in range(3))
    for line in out.splitlines():
        m = LINE.match(line)
        if not m:
            continue
        _, _, cpu, t, ev, trace = m.groups()
        cpu, t = int(cpu), float(t)
        if ev == "sched_switch":
            prev = re.search(r"prev_pid=(\d+) prev_prio=(\d+) prev_state=(\S+)", trace)
            nxt = re.search(r"next_comm=(.*) next_pid=(\d+)", trace)
            per_cpu[cpu].append((t, f"{nxt.group(1)}/{nxt.group(2)}"))
            ins[int(nxt.group(2))].append((t, cpu))
            if int(prev.group(2)) < 100:  # under a real-time policy
                outs[int(prev.group(1))].append((t, prev.group(3)))
        elif ev == "sched_waking":
            wakes[int(re.search(r" pid=(\d+)", trace).group(1))].append(t)
    return per_cpu, wakes, ins, outs


def classify(tid: int, per_cpu, wakes, ins, outs) -> collections.Counter:
    """Late wakes and long steps of the loop thread ``tid``, each classified and printed."""
    found = collections.Counter()
    W = np.array(wakes[tid])
    if not outs[tid] or len(W) < 100:
        return found
    phase = float(np.median(W % PERIOD_S))  # the loop sleeps to absolute deadlines: its wakes share one phase
    first, last = outs[tid][0][0], outs[tid][-1][0]
    moves = sorted([(t, "in", cpu) for t, cpu in ins[tid] if first <= t <= last]
                   + [(t, st, None) for t, st in outs[tid]])
    t_in, cpu = None, None
    for (t, what, c), (t_next, what_next, c_next) in zip(moves, moves[1:] + [(None, None, None)]):
        if what == "in":
            t_in, cpu = t, c
            continue
        if t_in is not None and t - t_in > PERIOD_S:  # ran a period without switching out
            found[("long step", "")] += 1
            print(f"  long step {(t - t_in) * 1e6:6.0f} us at {t_in:.4f} s, cpu{cpu}: no switch (the VM frozen, or "
                  "a slow step: scheduler events do not tell)")
        if not what.startswith("S") or what_next != "in":
            continue
        due = phase + np.ceil((t - phase) / PERIOD_S) * PERIOD_S  # the wake-up it slept for
        late = t_next - due
        if late < LATE_S:
            continue
        k = np.searchsorted(W, due - 0.5 * PERIOD_S)
        woken = W[k] if k < len(W) and W[k] <= t_next else t_next
        if woken - due >= 0.5 * late:
            verdict = (f"its timer interrupt came {(woken - due) * 1e6:.0f} us late: the vCPU was not running "
                       "(the hypervisor), or interrupts were off")
            key = "timer interrupt late"
        else:
            tt = [e for e in per_cpu[c_next] if woken <= e[0] <= t_next]
            ran = collections.Counter(name for _, name in tt)
            verdict = (f"woken on time, ran {(t_next - woken) * 1e6:.0f} us later; instead: "
                       + (", ".join(f"{k} x{n}" for k, n in ran.most_common(3)) or "nothing switched in"))
            key = "woken on time, waited for the CPU"
        found[("late wake", key)] += 1
        print(f"  late wake {late * 1e6:6.0f} us at {due:.4f} s, cpu{c_next}: {verdict}")
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--keep", default=None, metavar="DIR", help="keep perf.data and the recordings here")
    a = ap.parse_args()
    if shutil.which("perf") is None:
        raise SystemExit("trace_load: needs perf (linux-tools)")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(1))
    except PermissionError:
        print("trace_load: no permission for SCHED_FIFO: the loops will run under the normal scheduler")
    tmp = a.keep or tempfile.mkdtemp(prefix="trace_load_")
    os.makedirs(tmp, exist_ok=True)
    perf_data = os.path.join(tmp, "perf.data")
    perf = subprocess.Popen(["perf", "record", "-a", "-q", "-m", "8M", "-k", "CLOCK_MONOTONIC", "-o", perf_data,
                             "-e", "sched:sched_switch", "-e", "sched:sched_waking", "--filter", "prio < 90"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        steal0 = bench_load.host_steal_ms()
        row = bench_load.case("hogs_shipped", (20, 10, 0), len(os.sched_getaffinity(0)), a.duration, tmp)
        steal = bench_load.host_steal_ms() - steal0
    finally:
        perf.send_signal(signal.SIGINT)
        _, perf_err = perf.communicate(timeout=120)
    if perf.returncode not in (0, -signal.SIGINT) or not os.path.exists(perf_data):
        raise SystemExit(f"trace_load: perf record failed: {perf_err.strip()[-300:]}")
    print(f"{bench_load.kernel_facts()}; {a.duration:g} s, a hog per core, the shipped measures: controller "
          f"{row['steps']} steps, {row['overruns']} overruns ({row['overrun_pct']:.3f} %), stale {row['stale']}, "
          f"command timeouts {row['cmd_timeouts']}; host steal {steal:.0f} ms (whole bench, both vCPUs)")
    per_cpu, wakes, ins, outs = events(perf_data)
    total = collections.Counter()
    for who, pid in row["pids"].items():
        print(f"{who} (thread {pid}):")
        total.update(classify(pid, per_cpu, wakes, ins, outs))
    print("both loops | count")
    for (kind, why), n in sorted(total.items()):
        print(f"{kind}{': ' + why if why else ' (unclassified)'} | {n}")
    if a.keep is None:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
