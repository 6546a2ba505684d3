"""Compile the kernels of the live loop and of the sweep into numba's cache, at install (``make setup``).

Numba compiles a kernel on its first call and keeps it in its on-disk cache
(``__pycache__`` beside the sources); later processes load it in
milliseconds. Run once after installing, this is ahead-of-time compilation
where it pays: the first ``valvectl run`` and ``valvectl sweep`` after
install then compile nothing (a sweep's kernel alone takes tens of seconds
to compile). It runs the shipped run configuration's words for a few steps:
the live loop's warm-up (every word's step, resume and switch:
:meth:`controller.supervisor.Supervisor.warm_up`) and valve
(:class:`plant_sim.plant.RunningPlant`), and the sweep's closed loop
(:func:`controller.sweep.simulate.closed_loop`), which have one signature each.

Usage: ``python -m controller.precompile [RUN.toml]``.
"""
from __future__ import annotations

import sys
import time


def precompile(config_path: str = "config/run.toml") -> float:
    """Compile (or load) every kernel of ``run`` and ``sweep`` for the configuration; returns seconds."""
    import numpy as np

    from models.model import load_model
    from plant_sim.plant import BatchPlant, Plant, load_plant

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
    margins.operating_point(valve, 60.0, cfg.loop.rate_hz)  # the sweep's margins run the valve on a ramp
    for word in control.MODES:
        p = controller_params(cfg, word, model)
        simulate.closed_loop(control.repeat(p, 2), BatchPlant([valve, valve], cfg.loop.rate_hz), np.full(3, 10.0),
                             cfg.loop.rate_hz, 1)
    return time.perf_counter() - t0


if __name__ == "__main__":
    print(f"kernels of run and sweep compiled into numba's cache in {precompile(*sys.argv[1:]):.1f} s")
