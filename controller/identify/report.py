"""``report.md`` of an identification, with its figures, and ``identify.json``.

Figures (PNG, next to the report): ``protocol.png`` (duty and flow against
time, phases shaded), ``loops.png`` (flow against duty on the fitted rows,
measured and the chosen model), ``steps.png`` (steps with the fitted lag and
delay). The report has Table 1 of the paper for this valve (every kind,
in-sample and on the held-out steps), the lag and delay with their
uncertainty, and the gains the sweep chose.
"""
from __future__ import annotations

import os

import numpy as np

from models.atomicfile import save_figure_atomic, write_text_atomic

from .dynamics import Dynamics, steps_plot

#: Said (report, stderr) when no step could be read without a stall.
NOT_CLEAN = ("no step was read without a stall of this machine: the lag and delay are from the least disturbed "
             "steps and likely too long; identify again on a quieter machine (or with the loop at real-time priority)")
from .estimate import Estimate, loops_plot, table
from .session import SessionResult
from .timeline import DAMAGED_UNOBSERVED, STALL_PERIODS, Damage

PHASE_COLORS = {"range": "tab:gray", "sweep": "tab:blue", "reversals": "tab:purple", "steps": "tab:green"}


def summary_json(res: SessionResult, est: Estimate | None = None, dyn: Dynamics | None = None,
                 tuning=None, damage: Damage | None = None, coil_ref_c: float | None = None) -> dict:
    """identify.json (DESIGN.md): ``model, validation, tau_s, delay_s, duration_s, aborted``, then details
    (``timeline``: what a busy machine cost the recording, :meth:`.timeline.Damage.to_json`; ``coil_ref_c``:
    the coil temperature the models' duty is referred to, when the valve published one)."""
    out = {
        "model": est.chosen if est else None,
        "validation": est.results[est.chosen].validation.to_dict() if est else None,
        "tau_s": dyn.tau_s if dyn else None,
        "delay_s": dyn.delay_s if dyn else None,
        "duration_s": res.duration_s,
        "aborted": res.aborted,
    }
    if res.reason:
        out["reason"] = res.reason
    if res.working_range:
        r = res.working_range
        out["working_range"] = {"lo_pct": r.lo_pct, "hi_pct": r.hi_pct, "flow_max_lpm": r.flow_max_lpm}
    if dyn:
        out["dynamics"] = dyn.to_json()
    if est:
        out["models"] = est.to_json()
    if tuning:
        out["controller"] = tuning.controller
        out["gains"] = {w: b["params"] for w, b in tuning.best.items()}
    if damage:
        out["timeline"] = damage.to_json()
    if coil_ref_c is not None:
        out["coil_ref_c"] = coil_ref_c
    out.update(steps=res.steps, overruns=res.overruns, faults=res.faults)
    return out


