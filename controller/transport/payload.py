"""Defensive parsing of the Zenoh payloads of DESIGN.md: one parser for every key.

A payload is UTF-8 JSON ``{"t": s, "seq": n, "value": x, ...}`` (extra
fields allowed). Anything on the network may arrive instead, so the parser
is total: every input either yields a :class:`Message` or raises
:class:`PayloadError` (never RecursionError, OverflowError, MemoryError or a
decoding error), in time and memory bounded by the size limit:

1. size: at most ``max_bytes`` (checked by the transport before the payload
   is even copied out of Zenoh, :func:`controller.transport.zenoh.raw_payload`);
2. nesting depth: at most :data:`MAX_DEPTH` levels of arrays/objects,
   measured without recursion (strings blanked by one regular expression,
   every byte but brackets deleted, innermost pairs removed level by level,
   all in C) before ``json`` sees the text, whose scanner recurses;
3. numbers: finite floats only (``NaN``/``Infinity`` literals and overflowing
   exponents rejected), integers of at most :data:`INT_DIGITS` digits (a
   400-digit ``value`` is an error, not an OverflowError later);
4. shape: a JSON object with ``value`` (a finite number, or a short word for
   ``ctrl/mode``); ``seq`` an integer and ``t`` a finite number when present;
   ``src``, when present, a short string naming the publisher.

A payload of DESIGN.md's fields alone (``t``, ``seq``, ``value``, ``src``;
no other field, so nothing nested) takes a fast path: msgspec decodes it
into those fields (~0.3 µs, against ~7 µs for ``json`` with the checks
above) and the same limits are checked on the result; anything it does not
take goes through the full parser, which alone decides and words the
error. It is the measurement's path in the live loop, where each
microsecond is the command's.

Pure functions of bytes: no Zenoh here, so the fuzz tests drive them directly.
"""
from __future__ import annotations

import json
import math
import re
from typing import NamedTuple

import msgspec

#: Largest payload accepted on the control keys, bytes (a DESIGN.md payload is ~60 bytes).
MAX_PAYLOAD_BYTES = 4096
#: Largest nesting of arrays/objects (a DESIGN.md payload has 1; ``ctrl/status`` 3).
MAX_DEPTH = 8
#: Longest integer literal, digits (``seq`` counts 1 kHz steps: 16 digits last 300 000 years).
INT_DIGITS = 18
#: Longest ``ctrl/mode`` word and ``src`` string, characters.
WORD_CHARS = 64

_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')
_PAIR = re.compile(rb"\[\]|\{\}")  # one scan: removes exactly the innermost level
_NOT_BRACKET = bytes(b for b in range(256) if b not in b"[]{}")


class PayloadError(ValueError):
    """A payload that is not a DESIGN.md message; the text says why."""


class Message(NamedTuple):
    """A parsed payload: ``value`` (float, or str for a word), ``seq``, ``t_s`` and ``src`` (None when absent)."""

    value: float | str
    seq: int | None
    t_s: float | None
    src: str | None


def _int(s: str) -> int:
    if len(s.lstrip("-")) > INT_DIGITS:
        raise PayloadError(f"integer of {len(s)} digits")
    return int(s)


def _float(s: str) -> float:
    x = float(s)
    if not math.isfinite(x):
        raise PayloadError(f"number {s[:24]} overflows")
    return x


def _constant(s: str):
    raise PayloadError(f"{s} is not a finite number")


_DECODER = json.JSONDecoder(parse_float=_float, parse_int=_int, parse_constant=_constant)


def nesting_too_deep(data: bytes, max_depth: int = MAX_DEPTH) -> bool:
    """True if ``data`` nests arrays/objects deeper than ``max_depth`` (or its brackets do not pair).

    Strings are blanked first (brackets inside them do not count); then only
    brackets are kept and each pass removes the innermost pairs: a document of
    depth d is empty after d passes. Iterative and linear per pass.
    """
    if data.count(b"[") + data.count(b"{") <= max_depth:
        return False
    b = _STRING.sub(b'""', data).translate(None, _NOT_BRACKET)
    for _ in range(max_depth):
        if not b:
            return False
        b = _PAIR.sub(b"", b)
    return bool(b)


