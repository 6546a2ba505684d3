"""Batched closed loop of a sweep: candidates x plant variants as one batch.

:func:`closed_loop` runs B candidates of one controller word against B
simulated valves in simulated time, with the live loop's timing convention
(the flow measured at step k is the valve's answer to the duty of step k-1)
but without its watchdog and transports. One compiled kernel runs the whole
batch: loop by loop, each through all its steps, with the live loop's own
law (:func:`controller.laws.control.law_step`) and valve
(:func:`plant_sim.kernel.plant_step`), so a loop's state stays in the cache
and no step returns to Python. Its rows equal, bit for bit, those of the
earlier form that stepped the whole batch once per period from Python.

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
from numba import njit

from controller.laws import control
from models.borrow import borrow
from plant_sim import kernel

from . import metrics


@dataclass(frozen=True)
class ClosedLoop:
    """Columns (N, B) of a batch closed-loop simulation, and per-candidate IAE (L).

    ``true_flow_lpm``: the flow at the sensor without sensor errors, of the plant step that gave
    each row's measurement.
    """

    t_s: np.ndarray
    ref_lpm: np.ndarray
    flow_lpm: np.ndarray
    duty_pct: np.ndarray
    true_flow_lpm: np.ndarray

    def iae(self) -> np.ndarray:
        """∫|ref - flow| dt in litres per candidate."""
        dt = self.t_s[1] - self.t_s[0]
        return np.sum(np.abs(self.ref_lpm[:, None] - self.flow_lpm), axis=0) * dt / 60.0


@njit(cache=True)
def _run(mode, has_lead, P, method, r, w, a, p_asym, h, g, offset, floor, r_inv, w_inv, h_inv, g_inv, closed, x0,
         dc, dh, fc, fh, margin, beta, X, Y, H, pos0, PP, PMP, PEV, keys, ms, xs, buf, k0, meas0, ref, ahead, preview, dt,
         work, flow, duty, true_flow):
    # Loop by loop, each through all its steps: its state stays in the cache, and no step returns
    # to Python. The law (control.law_step) and the valve (kernel.plant_step) are the live loop's.
    # borrowed views (models.borrow): the views of the laws' rows then cost no atomics
    bank = (borrow(method), borrow(r), borrow(w), borrow(a), borrow(p_asym), borrow(h), borrow(g), borrow(offset),
            borrow(floor), borrow(r_inv), borrow(w_inv), borrow(h_inv), borrow(g_inv), borrow(closed), borrow(x0),
            borrow(dc), borrow(dh), borrow(fc), borrow(fh), borrow(margin), borrow(beta))
    P, X, Y, H = borrow(P), borrow(X), borrow(Y), borrow(H)
    PP, PMP, PEV, keys, ms, xs, buf = borrow(PP), borrow(PMP), borrow(PEV), borrow(keys), borrow(ms), borrow(xs), borrow(buf)
    n = ref.shape[0]
    L = H.shape[1]
    work = borrow(work)  # the inverse's scratch
    for b in range(X.shape[0]):
        p, x, y, hist = P[b], X[b], Y[b], H[b]
        Pb, MPb, EVb, kb, msb, xb, bufb = PP[b], PMP[b], PEV[b], keys[b], ms[b], xs[b], buf[b]
        meas = meas0[b]
        k_old = pos0
        for k in range(n):
            k_new = (k_old + 1) % L
            d = control.law_step(mode, has_lead, p, x, bank, b, y, work, hist, k_old, k_new, ref[k], meas,
                                 ahead[k + preview[b]], dt, False)[0]
            if mode == control.FF_KF:
                k_old = k_new
            flow[b, k] = meas
            duty[b, k] = d
            if k + 1 < n:  # the valve's answer, measured at the next step
                meas, true_flow[b, k + 1], _, _ = kernel.plant_step(Pb, MPb, EVb, kb, msb, xb, bufb, k0 + k, d,
                                                                    False)


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
    kernel_params = params.kernel
    ref = np.array(ref_lpm, dtype=np.float64)  # a writable copy: one compiled signature whatever the caller holds
    n = len(ref)
    flow, duty, true_flow = np.empty((B, n)), np.empty((B, n)), np.empty((B, n))
    true_flow[:, 0] = out.true_flow_lpm
    preview = np.array(np.broadcast_to(np.asarray(preview_steps, dtype=np.int64), (B,)))  # writable, as ref
    ahead = np.concatenate([ref, np.full(int(preview.max(initial=0)), ref[-1])])
    _run(kernel_params.mode, kernel_params.lead, kernel_params.P, *kernel_params.bank, s.x, s.forward, s.hist,
         int(s.pos[0]), plant._P, plant._MP, plant._EV, plant._keys, ps.model, ps.x, ps.buf, ps.k, meas, ref, ahead,
         preview, dt, np.empty(s.forward.shape[1]), flow, duty, true_flow)
    return ClosedLoop(np.arange(n) * dt, ref, flow.T, duty.T, true_flow.T)


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
    res = closed_loop(params, bp, np.asarray(ref_lpm, dtype=np.float64), rate_hz, preview_steps)
    return Response(res.ref_lpm, res.flow_lpm.T, res.true_flow_lpm.T, res.duty_pct.T, 1.0 / rate_hz)


def figures(r: Response, n_variants: int, block: int = 64) -> dict:
    """The figures of :data:`controller.sweep.metrics.NAMES`, arrays (C, V).

    Computed ``block`` loops at a time (every figure is a loop's own): the temporaries of a block
    stay in the cache, where those of a whole batch (tens of MB each) would stream from memory.
    """
    parts = [metrics.tracking_figures(r.ref_lpm, r.flow_lpm[a:a + block], r.duty_pct[a:a + block], r.dt_s,
                                      step_flow_lpm=r.true_flow_lpm[a:a + block])
             for a in range(0, r.flow_lpm.shape[0], block)]
    return {k: np.concatenate([f[k] for f in parts]).reshape(-1, n_variants) for k in metrics.NAMES}
