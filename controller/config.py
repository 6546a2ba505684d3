"""``config/run.toml``: the closed-loop run's settings, and the controllers they describe.

Paths in the file are relative to the file's folder. The file's schema is
the structs below, one per section (:class:`RunFile` holds them; the
framework and how to add a key: :mod:`models.schema`). Unknown keys, wrong
types, non-finite numbers, values out of range and broken cross-field rules
are bad input: one line naming the file and the dotted key, exit 2, e.g.
``config/run.toml: loop.rate_hz: must be > 0 (got 0)``. Safety settings
come first: the watchdog (``loop.stale_ms``) and the valve node's timeout
(``valve_node.command_timeout_ms``) finite and positive, the safe and limit
duties within 0-100 %, the Zenoh key id a plain key chunk (no wildcards).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Annotated, Literal

import msgspec

from models.recording import MAX_RATE_HZ, MAX_SAMPLES, InputError
from models.schema import KeyId, NoiseLpm, NonEmpty, NonNegative, Percent, Positive, convert
from models.tomlfile import read_toml

from .alarms import AlarmSettings
from .laws import control
from .loop import LoopSettings
from .supervisor import SupervisorSettings

DEFAULT_RUN = "config/run.toml"

#: Loop or node rate, Hz: from 1 Hz up to the fastest any verb accepts (the controller runs at 1 kHz; delay
#: lines are sized by it).
RateHz = Annotated[float, msgspec.Meta(ge=1.0, le=MAX_RATE_HZ)]
#: A controller gain: finite, >= 0, and below what any valve loop could use.
Gain = Annotated[float, msgspec.Meta(ge=0.0, le=1e6)]
#: A flow, L/min, within what any valve or sensor could report.
FlowLpm = Annotated[float, msgspec.Meta(gt=0.0, le=1e5)]
#: Longest valve lag or delay the controllers model, s (the effects' own limits: plant_sim.effects).
Seconds10 = Annotated[float, msgspec.Meta(ge=0.0, le=10.0)]
Seconds60 = Annotated[float, msgspec.Meta(ge=0.0, le=60.0)]
#: A safety timeout, ms: the watchdog's and the valve node's. Finite is not enough: 1e308 ms would switch
#: the safety off as surely as NaN did, so at most 10 s (a dead controller must not hold a valve open longer).
TimeoutMs = Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)]
#: How long a reference may be held without news, ms: a stack that died must not set the flow for ever.
RefTimeoutMs = Annotated[float, msgspec.Meta(gt=0.0, le=60_000.0)]
#: A gauge pressure, bar: from vacuum up to what any supply line could hold.
GaugeBar = Annotated[float, msgspec.Meta(ge=-1.01325, le=1000.0)]


class _Section(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A run-file section: unknown keys are refused."""


class Loop(_Section):
    rate_hz: RateHz = 1000.0
    stale_ms: TimeoutMs = 50.0            # watchdog: no measurement for this long -> safe state
    ref_stale_ms: RefTimeoutMs = 500.0    # a reference older than this -> 0 L/min
    safe_duty_pct: Percent = 0.0
    flow_max_lpm: FlowLpm = 200.0
    status_hz: Annotated[float, msgspec.Meta(ge=0.01)] = 10.0
    spin_us: NonNegative = 300.0
    rt_priority: Annotated[int, msgspec.Meta(ge=0, le=99)] = 0
    cpu: Annotated[int, msgspec.Meta(ge=-1, le=4095)] = -1
    trigger: Literal["period", "measurement"] = "period"
    rehearse: bool = True
    catch_up: bool = True

    def __post_init__(self):
        if self.status_hz > self.rate_hz:
            raise ValueError(f"status_hz: must be <= rate_hz (got {self.status_hz:g} > {self.rate_hz:g})")
        if self.spin_us >= 1e6 / self.rate_hz:
            raise ValueError(f"spin_us: must be shorter than one loop period, {1e6 / self.rate_hz:g} us "
                             f"(got {self.spin_us:g})")