def protocol_plot(res: SessionResult, ax=None):
    """Duty and flow against time, the protocol's phases shaded; the figure."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(11, 4))
    else:
        fig = ax.figure
    t, c = res.columns["t_s"], res.columns
    step = max(1, len(t) // 20000)
    ax.plot(t[::step], c["flow_lpm"][::step], lw=0.5, color="tab:orange", label="flow (L/min)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("flow (L/min)")
    ax2 = ax.twinx()
    ax2.plot(t[::step], c["duty_pct"][::step], lw=0.6, color="k", label="duty (%)")
    ax2.set_ylabel("duty (%)")
    ph = res.phase
    edges = np.flatnonzero(ph[1:] != ph[:-1]) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(ph)]):
        name = str(ph[a])
        if name in PHASE_COLORS:
            ax.axvspan(t[a], t[b - 1], color=PHASE_COLORS[name], alpha=0.08)
            ax.text((t[a] + t[b - 1]) / 2, ax.get_ylim()[1] * 0.95, name, ha="center", fontsize=8)
    ax.set_title("identification protocol" + (f" (aborted: {res.reason})" if res.aborted else ""))
    fig.tight_layout()
    return fig


def write_report(out_dir: str, res: SessionResult, ident, tuning) -> str:
    """Write ``report.md`` and its PNGs to ``out_dir`` (``ident``: :class:`.analysis.Identification`);
    returns the report's path."""
    import matplotlib.pyplot as plt

    tl, est, dyn, d = ident.timeline, ident.estimate, ident.dynamics, ident.damage
    for name, fig in (("protocol.png", protocol_plot(res)),
                      ("loops.png", loops_plot(est, tl.duty_pct, tl.flow_lpm, tl.rate_hz, dyn)),
                      ("steps.png", steps_plot(dyn, res.columns["t_s"], res.columns["flow_lpm"]))):
        save_figure_atomic(fig, os.path.join(out_dir, name), dpi=110)
        plt.close(fig)
    r = res.working_range
    v = est.results[est.chosen].validation
    lines = [
        "# Valve identification",
        "",
        f"{res.duration_s:.0f} s of valve time, {res.steps} steps ({res.overruns} overruns); recording "
        "`identification.csv`.",
        "",
        "![protocol](protocol.png)",
        "",
        "## Timeline",
        f"Of {d.periods} periods of {1e3 / tl.rate_hz:g} ms, {d.missed} ({d.missed_share:.1%}) were missed "
        f"in {d.stalls} stalls of this machine (longest {d.longest_stall_ms:.0f} ms): the valve held the duty "
        "it had, and the fits and the models' figures below are on that timeline (the duty in "
        f"force at each period, the readings at their times; the steps are read at their rows' own times). "
        f"{d.unobserved_share:.1%} of the periods lie in reading gaps longer than {STALL_PERIODS:g} periods "
        f"(never scored): {d.unobserved_fit_share:.1%} of the fitted phases and {d.unobserved_steps_share:.1%} "
        f"of the steps (refused above {DAMAGED_UNOBSERVED:.0%}); longest gap {d.longest_gap_ms:.0f} ms.",
        *([] if not ident.warning else ["", f"**Warning:** {ident.warning}"]),
        "",
        "## Working range",
        f"Cracking at {r.lo_pct:.1f} % duty, fully open (or the flow ceiling) at {r.hi_pct:.1f} %, "
        f"largest flow {r.flow_max_lpm:.1f} L/min (the range ramp).",
        "",
        "## Lag and delay (step tests)",
        "| | median | standard error | spread over steps |",
        "| --- | ---: | ---: | ---: |",
        f"| lag tau | {dyn.tau_s * 1e3:.2f} ms | {dyn.tau_se_s * 1e3:.2f} ms | {dyn.tau_sd_s * 1e3:.2f} ms |",
        f"| delay | {dyn.delay_s * 1e3:.2f} ms | {dyn.delay_se_s * 1e3:.2f} ms | {dyn.delay_sd_s * 1e3:.2f} ms |",
        "",
        f"From {len(dyn.steps)} of {dyn.read} steps read ({dyn.disturbed} with a stall of this machine in "
        f"the transient); sensor noise {dyn.noise_lpm:.2f} L/min per reading. The delay is the "
        "loop's: the command-to-reading delay less one loop period, transport latency included.",
        *([] if dyn.clean else ["", f"**Warning:** {NOT_CLEAN}"]),
        "",
        "![steps](steps.png)",
        "",
        "## Table 1: models fitted on the sweep, validated on the held-out steps",
        "Figures in L/min against the measured flow (sensor noise included), every model behind the lag "
        "and delay above" + ("." if ident.coil_ref_c is None else
                             f", on the duty the magnetics saw referred to the coil at {ident.coil_ref_c:.1f} °C "
                             "(its first reading; copper +0.393 %/K)."),
        "",
        table(est),
        "",
        f"Feedforward: **{est.chosen}**, the invertible kind with the least validation RMSE "
        f"(MAE {v.mae:.2f}, RMSE {v.rmse:.2f} L/min, r {v.r:.4f}).",
        "",
        "![loops](loops.png)",
        "",
        "## Run configuration",
        f"`run.toml`: controller **{tuning.controller}**, `[valve] tau_s = {dyn.tau_s:.4f}`, "
        f"`delay_s = {dyn.delay_s:.4f}`; gains from a sweep on the identified valve (`plant.toml`) and its drifts "
        f"(`sweep.toml`, `sweep.csv`, {tuning.seconds:.0f} s), least worst-case IAE per controller:",
        "",
        "| controller | gains | worst IAE (L) | IAE nominal (L) |",
        "| --- | --- | ---: | ---: |",
    ]
    for word, b in tuning.best.items():
        gains = ", ".join(f"{k} = {x:.4g}" for k, x in b["params"].items() if k != "controller")
        lines.append(f"| {word} | {gains} | {b['worst_iae']:.4f} | {b['iae']:.4f} |")
    path = os.path.join(out_dir, "report.md")
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
