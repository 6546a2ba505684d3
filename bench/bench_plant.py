"""Cost of a plant step: single plant, 1000 batched plants, and a plain numpy step as baseline.

Issue 4 asks: one single-plant step with all effects off costs at most 20 µs,
and the batched plant steps 1000 plants for at most 20x the cost of one.
A step's cost is the CPU time of this thread (``time.thread_time``), best of
several repeats: on a machine shared with other work the wall clock also
counts the time other processes hold the core, which is not the step's cost.
The wall-clock figure is printed beside it. Ratios are measured in the same run.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from plant_sim.effects import EFFECTS  # noqa: E402
from plant_sim.plant import BatchPlant, Plant, load_plant  # noqa: E402

RATE_HZ = 1000.0
REPEATS = 7


WALL: dict[str, float] = {}


def best_us(fn, n: int) -> float:
    """Best per-call CPU time (µs) of ``fn(n)`` over :data:`REPEATS` runs of ``n`` calls.

    The best wall-clock time of the same runs goes to :data:`WALL` under the function's name.
    """
    fn(max(1, n // 10))  # warm up (compilation, caches)
    cpu, wall = [], []
    for _ in range(REPEATS):
        t, c = time.perf_counter(), time.thread_time()
        fn(n)
        cpu.append((time.thread_time() - c) / n * 1e6)
        wall.append((time.perf_counter() - t) / n * 1e6)
    WALL[fn.__qualname__] = min(wall)
    return min(cpu)


def single_cost(params) -> float:
    plant = Plant(params, RATE_HZ, seed=1)
    state = [plant.init(50.0)]

    def loop(n):
        s = state[0]
        for i in range(n):
            s, _ = plant.step(s, 50.0 + (i % 100) * 0.1)
        state[0] = s

    return best_us(loop, 20_000)


def batch_cost(params, b: int) -> float:
    plant = BatchPlant([params] * b, RATE_HZ, seed=1)
    state = [plant.init(50.0)]
    duty = 50.0 + np.linspace(0.0, 10.0, b)

    def loop(n):
        s = state[0]
        for _ in range(n):
            s, _ = plant.step(s, duty)
        state[0] = s

    return best_us(loop, 500)


def numpy_cost(params) -> float:
    """Baseline: the fitted model's own numpy step (Eq. 1 and 4) plus sensor noise and quantization."""
    model = params.model
    rng = np.random.default_rng(1)
    state = [model.init(50.0)]

    def loop(n):
        s = state[0]
        for i in range(n):
            s, q = model.step(s, 50.0 + (i % 100) * 0.1)
            q = np.round((q + params.noise_lpm * rng.standard_normal()) * 120.0) / 120.0
        state[0] = s

    return best_us(loop, 20_000)


def main() -> int:
    base = load_plant()
    every = base.replace(**{name: e.default for name, e in EFFECTS.items()})
    print(f"plant step costs at {RATE_HZ:g} Hz: CPU time per step, best of {REPEATS} (wall clock in brackets; "
          f"load average {', '.join(f'{x:.1f}' for x in os.getloadavg())})")
    np_us = numpy_cost(base)
    np_wall = WALL["numpy_cost.<locals>.loop"]
    one = single_cost(base)
    one_wall = WALL["single_cost.<locals>.loop"]
    one_all = single_cost(every)
    b1000 = batch_cost(base, 1000)
    b1000_wall = WALL["batch_cost.<locals>.loop"]
    b1000_all = batch_cost(every, 1000)
    print(f"  numpy per-step baseline (model.step + noise):  {np_us:8.2f} µs [{np_wall:8.2f}]")
    print(f"  single plant, effects off:                     {one:8.2f} µs [{one_wall:8.2f}]  "
          f"({one / np_us:.2f}x numpy)")
    print(f"  single plant, every effect on:                 {one_all:8.2f} µs  ({one_all / np_us:.2f}x numpy)")
    print(f"  1000 batched plants, effects off:              {b1000:8.2f} µs [{b1000_wall:8.2f}]  "
          f"({b1000 / one:.1f}x one plant, {b1000 / 1000 * 1e3:.0f} ns per plant)")
    print(f"  1000 batched plants, every effect on:          {b1000_all:8.2f} µs  ({b1000_all / one_all:.1f}x one plant)")
    n = 200_000
    plant = Plant(base, RATE_HZ)
    duty = 55.0 + 15.0 * np.sin(np.arange(n) / 5000.0)
    plant.simulate(duty[:100])
    t = time.thread_time()
    plant.simulate(duty)
    sim_us = (time.thread_time() - t) / n * 1e6
    print(f"  Plant.simulate, whole recording:               {sim_us:8.3f} µs per step ({one / sim_us:.0f}x faster "
          f"than stepping)")
    ok_one = one <= 20.0
    ok_batch = b1000 <= 20.0 * one
    print(f"single step <= 20 µs: {'met' if ok_one else 'NOT met'}; "
          f"1000 plants <= 20x one: {'met' if ok_batch else 'NOT met'} ({b1000 / one:.1f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
