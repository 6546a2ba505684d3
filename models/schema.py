"""Input schemas: every file the tools read is checked here, in one place per input kind.

Each input kind declares its shape as :mod:`msgspec` structs (types, ranges,
defaults, cross-field rules in ``__post_init__``) next to the code that owns
it, and reads the parsed document through :func:`convert`, which turns any
mismatch into one :class:`~models.recording.InputError` line naming the
file and the dotted field::

    config/run.toml: loop.rate_hz: must be > 0 (got 0)

msgspec, not pydantic: it imports in about a quarter of the time (28 ms
against 121 ms measured here), and the CLI imports a schema only in the verb
that reads the file, so ``valvectl --help`` pays nothing either way.

Where the schemas live
----------------------
- ``config/run.toml``: :mod:`controller.config` (one struct per section,
  :class:`controller.config.RunFile` holds them).
- ``config/plant.toml``: :mod:`plant_sim.plant` (:class:`plant_sim.plant.PlantSettings`).
- ``config/sweep.toml``: :mod:`controller.sweep.spec`.
- Model files (JSON): :mod:`models.model_schema`, one struct per model kind.
- Recordings (CSV): :mod:`models.recording` (a vectorized reader; no msgspec).

How to add a key
----------------
Add a field to the section's struct with its type and default, e.g. in
:class:`controller.config.Loop`::

    trigger: Literal["timer", "measurement"] = "timer"

Use the constrained types below (``Finite``, ``Positive``, ``NonNegative``,
``Percent``, ``KeyId``, ...) so that NaN, infinities and out-of-range values
are refused with the file and the field named. A rule between fields goes in
the struct's ``__post_init__``: raise ``ValueError("duty_min_pct: must be <
duty_max_pct (got 80 >= 20)")``; the message is prefixed with the file and
the struct's path (``config/run.toml: limits.duty_min_pct: must be ...``). A new section is a new struct and one field of the file's struct.

How to add a model kind
-----------------------
See :mod:`models.model_schema`: one struct for the kind's ``params`` and one
:func:`models.model_schema.register` call naming its core class.
"""
from __future__ import annotations

import math
import os
import re
import sys
from typing import Annotated, Any

import msgspec

from .recording import InputError, decode_utf8, read_bytes

#: The largest finite float: an upper bound of ``le=MAX`` refuses +inf, and NaN fails every bound.
MAX = sys.float_info.max

Finite = Annotated[float, msgspec.Meta(ge=-MAX, le=MAX)]
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=MAX)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=MAX)]
Percent = Annotated[float, msgspec.Meta(ge=0.0, le=100.0)]
#: A noise standard deviation in L/min: squared by the filters, so bounded where a flow could be (1e4 L/min).
NoiseLpm = Annotated[float, msgspec.Meta(ge=0.0, le=1e4)]
NonEmpty = Annotated[str, msgspec.Meta(min_length=1)]
#: A Zenoh key chunk (``vent/valve/{id}``): no wildcards (``*``, ``**``, ``$*``), no ``/``, ``?``, ``#``.
KeyId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$")]

#: Depth of nesting allowed in a JSON input file (a model file needs 4).
MAX_JSON_DEPTH = 32
#: Largest JSON input file read, bytes (a preisach model with 1275 relays is ~100 kB).
MAX_JSON_BYTES = 64 << 20

_AT = re.compile(r"^(?P<msg>.*?)(?: - at `\$(?P<path>[^`]*)`)?$", re.S)
_BOUND = re.compile(r"^Expected `(?P<type>[^`]+)` (?P<op>>=|<=|>|<) (?P<num>\S+)$")
_TYPES = {"float": "a number", "int": "an integer", "str": "a string", "bool": "true or false",
          "array": "an array", "object": "a table/object", "null": "null"}


def _lookup(doc: Any, path: str):
    """The value at a msgspec path such as ``.loop.rate_hz`` or ``.w[3]``; ``...`` when absent."""
    node = doc
    for m in re.finditer(r"\.([^.\[]+)|\[(\d+)\]", path):
        try:
            node = node[m.group(1)] if m.group(1) is not None else node[int(m.group(2))]
        except (KeyError, IndexError, TypeError):
            return ...
    return node


def dotted(path: str) -> str:
    """``.loop.rate_hz`` -> ``loop.rate_hz``; ``.params.w[2]`` -> ``params.w[2]``."""
    return path[1:] if path.startswith(".") else path


def _got(value) -> str:
    if value is ...:
        return ""
    text = repr(value) if isinstance(value, str) else str(value).lower() if isinstance(value, (bool, float)) else str(value)
    if isinstance(value, (list, dict)):
        text = type(value).__name__ if len(text) > 40 else text
    return f" (got {text[:60]})"


