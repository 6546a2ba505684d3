"""Closed-loop simulation of a batch of controllers on simulated valves, and the grid tuning of run.toml.

:func:`closed_loop` runs B candidates of one controller word against B
simulated valves in simulated time, with the loop's timing convention (the
flow measured at step k is the valve's answer to the duty of step k-1) but
without the watchdog and transports of the live loop: the same laws, stepped
as arrays.

:func:`grid_tune` is how the gains of ``config/run.toml`` were found: every
combination of a small grid is simulated on the run's valve and breath
profile, and the one with the least IAE wins.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .laws import control


@dataclass(frozen=True)
class ClosedLoop:
    """Columns (N, B) of a batch closed-loop simulation, and per-candidate IAE (L)."""

    t_s: np.ndarray
    ref_lpm: np.ndarray
    flow_lpm: np.ndarray
    duty_pct: np.ndarray

    def iae(self, skip_s: float = 0.0) -> np.ndarray:
        """∫|ref - flow| dt in litres per candidate, from ``skip_s`` on."""
        dt = self.t_s[1] - self.t_s[0]
        m = self.t_s >= skip_s
        return np.sum(np.abs(self.ref_lpm[m, None] - self.flow_lpm[m]), axis=0) * dt / 60.0


def closed_loop(params: control.ControllerParams, plant, ref_lpm: np.ndarray, rate_hz: float,
                preview_steps: int = 0, duty0_pct: float = 0.0) -> ClosedLoop:
    """Simulate B candidates against ``plant`` (a ``BatchPlant`` of B valves) over ``ref_lpm`` (N,).

    The feedforward sees the reference ``preview_steps`` ahead (the last value past the end).
    """
    dt = 1.0 / rate_hz
    B = params.batch
    ps = plant.init(np.full(B, duty0_pct))
    ps, out = plant.step(ps, np.full(B, duty0_pct))
    meas = out.flow_lpm.copy()
    s = control.init(params, meas, duty0_pct)
    n = len(ref_lpm)
    flow, duty = np.empty((n, B)), np.empty((n, B))
    ahead = np.concatenate([ref_lpm[preview_steps:], np.full(preview_steps, ref_lpm[-1])])
    for k in range(n):
        s, cmd = control.step(params, s, np.full(B, ref_lpm[k]), meas, dt, np.full(B, ahead[k]))
        flow[k], duty[k] = meas, cmd.duty_pct
        ps, out = plant.step(ps, cmd.duty_pct)
        meas = out.flow_lpm.copy()
    return ClosedLoop(np.arange(n) * dt, np.asarray(ref_lpm, dtype=np.float64), flow, duty)


def grid_tune(make_params, grid: dict[str, list[float]], make_plant, ref_lpm, rate_hz: float, preview_steps: int = 0,
              skip_s: float = 0.0):
    """Least-IAE point of a grid.

    Parameters
    ----------
    make_params : callable
        ``make_params(batch, **columns) -> ControllerParams`` with each grid
        name given as an array of shape (B,).
    grid : dict
        Name -> values; every combination is a candidate.
    make_plant : callable
        ``make_plant(batch) -> BatchPlant``.

    Returns
    -------
    best : dict
        The winning grid point.
    iae : ndarray
        IAE of every candidate (L), in ``itertools.product`` order.
    """
    names = list(grid)
    points = list(itertools.product(*(grid[k] for k in names)))
    cols = {k: np.array([p[i] for p in points]) for i, k in enumerate(names)}
    res = closed_loop(make_params(len(points), **cols), make_plant(len(points)), ref_lpm, rate_hz, preview_steps)
    iae = res.iae(skip_s)
    best = int(np.nanargmin(iae))
    return dict(zip(names, points[best])), iae


#: The grids behind the gains of config/run.toml (feedforward lead lag in s, PID gains in %
#: per L/min, per L/min s and % s per L/min, Kalman noise std per period in L/min).
GRIDS = {
    "pid": {"kp": [0.05, 0.1, 0.2, 0.4, 0.8], "ki": [2.0, 5.0, 10.0, 20.0, 40.0, 80.0], "kd": [0.0, 0.001, 0.003]},
    "ff+pid": {"kp": [0.1, 0.2, 0.4, 0.8], "ki": [3.0, 10.0, 20.0], "kd": [0.0, 0.001], "lead_lag_s": [0.003, 0.005, 0.008]},
    "ff+kf": {"q_flow_lpm": [3.0, 10.0, 30.0], "q_bias_lpm": [0.003, 0.01, 0.03], "lead_lag_s": [0.003, 0.005, 0.008]},
}


def tune(config_path: str = "config/run.toml") -> dict:
    """Grid-tune every feedback controller on the run's simulated valve and profile; ``{word: (best, iae)}``."""
    import dataclasses

    from models.model import load_model
    from plant_sim.plant import BatchPlant, load_plant
    from plant_sim.protocols import BreathProfile

    from .config import controller_params, load_run_config, preview_s
    from .laws import feedforward as ffw
    from .laws import kalman, pid

    cfg = load_run_config(config_path)
    top, rate = cfg[""], cfg["loop"]["rate_hz"]
    model = load_model(cfg.resolve(top["model"]))
    pp = load_plant(cfg.resolve(top["plant_config"]), effects=cfg["effects"])
    ref = BreathProfile(**cfg["profile"]).value(np.arange(int(top["duration_s"] * rate)) / rate)
    preview = int(round(preview_s(cfg, "profile") * rate))
    valve, dt = cfg["valve"], 1.0 / rate

    def maker(word):
        base = controller_params(cfg, word, model)

        def make(batch, **cols):
            def tile(obj):
                return dataclasses.replace(obj, **{f.name: np.repeat(getattr(obj, f.name), batch, axis=0)
                                                   for f in dataclasses.fields(obj)
                                                   if isinstance(getattr(obj, f.name), np.ndarray)})

            kw = {k: tile(getattr(base, k)) for k in ("limits", "inverse", "forward") if getattr(base, k) is not None}
            if word != "pid":
                kw["lead"] = ffw.LeadParams.make(batch, valve["tau_s"], cols.pop("lead_lag_s"))
            if word == "ff+kf":
                kw["kf"] = kalman.KFParams.make(valve["tau_s"], valve["delay_s"], dt, cols["q_flow_lpm"],
                                                cols["q_bias_lpm"], cfg["kf"]["r_lpm"], batch)
            else:
                g = cfg["pid" if word == "pid" else "ff_pid"]
                kw["pid"] = pid.PIDParams.make(batch, **{**{k: g[k] for k in ("tf_s", "tt_s")}, **cols})
            return dataclasses.replace(base, **kw)

        return make

    out = {}
    for word, grid in GRIDS.items():
        best, iae = grid_tune(maker(word), grid, lambda b: BatchPlant([pp] * b, rate, top["seed"]), ref, rate,
                              preview if word != "pid" else 0)
        out[word] = (best, float(np.nanmin(iae)))
    return out


if __name__ == "__main__":
    import sys

    for word, (best, iae) in tune(*sys.argv[1:]).items():
        print(f"{word}: IAE {iae:.4f} L at {best}")
