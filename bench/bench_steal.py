"""Where the live loop's tail comes from: the thread's CPU time against its wall time, and the status step.

Parts (``--parts``, comma separated):

``clock``
    Does the thread's CPU time (``CLOCK_THREAD_CPUTIME_ID``, ``time.thread_time_ns``) leave out host steal
    on this VM? A fixed piece of work (a Python loop, ~10 ms) repeated ``--reps`` times on one CPU under
    ``SCHED_FIFO`` (nothing of the guest's own preempts it; a 3 ms sleep after each repetition keeps it under
    the kernel's real-time throttling), each timed by the wall clock and the thread's clock, with the
    CPU's steal (``/proc/stat``, ``cpuN`` column 8, 10 ms ticks) read before and after each: if the
    thread's clock leaves steal out, the wall time beyond the CPU time summed over the repetitions is the
    steal summed over the same windows, and the repetitions with the largest gap are those where steal
    rose. Then the cost of a read of the thread's clock (a system call: ``perf_counter`` is in the vDSO),
    back to back and after a 1 ms sleep (the loop's case).
``status``
    The live loop of ``make run`` (config/run.toml, ff+kf on the embedded valve, ``SCHED_FIFO``,
    rehearsed), in-process for ``--seconds``, per step: the status steps' compute (every 100th) against
    the others', and the tail (the steps above the p99) split by whether the step stood off its CPU; run in
    a subprocess per tree (``--trees``, this tree first), rounds interleaved, the host's steal and the load
    average per run.
``run``
    ``make run``'s own command (``python -m controller.cli run --config config/run.toml --json``) from
    each tree (``--trees``), rounds interleaved: compute p50/p99, the thread's CPU time, the steps off CPU,
    IAE, steady MAE, overruns, with the host's steal and the load average per run.

    .venv/bin/python bench/bench_steal.py [--parts clock,status,run] [--rounds 3] [--trees THIS,/tmp/main-tree]

A tree is a checkout with this interpreter's packages (``PYTHONPATH=TREE``, cwd TREE; its numba cache is its
own: run ``controller.precompile`` there first). A tree older than the CPU column prints no CPU figures.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TICK_MS = 1000.0 / os.sysconf("SC_CLK_TCK")


def steal_ms(cpu: int | None = None) -> float:
    """The host's steal, ms: of CPU ``cpu``, or of all CPUs (None)."""
    name = "cpu" if cpu is None else f"cpu{cpu}"
    with open("/proc/stat") as fh:
        for line in fh:
            f = line.split()
            if f[0] == name:
                return int(f[8]) * TICK_MS
    raise ValueError(f"no {name} in /proc/stat")


def work(n: int) -> int:
    x = 0
    for i in range(n):
        x += i & 7
    return x


