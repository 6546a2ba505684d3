"""Sweep pictures: the Pareto front of tracking against control effort, and a heatmap over two settings.

:func:`pareto_front`, :func:`heatmap_response` and :func:`winner_heatmap` (the
winning controller word's own settings, with units) compute; :func:`sweep_plot`
draws them and returns the figure; :func:`write_sweep_report` writes Markdown + PNG.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def pareto_front(a, b) -> np.ndarray:
    """Indices of the points not dominated in (``a``, ``b``), both to minimize, ordered by ``a``.

    A point is dominated when another is no worse in both and better in one.
    Non-finite points never belong to the front.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(a) & np.isfinite(b))
    order = ok[np.lexsort((b[ok], a[ok]))]  # by a, ties by b
    front, best_b = [], np.inf
    for i in order:
        if b[i] < best_b:
            front.append(i)
            best_b = b[i]
    return np.array(front, dtype=np.int64)


@dataclass(frozen=True)
class Heatmap:
    """Least value of a figure per cell of two settings.

    Attributes
    ----------
    x_edges, y_edges : ndarray
        Cell edges (one more than cells); log-spaced for settings spanning a decade or more.
    value : ndarray, shape (ny, nx)
        Least figure over the candidates in each cell (nan for empty cells).
    x_log, y_log : bool
    """

    x_name: str
    y_name: str
    x_edges: np.ndarray
    y_edges: np.ndarray
    value: np.ndarray
    x_log: bool
    y_log: bool


def _edges(v: np.ndarray, bins: int) -> tuple[np.ndarray, bool]:
    u = np.unique(v[np.isfinite(v)])
    log = u.size > 1 and u[0] > 0 and u[-1] / u[0] >= 10
    w = np.log10(u) if log else u
    if u.size <= bins:  # a grid: one cell per value
        mid = (w[1:] + w[:-1]) / 2 if u.size > 1 else np.array([])
        step = (w[-1] - w[0]) / max(u.size - 1, 1) or 1.0
        e = np.concatenate([[w[0] - step / 2], mid, [w[-1] + step / 2]])
    else:
        e = np.linspace(w[0], w[-1], bins + 1)
    return (10 ** e if log else e), log


def heatmap_response(x, y, figure, x_name: str, y_name: str, bins: int = 12) -> Heatmap:
    """The least ``figure`` per cell of settings ``x`` and ``y`` (the best the other settings achieve there)."""
    x, y, f = (np.asarray(v, dtype=np.float64) for v in (x, y, figure))
    xe, xl = _edges(x, bins)
    ye, yl = _edges(y, bins)
    ix = np.clip(np.searchsorted(xe, x, side="right") - 1, 0, len(xe) - 2)
    iy = np.clip(np.searchsorted(ye, y, side="right") - 1, 0, len(ye) - 2)
    value = np.full((len(ye) - 1, len(xe) - 1), np.inf)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(f)
    np.minimum.at(value, (iy[ok], ix[ok]), f[ok])
    value[np.isinf(value)] = np.nan
    return Heatmap(x_name, y_name, xe, ye, value, xl, yl)


#: Units of the swept settings, by key name (section.key: the key decides).
UNITS = {"kp": "% per L/min", "ki": "% per (L/min s)", "kd": "% s per L/min", "q_flow_lpm": "L/min",
         "q_bias_lpm": "L/min", "r_lpm": "L/min"}


def unit_of(setting: str) -> str:
    """The unit of a swept setting such as ``ff_pid.kp`` or ``valve.tau_s`` (from its name)."""
    key = setting.rsplit(".", 1)[-1]
    if key in UNITS:
        return UNITS[key]
    for suffix, unit in (("_s", "s"), ("_lpm", "L/min"), ("_pct", "%"), ("_bar", "bar"), ("_hz", "Hz")):
        if key.endswith(suffix):
            return unit
    return "-"


def winner_settings(table: dict, best_index: int, preferred=()) -> list[str]:
    """Two settings of the winning controller word to map: ``preferred`` when both apply to it, else the
    two it was swept over most widely (most distinct values among its candidates)."""
    words = np.asarray(table["controller"])
    mine = words == words[best_index]

    def spread(name):
        v = np.array([np.nan if x is None else x for x in np.asarray(table[name], dtype=object)[mine]], dtype=float)
        return 0 if np.isnan(v[np.flatnonzero(mine).tolist().index(best_index)]) else len(np.unique(v[np.isfinite(v)]))

    numeric = [k for k in table if "." in k and k != "controller"]
    candidates = {k: spread(k) for k in numeric}
    if len(preferred) == 2 and all(candidates.get(k, 0) > 1 for k in preferred):
        return list(preferred)
    ranked = sorted((k for k, n in candidates.items() if n > 1), key=lambda k: -candidates[k])
    return ranked[:2]


