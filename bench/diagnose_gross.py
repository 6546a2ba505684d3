"""Gross probes of the diagnosis: large effects (10-50 x the noise), alone and two or three together.

Made differently from the matrix (:mod:`diagnose_suite`), whose effects are sized by bisection to a
multiple of the noise on one excitation at a time: here each effect has a gross *physical* size (a
coil 25-40 K warm, a 45 % cracking duty, a 50 ms lag, a clip at 130 L/min, asymmetry x5-10), on
seeds the matrix does not use, on breaths resting far below the valve's opening, on the paper sweep,
and on *mixed* excitations (breaths, then a sweep, then random holds in one recording), from two
generators:

- ``plant``: plant_sim (its coil's 180 s thermal time constant, its supply wander, its creep);
- ``foreign``: the physics of :mod:`diagnose_foreign`, coded without plant_sim (a 20-operator valve,
  a 150 s coil, a first-order-hold lag, an interpolated delay, a generalized PI's asymmetry).

Each probe is judged on what a user needs: no word named that was not injected (a lag named with a
delay as its alternative is not a false finding); each injected word named, or said to be not
identifiable on the excitation; each named magnitude within a tolerance of the injected one
(:data:`TOLERANCE`); every finding lowers the holdout RMSE.

    .venv/bin/python bench/diagnose_gross.py [--workers N] [--only SUBSTRING]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import diagnose_foreign as F  # noqa: E402
import diagnose_suite as S  # noqa: E402

#: Magnitude checks: word -> (reported parameter, injected value -> (lo, hi)).
TOLERANCE = {
    "coil_heating": ("rise55_k", lambda v: (0.75 * v, 1.25 * v)),
    "dead_zone": ("cracking_pct", lambda v: (v - 1.5, v + 1.5)),
    "saturation": ("full_open_lpm", lambda v: (0.97 * v, 1.03 * v)),
    "valve_dynamics": ("tau_s", lambda v: (0.7 * v, 1.3 * v)),
    "transport_delay": ("delay_s", lambda v: (0.7 * v - 0.01, 1.3 * v + 0.01)),
    "sensor_offset": ("offset_lpm", lambda v: (v - 0.2 * abs(v), v + 0.2 * abs(v))),
    "supply_pressure": ("exponent", lambda v: (0.7, 1.3)),
    "creep": ("amplitude", lambda v: (0.5 * v, 1.5 * v)),
}
#: Plant_sim's asymmetry is reported in its own unit (extra width at full flow); the foreign one in
#: another (every threshold widened in proportion), so it is checked only for plant_sim.
PLANT_ONLY = {"asymmetric_hysteresis": ("extra_width", lambda v: (0.65 * v, 1.35 * v))}

DURATION_S = 300.0


@dataclass(frozen=True)
class Probe:
    generator: str  # "plant" or "foreign"
    effects: tuple  # ((word, value), ...)
    excitation: str
    seed: int
    noise_lpm: float

    @property
    def words(self) -> tuple:
        return tuple(w for w, _ in self.effects)

    def label(self) -> str:
        eff = "+".join(f"{w}={v:g}" for w, v in self.effects) or "none"
        return f"{eff} [{self.generator} {self.excitation}, seed {self.seed}, noise {self.noise_lpm:g}]"


def plant_duty(exc: str, seed: int) -> np.ndarray:
    """Duty at 100 Hz: breaths resting at 30 % (far below the valve's opening), the paper sweep, or
    mixed (a third each of breaths, the paper sweep and random holds)."""
    from plant_sim.protocols import paper_identification, random_holds

    rate = 100.0
    if exc == "breaths":
        return S.excitation("breaths", seed, 30.0, rate_hz=rate, duration_s=DURATION_S)
    if exc == "paper":
        return paper_identification(rate, DURATION_S, seed)
    if exc == "mixed":
        third = DURATION_S / 3
        return np.concatenate([S.excitation("breaths", seed, 34.0, rate_hz=rate, duration_s=third),
                               paper_identification(rate, third, seed + 1),
                               random_holds(rate, third, seed + 2, lo_pct=38.0, hi_pct=72.0)])
    raise ValueError(exc)


def foreign_duty(exc: str, seed: int) -> np.ndarray:
    """Duty at the foreign suite's 50 Hz: its breaths or chirp, or mixed (breaths, then triangles)."""
    if exc == "mixed":
        n = int(DURATION_S * F.RATE_HZ) // 2
        return np.concatenate([F.excitation("breaths", seed)[:n], F.excitation("triangles", seed + 1)[:n]])
    return F.excitation(exc, seed)[:int(DURATION_S * F.RATE_HZ)]


def record(p: Probe):
    from models.recording import Recording
    from plant_sim.plant import Plant, load_plant

    eff = dict(p.effects)
    if p.generator == "plant":
        cols = Plant(load_plant(S.PLANT_TOML, effects=eff, noise_lpm=p.noise_lpm), 100.0,
                     seed=p.seed).simulate(plant_duty(p.excitation, p.seed))
        keep = ("t_s", "duty_pct", "flow_lpm") + (("supply_bar",) if "supply_pressure" in eff else ())
        return Recording(f"<{p.label()}>", {k: np.asarray(cols[k], float) for k in keep})
    duty = foreign_duty(p.excitation, p.seed)
    q, supply = F.flow_of(eff, duty, p.seed)
    rng = np.random.default_rng(p.seed * 31 + 7)
    cols = {"t_s": np.arange(len(duty)) / F.RATE_HZ, "duty_pct": duty,
            "flow_lpm": q + rng.normal(0.0, p.noise_lpm, len(q))}
    if supply is not None:
        cols["supply_bar"] = supply + rng.normal(0.0, 0.005, len(q))
    return Recording(f"<{p.label()}>", cols)


def probes() -> list:
    """The probe set: gross single effects and two- and three-word combinations."""
    P = Probe
    plant = [
        # effect free (each excitation)
        P("plant", (), "breaths", 5, 0.5), P("plant", (), "paper", 6, 1.0), P("plant", (), "mixed", 7, 0.3),
        # single gross effects
        P("plant", (("coil_heating", 40.0),), "breaths", 5, 0.5),
        P("plant", (("coil_heating", 25.0),), "mixed", 6, 0.3),
        P("plant", (("saturation", 130.0),), "breaths", 5, 0.5),
        P("plant", (("saturation", 150.0),), "mixed", 8, 0.5),
        P("plant", (("dead_zone", 45.0),), "mixed", 6, 0.5),
        P("plant", (("dead_zone", 43.0),), "breaths", 7, 0.3),
        P("plant", (("valve_dynamics", 0.05),), "breaths", 8, 0.3),
        P("plant", (("transport_delay", 0.04),), "mixed", 5, 0.5),
        P("plant", (("asymmetric_hysteresis", 10.0),), "paper", 7, 0.5),
        P("plant", (("asymmetric_hysteresis", 5.0),), "mixed", 8, 0.5),
        P("plant", (("supply_pressure", 0.3),), "breaths", 6, 0.5),
        P("plant", (("creep", 0.15),), "paper", 8, 0.3),
        # combinations of two and three
        P("plant", (("coil_heating", 30.0), ("valve_dynamics", 0.05)), "breaths", 6, 0.5),
        P("plant", (("saturation", 130.0), ("coil_heating", 30.0)), "paper", 7, 0.5),
        P("plant", (("dead_zone", 44.0), ("transport_delay", 0.03)), "breaths", 8, 0.5),
        P("plant", (("asymmetric_hysteresis", 3.0), ("supply_pressure", 0.3)), "mixed", 5, 0.5),
        P("plant", (("coil_heating", 35.0), ("saturation", 140.0), ("valve_dynamics", 0.03)), "mixed", 7, 0.5),
        P("plant", (("coil_heating", 30.0), ("creep", 0.1), ("supply_pressure", 0.2)), "paper", 6, 0.5),
    ]
    foreign = [
        P("foreign", (), "breaths", 5, 0.5), P("foreign", (), "mixed", 6, 0.3),
        P("foreign", (("coil_heating", 40.0),), "breaths", 6, 0.5),
        P("foreign", (("coil_heating", 30.0),), "mixed", 5, 0.3),
        P("foreign", (("saturation", 130.0),), "breaths", 7, 0.5),
        P("foreign", (("dead_zone", 46.0),), "mixed", 8, 0.5),
        P("foreign", (("valve_dynamics", 0.05),), "chirp", 5, 0.3),
        P("foreign", (("transport_delay", 0.06),), "breaths", 6, 0.5),
        P("foreign", (("asymmetric_hysteresis", 5.0),), "mixed", 7, 0.5),
        P("foreign", (("creep", 0.2),), "chirp", 8, 0.3),
        P("foreign", (("supply_pressure", 0.2),), "mixed", 5, 0.5),
        P("foreign", (("coil_heating", 35.0), ("saturation", 140.0)), "mixed", 6, 0.5),
        P("foreign", (("dead_zone", 45.0), ("valve_dynamics", 0.04)), "breaths", 7, 0.5),
        P("foreign", (("coil_heating", 30.0), ("transport_delay", 0.04), ("supply_pressure", 0.2)), "mixed", 8, 0.5),
    ]
    return plant + foreign


def judge(p: Probe, d) -> list:
    """What is wrong with the diagnosis ``d`` of probe ``p`` (empty: right)."""
    wrong = []
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    alts = {f.effect for f in d.findings if f.alternative_to is not None}
    injected = dict(p.effects)
    for w in named:
        if w not in injected:
            wrong.append(f"false {w} {_params(named[w].params)}")
    for w, v in injected.items():
        if w not in named:
            if w in alts:
                continue
            if w in d.model.get("not_identifiable", {}):
                continue
            wrong.append(f"missed {w}")
            continue
        tol = TOLERANCE.get(w) or (PLANT_ONLY.get(w) if p.generator == "plant" else None)
        if tol is not None:
            key, rng = tol
            got = named[w].params.get(key)
            lo, hi = rng(v)
            if got is None or not lo <= got <= hi:
                wrong.append(f"{w} {key} = {got if got is None else f'{got:.4g}'} (injected {v:g}, needs {lo:.3g}..{hi:.3g})")
    for f in d.findings:
        if f.holdout_rmse_after >= f.holdout_rmse_before:
            wrong.append(f"{f.effect} does not lower the holdout RMSE")
    return wrong


def _params(params: dict) -> str:
    return "(" + ", ".join(f"{k} {v:.3g}" for k, v in params.items()) + ")"


def run(p: Probe):
    from models.diagnose import diagnose_response
    from models.model import load_model

    rec = record(p)
    model = None
    if "sensor_offset" in p.words:
        model = load_model(S.MODEL_JSON) if p.generator == "plant" else F.model_file()
    t0 = time.perf_counter()
    try:
        d = diagnose_response(rec, model)
    except Exception as exc:  # a crash is a wrong answer, reported with the others
        return p, [f"crashed: {type(exc).__name__}: {exc}"], "-", [], time.perf_counter() - t0
    found = ", ".join(f"{f.effect}{'~' if f.alternative_to else ''} {_params(f.params)}" for f in d.findings) or "-"
    ni = sorted(w for w in d.model.get("not_identifiable", {}) if w in p.words)
    return p, judge(p, d), found, ni, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", default="", help="probes whose label contains this")
    args = ap.parse_args()
    todo = [p for p in probes() if args.only in p.label()]
    t0 = time.perf_counter()
    bad, results = 0, []
    with ProcessPoolExecutor(args.workers) as ex:
        for p, wrong, found, ni, s in ex.map(run, todo, chunksize=1):
            results.append(p)
            bad += bool(wrong)
            print(f"{'WRONG' if wrong else 'ok   '} {p.label()}  ({s:.0f} s)\n      found: {found}"
                  + (f"\n      not identifiable: {', '.join(ni)}" if ni else "")
                  + "".join(f"\n      !! {w}" for w in wrong), flush=True)
    print(f"\ngross probes: {len(results) - bad}/{len(results)} right in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
