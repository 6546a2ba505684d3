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

import io
import os
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from .atomicfile import atomic_open

REQUIRED = ("t_s", "duty_pct", "flow_lpm")
OPTIONAL_NUMERIC = ("supply_bar", "ref_lpm", "coil_temp_c")
#: Inclusive bounds: duty by DESIGN.md; flows and the supply within what any valve or sensor could report
#: (a ventilator's valve: 0-200 L/min), so that a fit's sums of squares stay finite.
RANGES = {"duty_pct": (0.0, 100.0), "flow_lpm": (-1e6, 1e6), "ref_lpm": (-1e6, 1e6), "supply_bar": (-1e3, 1e3),
          "coil_temp_c": (-273.15, 1e4)}
#: Sample rates a recording may have, Hz (DESIGN.md: 10 Hz to 2 kHz seen), and any step rate a verb may ask for.
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e5
#: Largest step of ``t_s``, in median steps: beyond it, a recording is not sampled at one rate.
MAX_GAP_STEPS = 1000
#: Most samples a verb derives from a duration or a recording's span (800 MB per float column).
MAX_SAMPLES = 100_000_000
#: Fewest rows to fit on, and the least span of duty (%) and flow (L/min) that excites a model.
MIN_FIT_ROWS = 20
MIN_EXCITATION = {"duty_pct": 0.1, "flow_lpm": 0.1}


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


#: Largest input file read whole, bytes (a 1.8 M-row recording is ~60 MB): a bigger one (a sparse file of
#: holes, a wrong path) is refused before anything of its size is allocated.
MAX_INPUT_BYTES = 1 << 30


def check_input_file(path: str | os.PathLike, what: str = "file", max_bytes: int = MAX_INPUT_BYTES) -> int:
    """Refuse, in one :class:`InputError` line, what cannot be read whole as an input file: missing, a folder,
    a symlink loop, no regular file (a FIFO would block the read forever, ``/dev/zero`` never end it), or
    larger than ``max_bytes``. Returns the file's size."""
    import stat

    path = os.fspath(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a directory, not {what}")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a device, FIFO or socket), not {what}")
    if st.st_size > max_bytes:
        raise InputError(f"{path}: {st.st_size} bytes, larger than {max_bytes} for {what}")
    return st.st_size


def read_bytes(path: str | os.PathLike, what: str = "file", max_bytes: int = MAX_INPUT_BYTES) -> bytes:
    """A whole input file; a missing file, a folder, a special file (FIFO, device), a file larger than
    ``max_bytes`` or an unreadable file raises one :class:`InputError` line."""
    path = os.fspath(path)
    check_input_file(path, what, max_bytes)
    try:
        with open(path, "rb") as fh:
            data = fh.read(max_bytes + 1)  # bounded: /proc files report size 0 and may grow
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    if len(data) > max_bytes:
        raise InputError(f"{path}: larger than {max_bytes} bytes for {what}")
    return data


