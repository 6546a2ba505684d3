"""Recordings: the CSV format of DESIGN.md, read with line-accurate errors.

A recording has a header row and comma-separated numbers. Required columns
are ``t_s`` (seconds, strictly increasing), ``duty_pct`` (0-100) and
``flow_lpm``; ``supply_bar``, ``ref_lpm`` and ``coil_temp_c`` are optional
numeric columns; any other column is kept as text and ignored.

Every problem with the input raises :class:`InputError`, whose message is a
single line ``FILE:LINE: column 'NAME': problem`` that the CLI prints before
exiting with code 2.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

REQUIRED = ("t_s", "duty_pct", "flow_lpm")
OPTIONAL_NUMERIC = ("supply_bar", "ref_lpm", "coil_temp_c")
RANGES = {"duty_pct": (0.0, 100.0)}


class InputError(ValueError):
    """Bad user input: the message is one line naming file, line/field and problem."""


@dataclass(frozen=True)
class Recording:
    """A validated recording.

    Attributes
    ----------
    path : str
        Where it was read from (for messages).
    columns : dict of str to ndarray
        Every numeric column, float64, same length; includes ``t_s``,
        ``duty_pct`` and ``flow_lpm`` for a valve recording.
    text_columns : dict of str to list of str
        Columns kept as they were (non-numeric extras, e.g. ``state``).
    """

    path: str
    columns: Mapping[str, np.ndarray]
    text_columns: Mapping[str, list] = field(default_factory=dict)

    @property
    def t_s(self) -> np.ndarray:
        return self.columns["t_s"]

    @property
    def duty_pct(self) -> np.ndarray:
        return self.columns["duty_pct"]

    @property
    def flow_lpm(self) -> np.ndarray:
        return self.columns["flow_lpm"]

    def __len__(self) -> int:
        return len(self.columns["t_s"])

    @property
    def rate_hz(self) -> float:
        """Mean sample rate, from ``t_s``."""
        t = self.t_s
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else float("nan")

    def get(self, name: str) -> np.ndarray | None:
        return self.columns.get(name)

    def slice(self, start: int, stop: int) -> "Recording":
        """Rows ``start:stop`` as a new recording."""
        return Recording(
            self.path,
            {k: v[start:stop] for k, v in self.columns.items()},
            {k: v[start:stop] for k, v in self.text_columns.items()},
        )


def _parse_float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def read_table(
    path: str | os.PathLike,
    required: Sequence[str],
    numeric: Iterable[str] = (),
    ranges: Mapping[str, tuple[float, float]] | None = None,
    time_column: str | None = "t_s",
) -> Recording:
    """Read a CSV with validation; any other column is kept as text.

    Parameters
    ----------
    path : path-like
        The CSV file.
    required : sequence of str
        Columns that must exist and hold finite numbers.
    numeric : iterable of str
        Optional columns that, when present, must hold finite numbers.
    ranges : mapping, optional
        ``{column: (lo, hi)}`` inclusive bounds.
    time_column : str or None
        Column that must be strictly increasing.

    Raises
    ------
    InputError
        One line: ``FILE:LINE: column 'NAME': problem``.
    """
    path = os.fspath(path)
    ranges = dict(ranges or {})
    try:
        with open(path, "r", encoding="utf-8", newline="") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not a CSV file") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None

    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise InputError(f"{path}:1: empty file (expected a header row with {', '.join(required)})")
    header = [h.strip() for h in lines[0].split(",")]
    for name in required:
        if name not in header:
            raise InputError(f"{path}:1: column '{name}': missing from the header")
    dupes = {h for h in header if header.count(h) > 1}
    if dupes:
        raise InputError(f"{path}:1: column '{sorted(dupes)[0]}': appears twice in the header")
    numeric_cols = [h for h in header if h in set(required) | set(numeric)]
    idx = {h: i for i, h in enumerate(header)}
    values = {h: [] for h in numeric_cols}
    texts = {h: [] for h in header if h not in values}
    ncol = len(header)
    last_t = -math.inf
    data_rows = 0
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != ncol:
            raise InputError(f"{path}:{lineno}: expected {ncol} fields as in the header, found {len(cells)}")
        for h in numeric_cols:
            cell = cells[idx[h]].strip()
            v = _parse_float(cell)
            if v is None:
                raise InputError(f"{path}:{lineno}: column '{h}': not a number: {cell!r}")
            if not math.isfinite(v):
                raise InputError(f"{path}:{lineno}: column '{h}': {cell} is not a finite number")
            if h in ranges:
                lo, hi = ranges[h]
                if not lo <= v <= hi:
                    raise InputError(f"{path}:{lineno}: column '{h}': {cell} outside {lo:g}..{hi:g}")
            if h == time_column:
                if v <= last_t:
                    raise InputError(
                        f"{path}:{lineno}: column '{h}': time {cell} does not increase (previous {last_t:g})"
                    )
                last_t = v
            values[h].append(v)
        for h in texts:
            texts[h].append(cells[idx[h]])
        data_rows += 1
    if data_rows == 0:
        raise InputError(f"{path}:1: header only, no data rows")
    cols = {h: np.asarray(v, dtype=np.float64) for h, v in values.items()}
    return Recording(path, cols, texts)


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a valve recording (DESIGN.md, Recordings) with every check it names."""
    return read_table(path, REQUIRED, OPTIONAL_NUMERIC, RANGES, "t_s")


class RecordingWriter:
    """Write a recording row by row, flushed as it goes.

    A killed run keeps every row written before the kill; the file is valid
    CSV at every flush.
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str]):
        self.path = os.fspath(path)
        self.columns = tuple(columns)
        self._fh = open(self.path, "w", encoding="utf-8", newline="")
        self._fh.write(",".join(self.columns) + "\n")
        self._fh.flush()

    def write(self, row: Sequence) -> None:
        self._fh.write(",".join(v if isinstance(v, str) else f"{v:.9g}" for v in row) + "\n")
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_recording(path: str | os.PathLike, columns: Mapping[str, Sequence]) -> None:
    """Write whole columns (equal length) as a recording CSV, atomically."""
    names = list(columns)
    n = len(next(iter(columns.values())))
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(names) + "\n")
        cols = [np.asarray(columns[k]) if not isinstance(columns[k], list) else columns[k] for k in names]
        for i in range(n):
            fh.write(
                ",".join(c[i] if isinstance(c[i], str) else f"{float(c[i]):.9g}" for c in cols) + "\n"
            )
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
