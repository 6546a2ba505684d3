"""A fitted hysteresis model in physical units, and its model file.

Every model kind (``pi``, ``pi-asym``, ``pi-mod``, ``preisach``, ``preisach-cont``,
``bouc-wen``) is a *core* working in normalized units with the same shape:

- ``init(x0) -> state``, ``step(state, x) -> (state, y)``, pure;
- ``predict(x, state=None) -> (y, final_state)`` over a sequence;
- ``to_params() -> dict`` and ``from_params(dict)`` for the model file.

:class:`FittedModel` wraps a core with the input and output scalings of the
preprocessing (paper §2.3), so callers speak % duty and L/min.

Model file (JSON, written atomically, floats round-trip exactly)::

    {"format": "valvectl-model", "version": 1, "kind": KIND,
     "input": {"name", "center", "half_range"}, "output": {...},
     "params": {...}, "inverse": {...} (PI kinds), "meta": {...}}

Its schema, one per kind, is in :mod:`models.model_schema`.
"""
from __future__ import annotations

import importlib
import json
import os
from dataclasses import dataclass, field
from typing import Any

import msgspec
import numpy as np

from .preprocess import Scaling
from .recording import InputError

FORMAT = "valvectl-model"
VERSION = 1

def core_class(kind: str):
    """The core class for a kind word (forward kinds and their inverses, :data:`models.model_schema.KINDS`)."""
    from .model_schema import KINDS, forward_kinds

    try:
        mod, cls = KINDS[kind].core.split(":")
    except KeyError:
        raise InputError(f"unknown model kind {kind!r} (one of {', '.join(forward_kinds())})") from None
    return getattr(importlib.import_module(mod), cls)


@dataclass(frozen=True, eq=False)
class FittedModel:
    """A core model with physical-unit scalings.

    Attributes
    ----------
    kind : str
        Kind word.
    core : object
        The normalized-unit model.
    x_scale, y_scale : Scaling
        Input (e.g. ``duty_pct``) and output (e.g. ``flow_lpm``) scalings.
    x_name, y_name : str
        Column names of input and output.
    inverse : object or None
        For PI kinds, the inverse core (output to input, normalized units).
    meta : dict
        Provenance and fit figures.
    """

    kind: str
    core: Any
    x_scale: Scaling
    y_scale: Scaling
    x_name: str = "duty_pct"
    y_name: str = "flow_lpm"
    inverse: Any = None
    meta: dict = field(default_factory=dict)

    def init(self, x0: float):
        """Core state at the first input sample (physical units in)."""
        return self.core.init(float(self.x_scale.to_unit(x0)))

    def step(self, state, x: float):
        """One sample, physical units in and out."""
        state, y = self.core.step(state, float(self.x_scale.to_unit(x)))
        return state, float(self.y_scale.from_unit(y))

    def predict(self, x, state=None):
        """Output (physical units) over an input sequence (physical units); ``(y, final_state)``."""
        y, s = self.core.predict(self.x_scale.to_unit(x), state)
        return self.y_scale.from_unit(y), s

    def inverse_predict(self, y, state=None):
        """Input that yields output ``y`` (physical units), through the inverse core."""
        if self.inverse is None:
            raise ValueError(f"model kind {self.kind!r} has no inverse")
        x, s = self.inverse.predict(self.y_scale.to_unit(y), state)
        return self.x_scale.from_unit(x), s

    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "version": VERSION,
            "kind": self.kind,
            "input": {"name": self.x_name, **self.x_scale.to_dict()},
            "output": {"name": self.y_name, **self.y_scale.to_dict()},
            "params": self.core.to_params(),
            "meta": self.meta,
        }
        if self.inverse is not None:
            d["inverse"] = {"kind": self.inverse.kind, "params": self.inverse.to_params()}
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "<model>") -> "FittedModel":
        """A model from a parsed model file, checked against its kind's schema (:mod:`models.model_schema`)."""
        from .model_schema import KINDS, forward_kinds
        from .schema import convert

        if not isinstance(d, dict):
            raise InputError(f"{source}: a model file is a JSON object")
        if d.get("format") != FORMAT:
            raise InputError(f"{source}: format: not a valvectl model file (expected {FORMAT!r})")
        kind = d.get("kind")
        if not isinstance(kind, str) or kind not in forward_kinds():
            raise InputError(f"{source}: kind: {kind!r} is not a model kind (one of {', '.join(forward_kinds())})")
        f = convert(d, KINDS[kind].file, source)
        # the checked params, with the schema's defaults for the fields a file may leave out
        try:
            field = "params"
            core = core_class(kind).from_params(msgspec.to_builtins(f.params))
            inverse = None
            if getattr(f, "inverse", None) is not None:
                field = "inverse.params"
                inverse = core_class(f.inverse.kind).from_params(msgspec.to_builtins(f.inverse.params))
        except ValueError as exc:  # parameters each in range that do not make a model together (pi-mod's
            # inverse inverts its forward's: inverse_pi.NotInvertible, a dead zone's non-positive segment slope)
            raise InputError(f"{source}: {field}: {exc}") from None
        return cls(
            kind=kind,
            core=core,
            x_scale=Scaling(center=f.input.center, half_range=f.input.half_range),
            y_scale=Scaling(center=f.output.center, half_range=f.output.half_range),
            x_name=f.input.name or "duty_pct",
            y_name=f.output.name or "flow_lpm",
            inverse=inverse,
            meta=f.meta,
        )


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON atomically (:func:`models.atomicfile.atomic_open`: a kill leaves no temporary file)."""
    from .atomicfile import atomic_open

    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with atomic_open(path) as fh:
        json.dump(obj, fh, indent=1, default=_json_default, allow_nan=True)
        fh.write("\n")


def save_model(model: FittedModel, path: str | os.PathLike) -> None:
    """Write a model file atomically."""
    write_json_atomic(path, model.to_dict())


def load_model(path: str | os.PathLike) -> FittedModel:
    """Read a model file; bad files raise :class:`InputError` naming the file and the field."""
    from .schema import read_json

    path = os.fspath(path)
    return FittedModel.from_dict(read_json(path), source=path)
