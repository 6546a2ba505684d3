"""Model files (JSON): one schema per model kind, registered with the kind's core class.

A model file is ``{"format": "valvectl-model", "version": 1, "kind": KIND,
"input": {"name", "center", "half_range"}, "output": {...}, "params": {...},
"inverse": {"kind", "params"} (invertible kinds), "meta": {...}}``. The
envelope is :class:`ModelFile`; ``params`` (and ``inverse.params``) take the
struct registered for the kind, so a bad file names its field exactly::

    config/valve_model.json: params.w[3]: must be a finite number (got nan)

How to add a model kind
-----------------------
Write one struct for the kind's ``params`` (the dict its core's
``to_params`` returns and ``from_params`` reads), with the bounded numbers
below (``Coefficient``, ``Threshold``) and its shape rules in
``__post_init__``, and register it::

    class PIModParams(msgspec.Struct, forbid_unknown_fields=True):
        r: list[Threshold]
        ...

    register("pi-mod", "models.pi_mod:PIModModel", PIModParams,
             inverse=("inverse-pi-mod", "models.pi_mod:InversePIMod", InversePIModParams), max_n=2000)

That is all: :func:`models.model.core_class` and :func:`models.model.load_model`
find the kind through :data:`KINDS`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec



#: Largest magnitude of any number in a model file. Cores work in normalized units (inputs and
#: outputs within [-1, 1]), so their numbers are O(1) (inverse weights up to 1/MIN_SLOPE = 1e3);
#: the bound keeps every prediction, and a fit's sums of squares on it, finite.
LIMIT = 1e9
Coefficient = Annotated[float, msgspec.Meta(ge=-LIMIT, le=LIMIT)]
Threshold = Annotated[float, msgspec.Meta(ge=0.0, le=LIMIT)]
#: A scale's half range (duty %, flow L/min): below 1e-6 the normalized inputs leave every bound (1e-300 made
#: inf and NaN predictions in the diagnosis).
ScaleRange = Annotated[float, msgspec.Meta(ge=1e-6, le=LIMIT)]

#: Most operators/relays a model file may hold (the paper's largest, Preisach n = 50, has 1275; the largest a
#: fit makes, Preisach n = 200, 20 100). The diagnosis builds a design of rows x operators: 100 000 operators
#: on a 20 s recording asked for 1.5 GiB, on 150 000 rows for 120 GB.
MAX_ELEMENTS = 25_000
#: Lowest closed flow a pi-mod file may state (normalized units; the default: none).
MAX_FLOOR = 1e300
#: Most Everett mesh points per axis.
MAX_MESH = 1000


@dataclass(frozen=True)
class Kind:
    """One model kind: its core class (``"module:Class"``), params schema and file schema."""

    name: str
    core: str
    params: type
    file: type
    inverse_of: str | None = None
    max_n: int = 0


#: kind word -> :class:`Kind` (forward kinds and their inverses).
KINDS: dict[str, Kind] = {}


class Scale(msgspec.Struct, forbid_unknown_fields=True):
    """Affine map to the model's [-1, 1]: ``u = (x - center) / half_range``."""

    center: Coefficient
    half_range: ScaleRange
    name: str | None = None


class ModelFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The envelope every model file shares; ``params`` and ``inverse`` are typed per kind."""

    format: Literal["valvectl-model"]
    version: Literal[1]
    kind: str
    input: Scale
    output: Scale
    meta: dict = {}


def _same_length(struct, names: tuple[str, ...], optional: tuple[str, ...] = ()) -> None:
    n = len(getattr(struct, names[0]))
    if not 1 <= n <= MAX_ELEMENTS:
        raise ValueError(f"{names[0]}: must have 1..{MAX_ELEMENTS} entries (got {n})")
    for name in names[1:] + tuple(o for o in optional if getattr(struct, o) is not None):
        if len(getattr(struct, name)) != n:
            raise ValueError(f"{name}: must have as many entries as {names[0]} ({len(getattr(struct, name))} != {n})")


def _ascending(values: list, name: str) -> None:
    if any(b < a for a, b in zip(values, values[1:])):
        raise ValueError(f"{name}: must be ascending")


class PIParams(msgspec.Struct, forbid_unknown_fields=True):
    """Eq. (4): thresholds ``r`` (ascending, >= 0), weights ``w``, offset, optional memory ``y0``."""

    r: list[Threshold]
    w: list[Coefficient]
    offset: Coefficient = 0.0
    y0: list[Coefficient] | None = None

    def __post_init__(self):
        _same_length(self, ("r", "w"), ("y0",))
        _ascending(self.r, "r")


class InversePIParams(msgspec.Struct, forbid_unknown_fields=True):
    """Eq. (7): inverse thresholds and weights (``w[0] = 1/w_1`` of the forward, nonzero)."""

    r: list[Threshold]
    w: list[Coefficient]
    offset: Coefficient = 0.0
    x0: list[Coefficient] | None = None

    def __post_init__(self):
        _same_length(self, ("r", "w"), ("x0",))
        _ascending(self.r, "r")
        if self.w[0] == 0.0:
            raise ValueError("w[0]: must be nonzero (it is 1/w_1 of the forward model)")


class PIAsymParams(msgspec.Struct, forbid_unknown_fields=True):
    """Asymmetric PI: thresholds, weights, descending widening ``a`` >= 0, its exponent ``p`` > 0."""

    r: list[Threshold]
    w: list[Coefficient]
    a: Annotated[float, msgspec.Meta(ge=0.0, le=LIMIT)] = 0.0
    p: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.0
    offset: Coefficient = 0.0

    def __post_init__(self):
        _same_length(self, ("r", "w"))
        _ascending(self.r, "r")


class InversePIAsymParams(msgspec.Struct, forbid_unknown_fields=True):
    """The inverse of an asymmetric PI is solved through its forward model."""

    forward: PIAsymParams


class PIModParams(msgspec.Struct, forbid_unknown_fields=True):
    """Modified PI: play part (``r``, ``w``, memory ``y0``, descending envelope ``a`` >= 0 and
    ``p`` > 0 as in pi-asym; absent: ``a = 0``, Kuhnen's plays), dead-zone superposition
    (thresholds ``h`` ascending with one zero, weights ``g``), offset and closed flow ``floor``."""

    r: list[Threshold]
    w: list[Coefficient]
    h: list[Coefficient]
    g: list[Coefficient]
    offset: Coefficient = 0.0
    floor: Annotated[float, msgspec.Meta(ge=-MAX_FLOOR, le=LIMIT)] = -MAX_FLOOR  # none by default; at most
    # a normalized flow as large as any other coefficient (1e300 made every prediction 1e300 L/min)
    y0: list[Coefficient] | None = None
    a: Annotated[float, msgspec.Meta(ge=0.0, le=LIMIT)] = 0.0
    p: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.0

    def __post_init__(self):
        _same_length(self, ("r", "w"), ("y0",))
        _ascending(self.r, "r")
        _same_length(self, ("h", "g"))
        _ascending(self.h, "h")
        if self.h.count(0.0) != 1:
            raise ValueError("h: must hold exactly one zero threshold")


class InversePIModParams(msgspec.Struct, forbid_unknown_fields=True):
    """The inverse of a modified PI is computed in closed form from its forward model."""

    forward: PIModParams


class PreisachParams(msgspec.Struct, forbid_unknown_fields=True):
    """Relays ``(alpha_i, beta_i)`` with ``alpha >= beta`` and their weights ``mu``."""

    alpha: list[Coefficient]
    beta: list[Coefficient]
    mu: list[Coefficient]
    offset: Coefficient = 0.0

    def __post_init__(self):
        _same_length(self, ("alpha", "beta", "mu"))
        if any(a < b for a, b in zip(self.alpha, self.beta)):
            raise ValueError("alpha: every relay needs alpha >= beta")


class InversePreisachParams(msgspec.Struct, forbid_unknown_fields=True):
    """The inverse of a Preisach model is solved per sample through its forward model."""

    forward: PreisachParams


class PreisachContParams(msgspec.Struct, forbid_unknown_fields=True):
    """Everett function sampled on an (n+1) x (n+1) mesh, n >= 1."""

    everett: list[list[Coefficient]]
    offset: Coefficient = 0.0

    def __post_init__(self):
        n = len(self.everett)
        if not 2 <= n <= MAX_MESH:
            raise ValueError(f"everett: must have 2..{MAX_MESH} rows (got {n})")
        bad = next((i for i, row in enumerate(self.everett) if len(row) != n), None)
        if bad is not None:
            raise ValueError(f"everett[{bad}]: has {len(self.everett[bad])} entries; the mesh is square, {n} x {n}")


class BoucWenParams(msgspec.Struct, forbid_unknown_fields=True):
    """``dh/dx = 1 - (beta sign(dx h) + gamma)|h|^n``, ``y = a x + b h + c``.

    ``beta + gamma > 0`` and ``beta - gamma > 0`` keep ``h`` bounded on both
    branches (the fit searches exactly that region); ``0 < n <= 20``.
    """

    beta: Coefficient
    gamma: Coefficient
    n: Annotated[float, msgspec.Meta(gt=0.0, le=20.0)]
    a: Coefficient
    b: Coefficient
    c: Coefficient

    def __post_init__(self):
        if not (self.beta + self.gamma > 0 and self.beta - self.gamma > 0):
            raise ValueError(f"beta: must exceed |gamma| (got beta {self.beta:g}, gamma {self.gamma:g})")


def register(name: str, core: str, params: type, inverse: tuple[str, str, type] | None = None,
             max_n: int = 0) -> None:
    """Register a model kind: its word, its core ``"module:Class"``, its params struct, and its inverse.

    ``inverse``: ``(inverse word, inverse core, inverse params struct)`` for
    invertible kinds, whose model files carry ``"inverse": {"kind", "params"}``.
    ``max_n``: the largest resolution ``fit --n`` may ask for (0: the kind has none).
    """
    inv_field = []
    if inverse is not None:
        inv_name, inv_core, inv_params = inverse
        inv_ref = msgspec.defstruct(f"{inv_name}-ref", [("kind", Literal[inv_name]), ("params", inv_params)],
                                    forbid_unknown_fields=True)
        inv_field = [("inverse", inv_ref | None, None)]
        KINDS[inv_name] = Kind(inv_name, inv_core, inv_params, inv_ref, inverse_of=name)
    file = msgspec.defstruct(f"{name}-file", [("params", params), *inv_field], bases=(ModelFile,), kw_only=True,
                             forbid_unknown_fields=True)
    KINDS[name] = Kind(name, core, params, file, max_n=max_n)


# max_n: operators (PI kinds), levels per axis (Preisach: n (n + 1) / 2 relays), mesh points per axis
register("pi", "models.pi:PIModel", PIParams,
         inverse=("inverse-pi", "models.inverse_pi:InversePI", InversePIParams), max_n=2000)
register("pi-asym", "models.pi_asym:AsymmetricPIModel", PIAsymParams,
         inverse=("inverse-pi-asym", "models.pi_asym:InverseAsymmetricPI", InversePIAsymParams), max_n=2000)
register("pi-mod", "models.pi_mod:ModifiedPIModel", PIModParams,
         inverse=("inverse-pi-mod", "models.pi_mod:InverseModifiedPI", InversePIModParams), max_n=2000)
register("preisach", "models.preisach:PreisachModel", PreisachParams,
         inverse=("inverse-preisach", "models.preisach:InversePreisach", InversePreisachParams), max_n=200)
register("preisach-cont", "models.preisach_cont:ContinuousPreisachModel", PreisachContParams, max_n=MAX_MESH - 1)
register("bouc-wen", "models.bouc_wen:BoucWenModel", BoucWenParams)


def forward_kinds() -> list[str]:
    """Kind words a model file may name (inverses travel inside their forward's file)."""
    return [k for k, v in KINDS.items() if not v.inverse_of]