def decode_utf8(path: str, data: bytes, first_line: int = 1) -> str:
    """``data`` as UTF-8 text; bad bytes raise :class:`InputError` naming their line (``data`` starts at ``first_line``)."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + first_line
        raise InputError(f"{path}:{line}: not UTF-8 text ({exc.reason})") from None


class _Lines:
    """Where the data lines of a CSV body are, found with numpy over its bytes (no Python loop per line).

    Attributes
    ----------
    start, stop : ndarray of int
        Byte range of every line of the body (without its newline).
    fields : ndarray of int
        Fields per line (commas + 1).
    blank : ndarray of bool
        Lines with nothing but whitespace; skipped, as the format allows.
    """

    def __init__(self, body: bytes):
        b = np.frombuffer(body, dtype=np.uint8)
        nl = np.flatnonzero(b == 10)
        self.start = np.concatenate([[0], nl + 1])
        self.stop = np.concatenate([nl, [b.size]])
        if self.start[-1] == b.size:  # the body ends with a newline: no line after it
            self.start, self.stop = self.start[:-1], self.stop[:-1]
        commas = np.flatnonzero(b == 44)
        self.fields = np.searchsorted(commas, self.stop) - np.searchsorted(commas, self.start) + 1
        self.blank = np.zeros(self.start.size, dtype=bool)
        for i in np.flatnonzero(self.fields == 1):  # one field: empty, whitespace, or a lone value
            self.blank[i] = not body[self.start[i]:self.stop[i]].strip()

    def line_number(self, row: int) -> int:
        """File line (1-based, the header is line 1) of data row ``row`` (blank lines not counted as rows)."""
        return int(np.flatnonzero(~self.blank)[row]) + 2


def _parse(text: str, cols: list[int], dtype=np.float64) -> np.ndarray:
    """Columns ``cols`` of comma-separated ``text`` (no header, no blank lines), one C parser pass."""
    return np.loadtxt(io.StringIO(text), delimiter=",", usecols=cols, dtype=dtype, ndmin=2, comments=None,
                      encoding=None)


def _first_unparsable(body: bytes, lines: "_Lines", cols: list[int]) -> int:
    """Index of the first line of ``body`` whose columns ``cols`` numpy's reader refuses, by halving.

    Each half is parsed by the same C reader as the whole, so the line found is
    the one the reader refused; the work is about twice one parse.
    """
    lo, hi = 0, len(lines.start)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            _parse(body[lines.start[lo]:lines.stop[mid - 1]].decode("utf-8"), cols)
        except ValueError:
            hi = mid
        else:
            lo = mid
    return lo


def _fast_parse(body: bytes, ncol: int, num_idx: list[int], text_idx: list[int]):
    """Columns of a CSV body by Arrow's C reader: ``(numbers (rows, len(num_idx)), {index: texts})``, or None.

    None whenever Arrow refuses or doubts anything (ragged rows, a cell that is
    not a number, an empty cell, whitespace-only lines): numpy's reader then
    reads the file again and decides, so what is accepted, and every message,
    comes from one reader; Arrow only makes the common case fast.
    """
    import pyarrow as pa
    import pyarrow.csv as pcsv

    names = [f"c{i}" for i in range(ncol)]
    types = {names[i]: pa.float64() for i in num_idx} | {names[i]: pa.string() for i in text_idx}
    try:
        table = pcsv.read_csv(
            io.BytesIO(body),
            read_options=pcsv.ReadOptions(column_names=names, use_threads=False),
            parse_options=pcsv.ParseOptions(quote_char=False, ignore_empty_lines=True),
            convert_options=pcsv.ConvertOptions(column_types=types, null_values=[], strings_can_be_null=False),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return None
    numbers = [table.column(names[i]) for i in num_idx]
    if table.num_rows == 0 or any(c.null_count for c in numbers):
        return None
    values = np.empty((table.num_rows, len(num_idx)))
    for j, c in enumerate(numbers):
        values[:, j] = c.to_numpy()
    return values, {i: table.column(names[i]).to_pylist() for i in text_idx}


def read_table(
    path: str | os.PathLike,
    required: Sequence[str],
    numeric: Iterable[str] = (),
    ranges: Mapping[str, tuple[float, float]] | None = None,
    time_column: str | None = "t_s",
) -> Recording:
    """Read a CSV with validation, vectorized; any other column is kept as text.

    A UTF-8 byte-order mark and CRLF (or CR) line ends are accepted; blank
    lines are skipped. The cells are parsed by a C reader in one pass (Arrow's
    when it accepts the whole file, else numpy's, which decides and locates
    what it refuses), then checked as whole columns; the first bad row in file
    order is mapped back to its line.

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
    data = read_bytes(path, "a CSV file")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    end = data.find(b"\n")
    head = decode_utf8(path, data[: end if end >= 0 else len(data)])
    body = data[end + 1:] if end >= 0 else b""
    if not head.strip():
        raise InputError(f"{path}:1: empty file (expected a header row with {', '.join(required)})")
    header = [h.strip() for h in head.split(",")]
    for name in required:
        if name not in header:
            raise InputError(f"{path}:1: column '{name}': missing from the header")
    dupes = {h for h in header if header.count(h) > 1}
    if dupes:
        raise InputError(f"{path}:1: column '{sorted(dupes)[0]}': appears twice in the header")
    wanted = set(required) | set(numeric)
    num_idx = [i for i, h in enumerate(header) if h in wanted]
    text_idx = [i for i, h in enumerate(header) if h not in wanted]

    parsed = _fast_parse(body, len(header), num_idx, text_idx) if body.strip() else None
    if parsed is None:
        body, values, texts, line_of = _careful_parse(path, body, header, num_idx, text_idx)
    else:
        values, texts = parsed
        line_of = None
        if body.startswith(b"\n") or b"\n\n" in body:  # empty lines skipped: map rows to lines
            lines = _Lines(body)
            line_of = np.flatnonzero(~lines.blank) + 2
            body = b"\n".join(body[lines.start[i]:lines.stop[i]] for i in line_of - 2)

    def line(row: int) -> int:
        return int(line_of[row]) if line_of is not None else row + 2

    def cell(row: int, col: int) -> str:
        lines = _Lines(body)
        return body[lines.start[row]:lines.stop[row]].decode("utf-8", "replace").split(",")[col].strip()

    # every check on whole columns; the first bad row in file order wins, then header order, then check order
    problems = []
    for j, i in enumerate(num_idx):
        name, v = header[i], values[:, j]
        bad = ~np.isfinite(v)
        if bad.any():
            r = int(np.argmax(bad))
            problems.append((r, i, 0, lambda r=r, i=i, name=name: f"column '{name}': {cell(r, i)} is not a finite number"))
        if name in ranges:
            lo, hi = ranges[name]
            out = ~((v >= lo) & (v <= hi)) & ~bad
            if out.any():
                r = int(np.argmax(out))
                problems.append((r, i, 1, lambda r=r, i=i, name=name, lo=lo, hi=hi:
                                 f"column '{name}': {cell(r, i)} outside {lo:g}..{hi:g}"))
        if name == time_column and len(v) > 1:
            back = ~(np.diff(v) > 0) & ~bad[1:] & ~bad[:-1]
            if back.any():
                r = int(np.argmax(back)) + 1
                problems.append((r, i, 2, lambda r=r, i=i, name=name, v=v: f"column '{name}': time {cell(r, i)} "
                                                                               f"does not increase (previous {v[r - 1]:g})"))
    if problems:
        r, _, _, msg = min(problems, key=lambda p: p[:3])
        raise InputError(f"{path}:{line(r)}: {msg()}")
    cols = {header[i]: np.ascontiguousarray(values[:, j]) for j, i in enumerate(num_idx)}
    return Recording(path, cols, {header[i]: texts[i] for i in text_idx})


