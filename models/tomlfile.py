"""TOML configuration files (run, plant, sweep), read with one-line errors."""
from __future__ import annotations

import os
import tomllib

from .recording import InputError


def read_toml(path: str | os.PathLike) -> dict:
    """The parsed document; a missing or malformed file raises :class:`InputError` naming it."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:  # TOML is UTF-8 (a UTF-16 or Latin-1 file fails here, before parsing)
        line = _line_of(path, exc.start)
        raise InputError(f"{path}: line {line}: not UTF-8 (byte 0x{exc.object[exc.start]:02x}); TOML files are "
                         f"UTF-8") from None


def _line_of(path: str, offset: int) -> int:
    """The 1-based line of byte ``offset`` in the file at ``path``."""
    with open(path, "rb") as fh:
        return fh.read(offset).count(b"\n") + 1
