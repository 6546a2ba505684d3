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
