"""A second concealed-effect suite, made without plant_sim: the diagnosis built for the physics.

The diagnosis is judged on recordings from generators it has never seen, so
this suite shares nothing with :mod:`plant_sim` but the effect words' physics
as DESIGN.md states it:

- the valve: a PI of 20 play operators with uniform thresholds and positive
  weights (not Eq. 2's 50), stepped by its own loop, mapped to 38-72 % duty and
  0-180 L/min;
- the effects, each coded here in its own way: coil heating with a 150 s
  thermal time constant (explicit Euler); a supply that wanders as two slow
  sines, with a droop and a noisy gauge; a first-order lag exact for a command
  linear between samples (plant_sim holds it: zero-order hold); a delay by
  interpolation in time; a dead zone; a hard clip; creep that relaxes
  exponentially after each reversal with a 12 s time constant; an asymmetric
  loop whose descending thresholds grow *in proportion to each threshold*
  (Al Janaideh's generalized PI, where plant_sim lifts all by one amount);
  a sensor offset;
- its own excitations (staircase, triangles, a chirp, ventilator breaths) at
  50 Hz, white noise and no quantization.

Each effect is sized as in :mod:`diagnose_suite`: the part of its change to
the true flow that a PI of 50 operators cannot absorb has an RMS of the
sensor noise.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.signal import lfilter

from models.pi import regressors, thresholds
from models.preprocess import Scaling
from models.diagnose.words import WORDS
from models.recording import Recording

RATE_HZ = 50.0
DURATION_S = 300.0
LO_PCT, HI_PCT = 38.0, 72.0
FULL_FLOW_LPM = 180.0
COIL_TAU_S = 150.0
CREEP_TAU_S = 12.0
EXCITATIONS = ("staircase", "triangles", "chirp", "breaths")

# -- the valve: 20 play operators, uniform thresholds, positive weights (a smooth loading curve) --
_R = np.linspace(0.0, 0.6, 20)
_W = np.exp(-_R / 0.15)
_W *= 1.0 / _W.sum()


def _play(x_unit: np.ndarray, r: np.ndarray, r_down: np.ndarray | None = None) -> np.ndarray:
    """Play operators stepped one sample at a time; ``r_down(x)`` the descending thresholds (default ``r``)."""
    y = np.full(len(r), x_unit[0])  # at rest at the first input
    out = np.empty((len(x_unit), len(r)))
    for k, x in enumerate(x_unit):
        down = r if r_down is None else r_down(x)
        y = np.minimum(np.maximum(y, x - r), x + down)
        out[k] = y
    return out


def valve(duty_pct: np.ndarray, asym: float = 0.0) -> np.ndarray:
    """Static-hysteresis flow (L/min) of the valve, its descending thresholds ``r (1 + asym s)``."""
    x = np.clip((duty_pct - LO_PCT) / (HI_PCT - LO_PCT) * 2.0 - 1.0, -1.0, 1.0)
    r_down = None if asym == 0 else (lambda xk: _R * (1.0 + asym * (xk + 1.0) / 2.0))
    q = _play(x, _R, r_down) @ _W  # in about [-1, 1]
    return np.clip((q + 1.0) / 2.0, 0.0, None) * FULL_FLOW_LPM


# -- excitations --
def excitation(name: str, seed: int, rate_hz: float = RATE_HZ, duration_s: float = DURATION_S) -> np.ndarray:
    rng = np.random.default_rng(1000 + seed)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    if name == "staircase":
        out, level = [], 55.0
        while sum(map(len, out)) < n:
            level = float(np.clip(level + rng.choice([-1, 1]) * rng.uniform(2, 12), 40, 70))
            out.append(np.full(int(rng.uniform(1.0, 4.0) * rate_hz), level))
        return np.concatenate(out)[:n]
    if name == "triangles":
        out, level = [], 40.0
        while sum(map(len, out)) < n:
            target = rng.uniform(40, 70)
            m = max(2, int(abs(target - level) / rng.uniform(2.0, 8.0) * rate_hz))
            out.append(np.linspace(level, target, m, endpoint=False))
            level = target
        return np.concatenate(out)[:n]
    if name == "chirp":
        f = 0.02 + (0.5 - 0.02) * t / duration_s
        return 55.0 + 15.0 * np.sin(2 * np.pi * np.cumsum(f) / rate_hz)
    if name == "breaths":
        period, insp = 3.0, 1.0
        phase = t % period
        peak = 58.0 + 12.0 * rng.uniform(0, 1, int(duration_s / period) + 1)[(t // period).astype(int)]
        rise = np.clip(phase / 0.2, 0, 1)
        return np.where(phase < insp, 42.0 + (peak - 42.0) * rise, 42.0)
    raise ValueError(name)


# -- the effects, coded independently of plant_sim --
def _heat(duty: np.ndarray, rise55_k: float) -> np.ndarray:
    temp = np.empty(len(duty))
    T, dt = 0.0, 1.0 / RATE_HZ
    for k, d in enumerate(duty):
        temp[k] = T
        T += dt / COIL_TAU_S * (rise55_k * (d / 55.0) ** 2 - T)
    return duty / (1.0 + 0.00393 * temp)


def _supply(t: np.ndarray, amp_bar: float, q: np.ndarray, seed: int) -> np.ndarray:
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, 2)
    wander = amp_bar * (np.sin(2 * np.pi * t / 37.0 + phase[0]) + 0.5 * np.sin(2 * np.pi * t / 11.0 + phase[1]))
    return 3.0 + wander - 0.1 * (q / 200.0) ** 2


def _creep(q: np.ndarray, duty: np.ndarray, amount: float) -> np.ndarray:
    z = np.zeros(len(q))
    direction, q_rev, target, zk = 0.0, q[0], 0.0, 0.0
    a = np.exp(-1.0 / (RATE_HZ * CREEP_TAU_S))
    for k in range(1, len(q)):
        d = np.sign(duty[k] - duty[k - 1])
        if d != 0 and direction != 0 and d != direction:
            target, q_rev = amount * (q[k - 1] - q_rev), q[k - 1]
        if d != 0:
            direction = d
        zk = target + (zk - target) * a
        z[k] = zk
    return q + z


def true_flow(effects: dict, exc: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Duty (%), flow at the sensor without noise (L/min) and the true supply (bar gauge) or None."""
    duty = excitation(exc, seed)
    plain = None if effects.get("coil_heating") or effects.get("asymmetric_hysteresis") else _plain_valve(exc, seed)
    return (duty, *flow_of(effects, duty, seed, plain))


