"""Show a diagnosis: D.json, the per-row predictions (P.csv) and a Markdown report with plots.

Compute and draw are split: :func:`models.diagnose.diagnose_response`
computes, :func:`diagnose_plot` returns the figures (no global matplotlib backend switch) and
:func:`write_report` writes the Markdown that shows them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomicfile import save_figure_atomic, write_text_atomic
from ..model import write_json_atomic
from ..recording import write_recording
from . import Diagnosis
from .residuals import branch
from .words import VOCABULARY

#: Most points drawn per time series (plots decimate beyond this).
PLOT_POINTS = 20000


def write_json(diag: Diagnosis, path) -> None:
    """D.json, written atomically."""
    write_json_atomic(path, diag.to_json())


def write_predictions(diag: Diagnosis, path) -> None:
    """P.csv: ``t_s, flow_lpm, baseline_lpm, augmented_lpm, holdout``, one row per recording row."""
    write_recording(path, {"t_s": diag.t_s, "flow_lpm": diag.flow_lpm, "baseline_lpm": diag.baseline_lpm,
                           "augmented_lpm": diag.augmented_lpm, "holdout": diag.holdout.astype(int)})


def _every(n: int) -> slice:
    return slice(None, None, max(1, n // PLOT_POINTS))


def _shade_holdout(ax, diag: Diagnosis) -> None:
    h = diag.holdout.astype(int)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], h, [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(diag.t_s[a], diag.t_s[b - 1], color="0.9", lw=0)


def _figure(rows: int, cols: int, figsize, sharex: bool = False):
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, cols, sharex=sharex)


def diagnose_plot(diag: Diagnosis) -> dict:
    """The report's figures, ``{file name: matplotlib Figure}``.

    ``residuals.png``: residual before and after over time (holdout shaded);
    ``location.png``: where the baseline residual is (duty, flow, branch, after steps);
    ``finding_N_<effect>.png``: each finding's correction against the residual it explains.
    """
    figs = {}
    s = _every(len(diag.t_s))
    e0 = diag.flow_lpm - diag.baseline_lpm
    e1 = diag.flow_lpm - diag.augmented_lpm

    fig, ax = _figure(2, 1, (10, 6), sharex=True)
    _shade_holdout(ax[0], diag)
    ax[0].plot(diag.t_s[s], diag.flow_lpm[s], lw=0.6, label="measured")
    ax[0].plot(diag.t_s[s], diag.augmented_lpm[s], lw=0.6, label="augmented")
    ax[0].set_ylabel("flow (L/min)")
    ax[0].legend(loc="upper right", fontsize=8)
    _shade_holdout(ax[1], diag)
    ax[1].plot(diag.t_s[s], e0[s], lw=0.5, label=f"baseline (RMSE {np.sqrt(np.mean(e0 ** 2)):.3g})")
    ax[1].plot(diag.t_s[s], e1[s], lw=0.5, label=f"augmented (RMSE {np.sqrt(np.mean(e1 ** 2)):.3g})")
    ax[1].set_xlabel("t (s); grey: holdout rows")
    ax[1].set_ylabel("residual (L/min)")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    figs["residuals.png"] = fig

    loc = diag.location
    fig, ax = _figure(2, 2, (10, 6))
    for a, table, label in ((ax[0, 0], loc.duty, "duty (%)"), (ax[0, 1], loc.flow, "flow (L/min)"),
                            (ax[1, 1], loc.after_step, "time since step (s, bins)")):
        if label.startswith("time"):
            xs = np.arange(len(table))
            a.set_xticks(xs, [f"{r['lo']:g}-{r['hi']:g}" for r in table], fontsize=7)
        else:
            xs = [(r["lo"] + r["hi"]) / 2 for r in table]
        a.bar(xs, [r["rms"] for r in table], width=0.8 * (np.diff(xs).min() if len(xs) > 1 else 1), alpha=0.4,
              label="RMS")
        a.plot(xs, [r["mean"] for r in table], "o-", color="C3", label="mean")
        a.set_xlabel(label)
        a.set_ylabel("baseline residual (L/min)")
        a.legend(fontsize=7)
    b = branch(diag.duty_pct)
    for v, name, c in ((1, "ascending", "C0"), (-1, "descending", "C1")):
        m = (b == v)
        m[np.arange(len(m)) % max(1, len(m) // PLOT_POINTS) != 0] = False
        ax[1, 0].plot(diag.flow_lpm[m], e0[m], ".", ms=1, color=c, label=name)
    ax[1, 0].set_xlabel("flow (L/min)")
    ax[1, 0].set_ylabel("baseline residual (L/min)")
    ax[1, 0].legend(fontsize=7, markerscale=8)
    fig.tight_layout()
    figs["location.png"] = fig

    for i, (f, pred, prev) in enumerate(zip(diag.findings, diag.steps_lpm, diag.before_lpm), start=1):
        delta = pred - prev
        resid = diag.flow_lpm - prev
        fig, ax = _figure(1, 2, (10, 3.8))
        k = np.argmax(np.abs(delta))
        span = max(2.0, (diag.t_s[-1] - diag.t_s[0]) / 20)
        w = (diag.t_s > diag.t_s[k] - span) & (diag.t_s < diag.t_s[k] + span)
        if VOCABULARY[f.effect].whole_plot:
            w[:] = True
        ws = np.flatnonzero(w)[_every(int(w.sum()))]
        ax[0].plot(diag.t_s[ws], resid[ws], lw=0.5, label="residual before")
        ax[0].plot(diag.t_s[ws], delta[ws], lw=1.2, label=f"{f.effect} correction")
        ax[0].set_xlabel("t (s)")
        ax[0].set_ylabel("L/min")
        ax[0].legend(fontsize=7)
        h = diag.holdout
        hs = np.flatnonzero(h)[_every(int(h.sum()))]
        ax[1].plot(delta[hs], resid[hs], ".", ms=1)
        lim = np.array([float(np.min(delta)), float(np.max(delta))])
        ax[1].plot(lim, lim, "k--", lw=0.8, label="slope 1: the correction is the residual")
        ax[1].plot(lim, f.slope * lim, "C3-", lw=1.0,
                   label=f"holdout fit: slope {f.slope:.2f}, correlation {f.correlation:.2f}")
        ax[1].legend(fontsize=7)
        ax[1].set_xlabel("correction (L/min)")
        ax[1].set_ylabel("residual before, holdout rows (L/min)")
        ptxt = ", ".join(f"{k_} = {v:.3g}" for k_, v in f.params.items())
        fig.suptitle(f"{f.effect}: {ptxt}", fontsize=9)
        fig.tight_layout()
        figs[f"finding_{i}_{f.effect}.png"] = fig
    return figs


def write_report(diag: Diagnosis, folder, source: str = "") -> Path:
    """``folder/report.md`` with the figures of :func:`diagnose_plot`; returns its path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figs = diagnose_plot(diag)
    for name, fig in figs.items():
        save_figure_atomic(fig, folder / name, dpi=110)
    files = {"residuals": "residuals.png", "location": "location.png", **{n: n for n in figs}}
    b = diag.baseline
    m = diag.model
    lines = [f"# Diagnosis{': ' + source if source else ''}", "",
             f"Baseline: {m['baseline']['source']} — MAE {b.mae:.3f} L/min, RMSE {b.rmse:.3f} L/min, r {b.r:.5f} "
             f"(whole recording); holdout RMSE {m['baseline']['holdout']['rmse']:.3f} L/min, "
             f"augmented {m['augmented']['holdout']['rmse']:.3f} L/min.", "",
             f"Holdout: {100 * m['validation']['holdout_fraction']:.0f} % of the rows in "
             f"{m['validation']['blocks'] // 4} blocks of {m['validation']['block_s']:.1f} s spread over the recording, "
             f"never used to fit anything; decisions on {m['validation']['cv_folds']} blocked cross-validation folds "
             "of the other rows." + (f" {m['validation']['holdout_undecided_rows']} holdout rows between the training "
                                     "rows that place a cracking duty are not scored (any setting between them fits "
                                     "the training rows alike)." if m['validation'].get('holdout_undecided_rows') else ""),
             "", "## Findings", ""]
    if not diag.findings:
        lines += ["None: no effect lowered the held-out error by its calibrated margin.", ""]
    for i, f in enumerate(diag.findings, start=1):
        lines += [f"### {i}. `{f.effect}` (score {f.score:.3f})", "",
                  f"- where: {f.where}", f"- evidence: {f.evidence}",
                  f"- holdout RMSE {f.holdout_rmse_before:.4f} -> {f.holdout_rmse_after:.4f} L/min",
                  "- parameters: " + ", ".join(f"`{k}` = {v:.4g}" for k, v in f.params.items()), "",
                  f"![{f.effect}]({files[f'finding_{i}_{f.effect}.png']})", ""]
    lines += ["## Residual before and after", "", f"![residuals]({files['residuals']})", "",
              "## Where the baseline residual is", "", f"![location]({files['location']})", "",
              "| branch | rows | mean (L/min) | RMS (L/min) |", "| --- | --- | --- | --- |"]
    for k, v in diag.location.branches.items():
        lines.append(f"| {k} | {v['n']} | {v['mean']:.3f} | {v['rms']:.3f} |")
    lines += ["", "| time window (s) | mean (L/min) | RMS (L/min) |", "| --- | --- | --- |"]
    for r in diag.location.windows:
        lines.append(f"| {r['lo']:.0f}-{r['hi']:.0f} | {r['mean']:.3f} | {r['rms']:.3f} |")
    lines += ["", "## Not named", ""]
    for k, v in {**m["rejected"], **m["not_identifiable"]}.items():
        lines.append(f"- `{k}`: {v}")
    path = folder / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