def winner_heatmap(table: dict, objective: str, best_index: int, preferred=()) -> Heatmap | None:
    """:func:`heatmap_response` over the winning word's candidates and two of its settings (with units)."""
    names = winner_settings(table, best_index, preferred)
    if len(names) < 2:
        return None
    mine = np.asarray(table["controller"]) == np.asarray(table["controller"])[best_index]
    x, y = (np.array([np.nan if v is None else v for v in np.asarray(table[n], dtype=object)[mine]], dtype=float)
            for n in names)
    f = np.asarray(table[objective], dtype=np.float64)[mine]
    word = np.asarray(table["controller"])[best_index]
    return heatmap_response(x, y, f, f"{word}: {names[0]} ({unit_of(names[0])})",
                            f"{word}: {names[1]} ({unit_of(names[1])})")


def sweep_plot(table: dict, objective: str, effort: str = "duty_tv", heat: Heatmap | None = None,
               default_index: int | None = None, best_index: int | None = None, title: str = "", ax=None,
               best_xy: tuple | None = None):
    """Pareto front of ``objective`` against ``effort`` (all candidates, by controller word) and the heatmap.

    ``ax``: one Axes, or two when ``heat`` is given; a new figure when None. ``best_xy``: the best
    candidate's two heatmap settings, marked on the map. Returns the figure.
    """
    f = np.asarray(table[objective], dtype=np.float64)
    e = np.asarray(table[effort], dtype=np.float64)
    words = np.asarray(table["controller"])
    ncol = 2 if heat is not None else 1
    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.5 * ncol, 5.2), layout="constrained")
        ax = fig.subplots(1, ncol, squeeze=False)[0]
    else:
        ax = np.atleast_1d(ax)
        fig = ax[0].figure
    a = ax[0]
    for w in dict.fromkeys(words):
        m = words == w
        a.scatter(e[m], f[m], s=6, alpha=0.5, label=w)
    front = pareto_front(e, f)
    a.plot(e[front], f[front], "k-", lw=1.2, label="Pareto front")
    for idx, marker, label in ((default_index, "s", "default"), (best_index, "*", "best")):
        if idx is not None:
            a.plot(e[idx], f[idx], marker, ms=12, mfc="none", mec="C3", mew=1.8, label=f"{label} ({words[idx]})")
    a.set_xlabel(f"control effort: {effort} (%)")
    a.set_ylabel(f"{objective} (L)")
    a.set_yscale("log")
    if np.nanmin(np.where(e > 0, e, np.nan)) * 10 < np.nanmax(e):
        a.set_xscale("log")
    a.legend(fontsize=8, loc="upper right")
    a.set_title("tracking against effort")
    if heat is not None:
        h = ax[1]
        from matplotlib.colors import LogNorm
        from matplotlib.ticker import NullFormatter

        positive = np.nanmin(heat.value) > 0 if np.isfinite(heat.value).any() else False
        im = h.pcolormesh(heat.x_edges, heat.y_edges, heat.value, shading="flat", cmap="viridis_r",
                          norm=LogNorm() if positive else None)
        for log, axis, scale in ((heat.x_log, h.xaxis, h.set_xscale), (heat.y_log, h.yaxis, h.set_yscale)):
            if log:
                scale("log")
                axis.set_minor_formatter(NullFormatter())
        if best_xy is not None:
            h.plot(*best_xy, "*", ms=14, mfc="none", mec="C3", mew=1.8)
        h.set_xlabel(heat.x_name)
        h.set_ylabel(heat.y_name)
        h.set_title(f"least {objective} per cell (L)")
        fig.colorbar(im, ax=h)
    if title:
        fig.suptitle(title)
    return fig


def write_sweep_report(folder, summary: dict, objective: str, fig):
    """``folder/report.md``: the default and the best candidate with their parameters, and the figure."""
    from models.report import write_report

    def params(p):
        return "\n".join(f"| {k} | {v:.4g} {unit_of(k) if unit_of(k) != '-' else ''} |" if isinstance(v, float)
                         else f"| {k} | {v} |" for k, v in p.items())

    blocks = [f"{summary['candidates']} candidates in {summary['seconds']:.1f} s; objective `{objective}`."]
    for name in ("default", "best"):
        d = summary[name]
        figs = ", ".join(f"{k} {d[k]:.4g}" for k in ("iae", objective) if isinstance(d.get(k), float))
        blocks += [f"## {name}: {d['params'].get('controller')} ({figs})", "| parameter | value |\n| --- | --- |\n"
                   + params(d["params"])]
    blocks.append("{fig:sweep}")
    return write_report(folder, "Tuning sweep", blocks, {"sweep": fig})
