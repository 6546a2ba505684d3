"""The simulated valve: parameters, the single plant and the batched plant.

Duty (%) in, measured flow (L/min) out, stepped at a fixed rate. The forward
model is a fitted PI (``config/valve_model.json``); the sensor is SFM3300-like;
the effects of :mod:`plant_sim.effects` add the physics the PI leaves out.
Both plants run the one kernel of :mod:`plant_sim.kernel`; :class:`Plant` is
the batch of one.

Sensor noise is white with ``noise_lpm`` standard deviation per reading,
independent of the step rate: the SFM3300 converts every 0.5 ms and a reader
polling at any slower rate gets single conversions, not averages. The bench
recordings agree: their noise is 0.50 L/min per sample at 20 Hz and at 100 Hz
(robust estimate from second differences).

Shapes follow google/deluca: ``init(duty0) -> state``, ``step(state, duty) ->
(state, output)``, pure (the kernel writes the new state to new arrays).
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Annotated, Literal, NamedTuple, Sequence

import msgspec
import numpy as np

from models.direct import direct
from models.model import FittedModel, load_model
from models.recording import InputError
from models.schema import Finite, NoiseLpm, NonNegative, Positive, convert
from models.tomlfile import read_toml

from . import kernel as K
from .effects import EFFECTS

DEFAULT_PLANT = "config/plant.toml"


@dataclass(frozen=True, eq=False)
class PlantParams:
    """Everything that defines one simulated valve.

    Attributes
    ----------
    model : FittedModel
        Forward PI, duty % -> flow L/min, identified at ``model_supply_bar``.
    noise_lpm : float
        Sensor white noise, standard deviation per reading, L/min.
    scale_factor : float
        Sensor scale factor, counts per L/min (SFM3300: 120); 0 = no quantization.
    range_lpm : tuple of float
        Sensor range, L/min (SFM3300: -250..250 slm).
    supply_bar : float
        Nominal supply, bar gauge.
    model_supply_bar : float
        Supply at which the model was identified, bar gauge.
    atmosphere_bar : float
        Ambient pressure, bar absolute.
    droop_bar : float
        Supply droop at ``droop_ref_lpm`` (∝ flow²), bar; with ``supply_pressure``.
    droop_ref_lpm : float
        Flow at which the droop is ``droop_bar``, L/min.
    wander_tau_s : float
        Correlation time of the supply wander, s.
    ambient_c : float
        Ambient (and cold-coil) temperature, °C; the model is the valve at ambient.
    coil_tau_s : float
        Thermal time constant of the coil, s.
    coil_alpha_per_k : float
        Temperature coefficient of the coil resistance (copper: 0.00393 /K).
    dynamics_order : int
        Order of the ``valve_dynamics`` lag, 1 or 2.
    creep_tau_s : float
        Time constant of the creep relaxation, s.
    asymmetric_hysteresis, coil_heating, supply_pressure, valve_dynamics,
    transport_delay, dead_zone, saturation, creep, sensor_offset : float
        The effects, in the units of DESIGN.md (see :data:`plant_sim.effects.EFFECTS`); 0 = off.
    """

    model: FittedModel
    noise_lpm: float = 0.5
    scale_factor: float = 120.0
    range_lpm: tuple[float, float] = (-250.0, 250.0)
    supply_bar: float = 3.0
    model_supply_bar: float = 3.0
    atmosphere_bar: float = 1.01325
    droop_bar: float = 0.15
    droop_ref_lpm: float = 200.0
    wander_tau_s: float = 30.0
    ambient_c: float = 25.0
    coil_tau_s: float = 180.0
    coil_alpha_per_k: float = 0.00393
    dynamics_order: int = 1
    creep_tau_s: float = 20.0
    asymmetric_hysteresis: float = 0.0
    coil_heating: float = 0.0
    supply_pressure: float = 0.0
    valve_dynamics: float = 0.0
    transport_delay: float = 0.0
    dead_zone: float = 0.0
    saturation: float = 0.0
    creep: float = 0.0
    sensor_offset: float = 0.0

    def __post_init__(self):
        if self.model.kind not in PLANT_KINDS:
            raise InputError(f"plant model: kind {self.model.kind!r} cannot drive the simulated valve "
                             f"(one of {', '.join(PLANT_KINDS)})")
        checked = check_settings({f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "model"},
                                 "plant")
        for name in EFFECTS:
            object.__setattr__(self, name, getattr(checked, name))

    @property
    def effects(self) -> dict[str, float]:
        """The effects that are on, ``{word: value}``."""
        return {n: getattr(self, n) for n in EFFECTS if getattr(self, n) != 0.0}

    def replace(self, **changes) -> "PlantParams":
        """A copy with some fields changed (effects validated)."""
        return dataclasses.replace(self, **changes)


class _Settings(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The plant file's settings, flat (every field of :class:`PlantParams` but the model); effects added below."""

    noise_lpm: NoiseLpm = 0.5
    # counts per L/min (0: no quantization); bounded so that flow x scale stays far from overflow
    scale_factor: Annotated[float, msgspec.Meta(ge=0.0, le=1e9)] = 120.0
    range_lpm: tuple[Finite, Finite] = (-250.0, 250.0)
    supply_bar: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 3.0
    model_supply_bar: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 3.0
    atmosphere_bar: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.01325
    droop_bar: NonNegative = 0.15
    droop_ref_lpm: Annotated[float, msgspec.Meta(ge=1e-3, le=1e4)] = 200.0  # a flow; squared by the droop
    wander_tau_s: Positive = 30.0
    ambient_c: Annotated[float, msgspec.Meta(ge=-273.15, le=1000.0)] = 25.0
    coil_tau_s: Positive = 180.0
    coil_alpha_per_k: Annotated[float, msgspec.Meta(ge=0.0, le=1.0)] = 0.00393
    dynamics_order: Literal[1, 2] = 1
    creep_tau_s: Positive = 20.0

    def __post_init__(self):
        lo, hi = self.range_lpm
        if not lo < hi:
            raise ValueError(f"range_lpm: must be [low, high] with low < high (got [{lo:g}, {hi:g}])")


