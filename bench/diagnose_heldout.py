"""Held-out random gross probes of the diagnosis: words, sizes, excitations and seeds drawn at random.

:mod:`diagnose_gross` is a fixed set that the diagnosis has been developed against. Here probe ``i``
is drawn from its own random stream (``numpy.random.default_rng((DRAW, i))``), so a range of indices
never run before is a set nobody has tuned on: run a fresh ``--start`` each time a change is judged,
and the same range on the code before and after it. Each probe is 0-3 physical effect words at a
gross size, on plant_sim or on the foreign suite's independent physics, with the excitations,
judgement and tolerances of :mod:`diagnose_gross`; a ``sensor_offset`` is held against a model file.
A drawn word the recording does not show (its removal moves the noiseless flow by less than
:data:`SHOWN_PEAK` x the noise at every row and by less than :data:`SHOWN_ENERGY` squared noise
widths summed over the rows: a clip above the valve's peak flow, a short delay on a slow sweep) is
neither required nor false: it is printed as ``not shown``.

    .venv/bin/python bench/diagnose_heldout.py --start 0 --count 48 [--workers 2] [--show]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import diagnose_gross as G  # noqa: E402

#: Stream key of the draws: changing it makes every index new.
DRAW = 20261206

#: Gross size range of each word (DESIGN.md units); an offset's sign is drawn too.
SIZES = {
    "coil_heating": (15.0, 45.0),
    "dead_zone": (42.0, 47.0),
    "saturation": (125.0, 165.0),
    "valve_dynamics": (0.02, 0.06),
    "transport_delay": (0.02, 0.06),
    "asymmetric_hysteresis": (3.0, 10.0),
    "supply_pressure": (0.1, 0.4),
    "creep": (0.05, 0.2),
    "sensor_offset": (1.0, 3.0),
}
EXCITATIONS = {"plant": ("breaths", "paper", "mixed"), "foreign": ("breaths", "chirp", "triangles", "mixed")}
#: A word is shown when removing it moves the noiseless flow by this many noise widths at some row,
#: or by this many squared noise widths summed over the rows (a small offset on every row).
SHOWN_PEAK = 3.0
SHOWN_ENERGY = 1000.0
#: Probability of 0, 1, 2 and 3 words.
N_WORDS = (0.08, 0.4, 0.35, 0.17)


def probe(i: int) -> G.Probe:
    """Probe number ``i``: the same draw on every machine and every run."""
    rng = np.random.default_rng((DRAW, i))
    generator = ("plant", "foreign")[rng.integers(2)]
    n = rng.choice(len(N_WORDS), p=N_WORDS)
    words = sorted(rng.choice(sorted(SIZES), size=n, replace=False)) if n else []
    effects = []
    for w in words:
        lo, hi = SIZES[w]
        v = float(rng.uniform(lo, hi))
        if w == "sensor_offset":
            v *= float(rng.choice((-1.0, 1.0)))
        effects.append((str(w), round(v, 4 if abs(v) < 1 else 2)))
    exc = EXCITATIONS[generator][rng.integers(len(EXCITATIONS[generator]))]
    noise = round(float(rng.uniform(0.3, 1.0)), 2)
    return G.Probe(generator, tuple(effects), exc, 10_000 + i, noise)


def clean_flow(p: G.Probe, effects: dict) -> np.ndarray:
    """The noiseless flow (L/min) of probe ``p``'s generator with ``effects`` on its excitation."""
    if p.generator == "plant":
        from plant_sim.plant import Plant, load_plant

        plant = Plant(load_plant(G.S.PLANT_TOML, effects=effects, noise_lpm=0.0), 100.0, seed=p.seed)
        return np.asarray(plant.simulate(G.plant_duty(p.excitation, p.seed))["flow_lpm"], float)
    return G.F.flow_of(effects, G.foreign_duty(p.excitation, p.seed), p.seed)[0]


def unshown(p: G.Probe) -> set:
    """The words of ``p`` whose removal moves its noiseless flow too little to be seen."""
    eff = dict(p.effects)
    q = clean_flow(p, eff) if eff else None
    hidden = set()
    for w in eff:
        z = (q - clean_flow(p, {k: v for k, v in eff.items() if k != w})) / p.noise_lpm
        if np.max(np.abs(z)) < SHOWN_PEAK and np.sum(z ** 2) < SHOWN_ENERGY:
            hidden.add(w)
    return hidden


def run(p: G.Probe):
    """:func:`diagnose_gross.run`, with the words the recording does not show excused."""
    p, wrong, found, ni, s = G.run(p)
    hidden = unshown(p)
    wrong = [w for w in wrong if not any(w in (f"missed {h}",) or w.startswith(f"false {h} ") for h in hidden)]
    return p, wrong, found, [w for w in ni if w not in hidden] + [f"{h} (not shown)" for h in sorted(hidden)], s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", type=int, default=0, help="first probe index")
    ap.add_argument("--count", type=int, default=48)
    ap.add_argument("--indices", default="", help="comma-separated probe indices (instead of a range)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--show", action="store_true", help="list the probes and stop")
    args = ap.parse_args()
    index = ([int(i) for i in args.indices.split(",")] if args.indices
             else list(range(args.start, args.start + args.count)))
    todo = [probe(i) for i in index]
    if args.show:
        for i, p in zip(index, todo):
            print(f"{i:5d} {p.label()}")
        return 0
    t0 = time.perf_counter()
    right = false = 0
    with ProcessPoolExecutor(args.workers) as ex:
        for i, (p, wrong, found, ni, s) in zip(index, ex.map(run, todo, chunksize=1)):
            right += not wrong
            false += any(w.startswith("false ") for w in wrong)
            print(f"{'WRONG' if wrong else 'ok   '} {i:5d} {p.label()}  ({s:.0f} s)\n      found: {found}"
                  + (f"\n      not identifiable: {', '.join(ni)}" if ni else "")
                  + "".join(f"\n      !! {w}" for w in wrong), flush=True)
    what = args.indices or f"{args.start}-{args.start + args.count - 1}"
    print(f"\nheld-out probes {what}: {right}/{len(todo)} right, "
          f"{false} with a false finding, in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
