"""Locate a mismatch: where, and how big, the residual of a model is.

Residual ``e = measured - predicted`` (L/min) is summarised over time
windows, duty and flow regions, the branch of the loop (the direction of
the last duty motion: a hysteresis model's state), and the time since the
last step or reversal of the duty. :func:`where` describes where one
effect's correction (augmented minus previous prediction) concentrates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A duty change faster than this (%/s) is a step rather than a ramp (a valve command ramps at a few %/s).
STEP_PCT_PER_S = 200.0
#: Time-since-event bins (s).
EVENT_BINS_S = (0.0, 0.1, 0.5, 2.0, 10.0, np.inf)


def branch(duty_pct: np.ndarray) -> np.ndarray:
    """+1 on an ascending branch, -1 on a descending one (sign of the last duty motion), 0 before any."""
    d = np.diff(duty_pct, prepend=duty_pct[0])
    s = np.sign(d)
    idx = np.where(s != 0, np.arange(len(s)), 0)
    np.maximum.accumulate(idx, out=idx)
    out = s[idx]
    return out


def since_event(t_s: np.ndarray, duty_pct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seconds since the last step (duty faster than STEP_PCT_PER_S) and since the last reversal."""
    d = np.diff(duty_pct, prepend=duty_pct[0]) / np.diff(t_s, prepend=t_s[0] - 1.0)
    b = branch(duty_pct)
    rev = np.zeros(len(t_s), dtype=bool)
    rev[1:] = (b[1:] != b[:-1]) & (b[:-1] != 0)
    out = []
    for ev in (np.abs(d) > STEP_PCT_PER_S, rev):
        last = np.where(ev, t_s, -np.inf)
        np.maximum.accumulate(last, out=last)
        out.append(t_s - last)
    return out[0], out[1]


def _binned(x, e, edges):
    rows = []
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    for i in range(len(edges) - 1):
        m = k == i
        if m.any():
            rows.append({"lo": float(edges[i]), "hi": float(edges[i + 1]), "n": int(m.sum()),
                         "mean": float(e[m].mean()), "rms": float(np.sqrt(np.mean(e[m] ** 2)))})
    return rows


@dataclass(frozen=True)
class Location:
    """Residual summaries (L/min); each table is a list of ``{"lo","hi","n","mean","rms"}``.

    Attributes
    ----------
    rms : float
        Overall residual RMS.
    windows, duty, flow : list of dict
        By time window (s), duty region (%) and flow region (L/min).
    branches : dict
        ``ascending``/``descending`` -> ``{"n","mean","rms"}``.
    after_step, after_reversal : list of dict
        By time since the last step / reversal (s).
    """

    rms: float
    windows: list
    duty: list
    flow: list
    branches: dict
    after_step: list
    after_reversal: list

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def locate(t_s: np.ndarray, duty_pct: np.ndarray, flow_lpm: np.ndarray, pred_lpm: np.ndarray,
           n_windows: int = 12, n_bins: int = 8) -> Location:
    """Where the residual ``flow - pred`` is, and how big."""
    e = flow_lpm - pred_lpm
    b = branch(duty_pct)
    br = {}
    for name, v in (("ascending", 1), ("descending", -1)):
        m = b == v
        if m.any():
            br[name] = {"n": int(m.sum()), "mean": float(e[m].mean()), "rms": float(np.sqrt(np.mean(e[m] ** 2)))}
    s_step, s_rev = since_event(t_s, duty_pct)
    return Location(
        rms=float(np.sqrt(np.mean(e * e))),
        windows=_binned(t_s, e, np.linspace(t_s[0], t_s[-1], n_windows + 1)),
        duty=_binned(duty_pct, e, np.linspace(duty_pct.min(), duty_pct.max(), n_bins + 1)),
        flow=_binned(flow_lpm, e, np.linspace(flow_lpm.min(), flow_lpm.max(), n_bins + 1)),
        branches=br,
        after_step=_binned(s_step, e, np.array(EVENT_BINS_S)),
        after_reversal=_binned(s_rev, e, np.array(EVENT_BINS_S)),
    )


def _span(x: np.ndarray, w: np.ndarray, share: float = 0.8) -> tuple[float, float]:
    """Shortest central range of ``x`` holding ``share`` of the weight ``w`` (10 %..90 % quantiles)."""
    o = np.argsort(x)
    c = np.cumsum(w[o])
    c /= c[-1]
    lo = x[o][np.searchsorted(c, (1 - share) / 2)]
    hi = x[o][min(np.searchsorted(c, 1 - (1 - share) / 2), len(o) - 1)]
    return float(lo), float(hi)


def where(t_s: np.ndarray, duty_pct: np.ndarray, flow_lpm: np.ndarray, delta_lpm: np.ndarray) -> str:
    """Where a correction ``delta`` (augmented - previous prediction, L/min) concentrates, in words."""
    w = delta_lpm ** 2
    if not np.any(w > 0):
        return "nowhere (no correction)"
    parts = []
    b = branch(duty_pct)
    for name, v in (("descending", -1), ("ascending", 1)):
        share = w[b == v].sum() / w.sum()
        if share > 0.65:
            parts.append(f"{name} branch ({100 * share:.0f} % of the correction)")
    s_step, s_rev = since_event(t_s, duty_pct)
    for name, s in (("steps", s_step), ("reversals", s_rev)):
        for lim in (0.1, 0.5, 2.0):
            share = w[s < lim].sum() / w.sum()
            frac_t = np.mean(s < lim)
            if share > 0.6 and share > 2 * frac_t:
                parts.append(f"within {lim:g} s after {name} ({100 * share:.0f} % of the correction in "
                             f"{100 * frac_t:.0f} % of the time)")
                break
    dlo, dhi = _span(duty_pct, w)
    qlo, qhi = _span(flow_lpm, w)
    parts.append(f"duty {dlo:.1f}-{dhi:.1f} %")
    parts.append(f"flow {qlo:.0f}-{qhi:.0f} L/min")
    tlo, thi = _span(t_s, w)
    dur = t_s[-1] - t_s[0]
    if thi - tlo < 0.6 * dur:
        parts.append(f"mostly t = {tlo:.0f}-{thi:.0f} s")
    else:
        parts.append("throughout the recording")
    rms = float(np.sqrt(np.mean(w)))
    return f"{', '.join(parts)}; correction RMS {rms:.3g} L/min, peak {np.max(np.abs(delta_lpm)):.3g} L/min"
