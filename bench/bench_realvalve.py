"""Real valves: the figures of issue 12, with their baselines, in one run.

Prints
- the PVP sweep (a real SMC PVQ31): pi-mod's RMSE and its inverse fed the measured flow (duty MAE
  over rows >= 2 L/min) against the paper's PI;
- the bench recordings: pi-mod's validation RMSE against pi-asym's, and its inverse on measured flow;
- closed loop (`valvectl run`, real time): ff+kf against pid on the PVP twin
  (config/valves/pvp/run.toml), the same with the paper's PI as the feedforward, and `make run`'s
  configuration (plant kind != feedforward kind);
- the feedforward's cost per loop step for each invertible kind, and what a numerical Preisach
  inverse (bisection on the 1275-relay forward model) would cost, against the 1 ms loop period.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("VALVECTL_SHARED", ROOT.parent / "shared")) / "data"

from controller.laws import feedforward as ffw  # noqa: E402
from models.compare import inverse_on_measured_flow  # noqa: E402
from models.fitting import evaluate, fit_recording  # noqa: E402
from models.metrics import metrics  # noqa: E402
from models.recording import read_recording  # noqa: E402
from models import preisach  # noqa: E402


def fit_figures(kind, rec, val=None):
    m = fit_recording(kind, rec)
    fit = metrics(rec.flow_lpm, m.predict(rec.duty_pct)[0])
    v = evaluate(m, val.duty_pct, val.flow_lpm) if val is not None else None
    return m, fit, v, inverse_on_measured_flow(m, rec)


def run(config, controller, model=None):
    with tempfile.TemporaryDirectory() as tmp:
        cfg = config
        if model is not None:  # the same run with another feedforward model
            text = Path(config).read_text()
            lines = [f'model = "{model}"' if ln.startswith("model = ") else ln for ln in text.splitlines()]
            cfg = os.path.join(os.path.dirname(config), f".bench_{os.getpid()}.toml")
            Path(cfg).write_text("\n".join(lines) + "\n")
        try:
            out = os.path.join(tmp, "s.json")
            subprocess.run([sys.executable, "-m", "controller.cli", "run", "--config", cfg, "--controller", controller,
                            "--json", out], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
            return json.load(open(out))["tracking"]
        finally:
            if cfg != config:
                os.remove(cfg)


def main():
    print("== PVP sweep (SMC PVQ31, ../shared/data/external/pvp_valve_sweep.csv)")
    pvp = read_recording(DATA / "external" / "pvp_valve_sweep.csv")
    for kind in ("pi", "pi-mod"):
        _, fit, _, inv = fit_figures(kind, pvp)
        print(f"  {kind:7s} RMSE {fit.rmse:6.3f} L/min   inverse on measured flow: duty MAE {inv.mae:6.3f} %"
              f"   (targets for pi-mod: <= 2.0 L/min, <= 1.0 %)")

    print("== bench recordings (fit on identification, validate on validation)")
    rec, val = read_recording(DATA / "bench_identification.csv"), read_recording(DATA / "bench_validation.csv")
    figs = {k: fit_figures(k, rec, val) for k in ("pi", "pi-asym", "pi-mod")}
    for k, (_, fit, v, inv) in figs.items():
        print(f"  {k:7s} RMSE {fit.rmse:6.3f}  validation RMSE {v.rmse:6.3f} L/min   inverse on measured flow {inv.mae:6.3f} %")
    ratio = figs["pi-mod"][2].rmse / figs["pi-asym"][2].rmse
    print(f"  pi-mod / pi-asym validation RMSE: {ratio:.3f} (target <= 1.10); pi-mod inverse {figs['pi-mod'][3].mae:.3f} %"
          f" (target <= 0.61)")

    print("== closed loop, valvectl run (20 s, real time)")
    for label, cfg, model in (("PVP twin, ff = pi-mod", "config/valves/pvp/run.toml", None),
                              ("PVP twin, ff = paper's PI", "config/valves/pvp/run.toml", "valve_pi.json"),
                              ("make run (plant pi-asym, ff = pi)", "config/run.toml", None)):
        ff, pid = run(str(ROOT / cfg), "ff+kf", model), run(str(ROOT / cfg), "pid")
        print(f"  {label:36s} ff+kf IAE {ff['iae']:.3f} L, steady MAE {ff['steady_mae_lpm']:.3f} L/min;"
              f" pid IAE {pid['iae']:.3f} L;  IAE ratio {ff['iae'] / pid['iae']:.3f}")

    print("== feedforward cost per step (batch of one) against the 1 ms loop period")
    for kind, m in (("pi", figs["pi"][0]), ("pi-mod", figs["pi-mod"][0]), ("pi-asym", figs["pi-asym"][0])):
        bank = ffw.bank(m)
        s = ffw.init(bank, 50.0)
        ref = np.array([90.0])
        ffw.invert(bank, s, ref)  # compile (or load the cache) outside the timing
        n = 2000
        t0 = time.perf_counter()
        for _ in range(n):
            ffw.invert(bank, s, ref)
        print(f"  {kind:8s} invert {1e6 * (time.perf_counter() - t0) / n:7.1f} us")
    pz = fit_recording("preisach", rec).core
    g = pz.init(0.0)
    pz.step(g, 0.1)
    t0 = time.perf_counter()
    n = 200
    for _ in range(n):
        pz.step(g, 0.1)
    one = (time.perf_counter() - t0) / n
    print(f"  preisach forward evaluation {1e6 * one:.1f} us; a bisection inverse to 1e-12 (~45 evaluations):"
          f" {45e6 * one:.0f} us per step ({45 * one / 1e-3:.2f} of the loop period); not offered as feedforward")


if __name__ == "__main__":
    main()
