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
