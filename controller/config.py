"""``config/run.toml``: the closed-loop run's settings, and the controllers they describe.

Paths in the file are relative to the file's folder. Unknown keys and wrong
types are bad input (one line naming the file and the key, exit 2).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

from models.recording import InputError
from models.tomlfile import read_toml

from .laws import control
from .loop import LoopSettings

DEFAULT_RUN = "config/run.toml"

#: section -> key -> default (the type of the default is the type accepted).
SCHEMA: dict[str, dict] = {
    "": {"controller": "ff+kf", "plant": "sim", "reference": "profile", "duration_s": 20.0,
         "model": "valve_model.json", "plant_config": "plant.toml", "seed": 0},
    "loop": {"rate_hz": 1000.0, "stale_ms": 50.0, "ref_stale_ms": 500.0, "safe_duty_pct": 0.0,
             "flow_max_lpm": 200.0, "status_hz": 10.0, "spin_us": 300.0, "rt_priority": 0},
    "limits": {"duty_min_pct": 0.0, "duty_max_pct": 100.0, "rate_pct_per_s": 10000.0},
    "profile": {},  # keyword arguments of plant_sim.protocols.BreathProfile
    "valve": {"tau_s": 0.0, "delay_s": 0.0},
    "effects": {},  # effect words of the embedded simulated valve
    "feedforward": {"lead_lag_s": 0.005, "preview": True},
    "pid": {"kp": 0.0, "ki": 0.0, "kd": 0.0, "tf_s": 0.003, "tt_s": 0.01},
    "ff_pid": {"kp": 0.0, "ki": 0.0, "kd": 0.0, "tf_s": 0.003, "tt_s": 0.01},
    "kf": {"q_flow_lpm": 1.0, "q_bias_lpm": 0.05, "r_lpm": 0.5},
    "zenoh": {"id": "insp", "listen": ["tcp/127.0.0.1:7447"], "connect": [], "config": "zenoh.json5"},
    "valve_node": {"rate_hz": 1000.0, "command_timeout_ms": 100.0},
}
_FREE = {"profile", "effects"}


@dataclass(frozen=True)
class RunConfig:
    """The parsed file: ``sections[name][key]``, defaults filled in; ``folder`` for relative paths."""

    path: str
    folder: str
    sections: dict = field(default_factory=dict)

    def __getitem__(self, section: str) -> dict:
        return self.sections[section]

    def resolve(self, rel: str) -> str:
        return rel if os.path.isabs(rel) else os.path.join(self.folder, rel)

    @property
    def loop(self) -> LoopSettings:
        lp = self["loop"]
        return LoopSettings(rate_hz=lp["rate_hz"], stale_ms=lp["stale_ms"], ref_stale_ms=lp["ref_stale_ms"],
                            safe_duty_pct=lp["safe_duty_pct"], flow_max_lpm=lp["flow_max_lpm"],
                            status_hz=lp["status_hz"], spin_s=lp["spin_us"] * 1e-6, rt_priority=lp["rt_priority"])


def _check(path: str, name: str, value, default):
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif isinstance(default, list):
        ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
    else:
        ok = isinstance(value, type(default))
    if not ok:
        raise InputError(f"{path}: key '{name}': expected {type(default).__name__}, got {value!r}")
    return value


def load_run_config(path: str | os.PathLike = DEFAULT_RUN) -> RunConfig:
    """Read and check a run configuration."""
    path = os.fspath(path)
    doc = read_toml(path)
    sections = {name: dict(keys) for name, keys in SCHEMA.items()}
    for key, value in doc.items():
        if isinstance(value, dict):
            if key not in SCHEMA or key == "":
                raise InputError(f"{path}: section '{key}': unknown (one of {', '.join(s for s in SCHEMA if s)})")
            for k, v in value.items():
                if key in _FREE:
                    sections[key][k] = v
                elif k not in SCHEMA[key]:
                    raise InputError(f"{path}: key '{key}.{k}': unknown")
                else:
                    sections[key][k] = _check(path, f"{key}.{k}", v, SCHEMA[key][k])
        elif key in SCHEMA[""]:
            sections[""][key] = _check(path, key, value, SCHEMA[""][key])
        else:
            raise InputError(f"{path}: key '{key}': unknown")
    cfg = RunConfig(path, os.path.dirname(os.path.abspath(path)), sections)
    if cfg[""]["controller"] not in control.MODES:
        raise InputError(f"{path}: key 'controller': {cfg['']['controller']!r} is not one of {', '.join(control.MODES)}")
    return cfg


def controller_params(cfg: RunConfig, word: str, model, preview: bool = False) -> control.ControllerParams:
    """The controller ``word`` with the gains, limits and valve dynamics of ``cfg`` (batch of one).

    ``pid`` takes ``[pid]``, ``ff+pid`` takes ``[ff_pid]``; ``ff+kf`` designs its
    filter from ``[kf]`` and the valve's ``[valve]`` lag and delay at the loop
    period; the modes with feedforward invert the lag of ``[valve]`` when
    ``tau_s`` > 0. ``preview`` says whether the feedforward's reference comes
    ``[valve] delay_s`` ahead, which only a profile reference allows.
    """
    from .laws import feedforward as ffw
    from .laws import kalman, limits, pid

    if word not in control.MODES:
        raise InputError(f"--controller: {word!r} is not one of {', '.join(control.MODES)}")
    lim = limits.Limits.make(1, **cfg["limits"])
    dt = 1.0 / cfg["loop"]["rate_hz"]
    valve = cfg["valve"]
    kw: dict = {}
    if word.startswith("ff"):
        kw["inverse"], kw["forward"] = ffw.inverse_bank(model), ffw.forward_bank(model)
        if valve["tau_s"] > 0:
            kw["lead"] = ffw.LeadParams.make(1, valve["tau_s"], cfg["feedforward"]["lead_lag_s"])
    if word in ("pid", "ff+pid"):
        kw["pid"] = pid.PIDParams.make(1, **cfg["pid" if word == "pid" else "ff_pid"])
    if word == "ff+kf":
        k = cfg["kf"]
        kw["kf"] = kalman.KFParams.make(valve["tau_s"], valve["delay_s"], dt, k["q_flow_lpm"], k["q_bias_lpm"],
                                        k["r_lpm"])
    return control.ControllerParams(word, lim, **kw)


def preview_s(cfg: RunConfig, reference: str) -> float:
    """How far ahead the feedforward reads the reference: the valve's delay for a known profile, else 0."""
    return cfg["valve"]["delay_s"] if (reference == "profile" and cfg["feedforward"]["preview"]) else 0.0
