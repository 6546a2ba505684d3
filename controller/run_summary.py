"""The run summary of DESIGN.md (``S.json``), the run plot and the run report.

:class:`RunResult` is a finished run: ``summary()`` computes, ``plot()``
returns the figure (:func:`run_plot`, which draws into given axes or a new
figure and never switches matplotlib's backend), ``write_report(DIR)``
writes Markdown and PNG.

Tracking figures cover the steps in the running state; ``steady_mae_lpm``
the running steps where the reference has not changed for at least 100 ms;
``iae`` is the integral of |ref - flow| over time in litres
(L/min x s / 60). Timing figures are over every step.

Beside DESIGN.md's keys (all kept as they are): ``compute_cpu_us`` (p50, p99,
max), the thread's CPU time over each step's ``compute_us`` window, and
``steps_off_cpu``, the steps whose ``compute_us`` exceeded their CPU time by
more than :data:`OFF_CPU_US`: the thread stood off its CPU within the step
(host steal, or another thread of the guest), which the deadline pays for
all the same (README: A step in microseconds).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.report import write_report

from .loop import LoopResult
from .watchdog import RUNNING

STEADY_AFTER_S = 0.100
#: A step whose wall time exceeds its thread's CPU time by more than this, µs, counts in ``steps_off_cpu``.
OFF_CPU_US = 20.0
#: Window of the run plot's running mean of the error, s.
ERROR_MEAN_S = 0.050


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
        "compute_cpu_us": _pct_us(c["cpu_s"]),
        "steps_off_cpu": int(np.count_nonzero(c["compute_s"] - c["cpu_s"] > OFF_CPU_US * 1e-6)),
        "tracking": tracking(c["t_s"], c["ref_lpm"], c["flow_lpm"], c["state"] == RUNNING),
        "faults": result.faults.to_list(),
        "alarms": result.alarms.to_list() if result.alarms is not None else [],
    }


def summary_text(s: dict) -> str:
    """The summary as a few readable lines."""
    tr, la, co, cc = s["tracking"], s["lateness_us"], s["compute_us"], s["compute_cpu_us"]

    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    lines = [
        f"controller {s['controller']} on {s['plant']}: {s['steps']} steps at {f(s['rate_hz'], '.1f')} Hz, "
        f"{s['overruns']} overruns",
        f"lateness us p50 {f(la['p50'], '.1f')} p99 {f(la['p99'], '.1f')} max {f(la['max'], '.0f')}; "
        f"compute us p50 {f(co['p50'], '.1f')} p99 {f(co['p99'], '.1f')} max {f(co['max'], '.0f')}",
        f"compute CPU us (the thread's) p50 {f(cc['p50'], '.1f')} p99 {f(cc['p99'], '.1f')} max {f(cc['max'], '.0f')}; "
        f"{s['steps_off_cpu']} steps off CPU > {OFF_CPU_US:.0f} us",
        f"tracking: MAE {f(tr['mae_lpm'], '.3f')} L/min, RMSE {f(tr['rmse_lpm'], '.3f')} L/min, "
        f"IAE {f(tr['iae'], '.4f')} L, steady MAE {f(tr['steady_mae_lpm'], '.3f')} L/min",
        "faults: " + (", ".join(f"{x['kind']} x{x['count']} (first at {x['first_s']:.3f} s)" for x in s["faults"])
                      or "none"),
        "alarms: " + (", ".join(f"{x['kind']} x{x['count']} (first at {x['first_s']:.3f} s)"
                                for x in s.get("alarms", [])) or "none"),
    ]
    return "\n".join(lines)


def run_plot(columns: dict, ax=None, title: str = ""):
    """Reference and flow, the duty and its split, and the error against time; returns the figure.

    Parameters
    ----------
    columns : dict
        A run's columns (:attr:`controller.loop.LoopResult.columns`, or a run
        recording read back): ``t_s, ref_lpm, flow_lpm, duty_pct, ff_duty_pct,
        fb_duty_pct, state``; ``limit_duty_pct`` and ``controller`` when present.
    ax : sequence of three Axes, optional
        Where to draw (flow, duty, error); a new figure when None.
    title : str

    The error axis is symmetric-log, linear within ±1 L/min: the steady error
    of a few tenths of a L/min reads as well as the ±60 L/min of a breath's
    edges. Grey spans: not running (safe or fault); dotted lines: a switch of
    controller, labelled with the word taking over.
    """
    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(11, 9), layout="constrained")
        ax = fig.subplots(3, 1, sharex=True)
    else:
        fig = ax[0].figure
    t = np.asarray(columns["t_s"])
    state = np.asarray(columns["state"])
    run = state == RUNNING if state.dtype.kind in "iu" else state == "running"
    ax[0].plot(t, columns["ref_lpm"], lw=1.2, label="reference")
    ax[0].plot(t, columns["flow_lpm"], lw=0.7, label="measured flow")
    ax[0].set_ylabel("flow (L/min)")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, columns["duty_pct"], lw=0.9, color="k", label="duty applied")
    ax[1].plot(t, columns["ff_duty_pct"], lw=0.7, ls="--", label="feedforward")
    ax[1].plot(t, columns["fb_duty_pct"], lw=0.7, label="feedback law")
    if "limit_duty_pct" in columns:
        ax[1].plot(t, columns["limit_duty_pct"], lw=0.7, label="rate limit and clamp")
    ax[1].axhline(0, color="0.5", lw=0.4)
    ax[1].set_ylabel("duty (%)")
    ax[1].legend(loc="upper right", fontsize=8, ncol=2)
    err = np.where(run, np.asarray(columns["ref_lpm"]) - np.asarray(columns["flow_lpm"]), np.nan)
    ax[2].plot(t, err, lw=0.4, color="C3", alpha=0.6, label="per step")
    if len(t) > 1:  # the sensor noise averaged out: the steady error reads through it
        n = min(len(t), max(1, int(round(ERROR_MEAN_S / float(np.median(np.diff(t)))))))
        mean = np.convolve(np.nan_to_num(err), np.ones(n) / n, mode="same")
        ax[2].plot(t, np.where(run, mean, np.nan), lw=1.0, color="k", label=f"{ERROR_MEAN_S * 1e3:.0f} ms mean")
        ax[2].legend(loc="upper right", fontsize=8)
    ax[2].axhline(0, color="k", lw=0.5)
    ax[2].set_yscale("symlog", linthresh=1.0)
    steady = run & steady_mask(t, np.asarray(columns["ref_lpm"], dtype=float))
    if steady.any():
        mae = float(np.mean(np.abs(err[steady])))
        ax[2].set_title(f"steady MAE {mae:.3f} L/min (linear within ±1 L/min)", fontsize=9, loc="left")
    ax[2].set_ylabel("reference - flow (L/min)")
    ax[2].set_xlabel("time (s)")
    if (~run).any():
        for a in ax:
            a.fill_between(t, 0, 1, where=~run, transform=a.get_xaxis_transform(), color="0.85", lw=0)
    if "controller" in columns:
        words = np.asarray(columns["controller"])
        for i in np.flatnonzero(words[1:] != words[:-1]) + 1:
            for a in ax:
                a.axvline(t[i], color="0.3", ls=":", lw=0.8)
            ax[0].annotate(str(words[i]), (t[i], 1.0), xycoords=("data", "axes fraction"), fontsize=8,
                           va="top", ha="left")
    if title:
        ax[0].set_title(title)
    return fig


@dataclass
class RunResult:
    """A finished run with what names it: ``.summary()``, ``.plot()``, ``.write_report(DIR)``."""

    loop: LoopResult
    controller: str
    plant: str

    def summary(self) -> dict:
        return summary(self.loop, self.controller, self.plant)

    def plot(self, ax=None):
        return run_plot(self.loop.columns, ax, title=f"{self.controller} on {self.plant}")

    def write_report(self, folder) -> Path:
        """``folder/report.md``: the summary's figures, faults and alarms, and the run plot."""
        s = self.summary()
        tr, la, co, cc = s["tracking"], s["lateness_us"], s["compute_us"], s["compute_cpu_us"]

        def f(v, fmt=".4g"):
            return "-" if v is None else format(v, fmt)

        words = list(dict.fromkeys(self.loop.columns["controller"]))
        table = "\n".join([
            "| figure | value |", "| --- | --- |",
            f"| controller (in force over the run) | {' -> '.join(words) or s['controller']} |",
            f"| plant | {s['plant']} |",
            f"| steps, achieved rate | {s['steps']}, {f(s['rate_hz'], '.1f')} Hz |",
            f"| overruns | {s['overruns']} |",
            f"| lateness p50 / p99 / max | {f(la['p50'])} / {f(la['p99'])} / {f(la['max'])} us |",
            f"| compute p50 / p99 / max | {f(co['p50'])} / {f(co['p99'])} / {f(co['max'])} us |",
            f"| compute, the thread's CPU time, p50 / p99 / max | {f(cc['p50'])} / {f(cc['p99'])} / {f(cc['max'])} us |",
            f"| steps off CPU (wall > CPU + {OFF_CPU_US:.0f} us) | {s['steps_off_cpu']} |",
            f"| MAE, RMSE | {f(tr['mae_lpm'])}, {f(tr['rmse_lpm'])} L/min |",
            f"| IAE | {f(tr['iae'])} L |",
            f"| steady MAE (reference constant >= 100 ms) | {f(tr['steady_mae_lpm'])} L/min |",
        ])

        def events(items):
            return "\n".join(f"- `{x['kind']}`: {x['count']} x, first at {x['first_s']:.3f} s" for x in items) or "none"

        blocks = [table, "## Faults", events(s["faults"]), "## Alarms", events(s["alarms"]), "## The run", "{fig:run}",
                  "Duty split: duty = feedforward + feedback law + rate limit and clamp. Error axis symmetric-log."]
        return write_report(folder, f"Run: {self.controller} on {self.plant}", blocks, {"run": self.plot()})
