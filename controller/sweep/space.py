"""The candidates of a sweep: grids and random samples of controller settings, from the sweep TOML.

Each ``[[candidates]]`` block names one controller word and gives its
settings by the section and key they have in the run config (``pid.kp``,
``kf.q_bias_lpm``, ``ff.model``, ...)::

    [[candidates]]
    controller = "ff+pid"
    sample = "grid"               # every combination of the lists below
    pid.kp = [0.05, 0.1, 0.2]     # a list: one grid axis
    pid.tf_s = 0.004              # a number (or string): fixed

    [[candidates]]
    controller = "pid"
    sample = 300                  # 300 random points (seeded by the sweep's seed)
    pid.kp = {log = [0.02, 1.0]}  # log-uniform in [lo, hi]
    pid.kd = {uniform = [0, 0.002]}
    ff.model = ["a.json", "b.json"]   # a list with random sampling: an equally likely choice

Settings a block does not give keep the run config's values. The candidates
of all blocks form one :class:`Candidates` table (columns of equal length,
``nan`` / empty where a setting does not apply to a word).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from models.recording import InputError

RANGES = ("log", "uniform")
#: Most candidates one block may make (a grid's product or a sample count): beyond it, a sweep is a mistake.
MAX_CANDIDATES = 1_000_000


@dataclass(frozen=True)
class Candidates:
    """The candidate table.

    Attributes
    ----------
    controller : ndarray of str, shape (C,)
        Controller word per candidate.
    settings : dict
        ``"section.key"`` -> ndarray (C,): float (``nan`` where not given) or
        object (strings, ``""`` where not given).
    """

    controller: np.ndarray
    settings: dict

    def __len__(self) -> int:
        return len(self.controller)

    def row(self, i: int) -> dict:
        """Candidate ``i``'s given settings (``section.key`` -> value), without the blanks."""
        out = {}
        for k, v in self.settings.items():
            x = v[i]
            if isinstance(x, str):
                if x != "":
                    out[k] = x
            elif np.isfinite(x):
                out[k] = float(x)
        return out

    def take(self, idx) -> "Candidates":
        idx = np.asarray(idx)
        return Candidates(self.controller[idx], {k: v[idx] for k, v in self.settings.items()})


def _flatten(block: dict, prefix: str = "") -> dict:
    """``{"pid": {"kp": [..]}}`` -> ``{"pid.kp": [..]}``; range tables ({log|uniform = [lo, hi]}) stay leaves."""
    out = {}
    for k, v in block.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and not (set(v) & set(RANGES)):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


def _finite(v: int | float, where: str) -> float:
    """``v`` as a finite float (TOML integers have no size limit: 10**400 does not fit a float)."""
    try:
        x = float(v)
    except OverflowError:
        raise InputError(f"{where}: {str(v)[:24]}... is too large for a float") from None
    if not np.isfinite(x):
        raise InputError(f"{where}: not finite")
    return x


def _number_or_text(v, where: str):
    if isinstance(v, bool) or not isinstance(v, (int, float, str)):
        raise InputError(f"{where}: expected a number or a string, got {v!r}")
    return _finite(v, where) if isinstance(v, (int, float)) else v


def _range(v: dict, where: str) -> tuple[str, float, float]:
    if len(v) != 1 or next(iter(v)) not in RANGES:
        raise InputError(f"{where}: a range is {{log = [lo, hi]}} or {{uniform = [lo, hi]}}, got {v!r}")
    kind, lohi = next(iter(v.items()))
    if not (isinstance(lohi, list) and len(lohi) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                              for x in lohi)):
        raise InputError(f"{where}: {kind} = [lo, hi] with two numbers, got {lohi!r}")
    lo, hi = (_finite(x, f"{where}: {kind} range") for x in lohi)
    if not lo <= hi or (kind == "log" and lo <= 0):
        raise InputError(f"{where}: {kind} range [{lo:g}, {hi:g}] needs lo <= hi" + (" and lo > 0" if kind == "log" else ""))
    return kind, lo, hi


