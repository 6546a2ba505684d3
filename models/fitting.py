"""Fit any model kind to a recording: preprocessing (§2.3), the kind's fit, scalings.

Each kind's module offers ``fit_core(x, y, rate_hz, n=None) -> core`` on
normalized, preprocessed data; cores that can be inverted offer
``inverse()``. Evaluation always runs on the recording as given (raw duty in,
raw measured flow compared), so the figures include the sensor noise.
"""
from __future__ import annotations

import importlib

import numpy as np

from .metrics import Metrics, metrics
from .model_schema import KINDS as KIND_SCHEMAS
from .model import FittedModel
from .preprocess import Scaling, preprocess
from .recording import InputError, Recording, check_fittable
from .worktime import WorkTimer

KINDS = ("pi", "pi-asym", "pi-mod", "preisach", "preisach-cont", "bouc-wen")


def fit_model(
    kind: str,
    t_s: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    n: int | None = None,
    x_name: str = "duty_pct",
    y_name: str = "flow_lpm",
    source: str = "",
) -> FittedModel:
    """Preprocess, normalize and fit one model kind.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    t_s, x, y : ndarray
        Time (s), input and output in physical units.
    n : int, optional
        Resolution (operators, hysterons per axis); the kind's default if None.

    Returns
    -------
    FittedModel
        With ``meta["fit_s"]``, the seconds of preprocessing and fitting alone (imports, numba's
        compiling and cache loading excluded: :class:`models.worktime.WorkTimer`).
    """
    if kind not in KINDS:
        raise InputError(f"--model: unknown kind {kind!r} (one of {', '.join(KINDS)})")
    max_n = KIND_SCHEMAS[kind].max_n
    if n is not None and not 1 <= n <= max(max_n, 1):
        raise InputError(f"--n: must be 1..{max_n} for {kind}, got {n}" if max_n else
                         f"--n: {kind} has no resolution to set, got {n}")
    # fit_s times the work alone: the kind's module and preprocessing's filters imported first, numba's
    # compiling and cache loading left out (models.worktime)
    module = importlib.import_module(KIND_SCHEMAS[kind].core.split(":")[0])
    importlib.import_module("scipy.signal")
    with WorkTimer() as timer:
        pre = preprocess(t_s, x, y)
        xs, ys = Scaling.from_data(x), Scaling.from_data(y)
        core = module.fit_core(xs.to_unit(pre.x), ys.to_unit(pre.y), pre.rate_hz, n)
        inverse = core.inverse() if hasattr(core, "inverse") else None
    meta = {"source": source, "n": n, "fit_rate_hz": pre.rate_hz, "fit_s": timer.seconds}
    return FittedModel(kind, core, xs, ys, x_name, y_name, inverse, meta)


def fit_recording(kind: str, rec: Recording, n: int | None = None) -> FittedModel:
    """Fit ``kind`` to a valve recording (duty in, flow out); one without enough rows or excitation is refused."""
    check_fittable(rec)
    try:
        model = fit_model(kind, rec.t_s, rec.duty_pct, rec.flow_lpm, n=n, source=rec.path)
    except InputError as exc:  # a kind's own refusal ("preisach-cont: the input turns too rarely"): name the file
        text = str(exc)
        raise InputError(text if text.startswith(rec.path) else f"{rec.path}: {text}") from None
    supply = rec.columns.get("supply_bar")
    if supply is not None:
        # the supply the flow was identified at (bar gauge): choked flow is proportional to the upstream
        # absolute pressure, so a recording at another supply is held against the model at this one
        model.meta["supply_bar"] = float(np.mean(supply))
    return model


def evaluate(model: FittedModel, x: np.ndarray, y: np.ndarray) -> Metrics:
    """Paper §3 metrics of the model's prediction from ``x`` against measured ``y``."""
    pred, _ = model.predict(x)
    return metrics(y, pred)
