"""TOML configuration files (run, plant, sweep), read with one-line errors."""
from __future__ import annotations

import os
import tomllib

from .recording import InputError, read_bytes


#: Largest TOML file read, bytes (the shipped ones are a few kB).
MAX_TOML_BYTES = 16 << 20


def read_toml(path: str | os.PathLike) -> dict:
    """The parsed document; a missing, special (FIFO, device), oversized or malformed file raises
    :class:`InputError` naming it."""
    path = os.fspath(path)
    data = read_bytes(path, "a TOML file", MAX_TOML_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:  # TOML is UTF-8 (a UTF-16 or Latin-1 file fails here, before parsing)
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"{path}: line {line}: not UTF-8 (byte 0x{data[exc.start]:02x}); TOML files are "
                         f"UTF-8") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
