"""The concealed-effect suite of the diagnosis, made with plant_sim.

A case is a plant_sim recording with zero, one or two effect words switched
on, each *sized* so that it is concealed: the part of the change it makes to
the true flow that the paper's PI cannot absorb (the residual of a PI
least-squares fit to the change) has an RMS of ``size`` times the sensor
noise (bisection on the parameter, noise-free runs with the same seed). So
the PI still fits with r >= 0.998 and what is left of the effect is about
as big as the noise.

Excitations are plant_sim's protocols over the valve's open range (duty
40-72 %: the forward model itself closes near 35.6 %, a dead zone of its own,
and is flat above 72 %, a saturation of its own; dead-zone cases go down to
36 %). The coil temperature column is
dropped (a bench rarely has it; the detector then has to infer the thermal
state from the duty history), the supply pressure column is kept.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from models.pi import regressors, thresholds
from models.preprocess import Scaling
from models.recording import Recording
from models.diagnose.words import WORDS
from plant_sim import protocols as P
from plant_sim.effects import EFFECTS as PLANT_EFFECTS
from plant_sim.plant import Plant, load_plant

ROOT = Path(__file__).resolve().parents[1]
PLANT_TOML = ROOT / "config" / "plant.toml"
MODEL_JSON = ROOT / "config" / "valve_model.json"
RATE_HZ = 100.0
DURATION_S = 240.0
#: Thermal time constant of the suite's coil (s), so heating shows within DURATION_S.
COIL_TAU_S = 60.0
#: Top of the excitations (%): the identified range of the forward model ends at 72 %, above
#: it the model is flat (full open), a saturation of its own.
HI_PCT = 72.0

#: Lowest duty of dead-zone cases (%): below the cracking duty sought, above the forward model's own closing.
DEAD_ZONE_LO_PCT = 36.0

#: Period (s) and inspiratory time (s) of the open-loop breaths excitation.
BREATH_PERIOD_S, BREATH_INSP_S = 3.0, 1.0
#: Rate (Hz) of the closed-loop runs (controller and plant).
LOOP_RATE_HZ = 200.0


def excitation(name: str, seed: int, lo_pct: float = 40.0, rate_hz: float = RATE_HZ,
               duration_s: float = DURATION_S) -> np.ndarray:
    """Duty (%) of one of the suite's excitations."""
    if name == "random_holds":
        return P.random_holds(rate_hz, duration_s, seed, lo_pct=lo_pct, hi_pct=HI_PCT)
    if name == "ramps":
        return P.ramps(rate_hz, duration_s, seed, lo_pct=lo_pct, hi_pct=HI_PCT)
    if name == "sines":
        mid = (lo_pct + HI_PCT) / 2
        return P.sines(rate_hz, duration_s, seed, center_pct=mid, amplitude_pct=HI_PCT - mid,
                       periods_s=(40.0, 12.0, 4.0, 1.5))
    if name == "paper":
        return P.paper_identification(rate_hz, duration_s, seed, lo_pct=lo_pct, hi_pct=HI_PCT, max_rate_pct_s=2.0)
    if name == "steps":
        rng = np.random.default_rng(seed)
        levels = tuple(rng.uniform(lo_pct, HI_PCT, 24))
        return P.steps(rate_hz, duration_s, seed, levels_pct=levels, hold_s=3.0)
    if name == "breaths":
        # a ventilator's inspiratory valve: rests near closed, opens to a level per breath in 0.2 s
        t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
        k = (t // BREATH_PERIOD_S).astype(int)
        peak = np.random.default_rng(seed).uniform(lo_pct + 0.5 * (HI_PCT - lo_pct), HI_PCT, k[-1] + 1)[k]
        phase = t % BREATH_PERIOD_S
        rise = np.clip(phase / 0.2, 0.0, 1.0)
        return np.where(phase < BREATH_INSP_S, lo_pct + (peak - lo_pct) * rise, lo_pct)
    if name == "closed_loop":
        return closed_loop_run((), seed, lo_pct, 0.0)["duty_pct"]
    raise ValueError(name)


#: Excitations of the concealed suite.
EXCITATIONS = ("random_holds", "ramps", "sines", "paper")
#: Excitations of the magnitude x excitation matrix.
MATRIX_EXCITATIONS = ("paper", "steps", "ramps", "random_holds", "breaths", "closed_loop")
#: Magnitudes of the matrix: the unabsorbed part of each effect, in multiples of the noise.
MATRIX_SIZES = (1.0, 5.0, 30.0)


@lru_cache(maxsize=8)
def closed_loop_run(effects: tuple, seed: int, lo_pct: float, noise_lpm: float, duration_s: float = DURATION_S) -> dict:
    """A closed-loop run (ff+kf, config/run.toml's breath profile, simulated clock at
    :data:`LOOP_RATE_HZ`) of plant_sim with ``effects``: the columns of ``valvectl run --record``.

    The expiratory reference is the flow at ``lo_pct`` (the valve is held open a little, as a
    ventilator's bias flow), so that the duty stays where the forward model is identified.
    """
    from controller.config import controller_params, load_run_config
    from controller.loop import Loop, LoopSettings, ProfileReference, SimClock
    from controller.transport.sim import SimTransport
    from models.model import load_model

    cfg = load_run_config(ROOT / "config" / "run.toml")
    model = load_model(MODEL_JSON)
    base_lpm = float(model.predict(np.array([lo_pct + 4.0]))[0][0])
    profile = P.BreathProfile(**{**cfg["profile"], "base_lpm": base_lpm, "peak_lpm": 110.0})
    plant = Plant(load_plant(PLANT_TOML, effects=dict(effects), noise_lpm=noise_lpm, coil_tau_s=COIL_TAU_S),
                  LOOP_RATE_HZ, seed=seed)
    loop = Loop(controller_params(cfg, "ff+kf", model), SimTransport(plant), ProfileReference(profile.value),
                LoopSettings(rate_hz=LOOP_RATE_HZ), clock=SimClock())
    cols = loop.run(duration_s).columns
    keep = {k: np.asarray(cols[k], dtype=np.float64) for k in ("t_s", "ref_lpm", "flow_lpm", "duty_pct")}
    keep["state"] = np.asarray(cols["state"])
    return keep


@dataclass(frozen=True)
class Case:
    """One suite recording: effects (word -> parameter), excitation, seed, noise (L/min), with a model file or not."""

    effects: tuple
    excitation: str
    seed: int
    noise_lpm: float
    with_model: bool = False
    size: float = 1.0

    @property
    def words(self) -> tuple:
        return tuple(w for w, _ in self.effects)

    @property
    def lo_pct(self) -> float:
        return DEAD_ZONE_LO_PCT if "dead_zone" in self.words else 40.0

    def label(self) -> str:
        eff = "+".join(f"{w}={v:.4g}" for w, v in self.effects) or "none"
        return f"{eff} [{self.excitation}, seed {self.seed}, noise {self.noise_lpm:g}{', model' if self.with_model else ''}]"


def _run(effects: dict, duty: np.ndarray, seed: int, noise: float) -> dict:
    params = load_plant(PLANT_TOML, effects=effects, noise_lpm=noise, coil_tau_s=COIL_TAU_S)
    rate = RATE_HZ if len(duty) == int(round(DURATION_S * RATE_HZ)) else LOOP_RATE_HZ
    return Plant(params, rate, seed=seed).simulate(duty)


@lru_cache(maxsize=256)
def _true_flow(effects: tuple, exc: str, seed: int, lo: float) -> np.ndarray:
    return _run(dict(effects), _duty(exc, seed, lo), seed, 0.0)["true_flow_lpm"]


@lru_cache(maxsize=16)
def _duty(exc: str, seed: int, lo: float) -> np.ndarray:
    return excitation(exc, seed, lo, rate_hz=LOOP_RATE_HZ if exc == "closed_loop" else RATE_HZ)


#: Switching supply_pressure on also switches on the static droop with flow (a function of the
#: flow the PI absorbs); the wander is what is sized, against the droop alone.
FLOOR = {"supply_pressure": 1e-9}


@lru_cache(maxsize=16)
def _pi_basis(exc: str, seed: int, lo: float) -> np.ndarray:
    """Orthonormal basis of the PI regressors (50 operators and an offset) of the excitation."""
    duty = _duty(exc, seed, lo)
    xs = Scaling.from_data(duty)
    Y = regressors(thresholds(50), xs.to_unit(duty))
    q, _ = np.linalg.qr(np.column_stack([Y, np.ones(len(duty))]))
    return q


def effect_rms(word: str, value: float, exc: str, seed: int, lo: float) -> float:
    """RMS (L/min) of the part of the true-flow change made by ``word`` = ``value`` that a PI cannot absorb."""
    a = _true_flow(((word, float(value)),), exc, seed, lo)
    b = _true_flow(((word, FLOOR[word]),) if word in FLOOR else (), exc, seed, lo)
    d = a - b
    q = _pi_basis(exc, seed, lo)
    r = d - q @ (q.T @ d)
    return float(np.sqrt(np.mean(r ** 2)))


def size_effect(word: str, target_rms: float, exc: str, seed: int, lo: float, iters: int = 14) -> float:
    """Parameter of ``word`` whose effect RMS is ``target_rms`` (bisection within plant_sim's limits)."""
    if word == "sensor_offset":
        return float(target_rms * (1 if seed % 2 == 0 else -1))
    lim_lo, lim_hi = PLANT_EFFECTS[word].limits
    if word == "saturation":  # smaller full-open flow = larger effect
        flows = _true_flow((), exc, seed, lo)
        # never below the flow most of the recording holds (a breath's resting flow): a clip there
        # flattens the whole recording into a constant the PI absorbs
        a, b = max(float(np.percentile(flows, 30)), 1.05 * float(np.median(flows))), float(np.max(flows))
        for _ in range(iters):
            m = 0.5 * (a + b)
            a, b = (m, b) if effect_rms(word, m, exc, seed, lo) > target_rms else (a, m)
        return 0.5 * (a + b)
    if word == "dead_zone":
        a, b = lo, 60.0
    else:
        # from a tenth of the plausible low end: where switching the effect on is already
        # bigger than the target (a sampled lag delays by a sample), the case is not concealed
        a, b = PLANT_EFFECTS[word].plausible[0] / 100, min(lim_hi, 4 * PLANT_EFFECTS[word].plausible[1])
    for _ in range(iters):
        m = np.sqrt(a * b) if word != "dead_zone" else 0.5 * (a + b)
        a, b = (a, m) if effect_rms(word, m, exc, seed, lo) > target_rms else (m, b)
    return float(np.sqrt(a * b) if word != "dead_zone" else 0.5 * (a + b))


def make_case(words: tuple, exc: str, seed: int, noise: float, size: float = 1.0) -> Case:
    """A case with ``words`` sized to ``size`` x noise each (sensor offset and closed-loop cases use the
    model file: a closed-loop run is held against the model its feedforward used)."""
    lo = DEAD_ZONE_LO_PCT if "dead_zone" in words else 40.0
    eff = tuple((w, size_effect(w, size * noise, exc, seed, lo)) for w in words)
    return Case(eff, exc, seed, noise, with_model="sensor_offset" in words or exc == "closed_loop", size=size)


def record(case: Case, keep_temp: bool = False) -> Recording:
    """The case's recording (columns of DESIGN.md; coil_temp_c dropped unless ``keep_temp``; a
    closed-loop case has the columns of ``valvectl run --record``)."""
    if case.excitation == "closed_loop":
        return closed_loop_recording(case.effects, case.seed, case.noise_lpm, case.lo_pct, label=case.label())
    cols = _run(dict(case.effects), excitation(case.excitation, case.seed, case.lo_pct), case.seed, case.noise_lpm)
    keep = ["t_s", "duty_pct", "flow_lpm", "supply_bar"] + (["coil_temp_c"] if keep_temp else [])
    return Recording(f"<{case.label()}>", {k: np.asarray(cols[k], dtype=np.float64) for k in keep})


def cases(seeds=(1, 2, 3), noises=(0.25, 0.5, 1.0), excitations=EXCITATIONS, pairs=True, size=1.0) -> list:
    """The full suite: every effect word and effect-free over seeds x noises x excitations, plus two-effect pairs."""
    out = []
    for exc, seed, noise in itertools.product(excitations, seeds, noises):
        out.append(Case((), exc, seed, noise))
        for w in WORDS:
            out.append(make_case((w,), exc, seed, noise, size))
    if pairs:
        combos = [("coil_heating", "valve_dynamics"), ("asymmetric_hysteresis", "supply_pressure"),
                  ("transport_delay", "creep"), ("saturation", "coil_heating"), ("valve_dynamics", "creep")]
        for (a, b), exc in zip(combos, itertools.cycle(excitations)):
            for seed in seeds[:2]:
                out.append(make_case((a, b), exc, seed, 0.5, size))
    return out


def closed_loop_recording(effects: tuple, seed: int, noise_lpm: float, lo_pct: float = 40.0,
                          duration_s: float = DURATION_S, label: str = "closed loop") -> Recording:
    """A closed-loop run (:func:`closed_loop_run`) as ``valvectl run --record`` writes it."""
    from controller.watchdog import STATES

    cols = closed_loop_run(tuple(effects), seed, lo_pct, noise_lpm, duration_s)
    state = [STATES[int(v)] for v in cols["state"]]
    return Recording(f"<{label}>", {k: v for k, v in cols.items() if k != "state"}, {"state": state})


#: A matrix case is kept when its effect reaches at least this fraction of the magnitude asked for.
REACHED = 0.5


def reached(case: Case) -> float:
    """The unabsorbed RMS of the case's (single) effect in multiples of its noise."""
    (w, v), = case.effects
    if w == "sensor_offset":
        return case.size  # sized exactly
    return effect_rms(w, v, case.excitation, case.seed, case.lo_pct) / case.noise_lpm


def matrix(seeds=(1,), noise: float = 0.5, sizes=MATRIX_SIZES, excitations=MATRIX_EXCITATIONS, words=WORDS,
           left_out: list | None = None) -> list:
    """The magnitude x excitation matrix: every word alone at every size on every excitation, and each
    excitation effect free.

    A word that an excitation cannot show at a magnitude within its search range (four times its
    plausible maximum: an asymmetry of the descending branch on breaths that fall straight back to
    their resting duty, a dead zone between the levels of steps, a 0.2 s delay on a slow sweep) is
    left out at that magnitude, with the magnitude it reaches appended to ``left_out`` as
    ``(word, excitation, seed, size, reached)``, rather than counted as a case of that size."""
    out = []
    for exc, seed in itertools.product(excitations, seeds):
        out.append(Case((), exc, seed, noise, with_model=exc == "closed_loop"))
        for w, size in itertools.product(words, sizes):
            case = make_case((w,), exc, seed, noise, size)
            got = reached(case)
            if got >= REACHED * size:
                out.append(case)
            elif left_out is not None:
                left_out.append((w, exc, seed, size, got))
    return out