#: The plant's settings schema: :class:`_Settings` plus one field per effect word, within its limits.
PlantSettings = msgspec.defstruct(
    "PlantSettings",
    [(e.name, Annotated[float, msgspec.Meta(ge=e.limits[0], le=e.limits[1])], 0.0) for e in EFFECTS.values()],
    bases=(_Settings,), kw_only=True, forbid_unknown_fields=True)

#: plant file section -> its keys (fields of PlantSettings)
_SECTIONS = {
    "sensor": {"noise_lpm", "scale_factor", "range_lpm"},
    "supply": {"supply_bar", "model_supply_bar", "atmosphere_bar", "droop_bar", "droop_ref_lpm", "wander_tau_s"},
    "coil": {"ambient_c", "coil_tau_s", "coil_alpha_per_k"},
    "valve": {"dynamics_order", "creep_tau_s"},
    "effects": set(EFFECTS),
}
_WHERE = {name: f"{sec}.{name}" for sec, names in _SECTIONS.items() for name in names}


def check_settings(fields: dict, source: str):
    """Flat plant settings (:class:`PlantSettings` fields) checked; messages name the file's ``section.key``."""
    return convert(fields, PlantSettings, source, field_names=_WHERE)


def load_plant(
    path: str | os.PathLike = DEFAULT_PLANT,
    effects: dict[str, float] | None = None,
    **overrides,
) -> PlantParams:
    """Read a plant TOML file, then apply ``effects`` and field ``overrides``.

    The file's ``model`` key names the model file, relative to the TOML's folder.
    The default path is tried in the working directory, then in this checkout.
    Every setting, from the file or given, goes through :class:`PlantSettings`.
    """
    path = os.fspath(path)
    if path == DEFAULT_PLANT and not os.path.exists(path):
        path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), DEFAULT_PLANT)
    doc = read_toml(path)
    fields: dict = {}
    for key, value in doc.items():
        if key == "model":
            continue
        if key not in _SECTIONS or not isinstance(value, dict):
            raise InputError(f"{path}: {key}: unknown key (expected model, {', '.join(_SECTIONS)})")
        for name, v in value.items():
            if name not in _SECTIONS[key]:
                raise InputError(f"{path}: {key}.{name}: unknown key")
            fields[name] = v
    if not isinstance(doc.get("model"), str) or not doc["model"]:
        raise InputError(f"{path}: model: missing (path of the forward model file)")
    model_path = os.path.join(os.path.dirname(os.path.abspath(path)), doc["model"])
    fields.update(effects or {})
    fields.update(overrides)
    settings = check_settings(fields, path)
    model = load_model(model_path)
    return PlantParams(model=model, **{f: getattr(settings, f) for f in settings.__struct_fields__})