def _careful_parse(path: str, body: bytes, header: list[str], num_idx: list[int], text_idx: list[int]):
    """numpy's reader, with every refusal located: ``(body without blank lines, numbers, texts, line map)``."""
    text = decode_utf8(path, body, first_line=2)
    if "\x00" in text:
        raise InputError(f"{path}:{text.count(chr(10), 0, text.index(chr(0))) + 2}: NUL byte: not a text CSV file")
    lines = _Lines(body)
    ncol = len(header)
    ragged = np.flatnonzero((lines.fields != ncol) & ~lines.blank)
    if ragged.size:
        i = int(ragged[0])
        raise InputError(f"{path}:{i + 2}: expected {ncol} fields as in the header, found {int(lines.fields[i])}")
    rows = np.flatnonzero(~lines.blank)
    if rows.size == 0:
        raise InputError(f"{path}:1: header only, no data rows")
    line_of = None
    if lines.blank.any():  # the C parsers skip empty lines but not whitespace-only ones: drop both
        line_of = rows + 2
        body = b"\n".join(body[lines.start[i]:lines.stop[i]] for i in rows)
        text = body.decode("utf-8")
        lines = _Lines(body)
    try:
        values = _parse(text, num_idx)
    except ValueError:
        row = _first_unparsable(body, lines, num_idx)
        at = int(line_of[row]) if line_of is not None else row + 2
        cells = body[lines.start[row]:lines.stop[row]].decode("utf-8").split(",")
        for i in num_idx:
            try:
                if not cells[i].strip():
                    raise ValueError("empty")
                _parse(cells[i], [0])
            except ValueError:
                raise InputError(f"{path}:{at}: column '{header[i]}': not a number: {cells[i].strip()!r}") from None
        raise InputError(f"{path}:{at}: not a row of numbers")  # the parser refused the line as a whole
    texts = {}
    if text_idx:
        strings = _parse(text, text_idx, dtype=str)
        texts = {i: strings[:, j].tolist() for j, i in enumerate(text_idx)}
    return body, values, texts, line_of


