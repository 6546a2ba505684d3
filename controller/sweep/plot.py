"""Sweep pictures: the Pareto front of tracking against control effort, and a heatmap over two settings.

:func:`pareto_front` and :func:`heatmap_response` compute; :func:`sweep_plot`
draws them (matplotlib Agg, PNG).
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


def sweep_plot(table: dict, path: str, objective: str, effort: str = "duty_tv", heat: Heatmap | None = None,
               default_index: int | None = None, best_index: int | None = None, title: str = "") -> None:
    """Pareto front of ``objective`` against ``effort`` (all candidates, by controller word) and the heatmap."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = np.asarray(table[objective], dtype=np.float64)
    e = np.asarray(table[effort], dtype=np.float64)
    words = np.asarray(table["controller"])
    ncol = 2 if heat is not None else 1
    fig, ax = plt.subplots(1, ncol, figsize=(6.5 * ncol, 5.2), squeeze=False)
    a = ax[0, 0]
    for w in dict.fromkeys(words):
        m = words == w
        a.scatter(e[m], f[m], s=6, alpha=0.5, label=w)
    front = pareto_front(e, f)
    a.plot(e[front], f[front], "k-", lw=1.2, label="Pareto front")
    for idx, marker, label in ((default_index, "s", "default"), (best_index, "*", "best")):
        if idx is not None:
            a.plot(e[idx], f[idx], marker, ms=12, mfc="none", mec="C3", mew=1.8, label=label)
    a.set_xlabel(f"control effort: {effort} (%)")
    a.set_ylabel(f"{objective} (L)")
    a.set_yscale("log")
    if np.nanmin(np.where(e > 0, e, np.nan)) * 10 < np.nanmax(e):
        a.set_xscale("log")
    a.legend(fontsize=8, loc="upper right")
    a.set_title("tracking against effort")
    if heat is not None:
        h = ax[0, 1]
        from matplotlib.colors import LogNorm

        positive = np.nanmin(heat.value) > 0 if np.isfinite(heat.value).any() else False
        im = h.pcolormesh(heat.x_edges, heat.y_edges, heat.value, shading="flat", cmap="viridis_r",
                          norm=LogNorm() if positive else None)
        from matplotlib.ticker import NullFormatter

        for log, axis, scale in ((heat.x_log, h.xaxis, h.set_xscale), (heat.y_log, h.yaxis, h.set_yscale)):
            if log:
                scale("log")
                axis.set_minor_formatter(NullFormatter())
        h.set_xlabel(heat.x_name)
        h.set_ylabel(heat.y_name)
        h.set_title(f"least {objective} per cell (L)")
        fig.colorbar(im, ax=h)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
