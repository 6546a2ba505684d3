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

    [[candidates]]           # see controller.sweep.space
"""
from __future__ import annotations

import copy
import dataclasses
import os
from dataclasses import dataclass

import numpy as np

from models.recording import InputError
from models.tomlfile import read_toml

from . import metrics, space

DEFAULT_SWEEP = "config/sweep.toml"
TOP = {"run": str, "duration_s": float, "seed": int, "objective": str, "margins_top": int,
       "margins_flow_lpm": float, "heatmap": list, "chunk_loops": int}
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
    """``section.key`` -> type of every setting a candidate may change (from the run config's schema)."""
    from controller.config import SCHEMA

    out = {"model": str}
    for s in CONTROLLER_SECTIONS:
        for k, v in SCHEMA[s].items():
            if isinstance(v, (float, str)) and not isinstance(v, bool):
                out[f"{s}.{k}"] = type(v)
    return out


def relevant(name: str, word: str) -> bool:
    """Whether setting ``name`` changes controller ``word``."""
    return word in RELEVANT[name.split(".")[0]]


def plant_field_names() -> set[str]:
    from plant_sim.effects import EFFECTS
    from plant_sim.plant import PlantParams

    return {f.name for f in dataclasses.fields(PlantParams) if f.name != "model"} | set(EFFECTS)


def load_sweep(path: str | os.PathLike = DEFAULT_SWEEP) -> SweepSpec:
    """Read and check a sweep file; bad input raises InputError naming the file and the key."""
    from controller.config import load_run_config
    from controller.laws.control import MODES

    path = os.fspath(path)
    doc = read_toml(path)
    folder = os.path.dirname(os.path.abspath(path))
    top = {}
    for key, value in doc.items():
        if key in ("profile", "variants", "candidates"):
            continue
        if key not in TOP:
            raise InputError(f"{path}: key '{key}': unknown (one of {', '.join([*TOP, 'profile', 'variants', 'candidates'])})")
        want = TOP[key]
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool)) if want is float else \
            (isinstance(value, want) and not isinstance(value, bool))
        if not ok:
            raise InputError(f"{path}: key '{key}': expected {want.__name__}, got {value!r}")
        top[key] = float(value) if want is float else value

    run_rel = top.get("run", "run.toml")
    run = load_run_config(run_rel if os.path.isabs(run_rel) else os.path.join(folder, run_rel))
    run = _with_profile(run, doc.get("profile", {}), path)
    duration = top.get("duration_s", 5.0)
    if not duration > 0:
        raise InputError(f"{path}: key 'duration_s': must be positive, got {duration:g}")
    for k in ("margins_top", "chunk_loops"):
        if top.get(k, 1) < (0 if k == "margins_top" else 1):
            raise InputError(f"{path}: key '{k}': must be {'>= 0' if k == 'margins_top' else 'positive'}, got {top[k]}")

    variants = doc.get("variants", [{}])
    if not isinstance(variants, list) or not all(isinstance(v, dict) for v in variants) or not variants:
        raise InputError(f"{path}: key 'variants': expected [[variants]] tables")
    names = plant_field_names()
    for i, v in enumerate(variants):
        for k in v:
            if k not in names:
                raise InputError(f"{path}: key 'variants[{i}].{k}': unknown plant setting (one of {', '.join(sorted(names))})")

    known = known_settings(run)
    seed = top.get("seed", 0)
    cands = space.candidates(doc.get("candidates"), path, MODES, set(known), seed)
    for name, col in cands.settings.items():
        want = known[name]
        if (want is str) != (col.dtype == object):
            raise InputError(f"{path}: candidates: setting '{name}': expected {'a string' if want is str else 'numbers'}")
    cands = _with_default(run, cands)

    figure_names = list(metrics.NAMES) + [f"worst_{n}" for n in metrics.NAMES]
    objective = top.get("objective", "worst_iae" if len(variants) > 1 else "iae")
    if objective not in figure_names or (objective.startswith("worst_") and len(variants) < 2):
        raise InputError(f"{path}: key 'objective': {objective!r} is not a column of this sweep "
                         f"(one of {', '.join(figure_names[:len(metrics.NAMES) * (2 if len(variants) > 1 else 1)])})")
    heat = tuple(top.get("heatmap", ()))
    for h in heat:
        if h not in cands.settings:
            raise InputError(f"{path}: key 'heatmap': {h!r} is not a swept setting")
    if heat and len(heat) != 2:
        raise InputError(f"{path}: key 'heatmap': two settings, got {len(heat)}")
    return SweepSpec(path, run, duration, seed, objective, top.get("margins_top", 20), top.get("margins_flow_lpm"),
                     heat, top.get("chunk_loops", 512), variants, cands)


def _with_profile(run, changes: dict, path: str):
    if not isinstance(changes, dict):
        raise InputError(f"{path}: key 'profile': expected a table")
    sections = copy.deepcopy(run.sections)
    sections["profile"].update(changes)
    return dataclasses.replace(run, sections=sections)


def _with_default(run, cands: space.Candidates) -> space.Candidates:
    """The run's own controller, unchanged, as candidate 0."""
    words = [run[""]["controller"], *cands.controller]
    rows = [{}] + [cands.row(i) for i in range(len(cands))]
    t = space.table(words, rows)
    # keep the file's column order and types even when the default has none of them
    return space.Candidates(t.controller, {k: t.settings[k] for k in cands.settings})


def apply(run, word: str, settings: dict):
    """The run configuration of one candidate: controller ``word`` and ``settings`` (``section.key`` -> value)."""
    sections = copy.deepcopy(run.sections)
    sections[""]["controller"] = word
    for name, value in settings.items():
        sec, _, key = name.rpartition(".")
        sections[sec][key] = value
    return dataclasses.replace(run, sections=sections)


def effective(run, word: str, settings: dict, names) -> dict:
    """Every setting of ``names`` as the candidate has it (its own or the run's), None where irrelevant."""
    cfg = apply(run, word, settings)
    out = {}
    for n in names:
        sec, _, key = n.rpartition(".")
        out[n] = cfg[sec][key] if relevant(n, word) else None
    return out


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


def plants(run, variants: list, source: str) -> list:
    """PlantParams per variant: the run's simulated valve with each variant's changes."""
    from plant_sim.effects import EFFECTS
    from plant_sim.plant import load_plant

    out = []
    for i, v in enumerate(variants):
        effects = {**run["effects"], **{k: x for k, x in v.items() if k in EFFECTS}}
        fields = {k: (tuple(x) if isinstance(x, list) else x) for k, x in v.items() if k not in EFFECTS}
        try:
            out.append(load_plant(run.resolve(run[""]["plant_config"]), effects=effects, **fields))
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
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    os.replace(tmp, path)