class Limits(_Section):
    duty_min_pct: Percent = 0.0
    duty_max_pct: Percent = 100.0
    rate_pct_per_s: Positive = 10000.0

    def __post_init__(self):
        if not self.duty_min_pct < self.duty_max_pct:
            raise ValueError(f"duty_min_pct: must be < duty_max_pct (got {self.duty_min_pct:g} >= {self.duty_max_pct:g})")


class Valve(_Section):
    tau_s: Seconds60 = 0.0
    delay_s: Seconds10 = 0.0


class Feedforward(_Section):
    lead_lag_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.005
    preview: bool = True
    anticipation_s: Seconds10 = 0.0       # with preview: read this much further ahead than the delay
    ready_margin_pct: Percent = 2.0       # no flow asked: this far below the present cracking duty


class PID(_Section):
    kp: Gain = 0.0
    ki: Gain = 0.0
    kd: Gain = 0.0
    tf_s: Positive = 0.003
    tt_s: Positive = 0.01


class KF(_Section):
    q_flow_lpm: NoiseLpm = 1.0
    q_bias_lpm: NoiseLpm = 0.05
    r_lpm: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)] = 0.5


class Zenoh(_Section):
    id: KeyId = "insp"
    listen: list[NonEmpty] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[NonEmpty] = msgspec.field(default_factory=list)
    config: str = "zenoh.json5"
    io_priority: Annotated[int, msgspec.Meta(ge=0, le=99)] = 0  # SCHED_FIFO of Zenoh's threads (0: normal)
    io_nice: Annotated[int, msgspec.Meta(ge=-20, le=19)] = 0    # their nice value under the normal scheduler


class ValveNode(_Section):
    rate_hz: RateHz = 1000.0
    command_timeout_ms: TimeoutMs = 100.0  # no cmd/duty for this long -> the node closes its valve
    aux_hz: NonNegative = 50.0            # meas/supply and meas/coil_temp rate (0: not published)

    def __post_init__(self):
        if self.aux_hz > self.rate_hz:
            raise ValueError(f"aux_hz: must be <= rate_hz (got {self.aux_hz:g} > {self.rate_hz:g})")


class Identify(_Section):
    """``valvectl identify`` (controller.identify): protocol length and its safety rules."""

    duration_s: Annotated[float, msgspec.Meta(ge=10.0, le=86400.0)] = 600.0  # valve time of the protocol
    flow_limit_lpm: FlowLpm = 200.0       # measured flow above this -> safe duty, aborted
    stale_ms: TimeoutMs = 250.0           # no measurement for this long -> safe duty, aborted
    wait_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 10.0  # for the valve's first measurement
    seed: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)] = 0  # step levels
    tune_candidates: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 200  # the gain sweep on the identified valve


class Alarms(_Section):
    """:class:`controller.alarms.AlarmSettings`: thresholds and hold times of the online alarms."""

    error_tau_s: Positive = 0.02
    saturated_margin_pct: NonNegative = 0.5
    saturated_error_lpm: NonNegative = 5.0
    saturated_hold_s: NonNegative = 0.1
    mismatch_lpm: Positive = 10.0
    mismatch_hold_s: NonNegative = 0.1
    supply_low_bar: GaugeBar = 2.0
    supply_hold_s: NonNegative = 0.02


class Fallback(_Section):
    """:class:`controller.supervisor.SupervisorSettings`: when ``ff+kf`` hands over to ``ff+pid``."""

    innovation_limit_lpm: Positive = 10.0
    innovation_hold_s: NonNegative = 0.2
    tau_s: Positive = 0.02