def read_recording(path: str | os.PathLike) -> Recording:
    """Read a valve recording (DESIGN.md, Recordings) with every check it names, then its sampling.

    The sample rate is whatever ``t_s`` says; it must be one rate (no gap of
    more than :data:`MAX_GAP_STEPS` median steps) between :data:`MIN_RATE_HZ`
    and :data:`MAX_RATE_HZ`, so that nothing sized by the rate or the span
    downstream (filters, resampling, delay lines) can explode.
    """
    rec = read_table(path, REQUIRED, OPTIONAL_NUMERIC, RANGES, "t_s")
    check_sampling(rec)
    return rec


def check_sampling(rec: Recording) -> None:
    """Refuse a recording whose ``t_s`` is not one plausible sample rate (see :func:`read_recording`)."""
    t = rec.t_s
    if len(t) < 2:
        return
    span = t[-1] - t[0]
    rate = (len(t) - 1) / span
    if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        raise InputError(f"{rec.path}: column 't_s': {len(t)} rows over {span:.6g} s is {rate:.3g} Hz, "
                         f"outside {MIN_RATE_HZ:g}..{MAX_RATE_HZ:g} Hz")
    step = np.diff(t)
    median = float(np.median(step))
    k = int(np.argmax(step))
    if step[k] > MAX_GAP_STEPS * median:
        raise InputError(f"{rec.path}: column 't_s': a gap of {step[k]:.6g} s after t = {t[k]:.6g} s, more than "
                         f"{MAX_GAP_STEPS} times the median step ({median:.3g} s): not one sample rate")


def check_fittable(rec: Recording, min_rows: int = MIN_FIT_ROWS, purpose: str = "fit a model") -> None:
    """Refuse a recording that cannot identify (or validate) a model: too few rows, or no excitation (duty or
    flow constant)."""
    if len(rec) < min_rows:
        raise InputError(f"{rec.path}: {len(rec)} data rows, too few to {purpose} (at least {min_rows})")
    for name, unit in (("duty_pct", "%"), ("flow_lpm", "L/min")):
        v = rec.columns[name]
        if np.ptp(v) < MIN_EXCITATION[name]:
            raise InputError(f"{rec.path}: column '{name}': spans only {np.ptp(v):.3g} {unit} "
                             f"({v.min():g}..{v.max():g}): no excitation to {purpose} on")


class RecordingWriter:
    """Write a recording row by row, flushed as it goes.

    A killed run keeps every row written before the kill; the file is valid
    CSV at every flush.
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str]):
        self.path = os.fspath(path)
        self.columns = tuple(columns)
        if os.path.exists(self.path) and not os.path.isfile(self.path):  # a FIFO would block the run here
            raise InputError(f"{self.path}: exists and is not a regular file (a folder, device, FIFO or socket)")
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
    with atomic_open(path, newline="") as fh:
        fh.write(",".join(names) + "\n")
        cols = [np.asarray(columns[k]) if not isinstance(columns[k], list) else columns[k] for k in names]
        for i in range(n):
            fh.write(
                ",".join(c[i] if isinstance(c[i], str) else f"{float(c[i]):.9g}" for c in cols) + "\n"
            )
