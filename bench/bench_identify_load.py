"""valvectl identify on a loaded machine, emulated in-process: what missed periods cost the identified model.

A session on a busy machine misses periods (stalls of the process) while the
valve runs on, holding the last duty. Emulated deterministically
(:mod:`tests.loaded`: each step, with probability ``p``, a stall of
exponentially distributed length; the valve stepped through it at its own
rate, the session reading its newest measurement), against a twin
(``config/valves/NAME``, 15 ms lag, 10 ms delay, its 0.5 L/min noise). For
each load, one session, identified twice:

- ``timeline``: as ``valvectl identify`` does (:func:`controller.identify.analysis.identify`:
  fits and validation on the even grid the valve lived, the duty held through
  the missed periods);
- ``rows``: the same session's rows taken as evenly spaced (what identify did
  before), with the same lag and delay;

and the held-out RMSE of each chosen model against the twin's noise-free flow
(:func:`bench_identify.held_out_rmse`), beside a session with no stall (the
baseline of the same run). Run it at idle priority (no timing figure)::

    chrt -i 0 nice -n 19 python bench/bench_identify_load.py [--twin bench pvp] [--duration 120]
                                                             [--load P:MEAN_MS ...] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_identify import DELAY_S, TAU_S, held_out_rmse  # noqa: E402
from controller.identify.analysis import identify  # noqa: E402
from controller.identify.estimate import estimate  # noqa: E402
from controller.identify.protocol import Program, ProtocolParams  # noqa: E402
from controller.identify.session import Safety, run_session  # noqa: E402
from plant_sim.plant import Plant, load_plant  # noqa: E402
from tests.loaded import Bridge, Busy  # noqa: E402

RATE_HZ = 1000.0


def one(twin: str, duration_s: float, p: float, mean_ms: float, seed: int) -> dict:
    params = load_plant(os.path.join(ROOT, "config", "valves", twin, "plant.toml"),
                        effects={"valve_dynamics": TAU_S, "transport_delay": DELAY_S})
    clock = Busy(p, mean_ms * 1e-3, seed)
    res = run_session(Program(ProtocolParams(duration_s, RATE_HZ, flow_ceiling_lpm=180.0, seed=seed)),
                      Bridge(Plant(params, RATE_HZ, seed=seed + 1), clock), Safety(stale_s=60.0), RATE_HZ, clock)
    r = res.working_range
    ident = identify(res, RATE_HZ)
    dyn = ident.dynamics
    c = res.columns
    rows = estimate(c["t_s"], c["duty_pct"], c["flow_lpm"], res.phase, r.lo_pct, r.hi_pct, dyn, RATE_HZ,
                    fresh=c["meas_age_ms"] == 0.0)
    row = {"twin": twin, "duration_s": duration_s, "p": p, "mean_ms": mean_ms, "seed": seed,
           "missed": ident.damage.missed_share, "longest_stall_ms": ident.damage.longest_stall_ms,
           "verdict": ident.verdict, "tau_ms": dyn.tau_s * 1e3, "delay_ms": dyn.delay_s * 1e3}
    for name, est in (("timeline", ident.estimate), ("rows", rows)):
        row[name] = {"model": est.chosen, "validation_rmse": est.results[est.chosen].validation.rmse,
                     "held_out_rmse": held_out_rmse(params, est.model, dyn.tau_s, dyn.delay_s, r.lo_pct, r.hi_pct)}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--twin", nargs="+", default=["bench", "pvp"])
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--load", nargs="+", default=["0.12:8", "0.02:60"], metavar="P:MEAN_MS",
                    help="stall probability per step and mean stall length")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    rows = []
    for twin in a.twin:
        for load in ["0:0", *a.load]:
            p, mean_ms = (float(x) for x in load.split(":"))
            rows.append(one(twin, a.duration, p, mean_ms, a.seed))
            print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'twin':<6}{'stalls':>10}{'missed':>8}{'tau ms':>8}{'delay ms':>9}{'timeline: model':>17}{'held-out':>9}"
          f"{'rows: model':>13}{'held-out':>9}")
    for r in rows:
        t, w = r["timeline"], r["rows"]
        print(f"{r['twin']:<6}{r['p']:>5g}:{r['mean_ms']:<4g}{r['missed']:8.1%}{r['tau_ms']:8.2f}{r['delay_ms']:9.2f}"
              f"{t['model']:>17}{t['held_out_rmse']:9.2f}{w['model']:>13}{w['held_out_rmse']:9.2f}")


if __name__ == "__main__":
    main()
