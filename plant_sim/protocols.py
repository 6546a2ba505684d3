"""Excitation protocols for the valve (duty %) and breath profiles for the flow reference.

Duty protocols are functions ``f(rate_hz, duration_s, seed=0, **options) ->
ndarray`` of duty % at ``rate_hz``, ``round(duration_s * rate_hz)`` samples,
registered by name in :data:`PROTOCOLS`:

- ``paper_identification``: the paper's Fig. 2 signal (§2.2), a sinusoid of
  growing amplitude between 38 and 72 % duty, never faster than 0.4 %/s;
- ``steps``: steps between levels with holds;
- ``ramps``: triangles between two levels at mixed rates, with holds;
- ``random_holds``: random levels held for random times;
- ``sines``: sine segments of decreasing period.

:class:`BreathProfile` is the ventilator's inspiratory flow reference: a pure
function of time, so the live loop and batched sweeps share it.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np

from models.recording import MAX_RATE_HZ, MAX_SAMPLES, MIN_RATE_HZ, InputError, read_table

#: Identified duty range of the paper's bench (§2.2): 38 % is the last closed state,
#: 72 % just above full open.
LO_PCT, HI_PCT = 38.0, 72.0


def _samples(rate_hz: float, duration_s: float, what: str = "--duration") -> int:
    """Samples of ``duration_s`` at ``rate_hz``, checked before anything of that size is allocated."""
    if not (math.isfinite(rate_hz) and MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
        raise InputError(f"--rate: must be within {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz (got {rate_hz:g})")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"{what}: must be a positive number of seconds (got {duration_s:g})")
    if duration_s * rate_hz > MAX_SAMPLES:
        raise InputError(f"{what}: {duration_s:g} s at {rate_hz:g} Hz is {duration_s * rate_hz:.3g} samples "
                         f"(at most {MAX_SAMPLES:.0e})")
    return max(1, int(round(duration_s * rate_hz)))


def _fit(x: np.ndarray, n: int) -> np.ndarray:
    """Truncate to ``n`` samples, or hold the last value up to ``n``."""
    if len(x) >= n:
        return x[:n]
    return np.concatenate([x, np.full(n - len(x), x[-1])])


def paper_identification(
    rate_hz: float,
    duration_s: float = 1800.0,
    seed: int = 0,
    lo_pct: float = LO_PCT,
    hi_pct: float = HI_PCT,
    max_rate_pct_s: float = 0.4,
    start_amplitude_pct: float = 1.5,
) -> np.ndarray:
    """The paper's identification signal (Fig. 2): swings of growing amplitude about the middle.

    Consecutive extremes alternate above and below the center with an
    amplitude growing linearly from ``start_amplitude_pct`` to the half range;
    each swing is a half cosine whose peak slope is ``max_rate_pct_s``
    (duration ``pi |swing| / (2 max_rate)``). The number of swings is chosen so
    the sweep fills ``duration_s``; it ends at ``lo_pct`` and holds there.
    """
    n = _samples(rate_hz, duration_s)
    center, half = (hi_pct + lo_pct) / 2.0, (hi_pct - lo_pct) / 2.0
    a0 = min(start_amplitude_pct, half)
    # K swings span about K (a0 + half) in all, each taking pi span / (2 rate) seconds,
    # and the final top-to-bottom swing (2 half) comes on top.
    budget_s = duration_s - math.pi * 2.0 * half / (2.0 * max_rate_pct_s)
    k = max(3, int(budget_s * 2.0 * max_rate_pct_s / (math.pi * (a0 + half))))
    k -= 1 - k % 2  # odd: the last growing swing goes to the top, then the run ends at the bottom
    amps = np.linspace(a0, half, k)
    extremes = np.concatenate([[center], center + amps * np.where(np.arange(k) % 2 == 0, 1.0, -1.0)])
    extremes = np.append(extremes, lo_pct)  # the paper's run ends at the bottom
    return _fit(swings(extremes, max_rate_pct_s, rate_hz), n)


def swings(extremes_pct, max_rate_pct_s: float, rate_hz: float) -> np.ndarray:
    """Half cosines from each extreme to the next, each with peak slope ``max_rate_pct_s``, ending on the last.

    A swing of ``s`` % takes ``pi |s| / (2 max_rate)`` seconds: smooth reversals, no
    rate above the limit (the paper's sweep is made of them).
    """
    pieces = []
    for a, b in zip(extremes_pct[:-1], extremes_pct[1:]):
        t_swing = math.pi * abs(b - a) / (2.0 * max_rate_pct_s)
        m = max(1, math.ceil(t_swing * rate_hz))  # ceil keeps the sampled slope within the limit
        phase = np.arange(m) / m
        pieces.append(a + (b - a) * (1.0 - np.cos(np.pi * phase)) / 2.0)
    pieces.append([extremes_pct[-1]])
    return np.concatenate(pieces)


def steps(
    rate_hz: float,
    duration_s: float = 120.0,
    seed: int = 0,
    levels_pct: tuple[float, ...] = (45.0, 55.0, 65.0, 55.0, 45.0, 60.0, 40.0, 70.0, 50.0),
    hold_s: float = 5.0,
) -> np.ndarray:
    """Steps through ``levels_pct`` (cycled), each held ``hold_s``."""
    n = _samples(rate_hz, duration_s)
    per = max(1, int(round(hold_s * rate_hz)))
    idx = (np.arange(n) // per) % len(levels_pct)
    return np.asarray(levels_pct, dtype=np.float64)[idx]


def ramps(
    rate_hz: float,
    duration_s: float = 120.0,
    seed: int = 0,
    lo_pct: float = 40.0,
    hi_pct: float = 70.0,
    rates_pct_s: tuple[float, ...] = (1.0, 5.0, 0.5, 10.0, 2.0),
    hold_s: float = 2.0,
) -> np.ndarray:
    """Ramps up and down between ``lo_pct`` and ``hi_pct`` at the rates given in turn, holding at each end."""
    n = _samples(rate_hz, duration_s)
    pieces, level, j = [np.full(max(1, int(round(hold_s * rate_hz))), lo_pct)], lo_pct, 0
    total = len(pieces[0])
    while total < n:
        target = hi_pct if level == lo_pct else lo_pct
        m = max(1, int(round(abs(target - level) / rates_pct_s[j % len(rates_pct_s)] * rate_hz)))
        ramp = level + (target - level) * np.arange(1, m + 1) / m
        hold = np.full(max(0, int(round(hold_s * rate_hz))), target)
        pieces += [ramp, hold]
        total += len(ramp) + len(hold)
        level, j = target, j + 1
    return _fit(np.concatenate(pieces), n)


def random_holds(
    rate_hz: float,
    duration_s: float = 120.0,
    seed: int = 0,
    lo_pct: float = LO_PCT,
    hi_pct: float = HI_PCT,
    hold_s: tuple[float, float] = (0.5, 5.0),
) -> np.ndarray:
    """Uniformly random levels in [lo, hi], each held a uniformly random time in ``hold_s``."""
    n = _samples(rate_hz, duration_s)
    rng = np.random.default_rng(seed)
    pieces, total = [], 0
    while total < n:
        m = max(1, int(round(rng.uniform(*hold_s) * rate_hz)))
        pieces.append(np.full(m, rng.uniform(lo_pct, hi_pct)))
        total += m
    return _fit(np.concatenate(pieces), n)


def sines(
    rate_hz: float,
    duration_s: float = 120.0,
    seed: int = 0,
    center_pct: float = 55.0,
    amplitude_pct: float = 15.0,
    periods_s: tuple[float, ...] = (30.0, 10.0, 3.0, 1.0),
) -> np.ndarray:
    """Equal-length segments of sines about ``center_pct``, one per period, each from phase 0."""
    n = _samples(rate_hz, duration_s)
    seg = np.array_split(np.arange(n), len(periods_s))
    out = np.empty(n)
    for idx, period in zip(seg, periods_s):
        t = (idx - idx[0]) / rate_hz if len(idx) else idx
        out[idx] = center_pct + amplitude_pct * np.sin(2.0 * np.pi * t / period)
    return out


PROTOCOLS: dict[str, Callable[..., np.ndarray]] = {
    "paper_identification": paper_identification,
    "steps": steps,
    "ramps": ramps,
    "random_holds": random_holds,
    "sines": sines,
}


def protocol(name: str, rate_hz: float, duration_s: float | None = None, seed: int = 0) -> np.ndarray:
    """Duty % at ``rate_hz`` from a protocol name, or from a CSV file with ``t_s, duty_pct``.

    A file is interpolated linearly at ``rate_hz`` from its first time on; without
    ``duration_s`` it runs to its last time, with one it is cut or holds its last value.
    A protocol's own default duration applies when ``duration_s`` is None.
    """
    if name in PROTOCOLS:
        f = PROTOCOLS[name]
        return f(rate_hz, seed=seed) if duration_s is None else f(rate_hz, duration_s, seed=seed)
    if not (os.path.exists(name) or name.endswith(".csv")):
        raise InputError(f"--protocol {name}: neither a protocol ({', '.join(PROTOCOLS)}) nor a CSV file")
    table = read_table(name, ("t_s", "duty_pct"), ranges={"duty_pct": (0.0, 100.0)})
    t, d = table.columns["t_s"], table.columns["duty_pct"]
    span = t[-1] - t[0]
    n = _samples(rate_hz, duration_s, "--duration") if duration_s is not None else \
        _samples(rate_hz, max(span, 1.0 / rate_hz), f"{name}: column 't_s' (its span)")
    return np.interp(t[0] + np.arange(n) / rate_hz, t, d)


_KINDS = ("square", "ramp", "sine")


def _pick(cond, a, b):
    """``np.where`` for scalars."""
    return a if cond else b


@dataclass(frozen=True)
class BreathProfile:
    """Inspiratory flow reference of a volume-controlled ventilator.

    Attributes
    ----------
    kind : str
        ``"square"`` (constant flow), ``"ramp"`` (decelerating: from peak down to
        ``end_fraction`` of it) or ``"sine"`` (half sine over inspiration).
    peak_lpm : float
        Peak inspiratory flow, L/min.
    breath_rate_bpm : float
        Breaths per minute.
    ie_ratio : float
        Inspiration over expiration time (1:2 is 0.5).
    rise_s : float
        Linear rise from ``base_lpm`` at the start of inspiration (square and ramp), s.
    end_fraction : float
        Flow at the end of a decelerating ramp, fraction of the peak.
    base_lpm : float
        Flow during expiration (inspiratory valve nearly closed), L/min.
    """

    kind: str = "square"
    peak_lpm: float = 60.0
    breath_rate_bpm: float = 15.0
    ie_ratio: float = 0.5
    rise_s: float = 0.05
    end_fraction: float = 0.25
    base_lpm: float = 0.0

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise InputError(f"breath profile: kind {self.kind!r} (one of {', '.join(_KINDS)})")
        for name in ("peak_lpm", "breath_rate_bpm", "ie_ratio"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"breath profile: {name} must be positive, got {v}")
        for name in ("rise_s", "base_lpm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"breath profile: {name} must be zero or positive, got {v}")
        if not 0.0 <= self.end_fraction <= 1.0:
            raise InputError(f"breath profile: end_fraction must be in 0..1, got {self.end_fraction}")

    @cached_property  # computed once: the live loop reads both twice a step
    def period_s(self) -> float:
        """Breath period, s."""
        return 60.0 / self.breath_rate_bpm

    @cached_property
    def inspiration_s(self) -> float:
        """Inspiratory time, s."""
        return self.period_s * self.ie_ratio / (1.0 + self.ie_ratio)

    def value(self, t_s):
        """Reference flow (L/min) at time ``t_s`` (s, scalar or array; breaths start at t = 0).

        One law for both: scalars go through :mod:`math` (a few µs for the live loop),
        arrays through numpy.
        """
        if isinstance(t_s, float) or np.ndim(t_s) == 0:
            return self._law(float(t_s), min, math.sin, _pick)
        return self._law(np.asarray(t_s, dtype=np.float64), np.minimum, np.sin, np.where)

    def _law(self, t_s, minimum, sin, where):
        ph = t_s % self.period_s
        ti = self.inspiration_s
        if self.kind == "sine":
            level = self.base_lpm + (self.peak_lpm - self.base_lpm) * sin(math.pi * ph / ti)
        else:
            level = self.peak_lpm
            if self.kind == "ramp":
                level = self.peak_lpm * (1.0 - (1.0 - self.end_fraction) * ph / ti)
            if self.rise_s > 0:
                level = self.base_lpm + (level - self.base_lpm) * minimum(ph / self.rise_s, 1.0)
        return where(ph < ti, level, self.base_lpm)
