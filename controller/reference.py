"""A recorded reference (``valvectl run --reference FILE.csv``): the ventilator's set flow, replayed.

The file is a CSV with ``t_s`` (strictly increasing) and ``ref_lpm``; other
columns are ignored, so a run recording replays its own reference. Time is
taken from the file's first row. The value at time ``t`` is the newest
sample at or before ``t`` (a zero-order hold, as the stack published it:
steps stay steps); before the first sample the first value holds, after the
last the last one.
"""
from __future__ import annotations

import numpy as np

from models.recording import RANGES, check_sampling, read_table


class RecordedReference:
    """``ref_lpm(t_s)`` from a file; a pure function of time, so the loop may read it ahead.

    Attributes
    ----------
    span_s : float
        Time from the first to the last sample, s.
    """

    def __init__(self, path):
        rec = read_table(path, ("t_s", "ref_lpm"), ranges={"ref_lpm": RANGES["ref_lpm"]})
        check_sampling(rec)  # one sample rate: the run's length and its steps come from this file
        self.path = path
        self._t = rec.columns["t_s"] - rec.columns["t_s"][0]
        self._v = rec.columns["ref_lpm"]
        self.span_s = float(self._t[-1])

    def __call__(self, t_s: float) -> float:
        i = int(np.searchsorted(self._t, t_s, side="right")) - 1
        return float(self._v[max(i, 0)])
