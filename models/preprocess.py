"""Preprocessing of the paper, §2.3: downsampling, Chebyshev I lowpass, normalization.

The paper downsamples, filters with an order-8 Chebyshev type I IIR lowpass
and normalizes to [-1, 1]. Here the lowpass is applied zero-phase
(``sosfiltfilt``) *before* keeping every k-th sample, so it also serves as the
anti-alias filter, and input and output pass through the same filter so they
stay aligned. The scaling is kept (:class:`Scaling`) and stored in the model
file so that predictions come back in L/min and % duty.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: Rate the fits work at (Hz). Hysteresis is rate-independent; the paper's
#: protocol changes duty by at most 0.4 %/s, so 10 Hz keeps 0.04 % per sample.
FIT_RATE_HZ = 10.0
#: Lowpass corner as a fraction of the Nyquist frequency after downsampling.
CUTOFF_FRACTION = 0.4
CHEBY_ORDER = 8  # paper §2.3
CHEBY_RIPPLE_DB = 0.05  # small: filtfilt doubles it, and loop amplitudes must not be distorted


@dataclass(frozen=True)
class Scaling:
    """Affine map from physical units to the model's [-1, 1]: ``u = (x - center) / half_range``."""

    center: float
    half_range: float

    @classmethod
    def from_data(cls, x: np.ndarray) -> "Scaling":
        lo, hi = float(np.min(x)), float(np.max(x))
        half = (hi - lo) / 2.0
        return cls(center=(hi + lo) / 2.0, half_range=half if half > 0 else 1.0)

    def to_unit(self, x):
        return (np.asarray(x, dtype=np.float64) - self.center) / self.half_range

    def from_unit(self, u):
        return np.asarray(u, dtype=np.float64) * self.half_range + self.center

    def to_dict(self) -> dict:
        return {"center": self.center, "half_range": self.half_range}

    @classmethod
    def from_dict(cls, d: dict) -> "Scaling":
        return cls(center=float(d["center"]), half_range=float(d["half_range"]))


def lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Zero-phase Chebyshev type I lowpass of order 8 (second-order sections).

    Parameters
    ----------
    x : ndarray
        Signal sampled at ``rate_hz``. Unit gain at DC.
    cutoff_hz : float
        Passband edge (Hz); at or above Nyquist the signal is returned as is.
    rate_hz : float
        Sample rate (Hz).
    """
    nyq = rate_hz / 2.0
    if cutoff_hz >= nyq:
        return np.asarray(x, dtype=np.float64).copy()
    sos = _design(round(cutoff_hz / nyq, 12))
    padlen = min(3 * (2 * len(sos) + 1), len(x) - 1)
    sos = sos.copy()  # the cached design stays untouched by scipy
    from scipy import signal

    return signal.sosfiltfilt(sos, x, padlen=max(padlen, 0))


@lru_cache(maxsize=32)
def _design(wn: float) -> np.ndarray:
    from scipy import signal  # imported here: every verb loads this module, few filter

    sos = signal.cheby1(CHEBY_ORDER, CHEBY_RIPPLE_DB, wn, btype="low", output="sos")
    # An even-order Chebyshev I sits at the bottom of its ripple at DC (gain 10^(-rp/20)),
    # squared by filtfilt: rescale to unit DC gain so levels are kept.
    dc = np.prod(sos[:, :3].sum(axis=1) / sos[:, 3:].sum(axis=1))
    sos[0, :3] /= dc
    return sos


@dataclass(frozen=True)
class Preprocessed:
    """Filtered and downsampled input/output pair, physical units.

    Attributes
    ----------
    t_s, x, y : ndarray
        Time (s), input (e.g. duty %) and output (e.g. flow L/min).
    rate_hz : float
        Sample rate after downsampling (Hz).
    factor : int
        Downsampling factor applied.
    """

    t_s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    rate_hz: float
    factor: int


def preprocess(
    t_s: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    fit_rate_hz: float = FIT_RATE_HZ,
    filter_output: bool = True,
) -> Preprocessed:
    """Lowpass and downsample an input/output recording to about ``fit_rate_hz``.

    The downsampling factor is ``floor(rate / fit_rate_hz)`` (at least 1); the
    lowpass corner is :data:`CUTOFF_FRACTION` of the new Nyquist frequency.
    Recordings too short to filter (fewer than 30 samples) pass unfiltered.
    """
    t_s = np.asarray(t_s, dtype=np.float64)
    rate = (len(t_s) - 1) / (t_s[-1] - t_s[0]) if len(t_s) > 1 else fit_rate_hz
    factor = max(1, int(np.floor(rate / fit_rate_hz + 1e-6)))
    new_rate = rate / factor
    cutoff = CUTOFF_FRACTION * new_rate / 2.0
    if len(t_s) >= 30:
        xf = lowpass(x, cutoff, rate)
        yf = lowpass(y, cutoff, rate) if filter_output else np.asarray(y, dtype=np.float64)
    else:
        xf, yf = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return Preprocessed(t_s[::factor], xf[::factor], yf[::factor], new_rate, factor)