def explain(exc: msgspec.ValidationError, doc: Any, field_names: dict[str, str] | None = None) -> str:
    """``FIELD: problem (got VALUE)`` from a msgspec error, FIELD dotted, VALUE looked up in ``doc``."""
    m = _AT.match(str(exc))
    msg, path = m.group("msg"), m.group("path") or ""
    value = _lookup(doc, path)
    where = dotted(path)
    if field_names:
        where = field_names.get(where, where)
    if isinstance(value, float) and not math.isfinite(value):
        text = "must be a finite number"
    elif (b := _BOUND.match(msg)) is not None:
        num = b.group("num")
        if b.group("op") == "<=" and num in (repr(MAX), "1.7976931348623157e+308"):
            text = "must be a finite number"
        elif b.group("op") == ">=" and num in (repr(-MAX), "-1.7976931348623157e+308"):
            text = "must be a finite number"
        else:
            text = f"must be {b.group('op')} {float(num):g}"
    elif msg.startswith("Expected `"):
        want = re.match(r"Expected `([^`]+)`(?:, got `([^`]+)`)?", msg)
        kinds = " or ".join(_TYPES.get(t.strip(), t.strip()) for t in want.group(1).split("|"))
        text = f"expected {kinds}"
        if "matching regex" in msg:
            text = "must be letters, digits, '_', '-' or '.' (no wildcards or '/')"
        elif "length >=" in msg:
            text = "must not be empty"
        elif "length <=" in msg:
            text = msg.replace("Expected", "expected").replace("`", "")
    elif msg.startswith("Object contains unknown field"):
        name = re.search(r"`([^`]*)`", msg).group(1)
        where = f"{where}.{name}" if where else name
        return f"{where}: unknown key"
    elif msg.startswith("Object missing required field"):
        name = re.search(r"`([^`]*)`", msg).group(1)
        where = f"{where}.{name}" if where else name
        return f"{where}: missing"
    elif msg.startswith("Invalid enum value") or msg.startswith("Invalid value"):
        text = "not one of the accepted words"
    else:  # a rule of __post_init__: "FIELD: problem" names a field of the struct at ``where``
        own = re.match(r"^([A-Za-z_][\w\[\]]*): (.*)$", msg, re.S)
        if own:
            where, msg = (f"{where}.{own.group(1)}" if where else own.group(1)), own.group(2)
        return f"{where}: {msg}" if where else msg
    return f"{where}: {text}{_got(value)}" if where else f"{text}{_got(value)}"


def convert(doc: Any, type_, source: str, field_names: dict[str, str] | None = None):
    """``doc`` (parsed TOML/JSON) as an instance of ``type_``; any mismatch raises one :class:`InputError` line.

    Parameters
    ----------
    doc : object
        The parsed document (dicts, lists, numbers, strings).
    type_ : type
        A msgspec struct (or any type msgspec converts to).
    source : str
        The file, for the message (``FILE: FIELD: problem (got VALUE)``).
    field_names : dict, optional
        Dotted paths to rename in messages (a flat struct whose fields live in file sections).
    """
    try:
        return msgspec.convert(doc, type_)
    except msgspec.ValidationError as exc:
        raise InputError(f"{source}: {explain(exc, doc, field_names)}") from None
    except RecursionError:
        raise InputError(f"{source}: nested deeper than {MAX_JSON_DEPTH} levels") from None


def _json_depth(text: str) -> int:
    """Deepest nesting of ``[``/``{`` outside strings, without recursion (vectorized over the characters)."""
    import numpy as np

    # drop escaped backslashes, then escaped quotes: every quote left opens or closes a string
    b = np.frombuffer(text.replace("\\\\", "").replace('\\"', "").encode("utf-8"), dtype=np.uint8)
    quote = b == ord('"')
    inside = (np.cumsum(quote) % 2 == 1) | quote
    step = np.zeros(b.size, dtype=np.int8)
    step[(b == ord("[")) | (b == ord("{"))] = 1
    step[(b == ord("]")) | (b == ord("}"))] = -1
    step[inside] = 0
    return int(np.cumsum(step, dtype=np.int64).max(initial=0))


def read_json(path: str | os.PathLike, max_depth: int = MAX_JSON_DEPTH, max_bytes: int = MAX_JSON_BYTES):
    """Parse a JSON input file with its size and nesting bounded; errors name the file (and line).

    NaN and infinities are parsed (model files may carry them in ``meta``);
    the schema decides where they are allowed.
    """
    import json

    path = os.fspath(path)
    data = read_bytes(path, "a JSON file", max_bytes)
    text = decode_utf8(path, data.removeprefix(b"\xef\xbb\xbf"))
    depth = _json_depth(text)
    if depth > max_depth:
        raise InputError(f"{path}: JSON nested {depth} levels deep (at most {max_depth})")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    except (RecursionError, ValueError) as exc:  # ValueError: an integer of more than 4300 digits
        raise InputError(f"{path}: not valid JSON ({type(exc).__name__}: {str(exc)[:80]})") from None