def clock_part(reps: int, cpu: int) -> None:
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(20))
        sched = "SCHED_FIFO 20"
    except PermissionError:
        sched = "normal scheduler (no permission for SCHED_FIFO)"
    pc, tt = time.perf_counter_ns, time.thread_time_ns
    n = 1
    while True:  # a repetition of ~10 ms
        a = pc()
        work(n)
        if pc() - a > 10e6:
            break
        n *= 2
    n = int(n * 10e6 / (pc() - a + 1))
    load, total0 = os.getloadavg()[0], steal_ms()
    wall, cpu_t, st = np.empty(reps), np.empty(reps), np.empty(reps)
    for k in range(reps):
        s0 = steal_ms(cpu)
        w0, c0 = pc(), tt()
        work(n)
        c1, w1 = tt(), pc()
        st[k] = steal_ms(cpu) - s0
        wall[k], cpu_t[k] = (w1 - w0) * 1e-6, (c1 - c0) * 1e-6
        time.sleep(3e-3)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    gap = wall - cpu_t
    print(f"clock: {reps} repetitions of the same work on CPU {cpu}, {sched}; load {load:.1f}, "
          f"host steal over the part {steal_ms() - total0:.0f} ms (all CPUs)")
    print(f"  wall  ms per repetition: p50 {np.median(wall):7.2f}  p99 {np.percentile(wall, 99):7.2f}  "
          f"max {wall.max():7.2f}")
    print(f"  CPU   ms per repetition: p50 {np.median(cpu_t):7.2f}  p99 {np.percentile(cpu_t, 99):7.2f}  "
          f"max {cpu_t.max():7.2f}  (the same work: spread of the CPU time, max/p50 {cpu_t.max() / np.median(cpu_t):.2f})")
    print(f"  wall - CPU summed: {gap.sum():8.1f} ms;  CPU {cpu}'s steal over the same windows: {st.sum():8.1f} ms "
          f"(10 ms ticks)")
    stolen = st > 0
    print(f"  repetitions where CPU {cpu}'s steal rose: {stolen.sum()} of {reps}; their wall - CPU mean "
          f"{gap[stolen].mean() if stolen.any() else float('nan'):.2f} ms against {gap[~stolen].mean():.3f} ms "
          f"in the others")
    top = np.argsort(gap)[::-1][:max(1, reps // 100)]
    print(f"  the {len(top)} repetitions of largest wall - CPU ({gap[top].min():.2f}-{gap[top].max():.2f} ms): "
          f"steal rose in {int(stolen[top].sum())}")
    if np.std(st) > 0 and np.std(gap) > 0:
        print(f"  correlation of wall - CPU with the steal per repetition: {np.corrcoef(gap, st)[0, 1]:.3f}")

    # the cost of a read
    m = 200_000
    a = pc()
    for _ in range(m):
        tt()
    warm_tt = (pc() - a) / m
    a = pc()
    for _ in range(m):
        pc()
    warm_pc = (pc() - a) / m
    cold = np.empty(2000)
    for k in range(len(cold)):
        time.sleep(1e-3)
        a = pc()
        tt()
        b = pc()
        tt()
        c = pc()
        cold[k] = (b - a + c - b) / 2
    print(f"  a read of the thread's clock: {warm_tt:.0f} ns back to back (perf_counter: {warm_pc:.0f} ns); after "
          f"1 ms of sleep p50 {np.median(cold):.0f} ns, p99 {np.percentile(cold, 99):.0f} ns (two per step)")


ONE = r"""
import dataclasses, json, sys
import numpy as np
from controller.config import load_run_config, preview_s, supervisor
from controller.loop import Loop, ProfileReference, RealClock
from controller.run_summary import summary
from controller.transport.sim import SimTransport
from models.model import load_model
from plant_sim.plant import Plant, load_plant
from plant_sim.protocols import BreathProfile

seconds = float(sys.argv[1])
cfg = load_run_config("config/run.toml")
s = cfg.loop
pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
ref = ProfileReference(BreathProfile(**cfg["profile"]).value, preview_s(cfg, "profile"))
sup = supervisor(cfg, "ff+kf", load_model(cfg.resolve(cfg[""]["model"])))  # as valvectl run builds them
valve = SimTransport(Plant(pp, s.rate_hz, seed=cfg[""]["seed"]), s.safe_duty_pct)
loop = Loop(sup, valve, ref, s, clock=RealClock(s.spin_s))
res = loop.run(seconds)
c = res.columns
w = c["compute_s"] * 1e6
every = max(1, int(round(s.rate_hz / s.status_hz)))
st = np.zeros(len(w), bool)
st[::every] = True
out = {"summary": summary(res, "ff+kf", "sim"), "status_p50": float(np.median(w[st])),
       "other_p50": float(np.median(w[~st])), "status_p90": float(np.percentile(w[st], 90)),
       "other_p90": float(np.percentile(w[~st], 90))}
p99 = np.percentile(w, 99)
tail = w > p99
out["tail_n"] = int(tail.sum())
out["tail_status"] = int((tail & st).sum())
if "cpu_s" in c:
    cpu = c["cpu_s"] * 1e6
    off = w - cpu > 20.0
    out["tail_off_cpu"] = int((tail & off).sum())
    out["p99_on_cpu"] = float(np.percentile(w[~off], 99))
    out["status_cpu_p50"] = float(np.median(cpu[st]))
    out["other_cpu_p50"] = float(np.median(cpu[~st]))
print(json.dumps(out))
"""


def tree_env(tree: str) -> dict:
    return {**os.environ, "PYTHONPATH": tree}


def conditions():
    return os.getloadavg()[0], steal_ms()


def status_part(trees: list[str], rounds: int, seconds: float) -> None:
    print(f"\nstatus: make run's loop in-process, {seconds:g} s per run, rounds interleaved")
    for r in range(rounds):
        for tree in trees:
            load, s0 = conditions()
            p = subprocess.run([sys.executable, "-c", ONE, str(seconds)], cwd=tree, env=tree_env(tree),
                               capture_output=True, text=True)
            steal = steal_ms() - s0
            if p.returncode:
                print(f"  round {r + 1} {tree}: failed\n{p.stderr[-2000:]}")
                continue
            o = json.loads(p.stdout.strip().splitlines()[-1])
            co = o["summary"]["compute_us"]
            line = (f"  round {r + 1} {os.path.basename(tree):10s} load {load:4.1f} steal {steal:5.0f} ms  compute p50 "
                    f"{co['p50']:5.1f} p99 {co['p99']:6.1f}  status step p50 {o['status_p50']:5.1f} vs other "
                    f"{o['other_p50']:5.1f} (+{o['status_p50'] - o['other_p50']:.1f}; p90 {o['status_p90']:.1f} vs "
                    f"{o['other_p90']:.1f})  tail {o['tail_n']} steps: {o['tail_status']} status")
            if "tail_off_cpu" in o:
                line += (f", {o['tail_off_cpu']} off CPU; p99 of the steps on CPU {o['p99_on_cpu']:.1f}; "
                         f"status CPU p50 {o['status_cpu_p50']:.1f} vs {o['other_cpu_p50']:.1f}")
            print(line, flush=True)


def run_part(trees: list[str], rounds: int) -> None:
    print(f"\nrun: make run's command from each tree, rounds interleaved")
    out = tempfile.mkdtemp()
    rows = {t: [] for t in trees}
    for r in range(rounds):
        for tree in trees:
            js = os.path.join(out, f"{os.path.basename(tree)}_{r}.json")
            load, s0 = conditions()
            p = subprocess.run([sys.executable, "-m", "controller.cli", "run", "--config", "config/run.toml",
                                "--json", js], cwd=tree, env=tree_env(tree), capture_output=True, text=True)
            steal = steal_ms() - s0
            if p.returncode:
                print(f"  round {r + 1} {tree}: failed\n{p.stderr[-2000:]}")
                continue
            s = json.load(open(js))
            co, tr = s["compute_us"], s["tracking"]
            cc = s.get("compute_cpu_us")
            rows[tree].append((co["p50"], co["p99"]))
            print(f"  round {r + 1} {os.path.basename(tree):10s} load {load:4.1f} steal {steal:5.0f} ms  compute p50 "
                  f"{co['p50']:5.1f} p99 {co['p99']:6.1f} max {co['max']:6.0f}  "
                  + (f"CPU p50 {cc['p50']:5.1f} p99 {cc['p99']:6.1f} max {cc['max']:6.0f} off-CPU steps "
                     f"{s['steps_off_cpu']:4d}  " if cc else "")
                  + f"IAE {tr['iae']:.4f} L steady MAE {tr['steady_mae_lpm']:.3f}  overruns {s['overruns']}",
                  flush=True)
    base = trees[-1]
    for tree in trees:
        if rows[tree] and rows[base]:
            m = np.median(rows[tree], axis=0)
            b = np.median(rows[base], axis=0)
            print(f"  median {os.path.basename(tree):10s} p50 {m[0]:.1f} p99 {m[1]:.1f}  ({m[0] / b[0]:.2f}x, "
                  f"{m[1] / b[1]:.2f}x {os.path.basename(base)})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="clock,status,run")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=800)
    ap.add_argument("--cpu", type=int, default=1)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--trees", default=ROOT, help="comma separated; the last is the baseline of the ratios")
    a = ap.parse_args()
    parts = a.parts.split(",")
    trees = [os.path.abspath(t) for t in a.trees.split(",")]
    if "clock" in parts:
        clock_part(a.reps, a.cpu)
    if "status" in parts:
        status_part(trees, a.rounds, a.seconds)
    if "run" in parts:
        run_part(trees, a.rounds)


if __name__ == "__main__":
    main()