def flow_of(effects: dict, duty: np.ndarray, seed: int, plain: np.ndarray | None = None) -> tuple:
    """Flow at the sensor without noise (L/min) and the true supply (bar gauge) or None, of the valve
    with ``effects`` on any ``duty`` at :data:`RATE_HZ` (``plain``: the effect-free valve's flow on it,
    if known)."""
    t = np.arange(len(duty)) / RATE_HZ
    d_eff = _heat(duty, effects["coil_heating"]) if effects.get("coil_heating") else duty
    asym = effects.get("asymmetric_hysteresis", 0.0)
    q = valve(d_eff, asym) if plain is None else plain
    if effects.get("creep"):
        q = _creep(q, duty, effects["creep"])
    if effects.get("dead_zone"):
        q = np.where(d_eff < effects["dead_zone"], 0.0, q)
    supply = None
    if effects.get("supply_pressure"):
        supply = _supply(t, effects["supply_pressure"], q, seed)
        q = q * (supply + 1.01325) / (3.0 + 1.01325)
    if effects.get("saturation"):
        q = np.minimum(q, effects["saturation"])
    if effects.get("valve_dynamics"):
        # exact for an input linear between samples (first-order hold): a fast valve answers within
        # the sample, where plant_sim's zero-order hold answers one sample late
        tau = effects["valve_dynamics"]
        a = np.exp(-1.0 / (RATE_HZ * tau))
        c = 1.0 - RATE_HZ * tau * (1.0 - a)
        q = lfilter([c, 1.0 - a - c], [1.0, -a], q - q[0]) + q[0]  # at rest at the first flow
    if effects.get("transport_delay"):
        q = np.interp(t - effects["transport_delay"], t, q)
    return q + effects.get("sensor_offset", 0.0), supply


@lru_cache(maxsize=16)
def _plain_valve(exc: str, seed: int) -> np.ndarray:
    return valve(excitation(exc, seed))


@lru_cache(maxsize=16)
def _pi_basis(exc: str, seed: int) -> np.ndarray:
    duty = excitation(exc, seed)
    Y = regressors(thresholds(50), Scaling.from_data(duty).to_unit(duty))
    return np.linalg.qr(np.column_stack([Y, np.ones(len(duty))]))[0]


