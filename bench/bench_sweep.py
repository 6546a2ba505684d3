"""Sweep speed: the batched sweep against the live-loop code run once per candidate, in one run.

The default sweep (``config/sweep.toml``: over 1000 candidates, each on every
plant variant, a 5 s breath profile at 1 kHz) runs through ``run_sweep`` on a
local process pool (one worker per core). The baseline is the live loop
(:class:`controller.loop.Loop` on a simulated clock with the in-process
simulated valve, exactly what ``valvectl run`` steps) run once per candidate
and variant, for a stratified sample of the same candidates (every k-th row,
so the controller words appear in the sweep's proportions). Both are timed
in wall-clock seconds and in CPU seconds (this process and its pool
workers): the CPU figure compares the two at equal cores and moves less
when other work shares the machine, which the wall figures do not survive.

Usage: ``python bench/bench_sweep.py [SWEEP.toml] [--baseline N]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.config import preview_s  # noqa: E402
from controller.loop import Loop, ProfileReference, SimClock  # noqa: E402
from controller.sweep import runner  # noqa: E402
from controller.sweep import spec as sp  # noqa: E402
from controller.sweep.distributed import default_workers  # noqa: E402
from controller.transport.sim import SimTransport  # noqa: E402
from plant_sim.plant import Plant  # noqa: E402
from plant_sim.protocols import BreathProfile  # noqa: E402


def cpu_s() -> float:
    """CPU seconds of this process and of its finished children (the pool's workers)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def live_loop_seconds(s: sp.SweepSpec, idx, plants, models) -> tuple[float, float]:
    """Wall and CPU time of the live loop run once per candidate in ``idx`` and per plant variant."""
    run = s.run
    rate = run["loop"]["rate_hz"]
    c0, t0 = cpu_s(), time.perf_counter()
    for i in idx:
        word, row = s.candidates.controller[i], s.candidates.row(i)
        cfg = sp.apply(run, word, row)
        params, _ = runner.build_one(run, word, row, models)
        profile = BreathProfile(**cfg["profile"])
        for plant in plants:
            transport = SimTransport(Plant(plant, rate, seed=run[""]["seed"]), cfg.loop.safe_duty_pct)
            ref = ProfileReference(profile.value, preview_s(cfg, "profile"))
            Loop(params, transport, ref, cfg.loop, clock=SimClock()).run(s.duration_s)
    return time.perf_counter() - t0, cpu_s() - c0


def subset(s: sp.SweepSpec, idx) -> sp.SweepSpec:
    return dataclasses.replace(s, candidates=s.candidates.take(idx), margins_top=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", nargs="?", default=str(ROOT / "config" / "sweep.toml"))
    ap.add_argument("--baseline", type=int, default=8, help="candidates run one at a time by the live loop")
    a = ap.parse_args()

    s = sp.load_sweep(a.sweep)
    n, V = len(s.candidates), len(s.variants)
    steps = int(round(s.duration_s * s.run["loop"]["rate_hz"]))
    plants = sp.plants(s.run, s.variants, s.path)
    models = runner.load_models(s)
    workers = default_workers()
    print(f"sweep {a.sweep}: {n} candidates x {V} plant variants, {s.duration_s:g} s at "
          f"{s.run['loop']['rate_hz']:g} Hz ({steps} steps), {workers} workers")

    # warm-up: numba kernels loaded and python-control imported outside the timings
    runner.run_sweep(subset(s, [0, n - 1]), workers=1)

    c0 = cpu_s()
    r = runner.run_sweep(s, workers=workers)
    cpu = cpu_s() - c0
    print(f"batched sweep, {workers} processes: {r.seconds:.1f} s for {n} candidates = {n / r.seconds:.1f} candidates/s "
          f"({n * V * steps / r.seconds / 1e6:.2f} M loop-steps/s), {cpu:.1f} CPU s; "
          f"{'within' if r.seconds <= 60 and n >= 1000 else 'NOT within'} 60 s for >= 1000 candidates")

    k = max(1, n // a.baseline)
    idx = np.arange(0, n, k)[:a.baseline]
    wall, cpu_b = live_loop_seconds(s, idx, plants, models)
    base, base_cpu = wall / len(idx), cpu_b / len(idx)
    print(f"live loop once per candidate (x {V} variants), 1 process: {base:.2f} s per candidate = "
          f"{1 / base:.2f} candidates/s ({V * steps / base / 1e3:.1f} k loop-steps/s), {base_cpu:.2f} CPU s per "
          f"candidate, over {len(idx)} candidates")
    print(f"speed-up per candidate: {base / (r.seconds / n):.0f}x wall ({workers} processes against 1), "
          f"{base_cpu / (cpu / n):.0f}x CPU (per core)")


if __name__ == "__main__":
    main()
