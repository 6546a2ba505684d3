"""The grid tuning of run.toml, on the sweep's batched closed loop (:func:`controller.sweep.simulate.closed_loop`).

:func:`grid_tune` is how the gains of ``config/run.toml`` were found: every
combination of a small grid is simulated on the run's breath profile, on
the run's valve and on variants of it with model errors
(:data:`VARIANTS`), and the one with the least mean IAE wins: tuned on the
nominal valve alone, the feedback of ``ff+kf`` would learn that the
feedforward needs no correction.
"""
from __future__ import annotations

import itertools

import numpy as np

from .laws import control
from .sweep.simulate import closed_loop


def grid_tune(make_params, grid: dict[str, list[float]], plants: list, ref_lpm, rate_hz: float,
              preview_steps: int = 0, seed: int = 0):
    """Grid point with the least IAE, averaged over several simulated valves.

    Parameters
    ----------
    make_params : callable
        ``make_params(batch, **columns) -> ControllerParams`` with each grid
        name given as an array of shape (B,).
    grid : dict
        Name -> values; every combination is a candidate.
    plants : list of PlantParams
        Valves every candidate is simulated on (the nominal one and variants
        with model errors, so the feedback is tuned for errors it must fix).

    Returns
    -------
    best : dict
        The winning grid point.
    iae : ndarray, shape (len(plants), candidates)
        IAE (L) of every candidate on every valve, candidates in ``itertools.product`` order.
    """
    from plant_sim.plant import BatchPlant

    names = list(grid)
    points = list(itertools.product(*(grid[k] for k in names)))
    n, v = len(points), len(plants)
    cols = {k: np.tile(np.array([p[i] for p in points]), v) for i, k in enumerate(names)}
    batch = BatchPlant([pp for pp in plants for _ in range(n)], rate_hz, seed)
    res = closed_loop(make_params(n * v, **cols), batch, ref_lpm, rate_hz, preview_steps)
    iae = res.iae().reshape(v, n)
    best = int(np.nanargmin(iae.mean(axis=0)))
    return dict(zip(names, points[best])), iae


#: The grids behind the gains of config/run.toml (feedforward lead lag in s, PID gains in %
#: per L/min, per L/min s and % s per L/min, Kalman noise std per period in L/min).
GRIDS = {
    "pid": {"kp": [0.05, 0.1, 0.2, 0.4, 0.8], "ki": [2.0, 5.0, 10.0, 20.0, 40.0, 80.0], "kd": [0.0, 0.001, 0.003]},
    "ff+pid": {"kp": [0.1, 0.2, 0.4, 0.8], "ki": [3.0, 10.0, 20.0], "kd": [0.0, 0.001], "lead_lag_s": [0.003, 0.005, 0.008]},
    "ff+kf": {"q_flow_lpm": [3.0, 10.0, 30.0], "q_bias_lpm": [0.003, 0.01, 0.03], "lead_lag_s": [0.003, 0.005, 0.008]},
}


#: Model errors the tuning also simulates, on top of the run's valve (effect words of DESIGN.md).
VARIANTS = ({"asymmetric_hysteresis": 0.3}, {"supply_pressure": 0.1, "coil_heating": 40.0})


def tune(config_path: str = "config/run.toml") -> dict:
    """Grid-tune every feedback controller on the run's profile and valves.

    Returns ``{word: (best, iae)}``, ``iae`` the best point's IAE (L) on the
    nominal valve and on each of :data:`VARIANTS`.
    """
    import dataclasses

    from models.model import load_model
    from plant_sim.plant import load_plant
    from plant_sim.protocols import BreathProfile

    from .config import controller_params, load_run_config, preview_s
    from .laws import feedforward as ffw
    from .laws import kalman, pid

    cfg = load_run_config(config_path)
    top, rate = cfg[""], cfg["loop"]["rate_hz"]
    model = load_model(cfg.resolve(top["model"]))
    plants = [load_plant(cfg.resolve(top["plant_config"]), effects={**cfg["effects"], **v}) for v in ({},) + VARIANTS]
    ref = BreathProfile(**cfg["profile"]).value(np.arange(int(top["duration_s"] * rate)) / rate)
    preview = int(round(preview_s(cfg, "profile") * rate))
    valve, dt = cfg["valve"], 1.0 / rate

    def maker(word):
        base = controller_params(cfg, word, model)

        def make(batch, **cols):
            kw = {}
            if word != "pid":
                kw["lead"] = ffw.LeadParams.make(batch, valve["tau_s"], cols.pop("lead_lag_s"))
            if word == "ff+kf":
                kw["kf"] = kalman.KFParams.make(valve["tau_s"], valve["delay_s"], dt, cols["q_flow_lpm"],
                                                cols["q_bias_lpm"], cfg["kf"]["r_lpm"], batch)
            else:
                g = cfg["pid" if word == "pid" else "ff_pid"]
                kw["pid"] = pid.PIDParams.make(batch, **{**{k: g[k] for k in ("tf_s", "tt_s")}, **cols})
            return dataclasses.replace(control.repeat(base, batch), **kw)

        return make

    out = {}
    for word, grid in GRIDS.items():
        best, iae = grid_tune(maker(word), grid, plants, ref, rate, preview if word != "pid" else 0, top["seed"])
        out[word] = (best, iae[:, int(np.nanargmin(iae.mean(axis=0)))].round(4).tolist())
    return out


if __name__ == "__main__":
    import sys

    for word, (best, iae) in tune(*sys.argv[1:]).items():
        print(f"{word}: IAE (L) nominal {iae[0]}, variants {iae[1:]} at {best}")
