"""Compile the kernels of the live loop and of the sweep into numba's cache, at install (``make setup``).

Numba compiles a kernel on its first call and keeps it in its on-disk cache
(``__pycache__`` beside the sources); later processes load it in
milliseconds. Run once after installing, this is ahead-of-time compilation
where it pays: the first ``valvectl run`` and ``valvectl sweep`` after
install then compile nothing (a sweep's kernel alone takes tens of seconds
to compile). It runs the shipped run configuration's words for a few steps:
the live loop's warm-up (every word's step, resume and switch:
:meth:`controller.supervisor.Supervisor.warm_up`), valve
(:class:`plant_sim.plant.RunningPlant`) and alarms, and the sweep's closed loop
(:func:`controller.sweep.simulate.closed_loop`), which have one signature each.
``--models`` compiles the rest: every model kind's fit, prediction and inverse, and the
diagnosis's kernels, on a short synthetic sweep (a fresh clone's test suite otherwise compiled
these during its first run: 24 of 39 kernels, about 100 s). The two parts share no kernel, so
``make setup`` runs them in two processes at once.

Usage: ``python -m controller.precompile [--models] [RUN.toml]``.
"""
from __future__ import annotations

import sys
import time


def precompile(config_path: str = "config/run.toml") -> float:
    """Compile (or load) every kernel of ``run`` and ``sweep`` for the configuration; returns seconds."""
    import numpy as np

    from models.model import load_model
    from plant_sim.plant import BatchPlant, Plant, load_plant

    from .alarms import Alarms
    from .config import controller_params, load_run_config, supervisor
    from .laws import control
    from .sweep import margins, simulate

    t0 = time.perf_counter()
    cfg = load_run_config(config_path)
    model = load_model(cfg.resolve(cfg[""]["model"]))
    valve = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
    plant = Plant(valve, cfg.loop.rate_hz)
    plant.running(plant.init(0.0)).step(10.0)
    supervisor(cfg, cfg[""]["controller"], model).warm_up(1.0 / cfg.loop.rate_hz, cfg.loop.safe_duty_pct)
    Alarms(cfg.loop.alarms, 0.0, 100.0)  # its kernel's entry point, resolved as the loop does
    margins.operating_point(valve, 60.0, cfg.loop.rate_hz)  # the sweep's margins run the valve on a ramp
    for word in control.MODES:
        p = controller_params(cfg, word, model)
        simulate.closed_loop(control.repeat(p, 2), BatchPlant([valve, valve], cfg.loop.rate_hz), np.full(3, 10.0),
                             cfg.loop.rate_hz, 1)
    return time.perf_counter() - t0


def precompile_models(config_path: str = "config/run.toml") -> float:
    """Compile (or load) every model kind's kernels (fit, predict, live step, inverse) and the
    diagnosis's; returns seconds."""
    import numpy as np

    from models.diagnose import effects
    from models.fitting import KINDS, fit_model
    from models.model import load_model

    from .config import load_run_config

    t0 = time.perf_counter()
    cfg = load_run_config(config_path)
    shipped = load_model(cfg.resolve(cfg[""]["model"]))
    # the paper's growing triangle sweep at 20 Hz, through the shipped model: hysteresis to fit
    t_s = np.arange(0.0, 60.0, 0.05)
    duty_pct = 50.0 + 45.0 * (t_s / t_s[-1]) * (2.0 / np.pi) * np.arcsin(np.sin(2.0 * np.pi * t_s / 6.0))
    flow_lpm, _ = shipped.predict(duty_pct)
    for kind in KINDS:
        model = fit_model(kind, t_s, duty_pct, flow_lpm, n=4 if kind != "bouc-wen" else None)
        model.predict(duty_pct)
        model.step(model.init(float(duty_pct[0])), float(duty_pct[1]))
        if model.inverse is not None:
            model.inverse_predict(flow_lpm)
    effects.generalized_play(np.linspace(0.0, 0.5, 4), np.linspace(-1.0, 1.0, 50), 0.1, 0.05)
    effects.first_order_lag(duty_pct, 20.0, 0.1, phase=0.5)
    x_unit = np.linspace(-1.0, 1.0, 50)
    effects.descending_lift(np.tile(x_unit[:, None], (1, 4)), x_unit, np.linspace(0.0, 0.5, 4))
    return time.perf_counter() - t0


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--models"]:
        print(f"model and diagnosis kernels compiled into numba's cache in {precompile_models(*args[1:]):.1f} s")
    else:
        print(f"kernels of run and sweep compiled into numba's cache in {precompile(*args):.1f} s")