def decode(data: bytes, max_bytes: int = MAX_PAYLOAD_BYTES, max_depth: int = MAX_DEPTH) -> dict:
    """The JSON object of a payload, checked for size, depth and numbers; :class:`PayloadError` otherwise."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise PayloadError(f"payload of type {type(data).__name__}")
    if len(data) > max_bytes:
        raise PayloadError(f"payload of {len(data)} bytes (limit {max_bytes})")
    data = bytes(data)
    if nesting_too_deep(data, max_depth):
        raise PayloadError(f"nested deeper than {max_depth}")
    try:
        text = data.decode("utf-8")
        obj = _DECODER.decode(text)
    except PayloadError:
        raise
    except (ValueError, RecursionError, OverflowError, MemoryError) as exc:
        # ValueError covers JSONDecodeError and UnicodeDecodeError; the others cannot pass the
        # checks above but are caught so that the parser stays total whatever json does.
        raise PayloadError(f"not JSON ({type(exc).__name__}: {str(exc)[:60]})") from None
    if not isinstance(obj, dict):
        raise PayloadError(f"a JSON {type(obj).__name__}, not an object")
    return obj


def _fields(obj: dict) -> tuple[int | None, float | None, str | None]:
    seq, t, src = obj.get("seq"), obj.get("t"), obj.get("src")
    if seq is not None and (type(seq) is not int):
        raise PayloadError("seq is not an integer")
    if t is not None and (type(t) not in (int, float)):
        raise PayloadError("t is not a number")
    if src is not None and (type(src) is not str or len(src) > WORD_CHARS):
        raise PayloadError("src is not a short string")
    return seq, (None if t is None else float(t)), src


def _number(obj: dict) -> Message:
    if "value" not in obj:
        raise PayloadError("no value")
    v = obj["value"]
    if type(v) not in (int, float):  # bool is a subclass of int: excluded by the exact type test
        raise PayloadError(f"value is a {type(v).__name__}, not a number")
    return Message(float(v), *_fields(obj))


class _Fields(msgspec.Struct, forbid_unknown_fields=True):
    """DESIGN.md's fields and no other: the fast path's shape (numbers as written: int or float)."""

    value: int | float
    t: int | float | None = None
    seq: int | None = None
    src: str | None = None


_FIELDS = msgspec.json.Decoder(_Fields)
_INT_BOUND = 10 ** INT_DIGITS  # integers of at most INT_DIGITS digits are below it


def parse_number(data: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> Message:
    """A message whose ``value`` is a finite number (``ref/flow``, ``meas/flow``, ``cmd/duty``, ``ctrl/error``)."""
    if type(data) is bytes and len(data) <= max_bytes:
        try:
            f = _FIELDS.decode(data)  # JSON only: no NaN/Infinity literal, no overflowing float
        except (msgspec.DecodeError, ValueError):  # the full parser words the error
            pass
        else:
            v, t, seq, src = f.value, f.t, f.seq, f.src
            if ((type(v) is float or -_INT_BOUND < v < _INT_BOUND)
                    and (t is None or type(t) is float or -_INT_BOUND < t < _INT_BOUND)
                    and (seq is None or -_INT_BOUND < seq < _INT_BOUND)
                    and (src is None or len(src) <= WORD_CHARS)):
                return Message(float(v), seq, None if t is None else float(t), src)
    return _number(decode(data, max_bytes))


class Command(NamedTuple):
    """A ``cmd/duty`` message: a :class:`Message` plus ``meas_seq``, the ``seq`` of the measurement it
    was computed from (None when absent), for the valve's round-trip timing."""

    value: float
    seq: int | None
    t_s: float | None
    src: str | None
    meas_seq: int | None


def parse_command(data: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> Command:
    """A ``cmd/duty`` message with its ``meas_seq`` (an integer when present)."""
    obj = decode(data, max_bytes)
    ms = obj.get("meas_seq")
    if ms is not None and type(ms) is not int:
        raise PayloadError("meas_seq is not an integer")
    return Command(*_number(obj), ms)


def parse_word(data: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> Message:
    """A message whose ``value`` is a short word (``ctrl/mode``: a controller word)."""
    obj = decode(data, max_bytes)
    v = obj.get("value")
    if type(v) is not str or not 0 < len(v) <= WORD_CHARS:
        raise PayloadError("value is not a word")
    return Message(v, *_fields(obj))


_ENCODER = msgspec.json.Encoder()


def encode(t_s: float, seq: int, value, /, **extra) -> bytes:
    """The payload of a message: UTF-8 JSON, a non-finite number written ``null`` (a receiver refuses it as a
    value). msgspec writes it (~1 µs; ``json`` ~7), ``json`` what msgspec does not take (numpy scalars)."""
    doc = {"t": t_s, "seq": seq, "value": value, **extra}
    try:
        return _ENCODER.encode(doc)
    except TypeError:
        return json.dumps(doc, default=_builtins).encode()


def _builtins(obj):
    """What ``json`` cannot write itself: a msgspec Struct (a status) as its fields."""
    if isinstance(obj, msgspec.Struct):
        return msgspec.structs.asdict(obj)
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serializable")