class PlantState(NamedTuple):
    """State of B plants: step counter, model memory (B, M), scalar states (B, S), delay line (B, L)."""

    k: int
    model: np.ndarray
    x: np.ndarray
    buf: np.ndarray


class PlantOutput(NamedTuple):
    """One step's outputs (floats for :class:`Plant`, arrays (B,) for :class:`BatchPlant`).

    Attributes
    ----------
    flow_lpm : measured flow (sensor offset, noise, quantization, range), L/min
    true_flow_lpm : flow at the sensor without sensor errors, L/min
    supply_bar : supply pressure, bar gauge
    coil_temp_c : coil temperature, °C
    """

    flow_lpm: float | np.ndarray
    true_flow_lpm: float | np.ndarray
    supply_bar: float | np.ndarray
    coil_temp_c: float | np.ndarray


def _delay_samples(delay_s: float, rate_hz: float) -> tuple[int, float]:
    """Whole samples and fractional remainder of a delay; near-whole counts are whole."""
    d = delay_s * rate_hz
    n = round(d)
    if abs(d - n) < 1e-9:
        return int(n), 0.0
    return int(math.floor(d)), d - math.floor(d)


def _major_loop_half_width(core) -> float:
    """Half the horizontal gap between the major loop's branches at mid output (normalized input).

    The loop's own geometry, not a weight average: fitted weights of wide operators can be
    negative, and ``sum(w r) / sum(w)`` then says nothing about the width.
    """
    u = np.linspace(-1.0, 1.0, 401)
    _, s = core.predict(u[::-1], core.init(1.0))  # come down from the top: on the major loop
    up, s = core.predict(u, s)
    down, _ = core.predict(u[::-1], s)
    down = down[::-1]
    mid = 0.5 * (up[0] + up[-1])
    # both branches rise with u for an invertible model; np.interp wants them increasing
    half = 0.5 * (np.interp(mid, up, u) - np.interp(mid, down, u))
    return float(max(half, 0.0))


#: Model kinds the simulated valve runs: every kind.
PLANT_KINDS = ("pi", "pi-asym", "pi-mod", "preisach", "preisach-cont", "bouc-wen")


def _model_arrays(core) -> tuple[int, int, int, np.ndarray, np.ndarray]:
    """A core as the kernel sees it: ``(kind code, NM, NK, model row, Everett mesh)``.

    Model rows: PI family ``[r, w, h, g]`` (m operators, k dead zones; ``h = [0], g = [1]``
    without dead zones), Preisach ``[alpha, beta, mu]``, Bouc-Wen ``[beta, gamma, n, a, b]``;
    the continuous Preisach's Everett mesh goes separately (NM = its size).
    """
    if core.kind in ("pi", "pi-asym", "pi-mod"):
        h, g = getattr(core, "h", np.zeros(1)), getattr(core, "g", np.ones(1))
        return K.KIND_PI, len(core.r), len(h), np.concatenate([core.r, core.w, h, g]), np.zeros((1, 1))
    if core.kind == "preisach":
        return K.KIND_PREISACH, len(core.mu), 0, np.concatenate([core.alpha, core.beta, core.mu]), np.zeros((1, 1))
    if core.kind == "preisach-cont":
        return K.KIND_PREISACH_CONT, core.n_mesh + 1, 0, np.zeros(0), core.everett
    return K.KIND_BOUC_WEN, 0, 0, np.array([core.beta, core.gamma, core.n, core.a, core.b]), np.zeros((1, 1))


