"""The recording on the diagnosis' working grid.

The diagnosis works at the recording's own rate up to :data:`WORK_RATE_HZ`:
valve dynamics and transport delay of a few tens of milliseconds live
around steps, where any smoothing of the measured flow that the model's
prediction does not also undergo would look like a lag. Faster recordings
are decimated with every signal, duty included, averaged over a centred
window of the decimation factor: the same smoothing on input and output
keeps them aligned, and a boxcar does not ring around steps as a sharp
lowpass would (a ringing duty fed to a hysteresis model would add
reversals the valve never saw).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..recording import InputError, Recording

#: Working rate of the diagnosis (Hz); recordings slower than this are used as they are.
WORK_RATE_HZ = 250.0


@dataclass(frozen=True)
class Signals:
    """Aligned signals on one sample grid, physical units.

    Attributes
    ----------
    t_s : ndarray
        Time (s).
    duty_pct : ndarray
        Command duty (%).
    flow_lpm : ndarray
        Measured flow (L/min).
    supply_bar : ndarray or None
        Supply gauge pressure (bar), when recorded.
    coil_temp_c : ndarray or None
        Coil temperature (deg C), when recorded.
    rate_hz : float
        Sample rate (Hz).
    rest_pct : float or None
        The duty the valve rested at before the first row (a closed-loop run starts from its
        safe duty); ``None``: at rest at the first row's duty (Eq. 3 with ``y_i0 = x(0)``).
    cache : dict
        Derived signals kept while they are asked for again (an effective duty).
    """

    t_s: np.ndarray
    duty_pct: np.ndarray
    flow_lpm: np.ndarray
    supply_bar: np.ndarray | None
    coil_temp_c: np.ndarray | None
    rate_hz: float
    rest_pct: float | None = None
    cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.t_s)


def _varies(x: np.ndarray | None) -> bool:
    return x is not None and float(np.ptp(x)) > 0.0


def raw_signals(rec: Recording, rest_pct: float | None = None) -> Signals:
    """The recording at its own rate (for per-row predictions)."""
    return Signals(rec.t_s, rec.duty_pct, rec.flow_lpm,
                   rec.get("supply_bar") if _varies(rec.get("supply_bar")) else None,
                   rec.get("coil_temp_c") if _varies(rec.get("coil_temp_c")) else None,
                   rec.rate_hz, rest_pct)


def work_signals(rec: Recording, rest_pct: float | None = None, rate_hz: float = WORK_RATE_HZ) -> Signals:
    """Decimate a recording to about ``rate_hz`` (unchanged when not faster than 1.5 x that)."""
    raw = raw_signals(rec, rest_pct)
    factor = int(raw.rate_hz // rate_hz)
    if raw.rate_hz < 1.5 * rate_hz or factor < 2:
        return raw
    kernel = np.ones(factor) / factor

    def average(x):
        if x is None:
            return None
        # centred moving average, edges padded with the end values
        pad = np.concatenate([np.full(factor // 2, x[0]), x, np.full(factor - 1 - factor // 2, x[-1])])
        return np.convolve(pad, kernel, mode="valid")[::factor]

    return Signals(raw.t_s[::factor], average(raw.duty_pct), average(raw.flow_lpm),
                   average(raw.supply_bar), average(raw.coil_temp_c), raw.rate_hz / factor, rest_pct)


def noise_lpm(flow_lpm: np.ndarray) -> float:
    """Robust standard deviation of white sensor noise (L/min) from second differences.

    A smooth flow has second differences far below the noise's, whose standard deviation is
    ``sqrt(6)`` times the noise's; the median absolute value ignores steps.
    """
    d2 = np.diff(np.asarray(flow_lpm, dtype=np.float64), 2)
    return float(np.median(np.abs(d2)) / 0.6745 / np.sqrt(6.0)) if len(d2) else 0.0


def running_rows(rec: Recording) -> tuple[Recording, float | None]:
    """A closed-loop run recording (a ``state`` column, ``valvectl run --record``) cut to its longest
    stretch of ``running`` rows, and the duty its valve rested at before it; any other recording as
    it is, and ``None``.

    In the safe or fault state the controller commands the safe duty and the flow it measures is
    not the loop's; the longest stretch keeps the hysteresis memory continuous. Before it the valve
    was at the safe duty (the lowest duty of the rows left out; DESIGN.md's default 0 % when the
    run was running from its first row), which sets the memory the run starts with. A loop step
    reads the flow before it commands the duty, so each duty is paired with the next row's flow
    (the stretch loses a row).
    """
    state = rec.text_columns.get("state")
    if state is None:
        return rec, None
    run = np.array([s.strip() == "running" for s in state])
    if not run.any():
        raise InputError(f"{rec.path}: column 'state': no row is 'running'")
    rest = float(np.min(rec.duty_pct[~run])) if (~run).any() else SAFE_DUTY_PCT
    edges = np.flatnonzero(np.diff(np.concatenate([[0], run.astype(np.int8), [0]])))
    starts, stops = edges[::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    a, b = int(starts[k]), int(stops[k])
    if b - a < 2:
        raise InputError(f"{rec.path}: column 'state': fewer than two consecutive 'running' rows")
    # a loop step reads the flow, then commands the duty: the valve's answer to a row's duty is
    # the next row's flow, so each duty is paired with the flow measured after it
    cols = {name: v[a + 1:b] for name, v in rec.columns.items()}
    cols["duty_pct"] = rec.duty_pct[a:b - 1]
    return Recording(rec.path, cols, {name: v[a + 1:b] for name, v in rec.text_columns.items()}), rest


#: The controller's safe duty (DESIGN.md's default), where a closed-loop run's valve rests before it runs.
SAFE_DUTY_PCT = 0.0