class RunFile(_Section):
    """The whole file: top-level keys, then one struct per section."""

    controller: str = "ff+kf"
    plant: Literal["sim", "zenoh"] = "sim"
    reference: Literal["profile", "zenoh"] = "profile"
    duration_s: NonNegative = 20.0
    model: NonEmpty = "valve_model.json"
    plant_config: NonEmpty = "plant.toml"
    seed: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)] = 0
    loop: Loop = msgspec.field(default_factory=Loop)
    limits: Limits = msgspec.field(default_factory=Limits)
    profile: dict = msgspec.field(default_factory=dict)  # keyword arguments of plant_sim.protocols.BreathProfile
    valve: Valve = msgspec.field(default_factory=Valve)
    effects: dict = msgspec.field(default_factory=dict)  # effect words of the embedded simulated valve
    feedforward: Feedforward = msgspec.field(default_factory=Feedforward)
    pid: PID = msgspec.field(default_factory=PID)
    ff_pid: PID = msgspec.field(default_factory=PID)
    kf: KF = msgspec.field(default_factory=KF)
    zenoh: Zenoh = msgspec.field(default_factory=Zenoh)
    valve_node: ValveNode = msgspec.field(default_factory=ValveNode)
    alarms: Alarms = msgspec.field(default_factory=Alarms)
    fallback: Fallback = msgspec.field(default_factory=Fallback)
    identify: Identify = msgspec.field(default_factory=Identify)

    def __post_init__(self):
        if self.controller not in control.MODES:
            raise ValueError(f"controller: {self.controller!r} is not one of {', '.join(control.MODES)}")
        if self.duration_s * self.loop.rate_hz > MAX_SAMPLES:  # a run records every step
            raise ValueError(f"duration_s: {self.duration_s:g} s at loop.rate_hz {self.loop.rate_hz:g} is more than "
                             f"the {MAX_SAMPLES:.0e} steps a run records (0: until interrupted)")


#: section name -> its struct ("" : the top-level keys); sections typed ``dict`` are free tables.
SECTIONS: dict[str, type] = {"": RunFile, **{
    f.name: f.type for f in msgspec.structs.fields(RunFile) if isinstance(f.type, type) and issubclass(f.type, _Section)}}


def section_type(section: str, key: str):
    """The declared type of ``[section] key`` (None when the file has no such key)."""
    struct = SECTIONS.get(section)
    if struct is None:
        return None
    return next((f.type for f in msgspec.structs.fields(struct) if f.name == key), None)


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
                            status_hz=lp["status_hz"], spin_s=lp["spin_us"] * 1e-6, rt_priority=lp["rt_priority"],
                            cpu=lp["cpu"], trigger=lp["trigger"], rehearse=lp["rehearse"], catch_up=lp["catch_up"],
                            alarms=AlarmSettings(**self["alarms"]), fallback=SupervisorSettings(**self["fallback"]))


def check_sections(sections: dict, source: str) -> dict:
    """Validate ``sections`` (``{"": top keys, name: keys}``, as :class:`RunConfig` holds them) against the schema.

    Returns the sections with defaults filled in and numbers as floats; used on
    the file as read and on every changed copy (sweep candidates).
    """
    doc = {**sections.get("", {}), **{k: v for k, v in sections.items() if k}}
    f = convert(doc, RunFile, source)
    out = {"": {}}
    for fld in msgspec.structs.fields(RunFile):
        value = getattr(f, fld.name)
        if isinstance(value, _Section):
            out[fld.name] = msgspec.structs.asdict(value)
        elif isinstance(value, dict):
            out[fld.name] = dict(value)
        else:
            out[""][fld.name] = value
    _check_effects(out["effects"], source)
    _check_profile(out["profile"], out["loop"]["flow_max_lpm"], source)
    return out


def _check_effects(effects: dict, source: str) -> None:
    from plant_sim.effects import EFFECTS, check_effect

    for name, value in effects.items():
        if name not in EFFECTS:
            raise InputError(f"{source}: effects.{name}: unknown effect (one of {', '.join(EFFECTS)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{source}: effects.{name}: expected a number (got {value!r})")
        try:
            effects[name] = check_effect(name, value)
        except InputError:
            lo, hi = EFFECTS[name].limits
            raise InputError(f"{source}: effects.{name}: must be within {lo:g}..{hi:g} {EFFECTS[name].unit} "
                             f"(got {value})") from None


#: Breath rates a profile may have, breaths per minute (high-frequency ventilation reaches 900).
BREATH_RATE_BPM = (0.1, 1000.0)


