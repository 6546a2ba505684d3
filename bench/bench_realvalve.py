"""Real valves: the figures of issue 12, with their baselines, in one run.

Prints
- the PVP sweep (a real SMC PVQ31): pi-mod's RMSE and its inverse fed the measured flow (duty MAE
  over rows >= 2 L/min) against the paper's PI;
- the bench recordings: pi-mod's validation RMSE against pi-asym's, and its inverse on measured flow;
- closed loop (`valvectl run`, real time): ff+kf against pid on the PVP twin
  (config/valves/pvp/run.toml), the same with the paper's PI as the feedforward, and `make run`'s
  configuration (plant kind != feedforward kind);
- the feedforward's cost per loop step for each invertible kind (Preisach: the 1275-relay numerical
  inverse), against the 1 ms loop period, and the loop's own compute time with each on the PVP twin.
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
from models.model import save_model  # noqa: E402
from models.metrics import metrics  # noqa: E402
from models.recording import read_recording  # noqa: E402
from models import preisach  # noqa: E402


def fit_figures(kind, rec, val=None):
    m = fit_recording(kind, rec)
    fit = metrics(rec.flow_lpm, m.predict(rec.duty_pct)[0])
    v = evaluate(m, val.duty_pct, val.flow_lpm) if val is not None else None
    return m, fit, v, inverse_on_measured_flow(m, rec)


def run(config, controller, model=None):
    """``valvectl run`` of ``config`` (optionally another feedforward model file); its S.json."""
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
            return json.load(open(out))
        finally:
            if cfg != config:
                os.remove(cfg)


def main():
    print("== PVP sweep (SMC PVQ31, ../shared/data/external/pvp_valve_sweep.csv)")
    pvp = read_recording(DATA / "external" / "pvp_valve_sweep.csv")
    for kind in ("pi", "preisach", "pi-mod"):
        _, fit, _, inv = fit_figures(kind, pvp)
        print(f"  {kind:8s} RMSE {fit.rmse:6.3f} L/min   inverse on measured flow: duty MAE {inv.mae:6.3f} %"
              f"   (targets for pi-mod: <= 2.0 L/min, <= 1.0 %)")

    print("== bench recordings (fit on identification, validate on validation)")
    rec, val = read_recording(DATA / "bench_identification.csv"), read_recording(DATA / "bench_validation.csv")
    figs = {k: fit_figures(k, rec, val) for k in ("pi", "pi-asym", "preisach", "pi-mod")}
    for k, (_, fit, v, inv) in figs.items():
        print(f"  {k:8s} RMSE {fit.rmse:6.3f}  validation RMSE {v.rmse:6.3f} L/min   inverse on measured flow {inv.mae:6.3f} %")
    ratio = figs["pi-mod"][2].rmse / figs["pi-asym"][2].rmse
    print(f"  pi-mod / pi-asym validation RMSE: {ratio:.3f} (target <= 1.10); pi-mod inverse {figs['pi-mod'][3].mae:.3f} %"
          f" (target <= 0.61)")

    print("== closed loop, valvectl run (20 s, real time)")
    with tempfile.TemporaryDirectory() as tmp:
        pvp_preisach = os.path.join(tmp, "pvp_preisach.json")
        save_model(fit_recording("preisach", pvp), pvp_preisach)
        pids = {}
        for label, cfg, model in (("PVP twin, ff = pi-mod", "config/valves/pvp/run.toml", None),
                                  ("PVP twin, ff = paper's PI", "config/valves/pvp/run.toml", "valve_pi.json"),
                                  ("PVP twin, ff = preisach", "config/valves/pvp/run.toml", pvp_preisach),
                                  ("make run (plant pi-asym, ff = pi)", "config/run.toml", None)):
            if cfg not in pids:  # the baseline, once per configuration
                pids[cfg] = run(str(ROOT / cfg), "pid")
            ff, pid = run(str(ROOT / cfg), "ff+kf", model), pids[cfg]
            t, tp = ff["tracking"], pid["tracking"]
            print(f"  {label:36s} ff+kf IAE {t['iae']:.3f} L, steady MAE {t['steady_mae_lpm']:.3f} L/min,"
                  f" compute p99 {ff['compute_us']['p99']:.0f} us; pid IAE {tp['iae']:.3f} L,"
                  f" compute p99 {pid['compute_us']['p99']:.0f} us;  IAE ratio {t['iae'] / tp['iae']:.3f}")

    print("== feedforward cost per step (batch of one, from Python) against the 1 ms loop period")
    models = {k: figs[k][0] for k in ("pi", "pi-mod", "pi-asym", "preisach")}
    for kind, m in models.items():
        bank = ffw.bank(m)
        s = ffw.init(bank, 50.0)
        ffw.invert(bank, s, np.array([90.0]))  # compile (or load the cache) outside the timing
        n = 2000
        refs = 40.0 + 100.0 * np.random.default_rng(0).random(n)
        t0 = time.perf_counter()
        for k in range(n):
            ffw.invert(bank, s, refs[k:k + 1])
        print(f"  {kind:8s} invert {1e6 * (time.perf_counter() - t0) / n:7.1f} us")
    pz = models["preisach"].core
    g = pz.init(0.0)
    preisach.solve_input(pz.alpha, pz.beta, pz.mu, g, 0.1, -1.0, 1.0)
    n = 2000
    targets = np.linspace(-0.8, 0.8, n)
    t0 = time.perf_counter()
    for k in range(n):
        preisach.solve_input(pz.alpha, pz.beta, pz.mu, g, targets[k], -1.0, 1.0)
    print(f"  preisach numerical inverse alone ({len(pz.mu)} relays): {1e6 * (time.perf_counter() - t0) / n:.1f} us"
          f" per step (budget 100 us)")


if __name__ == "__main__":
    main()