def _pack(p: PlantParams, rate_hz: float) -> np.ndarray:
    """The kernel's parameter vector for one plant at ``rate_hz``."""
    dt = 1.0 / rate_hz
    v = np.zeros(K.N_PARAMS)
    xs, ys = p.model.x_scale, p.model.y_scale
    v[K.XC], v[K.XH], v[K.YC], v[K.YH] = xs.center, xs.half_range, ys.center, ys.half_range
    core = p.model.core
    v[K.OFF] = core.c if core.kind == "bouc-wen" else core.offset
    v[K.KIND], v[K.NM], v[K.NK] = _model_arrays(core)[:3]
    v[K.A_ENV], v[K.P_ENV] = (core.a, core.p) if core.kind in ("pi-asym", "pi-mod") else (0.0, 1.0)
    v[K.FLOOR] = getattr(core, "floor", -np.inf)
    v[K.GAIN_LO] = ys.half_range / xs.half_range
    core = p.model.core
    v[K.ASYM] = p.asymmetric_hysteresis * _major_loop_half_width(core)
    v[K.HEAT_K], v[K.E_TH], v[K.T_AMB], v[K.ALPHA] = (
        p.coil_heating, math.exp(-dt / p.coil_tau_s), p.ambient_c, p.coil_alpha_per_k)
    e_w = math.exp(-dt / p.wander_tau_s)
    v[K.P_NOM], v[K.P_MODEL_ABS], v[K.P_ATM] = p.supply_bar, p.model_supply_bar + p.atmosphere_bar, p.atmosphere_bar
    v[K.WANDER], v[K.E_W], v[K.SQ_W] = p.supply_pressure, e_w, math.sqrt(1.0 - e_w * e_w)
    v[K.DROOP] = p.droop_bar / p.droop_ref_lpm ** 2
    tau = p.valve_dynamics
    if tau > 0.0:
        v[K.ORDER] = p.dynamics_order
        if p.dynamics_order == 1:
            e = math.exp(-dt / tau)
            v[K.PHI11], v[K.G1] = e, 1.0 - e
        else:  # critically damped, both poles at 2/tau: total lag tau
            a = 2.0 / tau
            e = math.exp(-a * dt)
            v[K.PHI11], v[K.G1] = e, 1.0 - e
            v[K.PHI21], v[K.PHI22], v[K.G2] = a * dt * e, e, 1.0 - e - a * dt * e
    v[K.DELAY_N], v[K.DELAY_F] = _delay_samples(p.transport_delay, rate_hz)
    v[K.CRACK], v[K.SAT] = p.dead_zone, p.saturation
    v[K.CREEP], v[K.E_CREEP] = p.creep, math.exp(-dt / p.creep_tau_s)
    v[K.NOISE], v[K.SENSOR_OFFSET], v[K.SCALE] = p.noise_lpm, p.sensor_offset, p.scale_factor
    v[K.RANGE_LO], v[K.RANGE_HI] = p.range_lpm
    return v


