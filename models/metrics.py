"""The paper's metrics (§3): mean absolute error, root mean square error, correlation r."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Metrics:
    """Fit figures in the units of the compared signal.

    Attributes
    ----------
    mae : float
        Mean absolute error.
    rmse : float
        Root mean square error.
    r : float
        Pearson correlation between measured and predicted.
    """

    mae: float
    rmse: float
    r: float

    def to_dict(self) -> dict:
        return asdict(self)


def metrics(measured, predicted) -> Metrics:
    """MAE, RMSE and Pearson r of ``predicted`` against ``measured``."""
    m = np.asarray(measured, dtype=np.float64)
    p = np.asarray(predicted, dtype=np.float64)
    if m.shape != p.shape:
        raise ValueError(f"shapes differ: {m.shape} vs {p.shape}")
    e = p - m
    mae = float(np.mean(np.abs(e)))
    rmse = float(np.sqrt(np.mean(e * e)))
    if np.std(m) == 0 or np.std(p) == 0:
        r = float("nan")
    else:
        r = float(np.corrcoef(m, p)[0, 1])
    return Metrics(mae, rmse, r)