def effect_rms(word: str, value: float, exc: str, seed: int) -> float:
    """RMS (L/min) of the part of the change ``word = value`` makes that a PI cannot absorb."""
    d = true_flow({word: value}, exc, seed)[1] - true_flow({}, exc, seed)[1]
    q = _pi_basis(exc, seed)
    return float(np.sqrt(np.mean((d - q @ (q.T @ d)) ** 2)))


#: Search range of each parameter (units of DESIGN.md); larger = stronger except saturation.
RANGES = {"asymmetric_hysteresis": (1e-3, 20.0), "coil_heating": (0.01, 400.0), "supply_pressure": (1e-4, 1.0),
          "valve_dynamics": (1e-4, 1.0), "transport_delay": (1e-4, 1.0), "dead_zone": (40.0, 55.0),
          "saturation": (90.0, 180.0), "creep": (1e-4, 1.0)}


def size_effect(word: str, target_rms: float, exc: str, seed: int, iters: int = 14) -> float | None:
    """Parameter of ``word`` whose unabsorbable RMS is ``target_rms`` (bisection); None when the
    excitation cannot show the effect at about that size (even the end of its range stays below,
    or the effect jumps past it, as a dead zone does at a level the excitation holds)."""
    if word == "sensor_offset":
        return target_rms * (1 if seed % 2 else -1) * 2.0
    lo, hi = RANGES[word]
    if effect_rms(word, lo if word == "saturation" else hi, exc, seed) < target_rms:
        return None
    linear = word in ("dead_zone", "saturation")
    for _ in range(iters):
        m = 0.5 * (lo + hi) if linear else np.sqrt(lo * hi)
        stronger = effect_rms(word, m, exc, seed) > target_rms
        if word == "saturation":
            lo, hi = (m, hi) if stronger else (lo, m)
        else:
            lo, hi = (lo, m) if stronger else (m, hi)
    value = float(0.5 * (lo + hi) if linear else np.sqrt(lo * hi))
    return value if 0.5 < effect_rms(word, value, exc, seed) / target_rms < 2.0 else None


@dataclass(frozen=True)
class Case:
    """One foreign recording: effects (word -> parameter), excitation, seed, noise (L/min)."""

    effects: tuple
    excitation: str
    seed: int
    noise_lpm: float

    @property
    def words(self) -> tuple:
        return tuple(w for w, _ in self.effects)

    @property
    def with_model(self) -> bool:
        return "sensor_offset" in self.words

    def label(self) -> str:
        eff = "+".join(f"{w}={v:.4g}" for w, v in self.effects) or "none"
        return f"{eff} [foreign {self.excitation}, seed {self.seed}, noise {self.noise_lpm:g}]"


def make_case(words: tuple, exc: str, seed: int, noise: float) -> Case | None:
    """A case with ``words`` sized to the noise each, or None if one cannot be made that large."""
    sizes = tuple((w, size_effect(w, noise, exc, seed)) for w in words)
    return None if any(v is None for _, v in sizes) else Case(sizes, exc, seed, noise)


def record(case: Case) -> Recording:
    """The case's recording (t_s, duty_pct, flow_lpm, and supply_bar read by a gauge with 5 mbar noise)."""
    duty, q, supply = true_flow(dict(case.effects), case.excitation, case.seed)
    rng = np.random.default_rng(case.seed * 7919 + int(case.noise_lpm * 1000))
    cols = {"t_s": np.arange(len(duty)) / RATE_HZ, "duty_pct": duty,
            "flow_lpm": q + rng.normal(0.0, case.noise_lpm, len(q))}
    if supply is not None:
        cols["supply_bar"] = supply + rng.normal(0.0, 0.005, len(q))
    return Recording(f"<{case.label()}>", cols)


@lru_cache(maxsize=1)
def model_file(seed: int = 99):
    """The simulation a sensor-offset case is held against: the paper's PI fitted on an effect-free
    foreign staircase recording of another seed."""
    from models.fitting import fit_recording

    return fit_recording("pi", record(Case((), "staircase", seed, 0.5)))


def cases(seeds=(1, 2), noises=(0.3, 0.8), excitations=EXCITATIONS) -> tuple[list, list]:
    """Every effect word and effect-free over seeds x noises x excitations, and the (word, excitation,
    seed, noise) left out because the excitation cannot show the effect at the noise level."""
    out, left_out = [], []
    for exc, seed, noise in itertools.product(excitations, seeds, noises):
        out.append(Case((), exc, seed, noise))
        for w in WORDS:
            case = make_case((w,), exc, seed, noise)
            if case is None:
                left_out.append((w, exc, seed, noise))
            else:
                out.append(case)
    return out, left_out