class BatchPlant:
    """B simulated valves, each with its own parameters and seed, stepped as one array.

    Parameters
    ----------
    params : PlantParams or sequence of PlantParams
    rate_hz : float
        Step rate, Hz.
    seed : int or sequence of int
        Noise seeds; an int ``s`` gives plant ``i`` the seed ``s + i``, so plant
        ``i`` reproduces ``Plant(params[i], rate_hz, seed=s + i)`` bit for bit.
    """

    def __init__(self, params: PlantParams | Sequence[PlantParams], rate_hz: float, seed: int | Sequence[int] = 0):
        self.params = [params] if isinstance(params, PlantParams) else list(params)
        if not self.params:
            raise ValueError("BatchPlant needs at least one plant")
        if not rate_hz > 0:
            raise InputError(f"--rate: must be positive, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        B = len(self.params)
        seeds = [seed + i for i in range(B)] if isinstance(seed, (int, np.integer)) else list(seed)
        if len(seeds) != B:
            raise ValueError(f"{len(seeds)} seeds for {B} plants")
        self.seeds = seeds
        self._keys = np.array([K.plant_keys(s) for s in seeds], dtype=np.uint64)
        # packed once per distinct valve: a sweep batches a few valves repeated over hundreds of candidates
        distinct = {id(p): p for p in self.params}
        rows = {i: _pack(p, self.rate_hz) for i, p in distinct.items()}
        models = {i: _model_arrays(p.model.core) for i, p in distinct.items()}
        self._P = np.array([rows[id(p)] for p in self.params])
        arrays = [models[id(p)] for p in self.params]
        self._MP = np.zeros((B, max(len(a[3]) for a in arrays)))  # padding: never read
        n_ev = max(a[4].shape[0] for a in arrays)
        self._EV = np.zeros((B, n_ev, n_ev))
        for b, a in enumerate(arrays):
            self._MP[b, :len(a[3])] = a[3]
            self._EV[b, :a[4].shape[0], :a[4].shape[1]] = a[4]
        n_del = self._P[:, K.DELAY_N].astype(int) + (self._P[:, K.DELAY_F] > 0)
        self._L = int(n_del.max()) + 1 if n_del.max() > 0 else 1

    def __len__(self) -> int:
        return len(self.params)

    def retune(self, index: int, **changes) -> None:
        """Change settings of plant ``index`` while it runs: from its next step on.

        ``changes`` are :class:`PlantParams` fields or effect words (e.g.
        ``supply_bar=0.3``: the supply fails, choked flow falls with the
        absolute upstream pressure). The state carries over unchanged, so a
        change acts as the physical change would: at once on the flow, through
        the valve's lag and delay on the measurement. The model and a delay
        longer than the delay line the plant was built with cannot change.
        """
        if "model" in changes:
            raise InputError("plant: the model of a running plant cannot change")
        try:
            params = self.params[index].replace(**changes)
        except TypeError:
            bad = sorted(set(changes) - {f.name for f in dataclasses.fields(PlantParams)})
            raise InputError(f"plant: unknown setting {', '.join(bad)}") from None
        row = _pack(params, self.rate_hz)
        n_del = int(row[K.DELAY_N]) + (row[K.DELAY_F] > 0)
        if n_del >= self._L:
            raise InputError(f"plant: transport_delay {params.transport_delay:g} s is longer than the running "
                             "plant's delay line")
        self.params[index] = params
        self._P[index] = row

    def init(self, duty0_pct: float | np.ndarray) -> PlantState:
        """Plants at rest at ``duty0_pct``: operators by Eq. (3), lag and delay line settled, coil at ambient."""
        B = len(self)
        d0 = np.broadcast_to(np.asarray(duty0_pct, dtype=np.float64), (B,))
        P = self._P
        u0 = np.clip((d0 - P[:, K.XC]) / P[:, K.XH], -1.0, 1.0)
        # each model's own initial memory (Eq. 3 for the PI family, relaxed relays, staircase, h = 0)
        memo = {}
        memories = [memo[key] if key in memo else memo.setdefault(key, p.model.core.init(key[1]))
                    for p, u in zip(self.params, u0) for key in [(id(p), float(u))]]
        ms = np.zeros((B, max(len(m) for m in memories)))
        for b, m in enumerate(memories):
            ms[b, :len(m)] = m
        x = np.zeros((B, K.N_STATE))
        x[:, K.S_TEMP] = P[:, K.T_AMB]
        x[:, K.S_U_PREV] = u0
        x[:, K.S_U_BACK] = u0
        state = PlantState(0, ms, x, np.zeros((B, self._L)))
        new, _ = self._advance(state, d0[None, :].copy(), settle=True)
        return PlantState(0, new.model, new.x, new.buf)

    def _advance(self, state: PlantState, duty: np.ndarray, settle: bool = False):
        """Run the kernel on ``duty`` of shape (N, B); outputs (N, B, N_OUT)."""
        out = np.empty(duty.shape + (K.N_OUT,))
        ms, x, buf = np.empty_like(state.model), np.empty_like(state.x), np.empty_like(state.buf)
        K.advance(duty, state.k, settle, self._P, self._MP, self._EV, self._keys,
                  state.model, state.x, state.buf, ms, x, buf, out)
        return PlantState(state.k + duty.shape[0], ms, x, buf), out

    def step(self, state: PlantState, duty_pct: np.ndarray) -> tuple[PlantState, PlantOutput]:
        """One step of every plant; ``duty_pct`` shape (B,) (or a scalar for all)."""
        duty = np.empty((1, len(self)))
        duty[0, :] = duty_pct
        state, out = self._advance(state, duty)
        o = out[0]
        return state, PlantOutput(o[:, K.O_FLOW], o[:, K.O_TRUE], o[:, K.O_SUPPLY], o[:, K.O_TEMP])

    def run(self, state: PlantState, duty_pct: np.ndarray) -> tuple[PlantState, dict[str, np.ndarray]]:
        """Many steps at once: ``duty_pct`` shape (B, N); returns the state and columns (B, N).

        Chunks chain like ``lfilter``'s ``zi``/``zf``: running two chunks equals running them joined.
        """
        duty = np.broadcast_to(np.asarray(duty_pct, dtype=np.float64), (len(self), np.shape(duty_pct)[-1]))
        state, out = self._advance(state, np.ascontiguousarray(duty.T))
        cols = out.transpose(1, 0, 2)  # (B, N, N_OUT)
        return state, {
            "flow_lpm": np.ascontiguousarray(cols[..., K.O_FLOW]),
            "true_flow_lpm": np.ascontiguousarray(cols[..., K.O_TRUE]),
            "supply_bar": np.ascontiguousarray(cols[..., K.O_SUPPLY]),
            "coil_temp_c": np.ascontiguousarray(cols[..., K.O_TEMP]),
        }

    def simulate(self, duty_pct: np.ndarray) -> dict[str, np.ndarray]:
        """A whole recording from rest at the first duty: ``t_s`` (N,) and columns (B, N)."""
        duty = np.asarray(duty_pct, dtype=np.float64)
        first = duty[..., 0]
        _, cols = self.run(self.init(first), duty)
        n = duty.shape[-1]
        return {"t_s": np.arange(n) / self.rate_hz, "duty_pct": np.broadcast_to(duty, (len(self), n)), **cols}


class Plant:
    """One simulated valve: the batch of one, with float inputs and outputs.

    Parameters
    ----------
    params : PlantParams
    rate_hz : float
        Step rate, Hz.
    seed : int
        Noise seed; a fixed seed reproduces a recording bit for bit.
    """

    def __init__(self, params: PlantParams, rate_hz: float, seed: int = 0):
        self.params = params
        self.rate_hz = float(rate_hz)
        self.seed = int(seed)
        self._batch = BatchPlant([params], rate_hz, [seed])
        self._duty = np.empty((1, 1))

    def retune(self, **changes) -> None:
        """Change settings while the valve runs (see :meth:`BatchPlant.retune`)."""
        self._batch.retune(0, **changes)
        self.params = self._batch.params[0]

    def init(self, duty0_pct: float) -> PlantState:
        """The valve at rest at ``duty0_pct`` (see :meth:`BatchPlant.init`)."""
        return self._batch.init(duty0_pct)

    def step(self, state: PlantState, duty_pct: float) -> tuple[PlantState, PlantOutput]:
        """One step: command ``duty_pct`` (%), read the flow (L/min)."""
        self._duty[0, 0] = duty_pct
        state, out = self._batch._advance(state, self._duty)
        o = out[0, 0]
        return state, PlantOutput(float(o[0]), float(o[1]), float(o[2]), float(o[3]))

    def running(self, state: PlantState) -> "RunningPlant":
        """The valve from ``state`` on, advanced in place step by step (see :class:`RunningPlant`)."""
        return RunningPlant(self._batch, state)

    def simulate(self, duty_pct: np.ndarray) -> dict[str, np.ndarray]:
        """A whole recording from rest at ``duty_pct[0]``: columns ``t_s, duty_pct, flow_lpm,
        true_flow_lpm, supply_bar, coil_temp_c`` (N,)."""
        cols = self._batch.simulate(np.asarray(duty_pct, dtype=np.float64)[None, :])
        return {k: (v if v.ndim == 1 else v[0]) for k, v in cols.items()}


class RunningPlant:
    """One valve advanced in place: :meth:`Plant.step` without its allocations, for a live loop.

    The same kernel, on state arrays owned here (read and written in place) instead of fresh
    ones per step; settings changed on the plant (:meth:`Plant.retune`) act from the next step.
    """

    def __init__(self, batch: BatchPlant, state: PlantState):
        self._batch = batch
        self.k = state.k
        self._ms, self._x, self._buf = state.model.copy(), state.x.copy(), state.buf.copy()
        self._scratch = self._ms.copy(), self._x.copy(), self._buf.copy()  # rehearse()'s state
        # plant 0's rows by address (models.borrow.pointer): the batch's own parameter rows, which
        # retune() rewrites in place, and the state arrays above, kept here and never reallocated
        rows = [batch._P[0], batch._MP[0], batch._EV[0], batch._keys[0]]
        self._heads = [np.array([v for a in rows + list(own) for v in (a.ctypes.data, len(a))], dtype=np.int64)
                       for own in ((self._ms[0], self._x[0], self._buf[0]), [a[0] for a in self._scratch])]
        self._head, self._scratch_head = (h.ctypes.data for h in self._heads)
        # the kernel's machine code, called without numba's dispatcher (models.direct)
        self._step_at = direct(K.step_at, self._head, self.k, 0.0)

    @property
    def state(self) -> PlantState:
        """A copy of the present state."""
        return PlantState(self.k, self._ms.copy(), self._x.copy(), self._buf.copy())

    def rehearse(self, duty_pct: float) -> None:
        """The next step on a scratch copy of the state: its machine code and data pass through the
        caches, and the valve is untouched (a live loop's rehearsal before its deadline)."""
        ms, x, buf = self._scratch
        np.copyto(ms, self._ms)
        np.copyto(x, self._x)
        np.copyto(buf, self._buf)
        self._step_at(self._scratch_head, self.k, float(duty_pct))

    def step(self, duty_pct: float) -> PlantOutput:
        """One step: command ``duty_pct`` (%), read the flow (L/min)."""
        out = self._step_at(self._head, self.k, float(duty_pct))
        self.k += 1
        return PlantOutput(*out)
