"""The sweep file (``config/sweep.toml``): base run, reference, plant variants, candidates, ranking.

A sweep is a set of changes to a run configuration (``config/run.toml`` by
default, key ``run``): each candidate is that run with its controller word
and some settings replaced, so the run's own controller is the *default*
candidate and the best one can be written back as a run configuration.

Top-level keys (all optional except ``candidates``)::

    run = "run.toml"         # base run configuration, relative to this file
    duration_s = 5.0         # simulated time per candidate
    seed = 0                 # random sampling of candidates (plant noise: the run's seed)
    objective = "worst_iae"  # rank by this column, least wins (iae when there are no variants)
    margins_top = 20         # gain and phase margins for the best N candidates
    margins_flow_lpm = 60.0  # operating flow of the linearized loop (default: the profile's peak)
    heatmap = ["ff_pid.kp", "ff_pid.ki"]   # the two settings of the plot's heatmap
    chunk_loops = 512        # loops (candidates x variants) per batch

    [profile]                # changes to the run's [profile] (plant_sim.protocols.BreathProfile)

    [[variants]]             # plant variants on top of the run's simulated valve; the first is the
    [[variants]]             # nominal one (an empty table: the run's valve as it is)
    supply_bar = 2.6         # PlantParams fields and effect words (DESIGN.md units)
    [[variants]]
    model = "other.json"     # another forward model as the valve (relative to this file): model error

    [[candidates]]           # see controller.sweep.space
"""
from __future__ import annotations

import copy
import dataclasses
import os
from dataclasses import dataclass
from typing import Annotated

import msgspec
import numpy as np

from models.atomicfile import write_text_atomic
from models.recording import InputError
from models.schema import NonEmpty, Positive, convert
from models.tomlfile import read_toml

from . import metrics, space

DEFAULT_SWEEP = "config/sweep.toml"
#: Fewest loop steps a sweep's run may have (0 made an empty reference and an IndexError in the figures).
MIN_STEPS = 10


class SweepFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The sweep file's schema (framework and how to add a key: :mod:`models.schema`)."""

    run: NonEmpty = "run.toml"
    duration_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 5.0
    seed: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)] = 0
    objective: str | None = None
    margins_top: Annotated[int, msgspec.Meta(ge=0, le=100_000)] = 20
    margins_flow_lpm: Positive | None = None
    heatmap: list[str] = msgspec.field(default_factory=list)
    chunk_loops: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] = 512
    profile: dict = msgspec.field(default_factory=dict)
    variants: Annotated[list[dict], msgspec.Meta(min_length=1)] = msgspec.field(default_factory=lambda: [{}])
    candidates: list = msgspec.field(default_factory=list)