def expand_block(block: dict, where: str, modes, known: set[str], rng: np.random.Generator) -> tuple[list, list[dict]]:
    """One ``[[candidates]]`` block -> (controller words, settings dicts)."""
    block = dict(block)
    word = block.pop("controller", None)
    if word not in modes:
        raise InputError(f"{where}.controller: {word!r} is not a controller word (one of {', '.join(modes)})")
    sample = block.pop("sample", "grid")
    settings = _flatten(block)
    for name in settings:
        if name not in known:
            raise InputError(f"{where}.{name}: unknown setting (one of {', '.join(sorted(known))})")
    if sample == "grid":
        axes = {}
        for name, v in settings.items():
            if isinstance(v, dict):
                raise InputError(f"{where}.{name}: a range needs random sampling (sample = N)")
            vals = v if isinstance(v, list) else [v]
            if not vals:
                raise InputError(f"{where}.{name}: empty list")
            axes[name] = [_number_or_text(x, f"{where}.{name}") for x in vals]
        names = list(axes)
        size = int(np.prod([len(axes[n]) for n in names], dtype=float))
        if size > MAX_CANDIDATES:
            raise InputError(f"{where}: the grid has {size:.3g} points, more than {MAX_CANDIDATES}")
        rows = [dict(zip(names, combo)) for combo in itertools.product(*(axes[n] for n in names))]
        return [word] * len(rows), rows
    if isinstance(sample, bool) or not isinstance(sample, int) or sample < 1:
        raise InputError(f"{where}.sample: \"grid\" or a positive number of random points, got {sample!r}")
    if sample > MAX_CANDIDATES:
        raise InputError(f"{where}.sample: at most {MAX_CANDIDATES} random points, got {sample}")
    cols = {}
    for name, v in settings.items():
        w = f"{where}.{name}"
        if isinstance(v, dict):
            kind, lo, hi = _range(v, w)
            u = rng.uniform(0.0, 1.0, sample)
            cols[name] = list(np.exp(np.log(lo) + u * (np.log(hi) - np.log(lo))) if kind == "log" else lo + u * (hi - lo))
        elif isinstance(v, list):
            if not v:
                raise InputError(f"{w}: empty list")
            choices = [_number_or_text(x, w) for x in v]
            cols[name] = [choices[i] for i in rng.integers(0, len(choices), sample)]
        else:
            cols[name] = [_number_or_text(v, w)] * sample
    rows = [{n: cols[n][i] for n in cols} for i in range(sample)]
    return [word] * sample, rows


def candidates(blocks: list, source: str, modes, known: set[str], seed: int = 0) -> Candidates:
    """All blocks of a sweep file as one table (random blocks drawn from one generator seeded ``seed``)."""
    if not isinstance(blocks, list) or not blocks:
        raise InputError(f"{source}: key 'candidates': missing or empty (a [[candidates]] block per controller word)")
    rng = np.random.default_rng(seed)
    words, rows = [], []
    for i, block in enumerate(blocks):
        if not isinstance(block, dict):
            raise InputError(f"{source}: candidates[{i}]: expected a table")
        w, r = expand_block(block, f"{source}: candidates[{i}]", modes, known, rng)
        words += w
        rows += r
    return table(words, rows)


def table(words: list, rows: list[dict]) -> Candidates:
    """Candidates from words and settings dicts (missing settings blank)."""
    names = list(dict.fromkeys(n for r in rows for n in r))
    settings = {}
    for n in names:
        vals = [r.get(n) for r in rows]
        if any(isinstance(v, str) for v in vals):
            settings[n] = np.array(["" if v is None else str(v) for v in vals], dtype=object)
        else:
            settings[n] = np.array([np.nan if v is None else float(v) for v in vals])
    return Candidates(np.array(words, dtype=object), settings)
