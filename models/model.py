"""A fitted hysteresis model in physical units, and its model file.

Every model kind (``pi``, ``pi-asym``, ``preisach``, ``preisach-cont``,
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
"""
from __future__ import annotations

import importlib
import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .preprocess import Scaling
from .recording import InputError

FORMAT = "valvectl-model"
VERSION = 1

#: kind word -> "module:Class" of its core (imported on first use).
CORES = {
    "pi": "models.pi:PIModel",
    "inverse-pi": "models.inverse_pi:InversePI",
    "pi-asym": "models.pi_asym:AsymmetricPIModel",
    "inverse-pi-asym": "models.pi_asym:InverseAsymmetricPI",
    "preisach": "models.preisach:PreisachModel",
    "preisach-cont": "models.preisach_cont:ContinuousPreisachModel",
    "bouc-wen": "models.bouc_wen:BoucWenModel",
}


def core_class(kind: str):
    """The core class for a kind word."""
    try:
        mod, cls = CORES[kind].split(":")
    except KeyError:
        raise InputError(f"unknown model kind {kind!r} (one of {', '.join(k for k in CORES if not k.startswith('inverse-'))})") from None
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
        try:
            if d.get("format") != FORMAT:
                raise InputError(f"{source}: field 'format': not a valvectl model file")
            core = core_class(d["kind"]).from_params(d["params"])
            inverse = None
            if d.get("inverse"):
                inverse = core_class(d["inverse"]["kind"]).from_params(d["inverse"]["params"])
            return cls(
                kind=d["kind"],
                core=core,
                x_scale=Scaling.from_dict(d["input"]),
                y_scale=Scaling.from_dict(d["output"]),
                x_name=d["input"].get("name", "duty_pct"),
                y_name=d["output"].get("name", "flow_lpm"),
                inverse=inverse,
                meta=d.get("meta", {}),
            )
        except KeyError as exc:
            raise InputError(f"{source}: field {exc.args[0]!r}: missing") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{source}: malformed model file ({exc})") from None


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON to a temporary file in the same folder, fsync, then rename over ``path``."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    tmp = os.path.join(folder, f".{os.path.basename(path)}.tmp{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=1, default=_json_default, allow_nan=True)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def save_model(model: FittedModel, path: str | os.PathLike) -> None:
    """Write a model file atomically."""
    write_json_atomic(path, model.to_dict())


def load_model(path: str | os.PathLike) -> FittedModel:
    """Read a model file; bad files raise :class:`InputError` naming the file."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}:1: a model file is a JSON object")
    return FittedModel.from_dict(d, source=path)