def _check_profile(profile: dict, flow_max_lpm: float, source: str) -> None:
    """The ``[profile]`` table: :class:`plant_sim.protocols.BreathProfile`'s own checks, then its flows within
    the loop's range (the loop clamps references to ``[0, flow_max_lpm]``) and a plausible breath rate."""
    from plant_sim.protocols import BreathProfile

    for name, v in profile.items():  # a TOML boolean is no number, though Python's bool is an int
        word = name == "kind"
        if isinstance(v, bool) or not isinstance(v, str if word else (int, float)):
            raise InputError(f"{source}: profile.{name}: expected {'a word' if word else 'a number'}, got {v!r}")
    try:
        p = BreathProfile(**profile)
    except TypeError as exc:
        raise InputError(f"{source}: profile: {exc}".replace("BreathProfile.__init__() got an ", "")) from None
    except ValueError as exc:
        raise InputError(f"{source}: profile: {str(exc).removeprefix('breath profile: ')}") from None
    for name in ("peak_lpm", "base_lpm"):
        if getattr(p, name) > flow_max_lpm:
            raise InputError(f"{source}: profile.{name}: must be <= loop.flow_max_lpm, {flow_max_lpm:g} "
                             f"(got {getattr(p, name):g})")
    lo, hi = BREATH_RATE_BPM
    if not lo <= p.breath_rate_bpm <= hi:
        raise InputError(f"{source}: profile.breath_rate_bpm: must be within {lo:g}..{hi:g} (got {p.breath_rate_bpm:g})")


def load_run_config(path: str | os.PathLike = DEFAULT_RUN) -> RunConfig:
    """Read and check a run configuration (bad input: :class:`InputError` naming the file and key)."""
    path = os.fspath(path)
    doc = read_toml(path)
    sections = {"": {k: v for k, v in doc.items() if not isinstance(v, dict)},
                **{k: v for k, v in doc.items() if isinstance(v, dict)}}
    return RunConfig(path, os.path.dirname(os.path.abspath(path)), check_sections(sections, path))


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
        try:
            kw["forward"] = ffw.bank(model, 1, cfg["feedforward"]["ready_margin_pct"])
        except ValueError as exc:
            raise InputError(f"{cfg.path}: key 'model': {exc}") from None
        if valve["tau_s"] > 0:
            kw["lead"] = ffw.LeadParams.make(1, valve["tau_s"], cfg["feedforward"]["lead_lag_s"])
    if word in ("pid", "ff+pid"):
        kw["pid"] = pid.PIDParams.make(1, **cfg["pid" if word == "pid" else "ff_pid"])
    if word == "ff+kf":
        k = cfg["kf"]
        kw["kf"] = kalman.KFParams.make(valve["tau_s"], valve["delay_s"], dt, k["q_flow_lpm"], k["q_bias_lpm"],
                                        k["r_lpm"])
    return control.ControllerParams(word, lim, **kw)


def supervisor(cfg: RunConfig, word: str, model):
    """The run's :class:`controller.supervisor.Supervisor`: ``word`` in force, every word ready to switch to."""
    from .supervisor import Supervisor

    laws = {w: controller_params(cfg, w, model) for w in control.MODES}
    return Supervisor(laws, word, cfg.loop.fallback)


def preview_s(cfg: RunConfig, reference: str) -> float:
    """How far ahead the feedforward reads the reference: for a known profile the valve's delay plus
    ``[feedforward] anticipation_s``, else 0.

    The delay alone puts the model's flow on the reference on time, but the valve's lag still trails
    each edge (the lag inversion is bounded; a closing valve's flow decays with the lag whatever the duty);
    the IAE of a first-order decay is least when it starts ``tau ln 2`` early, so reading further ahead
    trades a little error before each edge for more after it.
    """
    if reference != "profile" or not cfg["feedforward"]["preview"]:
        return 0.0
    return cfg["valve"]["delay_s"] + cfg["feedforward"]["anticipation_s"]
