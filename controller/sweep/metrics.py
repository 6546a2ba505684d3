"""Tracking figures of closed-loop responses, vectorized over a batch of candidates.

All responses of a batch share one reference ``ref_lpm`` (shape (N,)) sampled
every ``dt_s``; flows and duties are arrays of shape (B, N).

- ``iae``: integral of |ref - flow| dt, in L (L/min x s / 60), as the run
  summary of DESIGN.md defines it, so a sweep's IAE compares with
  ``valvectl run``'s ``tracking.iae``;
- ``ise``: integral of (ref - flow)² dt, (L/min)² s;
- ``steady_mae_lpm``: mean |ref - flow| over the samples where the reference
  has been constant for at least 100 ms (DESIGN.md's ``steady_mae_lpm``, the
  run summary's mask :func:`controller.run_summary.steady_mask`);
- ``duty_tv``: total variation of the duty, sum |duty[k] - duty[k-1]|, % (the
  control effort: how much the coil and the plunger are worked);
- step figures, per transition of the reference between two holds (runs of
  constant reference at least ``min_hold_s`` long, levels differing by at
  least ``min_step_frac`` of the reference span), the worst over the
  transitions of the profile:

  * ``overshoot_lpm``: largest excursion beyond the new level, in the
    direction of the step, until the new hold ends (0 if none);
  * ``rise_ms``: 10-90 % rise time (falls are measured the same way, mirrored);
  * ``settle_ms``: time from the start of the transition until the response
    stays within ``band_frac`` (2 %) of the step size of the new level for the
    rest of the hold.

  Crossing instants are interpolated linearly between samples. A response
  that never reaches 90 % or never settles within the hold gets ``inf``; a
  reference without transitions gives ``nan`` for the step figures.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: CSV column order of the figures (DESIGN.md, sweep).
NAMES = ("iae", "ise", "overshoot_lpm", "rise_ms", "settle_ms", "steady_mae_lpm", "duty_tv")


@dataclass(frozen=True)
class Transition:
    """A reference step between two holds: samples ``[start, stop)``, levels before and after."""

    start: int
    stop: int
    before_lpm: float
    after_lpm: float


def holds(ref_lpm: np.ndarray, dt_s: float, min_hold_s: float) -> list[tuple[int, int]]:
    """Runs ``[start, stop)`` of constant reference lasting at least ``min_hold_s``."""
    ref = np.asarray(ref_lpm, dtype=np.float64)
    edges = np.flatnonzero(np.diff(ref) != 0.0) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [len(ref)]])
    n_min = max(1, int(round(min_hold_s / dt_s)))
    return [(int(a), int(b)) for a, b in zip(starts, stops) if b - a >= n_min]


def transitions(ref_lpm: np.ndarray, dt_s: float, min_hold_s: float = 0.05,
                min_step_frac: float = 0.1) -> list[Transition]:
    """Steps of the reference between consecutive holds (instantaneous or ramped).

    A transition starts at the first sample after a hold and lasts until the
    end of the next hold.
    """
    ref = np.asarray(ref_lpm, dtype=np.float64)
    span = float(ref.max() - ref.min()) if ref.size else 0.0
    hs = holds(ref, dt_s, min_hold_s)
    out = []
    for (_, e0), (s1, e1) in zip(hs[:-1], hs[1:]):
        before, after = ref[e0 - 1], ref[s1]
        if span > 0 and abs(after - before) >= min_step_frac * span:
            out.append(Transition(e0, e1, float(before), float(after)))
    return out


def _first_crossing_s(p: np.ndarray, level: float, dt_s: float) -> np.ndarray:
    """Time (s from column 0) at which each row of ``p`` first reaches ``level``, interpolated; inf if never."""
    above = p >= level
    hit = above.any(axis=1)
    i = np.argmax(above, axis=1)
    rows = np.arange(p.shape[0])
    prev = p[rows, np.maximum(i - 1, 0)]
    cur = p[rows, i]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(i > 0, (level - prev) / (cur - prev), 1.0)
    t = (i - 1 + frac) * dt_s
    return np.where(hit, np.where(i > 0, t, 0.0), np.inf)


def step_figures(flow_lpm: np.ndarray, tr: Transition, dt_s: float, band_frac: float = 0.02):
    """``(overshoot_lpm, rise_s, settle_s)`` per row for one transition, time from its start."""
    y = np.atleast_2d(np.asarray(flow_lpm, dtype=np.float64))[:, tr.start:tr.stop]
    delta = tr.after_lpm - tr.before_lpm
    sign = np.sign(delta)
    progress = sign * (y - tr.before_lpm) / abs(delta)  # 0 at the old level, 1 at the new
    overshoot = np.maximum(np.max(sign * (y - tr.after_lpm), axis=1), 0.0)
    t90 = _first_crossing_s(progress, 0.9, dt_s)
    t10 = _first_crossing_s(progress, 0.1, dt_s)
    rise = np.full_like(t90, np.inf)
    reached = np.isfinite(t90)  # reaching 90 % passes 10 % first
    rise[reached] = t90[reached] - t10[reached]
    # Settling: reverse time, find where the error first leaves the band, i.e. the last exit.
    err = np.abs(y - tr.after_lpm)[:, ::-1]
    band = band_frac * abs(delta)
    w = y.shape[1]
    outside = err > band
    any_out = outside.any(axis=1)
    j = np.argmax(outside, axis=1)  # reversed index of the last sample outside the band
    last_out = w - 1 - j
    rows = np.arange(y.shape[0])
    e_out = err[rows, j]
    e_in = err[rows, np.maximum(j - 1, 0)]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(j > 0, (e_out - band) / (e_out - e_in), 0.0)
    settle = np.where(~any_out, 0.0, np.where(j == 0, np.inf, (last_out + frac) * dt_s))
    return overshoot, rise, settle


def tracking_figures(ref_lpm, flow_lpm, duty_pct, dt_s: float, step_flow_lpm=None,
                     min_hold_s: float = 0.05, min_step_frac: float = 0.1, band_frac: float = 0.02) -> dict:
    """All figures of :data:`NAMES`, arrays of shape (B,).

    Parameters
    ----------
    ref_lpm : ndarray, shape (N,)
        Reference flow, L/min.
    flow_lpm : ndarray, shape (B, N)
        Measured flow the controller tracked, L/min (``iae``, ``ise``, ``steady_mae_lpm``).
    duty_pct : ndarray, shape (B, N)
        Applied duty, %.
    dt_s : float
        Sample period, s.
    step_flow_lpm : ndarray, shape (B, N), optional
        Flow for the step figures (the sweep passes the flow without sensor
        noise, whose 0.5 L/min would otherwise decide the settling band);
        ``flow_lpm`` if absent.
    """
    ref = np.asarray(ref_lpm, dtype=np.float64)
    y = np.atleast_2d(np.asarray(flow_lpm, dtype=np.float64))
    u = np.atleast_2d(np.asarray(duty_pct, dtype=np.float64))
    ys = y if step_flow_lpm is None else np.atleast_2d(np.asarray(step_flow_lpm, dtype=np.float64))
    from controller.run_summary import steady_mask

    e = ref - y
    steady = steady_mask(np.arange(len(ref)) * dt_s, ref)
    out = {
        "iae": np.sum(np.abs(e), axis=1) * dt_s / 60.0,
        "ise": np.sum(e * e, axis=1) * dt_s,
        "steady_mae_lpm": np.mean(np.abs(e[:, steady]), axis=1) if steady.any() else np.full(len(y), np.nan),
        "duty_tv": np.sum(np.abs(np.diff(u, axis=1)), axis=1),
    }
    trs = transitions(ref, dt_s, min_hold_s, min_step_frac)
    if trs:
        figs = np.array([step_figures(ys, tr, dt_s, band_frac) for tr in trs])  # (T, 3, B)
        worst = figs.max(axis=0)
        out["overshoot_lpm"], out["rise_ms"], out["settle_ms"] = worst[0], worst[1] * 1e3, worst[2] * 1e3
    else:
        out["overshoot_lpm"] = out["rise_ms"] = out["settle_ms"] = np.full(len(y), np.nan)
    return {k: out[k] for k in NAMES}


def worst_case(figures_by_variant: dict) -> dict:
    """Worst over plant variants (axis 1 of each (C, V) array): every figure is worse when larger."""
    return {k: np.max(v, axis=1) for k, v in figures_by_variant.items()}
