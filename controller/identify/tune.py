"""From the identification to a run configuration: the valve as a plant, a short gain sweep, ``run.toml``.

Written to the output folder:

- ``plant.toml``: the identified valve as a simulated plant (the model, its
  lag and delay as ``valve_dynamics`` and ``transport_delay``, the sensor
  noise measured on the steps), so ``valvectl run --plant sim`` and sweeps
  drive a twin of this valve;
- ``run.toml``: the input run configuration with this valve's feedforward
  model, ``[valve] tau_s, delay_s`` and the gains of the sweep;
- ``sweep.toml`` and ``sweep.csv``: the gain sweep (:mod:`controller.sweep`)
  on that plant and on variants of it, ranked by the worst IAE over them.
  The feedforward inverts the very model the nominal plant runs, so on the
  nominal plant alone the sweep would trust it more than the real valve
  deserves; the variants are the errors of the identification and the drifts
  of a valve: lag and delay 30 % longer or shorter, every flow 20 % lower or
  higher (:data:`FLOW_GAIN_ERROR`), and the valve as the runner-up model kind
  describes it (``plant_alt.json``: a model error as large as the kinds'
  disagreement). Every controller word, ``pid`` included, gets its best gains
  on the same variants, and the run's controller is the best word.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import os
from dataclasses import dataclass

from models.atomicfile import write_text_atomic
from models.model import FittedModel, save_model
from models.recording import InputError

#: Random candidates per controller word in the short sweep (of 200; scaled to ``[identify] tune_candidates``),
#: and their ranges.
SWEEP_CANDIDATES = {
    "pid": (60, {"pid.kp": {"log": [0.02, 1.0]}, "pid.ki": {"log": [0.5, 100.0]}, "pid.kd": {"uniform": [0.0, 0.004]}}),
    "ff+pid": (60, {"ff_pid.kp": {"log": [0.02, 1.0]}, "ff_pid.ki": {"log": [0.5, 100.0]},
                    "ff_pid.kd": {"uniform": [0.0, 0.003]}}),
    "ff+kf": (80, {"kf.q_flow_lpm": {"log": [0.3, 30.0]}, "kf.q_bias_lpm": {"log": [0.002, 0.5]}}),
}
SWEEP_DURATION_S = 6.0
#: The feedforward words also sample how far beyond the delay their feedforward reads the profile
#: (``feedforward.anticipation_s``), uniform in [0, this x the identified lag]: the IAE of a first-order
#: edge is least when it starts ``tau ln 2`` early (a closing valve's flow decays with the lag whatever the
#: duty); an opening one is sped up by the lag inversion, so it wants less, and no edge wants more
#: (reading further only adds error before each edge; a sweep on [0, tau] picked up to 0.9 tau, which
#: cost the bench twin 10 % of its IAE against tau ln 2).
ANTICIPATION_TAUS = math.log(2.0)
#: With no flow asked, the identified run parks the valve this share of its working range below the model's
#: onset of flow ([feedforward] ready_margin_pct). Where a minor loop's descending branch closes is what the
#: identification sees least (its excitation stays above the cracking duty; the bench twin, descending from
#: 60 L/min, still passes 2 L/min 2 % below the identified model's onset, which doubled ff+kf's IAE), and
#: parking lower costs the next breath nothing measurable (both twins: IAE within 1 % from a margin of 6 % to 12 %).
READY_SHARE = 0.2


@dataclass(frozen=True)
class Tuning:
    """The run configuration written and the sweep behind it.

    Attributes
    ----------
    run_path : str
    controller : str
        The best controller word (the run's).
    best : dict
        Per controller word, ``{"params": {...}, "worst_iae": L, "iae": L}``.
    seconds : float
        Wall time of the sweep, s.
    """

    run_path: str
    controller: str
    best: dict
    seconds: float


def _toml(v) -> str:
    from controller.sweep.spec import _toml_value

    return _toml_value(v)


def plant_model(model: FittedModel, fallback) -> FittedModel:
    """``model`` if the simulated plant can run its kind, else ``fallback()`` (a PI fitted on the same rows)."""
    from plant_sim.plant import PlantParams

    try:
        PlantParams(model=model)
        return model
    except InputError:
        return fallback()


def write_plant(out_dir: str, model_file: str, tau_s: float, delay_s: float, noise_lpm: float) -> str:
    """``plant.toml``: the identified valve as a simulated plant; its path."""
    path = os.path.join(out_dir, "plant.toml")
    text = (
        "# The identified valve as a simulated plant (valvectl identify): model, lag, delay, sensor noise.\n"
        f"model = {_toml(model_file)}\n\n"
        "[sensor]\n"
        f"noise_lpm = {noise_lpm!r}   # measured on the steps (second differences)\n\n"
        "[effects]\n"
        f"valve_dynamics = {tau_s!r}   # s, from the steps\n"
        f"transport_delay = {delay_s!r}   # s, from the steps (loop convention: one period less than command to reading)\n"
    )
    write_text_atomic(path, text)
    return path


def run_config(base, out_dir: str, tau_s: float, delay_s: float, noise_lpm: float, span_pct: float = 0.0):
    """The input run configuration made this valve's: model, plant, ``[valve]``, the ready margin
    (:data:`READY_SHARE` of the working range's span ``span_pct``, the input's at least), no extra effects."""
    from controller.config import RunConfig

    s = copy.deepcopy(base.sections)
    s[""].update(model="model.json", plant_config="plant.toml", plant="zenoh")
    s["valve"].update(tau_s=float(tau_s), delay_s=float(delay_s))
    s["feedforward"]["ready_margin_pct"] = max(float(s["feedforward"]["ready_margin_pct"]), READY_SHARE * span_pct)
    s["kf"]["r_lpm"] = max(float(noise_lpm), 0.01)  # the sensor noise measured on the steps (a quantum at least)
    s["effects"] = {}  # the valve's lag and delay are in plant.toml now
    s["zenoh"]["config"] = os.path.abspath(base.resolve(base["zenoh"]["config"]))
    return RunConfig(os.path.join(out_dir, "run.toml"), os.path.abspath(out_dir), s)


#: The flow gain errors the sweep's variants give the plant: the identified models miss paths the protocol
#: never drove by this much (the bench twin reopened from its power-up memory: 10-15 L/min at 60 L/min, every
#: kind alike, so the runner-up kind's variant does not show it), on top of the supply's drift. With 7 % the
#: sweep trusted the feedforward: ff+kf with a slow bias estimate, 0.63 x pid on that twin; with 20 %, 0.39 x.
FLOW_GAIN_ERROR = 0.2


def _supply_bar(gain: float) -> float:
    """The identified plant's supply (gauge, bar) at which every flow is ``gain`` times the model's (flow is
    proportional to the absolute supply; the plant's nominal is its model's own supply)."""
    from plant_sim.plant import PlantParams

    f = {f.name: f.default for f in dataclasses.fields(PlantParams)}
    return round(gain * (f["model_supply_bar"] + f["atmosphere_bar"]) - f["atmosphere_bar"], 4)


def sweep_text(tau_s: float, delay_s: float, seed: int, candidates: int = 200, alt_model: str | None = None) -> str:
    """``sweep.toml`` of the short gain sweep on the identified plant, about ``candidates`` candidates
    (``alt_model``: the runner-up kind's model file, a variant when given)."""
    lines = [
        "# The short gain sweep of valvectl identify, on the identified valve (plant.toml) and its drifts.",
        'run = "run.toml"',
        f"duration_s = {SWEEP_DURATION_S!r}",
        f"seed = {seed}",
        'objective = "worst_iae"',
        "margins_top = 0",
        "",
        "[[variants]]",
        "",
        "[[variants]]              # slower valve",
        f"valve_dynamics = {1.3 * tau_s!r}",
        f"transport_delay = {1.3 * delay_s!r}",
        "",
        "[[variants]]              # faster valve",
        f"valve_dynamics = {0.7 * tau_s!r}",
        f"transport_delay = {0.7 * delay_s!r}",
        "",
        f"[[variants]]              # every flow {FLOW_GAIN_ERROR:.0%} lower than the model says",
        f"supply_bar = {_supply_bar(1.0 - FLOW_GAIN_ERROR)!r}",
        "",
        f"[[variants]]              # every flow {FLOW_GAIN_ERROR:.0%} higher",
        f"supply_bar = {_supply_bar(1.0 + FLOW_GAIN_ERROR)!r}",
    ]
    if alt_model:
        lines += ["", "[[variants]]              # the valve as the runner-up model kind describes it: model error",
                  f"model = {_toml(alt_model)}"]
    for word, (n, ranges) in SWEEP_CANDIDATES.items():
        lines += ["", "[[candidates]]", f'controller = "{word}"', f"sample = {max(4, round(n * candidates / 200))}"]
        if word.startswith("ff"):
            ranges = {**ranges, "feedforward.anticipation_s": {"uniform": [0.0, ANTICIPATION_TAUS * tau_s]}}
        for k, (kind, (lo, hi)) in ((k, next(iter(v.items()))) for k, v in ranges.items()):
            lines.append(f"{k} = {{{kind} = [{lo!r}, {hi!r}]}}")
    return "\n".join(lines) + "\n"


def tune(base, out_dir: str, model: FittedModel, plant: FittedModel, tau_s: float, delay_s: float, noise_lpm: float,
         seed: int = 0, candidates: int = 200, workers: int | None = None, alt: FittedModel | None = None,
         span_pct: float = 0.0) -> Tuning:
    """Write model, plant, sweep and run files to ``out_dir``, run the sweep, write the tuned ``run.toml``.

    ``alt`` (a kind the simulated plant can run, other than ``plant``'s) is the model-error variant;
    ``span_pct`` the working range's span (duty %), for the ready margin (:func:`run_config`).
    """
    from controller.sweep import runner
    from controller.sweep.spec import apply, load_sweep, write_run_config

    save_model(model, os.path.join(out_dir, "model.json"))
    plant_file = "model.json"
    if plant is not model:
        plant_file = "plant_model.json"
        save_model(plant, os.path.join(out_dir, plant_file))
    write_plant(out_dir, plant_file, tau_s, delay_s, noise_lpm)
    run = run_config(base, out_dir, tau_s, delay_s, noise_lpm, span_pct)
    write_run_config(run, run.path)
    sweep_path = os.path.join(out_dir, "sweep.toml")
    alt_file = None
    if alt is not None:
        alt_file = "plant_alt.json"
        save_model(alt, os.path.join(out_dir, alt_file))
    write_text_atomic(sweep_path, sweep_text(tau_s, delay_s, seed, candidates, alt_file))
    spec = load_sweep(sweep_path)
    res = runner.run_sweep(spec, None, workers)
    runner.write_csv(res, os.path.join(out_dir, "sweep.csv"))
    obj = res.table[spec.objective]
    words = res.table["controller"]
    best, rows, cfg = {}, {}, run
    for word in SWEEP_CANDIDATES:
        idx = [i for i in range(len(words)) if words[i] == word and obj[i] == obj[i]]
        if not idx:
            continue
        i = min(idx, key=lambda j: obj[j])
        best[word] = runner.candidate_summary(res, i)
        rows[word] = spec.candidates.row(i)
        cfg = apply(cfg, word, rows[word])
    if not best:
        raise ValueError("the gain sweep gave no finite IAE for any candidate")
    winner = min(best, key=lambda w: best[w][spec.objective])
    # last, so any setting the words share is the winner's
    cfg = apply(cfg, winner, rows[winner])
    write_run_config(cfg, run.path)
    return Tuning(run.path, winner, best, res.seconds)


def tune_identified(base, out_dir: str, est, dyn, seed: int = 0, candidates: int = 200, span_pct: float = 0.0,
                    workers: int | None = None) -> Tuning:
    """:func:`tune` for an identification (``est``: :class:`.estimate.Estimate`, ``dyn``: its
    :class:`.dynamics.Dynamics`): the simulated plant runs the chosen model (a PI fitted on the same
    rows when it cannot), and the model-error variant is the next-best kind it can run.

    Raises
    ------
    ValueError
        The simulated plant can run no fitted kind, or the sweep gave no finite IAE.
    """
    pi = est.results["pi"].model if "pi" in est.results else None
    plant = plant_model(est.model, lambda: pi)
    if plant is None:
        raise ValueError("the simulated plant cannot run any fitted kind")
    others = sorted((r for r in est.results.values() if r.model.kind != plant.kind), key=lambda r: r.validation.rmse)
    alt = next((r.model for r in others if plant_model(r.model, lambda: None) is not None), None)
    return tune(base, out_dir, est.model, plant, dyn.tau_s, dyn.delay_s, dyn.noise_lpm, seed, candidates, workers,
                alt, span_pct)
