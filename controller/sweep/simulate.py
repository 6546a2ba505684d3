"""Batched closed loop of a sweep: candidates x plant variants as one batch.

:func:`closed_loop` runs B candidates of one controller word against B
simulated valves in simulated time, with the live loop's timing convention
(the flow measured at step k is the valve's answer to the duty of step k-1)
but without its watchdog and transports: the live loop's compiled laws
(:func:`controller.laws.control.advance`) for a batch of B instead of one.

A group of C candidates of one controller word is repeated over the V plant
variants (candidate-major: loop ``c * V + v`` is candidate c on variant v)
and simulated as one batch of C V loops against a
:class:`plant_sim.plant.BatchPlant` of the C V valves. Every loop's valve gets the same noise seed (common
random numbers: candidates are compared on the same noise, and a candidate
run alone by ``valvectl run`` with that seed sees that same noise).

The figures of :mod:`controller.sweep.metrics` come out as arrays (C, V):
IAE, ISE and steady MAE on the measured flow the controller tracked, as the
run summary has them; the step figures on the flow without sensor noise
(``true_flow_lpm``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from controller.laws import control

from . import metrics


@dataclass(frozen=True)
class ClosedLoop:
    """Columns (N, B) of a batch closed-loop simulation, and per-candidate IAE (L)."""

    t_s: np.ndarray
    ref_lpm: np.ndarray
    flow_lpm: np.ndarray
    duty_pct: np.ndarray

    def iae(self) -> np.ndarray:
        """∫|ref - flow| dt in litres per candidate."""
        dt = self.t_s[1] - self.t_s[0]
        return np.sum(np.abs(self.ref_lpm[:, None] - self.flow_lpm), axis=0) * dt / 60.0


def closed_loop(params: control.ControllerParams, plant, ref_lpm: np.ndarray, rate_hz: float,
                preview_steps: int | np.ndarray = 0, duty0_pct: float = 0.0) -> ClosedLoop:
    """Simulate B candidates against ``plant`` (a ``BatchPlant`` of B valves) over ``ref_lpm`` (N,).

    The feedforward sees the reference ``preview_steps`` ahead (the last value past the end);
    an array (B,) gives each candidate its own preview.
    """
    dt = 1.0 / rate_hz
    B = params.batch
    ps = plant.init(np.full(B, duty0_pct))
    ps, out = plant.step(ps, np.full(B, duty0_pct))
    meas = np.ascontiguousarray(out.flow_lpm)
    s = control.init(params, meas, duty0_pct)
    kernel = params.kernel
    n = len(ref_lpm)
    flow, duty = np.empty((n, B)), np.empty((n, B))
    preview = np.broadcast_to(np.asarray(preview_steps, dtype=np.int64), (B,))
    ahead = np.concatenate([ref_lpm, np.full(int(preview.max(initial=0)), ref_lpm[-1])])
    ref_now, cmd = np.empty(B), np.empty((B, 4))
    for k in range(n):
        ref_now.fill(ref_lpm[k])
        control.advance(kernel, s, ref_now, meas, ahead[k + preview], dt, cmd)
        flow[k], duty[k] = meas, cmd[:, 0]
        ps, out = plant.step(ps, duty[k])
        meas = np.ascontiguousarray(out.flow_lpm)
    return ClosedLoop(np.arange(n) * dt, np.asarray(ref_lpm, dtype=np.float64), flow, duty)


def stack_params(items: list):
    """One batch from several (frozen dataclasses of per-candidate arrays, e.g. ControllerParams).

    Arrays are joined along the candidate axis, nested parameter dataclasses
    likewise; everything else (the controller word, flags) must agree.
    """
    first = items[0]
    if any(type(x) is not type(first) for x in items):
        raise ValueError(f"cannot batch a {type(first).__name__} with a "
                         f"{next(type(x).__name__ for x in items if type(x) is not type(first))}")
    if dataclasses.is_dataclass(first):
        return dataclasses.replace(first, **{f.name: stack_params([getattr(x, f.name) for x in items])
                                             for f in dataclasses.fields(first)})
    if isinstance(first, np.ndarray):
        return np.concatenate(items)
    if any(x != first for x in items):
        raise ValueError(f"cannot batch differing values {first!r} and {next(x for x in items if x != first)!r}")
    return first


class _Recorder:
    """A BatchPlant that keeps the flow without sensor errors of every step (for the step figures)."""

    def __init__(self, plant, n_steps: int):
        self.plant = plant
        self.true_flow_lpm = np.empty((n_steps + 1, len(plant)))
        self.k = 0

    def init(self, duty0_pct):
        return self.plant.init(duty0_pct)

    def step(self, state, duty_pct):
        state, out = self.plant.step(state, duty_pct)
        if self.k < len(self.true_flow_lpm):
            self.true_flow_lpm[self.k] = out.true_flow_lpm
        self.k += 1
        return state, out


@dataclass(frozen=True)
class Response:
    """Closed-loop columns of C V loops, arrays (C V, N), and the reference (N,)."""

    ref_lpm: np.ndarray
    flow_lpm: np.ndarray
    true_flow_lpm: np.ndarray
    duty_pct: np.ndarray
    dt_s: float


def response(params: control.ControllerParams, plants: list, ref_lpm: np.ndarray, rate_hz: float,
             seed: int = 0, preview_steps: int | np.ndarray = 0) -> Response:
    """Simulate ``params`` (batch C V, candidate-major) on the V ``plants`` (PlantParams) repeated C times.

    ``preview_steps``: how far ahead the feedforward reads the reference, one for all or one per loop.
    """
    from plant_sim.plant import BatchPlant

    V = len(plants)
    if params.batch % V:
        raise ValueError(f"batch {params.batch} is not a multiple of {V} plant variants")
    n_loops = params.batch
    bp = BatchPlant(list(plants) * (n_loops // V), rate_hz, [seed] * n_loops)
    rec = _Recorder(bp, len(ref_lpm))
    res = closed_loop(params, rec, np.asarray(ref_lpm, dtype=np.float64), rate_hz, preview_steps)
    # flow measured at step k answers the duty of step k-1: recorder row k is that plant step
    return Response(res.ref_lpm, res.flow_lpm.T, rec.true_flow_lpm[:len(ref_lpm)].T, res.duty_pct.T, 1.0 / rate_hz)


def figures(r: Response, n_variants: int) -> dict:
    """The figures of :data:`controller.sweep.metrics.NAMES`, arrays (C, V)."""
    f = metrics.tracking_figures(r.ref_lpm, r.flow_lpm, r.duty_pct, r.dt_s, step_flow_lpm=r.true_flow_lpm)
    return {k: v.reshape(-1, n_variants) for k, v in f.items()}
