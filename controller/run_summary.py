"""The run summary of DESIGN.md (``S.json``) and the run plot.

Tracking figures cover the steps in the running state; ``steady_mae_lpm``
the running steps where the reference has not changed for at least 100 ms;
``iae`` is the integral of |ref - flow| over time in litres
(L/min x s / 60). Timing figures are over every step.
"""
from __future__ import annotations

import math

import numpy as np

from .loop import LoopResult
from .watchdog import RUNNING

STEADY_AFTER_S = 0.100


def _pct_us(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"p50": None, "p99": None, "max": None}
    p50, p99 = np.percentile(x, [50, 99])
    return {"p50": float(p50) * 1e6, "p99": float(p99) * 1e6, "max": float(np.max(x)) * 1e6}


def steady_mask(t_s: np.ndarray, ref_lpm: np.ndarray, after_s: float = STEADY_AFTER_S) -> np.ndarray:
    """True where the reference has been constant for at least ``after_s`` seconds."""
    changed = np.concatenate([[True], ref_lpm[1:] != ref_lpm[:-1]])
    t_change = np.maximum.accumulate(np.where(changed, t_s, -np.inf))
    return t_s - t_change >= after_s - 1e-9


def tracking(t_s, ref_lpm, flow_lpm, running) -> dict:
    """``mae_lpm, rmse_lpm, iae, steady_mae_lpm`` over the running steps (None when there are none)."""
    t_s, ref_lpm, flow_lpm = (np.asarray(v, dtype=np.float64) for v in (t_s, ref_lpm, flow_lpm))
    dt = np.diff(t_s, append=t_s[-1] + (np.median(np.diff(t_s)) if len(t_s) > 1 else 0.0))
    e = np.abs(ref_lpm - flow_lpm)
    run = np.asarray(running, dtype=bool)
    steady = run & steady_mask(t_s, ref_lpm)

    def mean(x, m):
        return float(np.mean(x[m])) if m.any() else None

    return {
        "mae_lpm": mean(e, run),
        "rmse_lpm": math.sqrt(mean(e * e, run)) if run.any() else None,
        "iae": float(np.sum(e[run] * dt[run]) / 60.0) if run.any() else None,
        "steady_mae_lpm": mean(e, steady),
    }


def summary(result: LoopResult, controller: str, plant: str) -> dict:
    """The run summary ``S.json`` of DESIGN.md."""
    c = result.columns
    return {
        "controller": controller,
        "plant": plant,
        "rate_hz": result.rate_hz,
        "steps": result.steps,
        "overruns": result.overruns,
        "lateness_us": _pct_us(c["lateness_s"]),
        "compute_us": _pct_us(c["compute_s"]),
        "tracking": tracking(c["t_s"], c["ref_lpm"], c["flow_lpm"], c["state"] == RUNNING),
        "faults": result.faults.to_list(),
    }


def summary_text(s: dict) -> str:
    """The summary as a few readable lines."""
    tr, la, co = s["tracking"], s["lateness_us"], s["compute_us"]

    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    lines = [
        f"controller {s['controller']} on {s['plant']}: {s['steps']} steps at {f(s['rate_hz'], '.1f')} Hz, "
        f"{s['overruns']} overruns",
        f"lateness us p50 {f(la['p50'], '.1f')} p99 {f(la['p99'], '.1f')} max {f(la['max'], '.0f')}; "
        f"compute us p50 {f(co['p50'], '.1f')} p99 {f(co['p99'], '.1f')} max {f(co['max'], '.0f')}",
        f"tracking: MAE {f(tr['mae_lpm'], '.3f')} L/min, RMSE {f(tr['rmse_lpm'], '.3f')} L/min, "
        f"IAE {f(tr['iae'], '.4f')} L, steady MAE {f(tr['steady_mae_lpm'], '.3f')} L/min",
        "faults: " + (", ".join(f"{x['kind']} x{x['count']} (first at {x['first_s']:.3f} s)" for x in s["faults"])
                      or "none"),
    ]
    return "\n".join(lines)


def run_plot(columns: dict, path: str, title: str = "") -> None:
    """Reference and measured flow, duty (with its feedforward part) and error against time, to PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = columns["t_s"]
    run = columns["state"] == RUNNING
    fig, ax = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    ax[0].plot(t, columns["ref_lpm"], lw=1.2, label="reference")
    ax[0].plot(t, columns["flow_lpm"], lw=0.7, label="measured flow")
    ax[0].set_ylabel("flow (L/min)")
    ax[0].legend(loc="upper right")
    ax[1].plot(t, columns["duty_pct"], lw=0.8, label="duty")
    ax[1].plot(t, columns["ff_duty_pct"], lw=0.6, ls="--", label="feedforward part")
    ax[1].set_ylabel("duty (%)")
    ax[1].legend(loc="upper right")
    err = np.where(run, columns["ref_lpm"] - columns["flow_lpm"], np.nan)
    ax[2].plot(t, err, lw=0.6, color="C3")
    ax[2].axhline(0, color="k", lw=0.5)
    ax[2].set_ylabel("error (L/min)")
    ax[2].set_xlabel("time (s)")
    if (~run).any():
        for a in ax:
            a.fill_between(t, 0, 1, where=~run, transform=a.get_xaxis_transform(), color="0.85", lw=0,
                           label="safe/fault")
    if title:
        ax[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