#: run-config sections whose keys a candidate may set ("model": the feedforward's model file)
CONTROLLER_SECTIONS = ("limits", "valve", "feedforward", "pid", "ff_pid", "kf")
#: which controller words a setting matters to (for the table: blank where it does not)
RELEVANT = {"pid": {"pid"}, "ff_pid": {"ff+pid"}, "kf": {"ff+kf"}, "feedforward": {"ff", "ff+pid", "ff+kf"},
            "valve": {"ff", "ff+pid", "ff+kf"}, "model": {"ff", "ff+pid", "ff+kf"},
            "limits": {"pid", "ff", "ff+pid", "ff+kf"}}


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep file.

    Attributes
    ----------
    path : str
    run : controller.config.RunConfig
        The base run, with the sweep's ``[profile]`` changes applied.
    duration_s, seed, objective, margins_top, margins_flow_lpm, heatmap, chunk_loops
        As in the file (``objective`` resolved).
    variants : list of dict
        Plant changes per variant (the first: nominal).
    candidates : controller.sweep.space.Candidates
        The default candidate first (the run's controller as configured), then the file's.
    """

    path: str
    run: object
    duration_s: float
    seed: int
    objective: str
    margins_top: int
    margins_flow_lpm: float | None
    heatmap: tuple
    chunk_loops: int
    variants: list
    candidates: space.Candidates


def known_settings(run_cfg) -> dict:
    """``section.key`` -> type (float or str) of every setting a candidate may change (from the run schema)."""
    import typing

    from controller.config import SECTIONS

    out = {"model": str}
    for sec in CONTROLLER_SECTIONS:
        for f in msgspec.structs.fields(SECTIONS[sec]):
            t = typing.get_args(f.type)[0] if typing.get_origin(f.type) is typing.Annotated else f.type
            if t in (float, str):
                out[f"{sec}.{f.name}"] = t
    return out


def relevant(name: str, word: str) -> bool:
    """Whether setting ``name`` changes controller ``word``."""
    return word in RELEVANT[name.split(".")[0]]


def load_sweep(path: str | os.PathLike = DEFAULT_SWEEP) -> SweepSpec:
    """Read and check a sweep file; bad input raises InputError naming the file and the key."""
    from controller.config import load_run_config
    from controller.laws.control import MODES

    path = os.fspath(path)
    doc = read_toml(path)
    folder = os.path.dirname(os.path.abspath(path))
    f = convert(doc, SweepFile, path)
    run = load_run_config(f.run if os.path.isabs(f.run) else os.path.join(folder, f.run))
    run = _with_profile(run, f.profile, path)
    duration = f.duration_s
    rate = run["loop"]["rate_hz"]
    if round(duration * rate) < MIN_STEPS:  # each candidate's figures need a few loop steps
        raise InputError(f"{path}: duration_s: {duration:g} s at the run's {rate:g} Hz is fewer than {MIN_STEPS} "
                         f"loop steps")
    variants = f.variants
    from plant_sim.plant import check_settings

    for i, v in enumerate(variants):
        if "model" in v:
            variants[i] = v = {**v, "model": _variant_model(v["model"], folder, f"{path}: variants[{i}]")}
        check_settings({k: x for k, x in v.items() if k != "model"}, f"{path}: variants[{i}]")

    known = known_settings(run)
    seed = f.seed
    cands = space.candidates(doc.get("candidates"), path, MODES, set(known), seed)
    for name, col in cands.settings.items():
        want = known[name]
        if (want is str) != (col.dtype == object):
            raise InputError(f"{path}: candidates: setting '{name}': expected {'a string' if want is str else 'numbers'}")
    cands = _with_default(run, cands)

    figure_names = list(metrics.NAMES) + [f"worst_{n}" for n in metrics.NAMES]
    objective = f.objective or ("worst_iae" if len(variants) > 1 else "iae")
    if objective not in figure_names or (objective.startswith("worst_") and len(variants) < 2):
        raise InputError(f"{path}: key 'objective': {objective!r} is not a column of this sweep "
                         f"(one of {', '.join(figure_names[:len(metrics.NAMES) * (2 if len(variants) > 1 else 1)])})")
    heat = tuple(f.heatmap)
    for h in heat:
        if h not in cands.settings:
            raise InputError(f"{path}: key 'heatmap': {h!r} is not a swept setting")
    if heat and len(heat) != 2:
        raise InputError(f"{path}: key 'heatmap': two settings, got {len(heat)}")
    _check_candidates(run, cands, path)
    return SweepSpec(path, run, duration, seed, objective, f.margins_top, f.margins_flow_lpm,
                     heat, f.chunk_loops, variants, cands)


def _with_profile(run, changes: dict, path: str):
    from controller.config import check_sections

    sections = copy.deepcopy(run.sections)
    sections["profile"].update(changes)
    return dataclasses.replace(run, sections=check_sections(sections, f"{path} (profile on {run.path})"))


def _check_candidates(run, cands: space.Candidates, path: str) -> None:
    """Every candidate's run configuration through the run schema; the first bad one named with its settings."""
    from controller.config import check_sections
    from models.model import load_model

    if "model" in cands.settings:
        for m in sorted(set(cands.settings["model"]) - {""}):
            load_model(run.resolve(m))
    for i in range(len(cands)):
        row = cands.row(i)
        try:
            check_sections(apply(run, cands.controller[i], {k: v for k, v in row.items() if k != "model"}).sections,
                           "")
        except InputError as exc:
            shown = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
            raise InputError(f"{path}: candidate {i} ({cands.controller[i]}: {shown}): {str(exc).removeprefix(': ')}") from None


def _with_default(run, cands: space.Candidates) -> space.Candidates:
    """The run's own controller, unchanged, as candidate 0."""
    words = [run[""]["controller"], *cands.controller]
    rows = [{}] + [cands.row(i) for i in range(len(cands))]
    t = space.table(words, rows)
    # keep the file's column order and types even when the default has none of them
    return space.Candidates(t.controller, {k: t.settings[k] for k in cands.settings})


def apply(run, word: str, settings: dict):
    """The run configuration of one candidate: controller ``word`` and ``settings`` (``section.key`` -> value)."""
    # the sections it changes copied, the others shared with the run (read only; copy.deepcopy of the
    # whole configuration was most of the cost of building a candidate)
    changed = {""} | {name.rpartition(".")[0] for name in settings}
    sections = {sec: dict(keys) if sec in changed else keys for sec, keys in run.sections.items()}
    sections[""]["controller"] = word
    for name, value in settings.items():
        sec, _, key = name.rpartition(".")
        sections[sec][key] = value
    return dataclasses.replace(run, sections=sections)


def setting(run, settings: dict, name: str):
    """Setting ``name`` (``section.key``) as :func:`apply` leaves it: the candidate's own, else the run's."""
    if name in settings:
        return settings[name]
    sec, _, key = name.rpartition(".")
    return run[sec][key]


def effective(run, word: str, settings: dict, names) -> dict:
    """Every setting of ``names`` as the candidate has it (its own or the run's), None where irrelevant."""
    return {n: setting(run, settings, n) if relevant(n, word) else None for n in names}


def reference(run, duration_s: float) -> np.ndarray:
    """The run's breath profile sampled at the loop rate, clamped like the live loop clamps it."""
    from plant_sim.protocols import BreathProfile

    try:
        profile = BreathProfile(**run["profile"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{run.path}: section 'profile': {exc}") from None
    rate = run["loop"]["rate_hz"]
    t = np.arange(int(round(duration_s * rate))) / rate
    return np.clip(profile.value(t), 0.0, run["loop"]["flow_max_lpm"])


def _variant_model(value, folder: str, where: str) -> str:
    """A variant's ``model``: the absolute path of a forward model file the simulated valve can run."""
    from models.model import load_model
    from plant_sim.plant import PLANT_KINDS

    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: model: expected the path of a model file")
    path = value if os.path.isabs(value) else os.path.join(folder, value)
    kind = load_model(path).kind
    if kind not in PLANT_KINDS:
        raise InputError(f"{where}: model: the simulated valve cannot run kind {kind!r} (one of {', '.join(PLANT_KINDS)})")
    return path


def plants(run, variants: list, source: str) -> list:
    """PlantParams per variant: the run's simulated valve with each variant's changes (``model``: another
    forward model, an absolute path as :func:`load_sweep` leaves it)."""
    from models.model import load_model
    from plant_sim.effects import EFFECTS
    from plant_sim.plant import load_plant

    out = []
    for i, v in enumerate(variants):
        effects = {**run["effects"], **{k: x for k, x in v.items() if k in EFFECTS}}
        fields = {k: (tuple(x) if isinstance(x, list) else x) for k, x in v.items() if k not in EFFECTS and k != "model"}
        try:
            p = load_plant(run.resolve(run[""]["plant_config"]), effects=effects, **fields)
            out.append(p.replace(model=load_model(v["model"])) if "model" in v else p)
        except InputError as exc:
            raise InputError(f"{source}: variants[{i}]: {exc}") from None
    return out


def _toml_value(v) -> str:
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if np.isfinite(v) else ("inf" if v > 0 else "-inf") if np.isinf(v) else "nan"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


#: run-config keys holding paths relative to the file
PATH_KEYS = (("", "model"), ("", "plant_config"), ("zenoh", "config"))


def write_run_config(run, path: str, duration_s: float | None = None) -> None:
    """Write a run configuration (every section, paths made relative to ``path``), atomically."""
    sections = copy.deepcopy(run.sections)
    out_dir = os.path.dirname(os.path.abspath(path))
    for sec, key in PATH_KEYS:
        if key in sections.get(sec, {}):
            sections[sec][key] = os.path.relpath(os.path.abspath(run.resolve(sections[sec][key])), out_dir)
    if duration_s is not None:
        sections[""]["duration_s"] = float(duration_s)
    lines = [f"# written by valvectl sweep from {run.path}"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in sections[""].items()]
    for sec, keys in sections.items():
        if sec and keys:
            lines += ["", f"[{sec}]"] + [f"{k} = {_toml_value(v)}" for k, v in keys.items()]
    write_text_atomic(path, "\n".join(lines) + "\n")
