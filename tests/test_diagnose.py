"""valvectl diagnose end to end: D.json and P.csv as DESIGN.md fixes them, and a fast subset of the
concealed-effect suite (bench/bench_diagnose.py runs the whole of it)."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

S = pytest.importorskip("diagnose_suite")
F = pytest.importorskip("diagnose_foreign")

from controller.cli import main  # noqa: E402
from models.diagnose import diagnose_response  # noqa: E402
from models.diagnose.words import VOCABULARY, WORDS  # noqa: E402
from models.model import load_model  # noqa: E402
from models.recording import Recording, write_recording  # noqa: E402


@pytest.fixture(scope="module")
def free_csv(tmp_path_factory):
    """An effect-free plant_sim recording, 240 s at 100 Hz."""
    rec = S.record(S.Case((), "ramps", 7, 0.5))
    path = tmp_path_factory.mktemp("diag") / "free.csv"
    write_recording(path, rec.columns)
    return path


def test_cli_outputs_follow_design(free_csv, tmp_path):
    d_json, p_csv, rep = tmp_path / "D.json", tmp_path / "P.csv", tmp_path / "report"
    rc = main(["diagnose", str(free_csv), "--json", str(d_json), "--predictions", str(p_csv), "--report", str(rep)])
    assert rc == 0
    d = json.loads(d_json.read_text())
    assert set(d) == {"baseline", "findings", "model"}
    assert set(d["baseline"]) == {"mae", "rmse", "r"}
    assert d["baseline"]["r"] >= 0.998
    assert d["findings"] == []  # effect free
    with open(p_csv) as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t_s", "flow_lpm", "baseline_lpm", "augmented_lpm", "holdout"]
    n_rec = sum(1 for _ in open(free_csv)) - 1
    assert len(rows) - 1 == n_rec
    data = np.array(rows[1:], dtype=float)
    hold = data[:, 4]
    assert set(np.unique(hold)) == {0.0, 1.0} and hold.mean() >= 0.2
    third = len(hold) // 3
    assert hold[:third].any() and hold[-third:].any()  # spread over the recording
    np.testing.assert_array_equal(data[:, 3], data[:, 2])  # augmented = baseline when nothing is found
    assert (rep / "report.md").exists() and (rep / "residuals.png").exists()


def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert main(["diagnose", str(tmp_path / "nope.csv"), "--json", str(tmp_path / "d.json")]) == 2
    short = tmp_path / "short.csv"
    write_recording(short, {"t_s": np.arange(50) * 0.1, "duty_pct": 40 + np.arange(50) * 0.5, "flow_lpm": np.arange(50.0)})
    assert main(["diagnose", str(short), "--json", str(tmp_path / "d.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "short.csv" in err[1] and "too short" in err[1]


CASES = [
    (("supply_pressure",), "ramps"),
    (("valve_dynamics",), "sines"),
    (("asymmetric_hysteresis",), "random_holds"),
    (("sensor_offset",), "random_holds"),
    (("dead_zone",), "ramps"),
    (("transport_delay", "creep"), "random_holds"),
]


@pytest.mark.parametrize("words,exc", CASES, ids=["+".join(w) + "-" + e for w, e in CASES])
def test_concealed_effect_is_named_and_improves_holdout(words, exc):
    case = S.make_case(words, exc, seed=4, noise=0.5)
    rec = S.record(case)
    model = load_model(S.MODEL_JSON) if case.with_model else None
    d = diagnose_response(rec, model)
    assert d.baseline.r >= 0.998  # concealed: the baseline looks fine
    named = [f.effect for f in d.findings]
    assert words[0] in named
    for f in d.findings:
        assert f.holdout_rmse_after < f.holdout_rmse_before
    chain = [p for f, p in zip(d.findings, d.steps_lpm) if f.alternative_to is None]
    assert np.array_equal(d.augmented_lpm, chain[-1])


def test_coil_heating_parameters_are_recovered_in_physical_units():
    case = S.make_case(("coil_heating",), "random_holds", seed=4, noise=0.5)
    d = diagnose_response(S.record(case))
    assert d.baseline.r >= 0.998
    heating = {f.effect: f for f in d.findings}["coil_heating"]
    injected_k = dict(case.effects)["coil_heating"]
    # the thermal time constant and the steady rise at 55 % duty, not just a better fit (the rise
    # of an effect the size of the noise is known to within a factor of a few)
    assert 1 / 3 < heating.params["rise55_k"] / injected_k < 3.0
    assert 0.5 < heating.params["tau_s"] / S.COIL_TAU_S < 2.0
    assert heating.holdout_rmse_after < heating.holdout_rmse_before


def test_steps_tell_a_delay_of_a_few_samples_from_a_lag():
    # 25 ms at 100 Hz: the flow stays put for two and a half samples after each step, which no lag does
    d = diagnose_response(S.record(S.Case((("transport_delay", 0.025),), "random_holds", 4, 0.5)))
    named = {f.effect: f for f in d.findings}
    assert "transport_delay" in named and named["transport_delay"].alternative_to is None
    assert named["transport_delay"].params["delay_s"] == pytest.approx(0.025, rel=0.1)
    assert "valve_dynamics" not in named


def test_a_smooth_excitation_reports_lag_and_delay_as_alternatives():
    # on ramps a delay and a lag both shift the response by -tau dq/dt: the diagnosis says it cannot tell
    d = diagnose_response(S.record(S.make_case(("transport_delay",), "ramps", seed=4, noise=0.5)))
    named = {f.effect: f for f in d.findings}
    assert set(named) >= {"transport_delay", "valve_dynamics"}
    alt = [f for f in d.findings if f.alternative_to is not None]
    assert len(alt) == 1 and alt[0].alternative_to in named and "cannot tell a lag" in alt[0].evidence
    assert alt[0].holdout_rmse_after < alt[0].holdout_rmse_before


def test_supply_pressure_exponent_is_near_choked_flow():
    case = S.make_case(("supply_pressure",), "paper", seed=4, noise=0.5)
    d = diagnose_response(S.record(case))
    p = {f.effect: f for f in d.findings}["supply_pressure"].params
    # plant_sim's valve is choked (flow proportional to the absolute supply): exponent 1
    assert 0.6 < p["exponent"] < 1.5


def test_a_model_file_is_held_at_the_supply_it_was_identified_at():
    """A model file's flow is at its identification supply (its meta), and the supply law is referred
    to it: the recording's mean supply droops below it with the flow, and a baseline held fixed cannot
    take up that gain, which an offset and a heating then did (offset 2.5 for 1.2, a false heating)."""
    G = pytest.importorskip("diagnose_gross")
    model = load_model(S.MODEL_JSON)
    assert model.meta["supply_bar"] == pytest.approx(3.0, abs=0.02)
    probe = G.Probe("plant", (("supply_pressure", 0.2), ("sensor_offset", 1.2)), "paper", 42, 0.3)
    d = diagnose_response(G.record(probe), model)
    assert G.judge(probe, d) == []



def test_a_heating_is_placed_beside_the_recorded_supply():
    """A coil 30 K warm while the supply wanders by 0.2 bar (recorded), against the model file: refined
    alone, the heating's time constant ran onto the upper bound of its refinement (the wander read as a
    slow warming) and was refused, and a sensor offset of -11 L/min took up the heating; placed beside
    the supply's law, it is resolved, and each of the three is named at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("sensor_offset", -2.0), ("supply_pressure", 0.2), ("coil_heating", 30.0)), "mixed",
                    2132, 0.5)
    d = diagnose_response(G.record(probe), load_model(S.MODEL_JSON))
    assert G.judge(probe, d) == []


@pytest.mark.parametrize("effects,seed,noise", [
    ((("supply_pressure", 0.22), ("dead_zone", 46.5), ("coil_heating", 26.0)), 9622, 1.0),
    # (~40 s: the fast suite keeps the three-word case)
    pytest.param((("dead_zone", 46.2), ("coil_heating", 24.0)), 9628, 0.3, marks=pytest.mark.slow),
])
def test_a_warm_coil_beside_a_dead_zone_is_named_at_its_size(effects, seed, noise):
    """A coil warming beside a dead zone on a mixed excitation: the cracking duty, placed on the duty the
    magnetics see under each setting of the heating, shuts the rows of each hold whose effective duty
    drifts below it as the coil warms, so the heating's training error steps from row to row, and its
    refinement stopped at the start it was given (a coil 24 K warm read as 41 K on a 540 s time
    constant, 26 K as 35 K). The heating is named within a quarter of its rise, beside the dead zone."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", effects, "mixed", seed, noise)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []


def test_a_lag_beside_a_warm_coil_is_screened_with_the_pi_refitted_under_it():
    """A 45 ms lag beside a coil 25 K warm on the foreign chirp: with the heating named first and the PI
    refitted under it, the PI's loop took up part of the lag (the chirp lags more as its frequency
    rises), the lag's screen on that PI gained too little beside the heating and a delay was named in
    its place. Refined and cross-validated with the PI refitted with it in place, against the PI
    refitted with a time response that does nothing, the lag is named (a delay at most its
    alternative), and the heating, refined again beside it, at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("valve_dynamics", 0.045), ("coil_heating", 25.0)), "chirp", 9901, 1.0)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    named = {f.effect for f in d.findings if f.alternative_to is None}
    assert named == {"valve_dynamics", "coil_heating"}


@pytest.mark.parametrize("heat_k,offset_lpm,seed", [(30.0, 2.0, 2201), (25.0, -1.5, 2202)])
def test_a_sensor_offset_beside_a_heating_is_named_at_its_size(heat_k, offset_lpm, seed):
    """A warm coil and a sensor offset on a mixed excitation, against the model file: named first, the
    heating took up the offset in its size and time constant (32.8 K and 271 s for 30 K and 180 s) and
    the offset beside it gained too little to be named; tested with the heating refined jointly with it,
    both are named at their size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("coil_heating", heat_k), ("sensor_offset", offset_lpm)), "mixed", seed, 0.3)
    d = diagnose_response(G.record(probe), load_model(S.MODEL_JSON))
    assert G.judge(probe, d) == []


@pytest.mark.parametrize("exc,seed,heat_k,offset_lpm", [("breaths", 6106, 24.0, 2.0), ("chirp", 6105, 31.0, 0.0)])
def test_an_offset_that_trades_against_a_heating_on_a_valve_never_shut_is_not_asserted(exc, seed, heat_k, offset_lpm):
    """A warm coil on a valve its model file does not quite describe (the foreign valve held against a PI
    fitted on its staircase), on an excitation that never shuts the valve: no row reads the sensor's zero,
    and the heating's rise and time constant refined jointly with a constant take up the model file's
    misfit of the loading curve together with it (a 2 L/min offset missed, or an offset of -3.4 L/min
    named where there is none). The heating is named at its size; the offset is named at its size or
    said to be not identifiable, never named at another size or where there is none."""
    G = pytest.importorskip("diagnose_gross")
    effects = (("coil_heating", heat_k),) + ((("sensor_offset", offset_lpm),) if offset_lpm else ())
    probe = G.Probe("foreign", effects, exc, seed, 0.5 if exc == "breaths" else 0.3)
    d = diagnose_response(G.record(probe), F.model_file())
    assert G.judge(probe, d) == []
    if offset_lpm:
        named = {f.effect for f in d.findings}
        assert "sensor_offset" in named or "sensor_offset" in d.model["not_identifiable"]


def test_a_pi_refitted_under_a_warm_coil_does_not_run_off_on_held_out_levels():
    """A PI refitted under a warm coil's effective duty, whose training rows keep its widest operators
    near their thresholds: they moved together, once, and took opposite weights of several thousand
    (5700 L/min predicted on a held-out breath rising 0.4 % higher; a coil 22 K warm behind a lag went
    unconfirmed). The refit keeps the steps of the slope the rows do not tell near zero, and the
    held-out rows are predicted within the flow the valve passes."""
    G = pytest.importorskip("diagnose_gross")
    from models.diagnose import make_folds, memory_start_s, running_rows, work_signals
    from models.diagnose.design import build, fit_baseline, unbend
    from models.diagnose.detectors import fit_final

    rec, rest = running_rows(G.record(G.Probe("plant", (("valve_dynamics", 0.0536), ("coil_heating", 22.0)), "mixed",
                                              1393, 0.3)))
    sig = work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    # (as the search had refined them: the run-off is as sensitive to the setting as it is unidentified)
    chain = {"valve_dynamics": {"tau_s": 0.053624106284655255, "phase": 0.9999999996419414},
             "coil_heating": {"rise55_k": 20.77515355656243, "tau_s": 49.98294940337999, "start": 0.0,
                              "floor_pct": 33.99999993591311}}
    d = build(unbend(fit_baseline(sig, folds), sig, chain, folds.train), sig, chain)
    q = d.predict(fit_final(d, sig.flow_lpm, folds.train))[folds.holdout_at(sig.t_s)]
    assert q.max() < 1.2 * sig.flow_lpm.max()
    assert np.sqrt(np.mean((sig.flow_lpm[folds.holdout_at(sig.t_s)] - q) ** 2)) < 10 * 0.3


def test_a_word_refused_twice_is_tried_again_after_each_word_named():
    """A coil 24 K warm beside a clip at 125 L/min and a -2 L/min sensor offset, against the model file:
    with neither the clip nor the offset modelled the heating's time constant ran onto the lower bound of
    its refinement (refused), a spurious fast creep was named, and beside it the heating was refused
    again and dropped. Tried again once the clip is named, it is resolved, the offset follows, and the
    creep no longer earns its place."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("coil_heating", 23.9), ("saturation", 125.0), ("sensor_offset", -1.97)), "mixed",
                    1470, 0.3)
    d = diagnose_response(G.record(probe), load_model(S.MODEL_JSON))
    assert G.judge(probe, d) == []


# -- recordings made without plant_sim (bench/diagnose_foreign.py): the diagnosis is built for the physics --

@pytest.mark.parametrize("exc", ["breaths", "chirp"])
def test_foreign_effect_free_recording_has_no_finding(exc):
    d = diagnose_response(F.record(F.Case((), exc, 3, 0.5)))
    assert d.baseline.r >= 0.998
    assert d.findings == []


@pytest.mark.parametrize("word,exc", [("creep", "chirp"), ("valve_dynamics", "staircase"), ("coil_heating", "triangles"),
                                      ("dead_zone", "triangles")])
def test_foreign_concealed_effect_is_named(word, exc):
    # creep relaxing over 12 s, a first-order-hold lag, a 150 s coil, no flow below a cracking duty
    case = F.make_case((word,), exc, 3, 0.5)
    d = diagnose_response(F.record(case))
    assert d.baseline.r >= 0.998
    assert word in [f.effect for f in d.findings]
    for f in d.findings:
        assert f.holdout_rmse_after < f.holdout_rmse_before


# -- gross effects, measured states, closed-loop runs --

def test_readme_example(tmp_path):
    # the README's own example: a coil 20 K warm at 55 % duty (coil_temp_c recorded) and a 10 ms delay
    sim, d_json = tmp_path / "sim.csv", tmp_path / "D.json"
    assert main(["simulate", "--effect", "coil_heating=20", "--effect", "transport_delay=0.01", "--duration", "600",
                 "--seed", "1", "-o", str(sim)]) == 0
    assert main(["diagnose", str(sim), "--json", str(d_json)]) == 0
    d = json.loads(d_json.read_text())
    named = {f["effect"]: f for f in d["findings"]}
    assert "coil_heating" in named and "dead_zone" not in named
    rise = d["model"]["augmented"]["effects"]["coil_heating"]["rise55_k"]
    assert rise == pytest.approx(20.0, rel=0.25)
    assert "transport_delay" in named or "transport_delay" in d["model"]["not_identifiable"]
    for f in d["findings"]:
        assert f["holdout_rmse_after"] < f["holdout_rmse_before"]


def _plant_recording(effects: dict, protocol: str, duration_s: float, seed: int = 3):
    from plant_sim.plant import Plant, load_plant
    from plant_sim.protocols import protocol as make

    if protocol == "breaths":  # a ventilator's inspiratory valve resting at 30 % between breaths
        duty = S.excitation("breaths", seed, 30.0, rate_hz=100.0, duration_s=duration_s)
    else:
        duty = make(protocol, 100.0, duration_s, seed)
    cols = Plant(load_plant(S.PLANT_TOML, effects), 100.0, seed=seed).simulate(duty)
    keep = ("t_s", "duty_pct", "flow_lpm") + (("supply_bar",) if "supply_pressure" in effects else ())
    return Recording("<gross>", {k: np.asarray(cols[k], float) for k in keep})


def test_the_initial_loading_curve_is_not_scored():
    # breaths resting at 30 %, far below the valve's opening (plant_sim holds its valve's input at
    # 38 %): the first rise from rest runs on a loading curve no later breath repeats, so the PI
    # fitted on the recording misses it by tens of L/min. Its rows end at the first turn of the duty
    # and are neither fitted nor scored; with them, the baseline's cross-validated misfit is several
    # times the noise (7 x), without them about the noise.
    from models.diagnose.design import build, cross_validate, fit_baseline, memory_start_s
    from models.diagnose.detectors import misfit
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import noise_lpm, work_signals

    sig = work_signals(_plant_recording({"saturation": 130.0}, "breaths", 60.0, seed=5), None)
    start = memory_start_s(sig)
    first_turn = sig.t_s[np.argmax(np.diff(sig.duty_pct) < 0)]
    assert start == pytest.approx(first_turn, abs=0.02)
    noise = noise_lpm(sig.flow_lpm)
    for folds, lo, hi in ((make_folds(sig.t_s), 3.0, np.inf), (make_folds(sig.t_s, start_s=start), 0.0, 1.5)):
        cv = cross_validate(build(fit_baseline(sig, folds), sig, {}), sig.flow_lpm, folds)
        assert lo * noise < misfit(cv) < hi * noise


@pytest.mark.parametrize("word, size, seed", [("dead_zone", 43.0, 9008), ("saturation", 135.0, 9004)])
def test_a_law_the_fitted_baseline_passes_on_breaths_is_reported_absorbed_not_dropped_silently(word, size, seed):
    # breaths resting shut below a cracking duty (or topping out at a clip), no model file: the PI
    # fitted on the recording opens as steeply (flattens as well) and the diagnosis' model leaves a
    # holdout residual within the noise, so the law cannot be confirmed. The recording still shows its
    # signature: the word is reported as not identifiable against that baseline, and nothing is named
    import diagnose_gross as G

    d = diagnose_response(G.record(G.Probe("foreign", ((word, size),), "breaths", seed, 1.0)))
    named = {f.effect for f in d.findings}
    assert named <= {word}
    if word not in named:
        assert "not identifiable against a baseline fitted on this recording" in d.model["not_identifiable"][word]


def test_holdout_rows_between_the_training_rows_that_place_a_cracking_duty_are_not_scored():
    # any cracking duty between the highest training row it shuts and the lowest it leaves open fits
    # the training rows alike; a holdout row in that gap is shut or open as the setting happens to
    # fall, so it is left out of the holdout (and no other row is)
    from models.diagnose.signals import Signals
    from models.diagnose.words import VOCABULARY

    rate = 50.0
    t = np.arange(0.0, 20.0, 1.0 / rate)
    train = np.arange(t.size) % 4 != 0
    duty = np.random.default_rng(3).uniform(40.0, 50.0, t.size)
    duty[train & (np.abs(duty - 44.0) < 0.1)] += 0.3  # no training row within 0.1 % of 44 %
    duty[np.flatnonzero(~train)[:4]] = [43.95, 43.99, 44.01, 44.05]
    sig = Signals(t, duty, np.where(duty > 44.0, 30.0, 0.0), None, None, rate)
    dz = VOCABULARY["dead_zone"]
    lo, hi = np.max(duty[train & (duty <= 44.0)]), np.min(duty[train & (duty > 44.0)])
    rows = dz.undecided(sig, {"cracking_pct": 44.0}, {}, train, sig)
    assert np.array_equal(rows, (duty > lo) & (duty < hi))
    assert not np.any(rows & train) and np.any(rows)
    assert dz.midway(sig, {"cracking_pct": 44.0}, {}, train)["cracking_pct"] == pytest.approx(0.5 * (lo + hi))
    assert dz.undecided(sig, {"cracking_pct": 30.0}, {}, train, sig) is None  # shuts no row


def test_gross_coil_heating_is_modelled_by_its_exact_law():
    # 30 K at 55 % duty, no temperature column: the effective duty shifts by some 10 %, far past the
    # first-order column; the exact law recovers the rise and the thermal time constant
    d = diagnose_response(_plant_recording({"coil_heating": 30.0}, "paper_identification", 300.0))
    named = {f.effect: f for f in d.findings}
    assert list(named)[0] == "coil_heating" and "dead_zone" not in named
    p = named["coil_heating"].params
    assert p["rise55_k"] == pytest.approx(30.0, rel=0.25)
    assert p["tau_s"] == pytest.approx(180.0, rel=0.35)  # plant.toml's coil
    f = named["coil_heating"]
    assert f.holdout_rmse_after < 0.3 * f.holdout_rmse_before and f.slope > 0.7


def test_a_warm_coils_effective_duty_is_held_at_the_valves_input_floor():
    # the foreign valve is identified over 38-72 % and holds its input at 38 %; a chirp over 40-70 %
    # with a coil 35 K warm drives the effective duty down to 36 %, where a PI fitted on the recording
    # ran on down its loading curve (the rise read as 55 K). The valve passes flow at the chirp's
    # lowest duty, so the heating law places the valve's input floor, and the rise comes out right
    import diagnose_gross as G

    p = G.Probe("foreign", (("coil_heating", 35.0),), "chirp", 3303, 1.0)
    named = {f.effect: f for f in diagnose_response(G.record(p)).findings}
    assert set(named) == {"coil_heating"}
    params = named["coil_heating"].params
    assert params["rise55_k"] == pytest.approx(35.0, rel=0.15)
    assert params["floor_pct"] == pytest.approx(F.LO_PCT, abs=0.5)
    # a valve shut at its lowest commanded duty (breaths resting at 30 %, far below the valve's
    # opening) is seated there: its input is held at that duty, a setting of the law, not refined;
    # one opening just above its lowest duty (the paper's sweep from 38 %) is not
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    heating = VOCABULARY["coil_heating"]
    for rec in (G.record(p), _plant_recording({"coil_heating": 30.0}, "paper_identification", 300.0)):
        sig = work_signals(rec, None)
        base = fit_baseline(sig, make_folds(sig.t_s))
        starts = heating.restarts(sig, base)
        assert 0 < sum("floor_pct" in s for s in starts) < len(starts)
        assert "floor_pct" in heating.bounds(sig, base)
    sig = work_signals(_plant_recording({"coil_heating": 30.0}, "breaths", 60.0), None)
    base = fit_baseline(sig, make_folds(sig.t_s))
    starts = heating.restarts(sig, base)
    assert all("floor_pct" in s for s in starts)
    assert min(s["floor_pct"] for s in starts) == sig.duty_pct.min()
    assert "floor_pct" not in heating.bounds(sig, base)


def test_a_warm_coils_valve_closes_below_its_input_floor_along_a_line():
    # plant_sim's valve is seated at 38 % (its identified range's bottom) and closes below it along its
    # mean gain; random holds reach down to 34 %. A coil 31 K warm takes the effective duty of the
    # lowest holds far below the seat, and the baseline fitted on the warm recording finds no seat on
    # the commanded duty. At the true heating, the PI refitted with its input held at 38 % of effective
    # duty and a line below it fits the recording to about the noise; held there without the line, or
    # not held, several times worse
    import diagnose_gross as G
    from models.diagnose.design import build, cross_validate, fit_baseline, memory_start_s, unbend
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import running_rows, work_signals

    noise = 0.2
    rec, rest = running_rows(G.record(G.Probe("plant", (("coil_heating", 31.0),), "mixed", 11224, noise)))
    sig = work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    base = fit_baseline(sig, folds)
    assert base.seat is None

    def rms(chain):
        cv = cross_validate(build(unbend(base, sig, chain, folds.train), sig, chain), sig.flow_lpm, folds)
        return float(np.sqrt(cv.test.sum() / cv.n.sum()))

    heating = {"rise55_k": 31.0, "tau_s": 180.0, "start": 0.0}
    seated = rms({"coil_heating": {**heating, "floor_pct": 38.0}})
    assert seated < 1.5 * noise
    assert rms({"coil_heating": heating}) > 2.0 * seated
    assert rms({"coil_heating": {**heating, "floor_pct": 34.0}}) > 2.0 * seated


def test_a_valves_input_floor_must_fit_the_rows_it_holds():
    # the foreign valve holds its input at 38 %: with its coil 35 K warm, the rows whose effective
    # duty runs below it are fitted better held there than by the PI run on down its loading curve
    import diagnose_gross as G
    from models.diagnose.design import fit_baseline, memory_start_s
    from models.diagnose.detectors import _holds
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    def holds(rec, params):
        sig = work_signals(rec, None)
        folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
        return _holds(VOCABULARY["coil_heating"], params, {}, fit_baseline(sig, folds), sig, folds)

    foreign = G.record(G.Probe("foreign", (("coil_heating", 35.0),), "chirp", 3303, 1.0))
    assert holds(foreign, {"rise55_k": 35.0, "tau_s": F.COIL_TAU_S, "start": 0.0, "floor_pct": F.LO_PCT})


@pytest.mark.slow  # ~80 s, the longest of the fast suite before
def test_a_jump_just_above_the_lowest_duty_is_named_a_dead_zone_not_a_heating_held_at_a_floor():
    # A valve that opens with a jump just above the lowest duty (a concealed dead zone at 36 %) had
    # its bottom rows held at a floor only to free the PI elsewhere; the floor's seat line now takes
    # up the jump as well as the PI did not, but a heating so held explains no more than the seat
    # alone with the coil cold (:meth:`CoilHeating.at_rest`): the jump is named a dead zone, no heating
    jump = S.record(S.make_case(("dead_zone",), "sines", seed=1, noise=0.25))
    named = {f.effect for f in diagnose_response(jump).findings}
    assert "dead_zone" in named and "coil_heating" not in named


def test_a_seated_valves_memory_sizes_a_heating_beside_a_clip():
    # breaths resting at 30 %, far below the valve's opening, a clip hiding their tops: the valve's
    # memory rests seated whatever the coil's warmth, and held there the training error is least at
    # the injected rise; run on below the lowest duty, the PI's rest moved with every kelvin and the
    # error fell on past it (30 K fitted best as 40 K). A coil warm from the start trades with a cold
    # one (a duty scale the PI takes up); the cold reading is kept where they tie
    import diagnose_gross as G
    from models.diagnose.design import build, fit_baseline, memory_start_s, unbend
    from models.diagnose.detectors import train_sse
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import running_rows, work_signals

    p = G.Probe("plant", (("saturation", 138.0), ("coil_heating", 30.0)), "breaths", 3701, 0.5)
    rec, rest = running_rows(G.record(p))
    sig = work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    root = fit_baseline(sig, folds)

    def error(rise_k, **held):
        chain = {"saturation": {"full_open_lpm": 138.0},
                 "coil_heating": {"rise55_k": rise_k, "tau_s": 180.0, "start": 0.0, **held}}
        return train_sse(build(unbend(root, sig, chain, folds.train), sig, chain), sig.flow_lpm, folds.train)

    seat = {"floor_pct": float(sig.duty_pct.min())}
    assert error(30.0, **seat) < min(error(22.0, **seat), error(40.0, **seat))
    # the baseline's seat (above the rest) holds the input first: a floor below it holds nothing more
    assert root.seat is not None and root.seat[0] > seat["floor_pct"]
    assert error(30.0, **seat) == pytest.approx(error(30.0), rel=1e-9)
    named = {f.effect: f for f in diagnose_response(G.record(p)).findings}
    assert named["coil_heating"].params["rise55_k"] == pytest.approx(30.0, rel=0.15)
    assert named["coil_heating"].params["start"] == 0.0


def test_a_warm_start_that_ties_with_a_cold_one_gives_way_to_it():
    # a coil warm from the start and a cold one trade to first order on a PI fitted on the recording
    # (the warm one's first rise is a duty scale the PI takes up): among settings whose training error
    # is within PHYSICS_TIE of what the best explains, the cold one is kept even where the warm one
    # fits a little better; a cold one that fits clearly worse is not
    import diagnose_gross as G
    from models.diagnose.design import fit_baseline, memory_start_s
    from models.diagnose.detectors import _subsample, _tied_choice, design, train_sse
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import running_rows, work_signals
    from models.diagnose.words import VOCABULARY

    p = G.Probe("plant", (("saturation", 138.0), ("coil_heating", 30.0)), "breaths", 3701, 0.5)
    rec, rest = running_rows(G.record(p))
    sig = work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    root = fit_baseline(sig, folds)
    chain, rows = {"saturation": {"full_open_lpm": 138.0}}, _subsample(folds.train)

    def setting(rise_k, start):
        return {"rise55_k": rise_k, "tau_s": 180.0, "start": start, "floor_pct": float(sig.duty_pct.min())}

    def error(params):
        d = design("coil_heating", root, sig, {**chain, "coil_heating": params}, folds, rows)[0]
        return train_sse(d, sig.flow_lpm, rows)

    heating = VOCABULARY["coil_heating"]
    # (the cold reading at the injected 30 K fits best of all; these are the nearest of each kind)
    warm, near, far = setting(70.0, 1.0), setting(18.0, 0.0), setting(14.0, 0.0)
    assert error(warm) < error(near) < error(far)
    assert _tied_choice(heating, chain, [warm, near], root, sig, folds) is near
    assert _tied_choice(heating, chain, [warm, far], root, sig, folds) is warm


def test_a_clips_plateau_is_its_signature():
    # breaths whose tops a clip at 128 L/min holds over ten per cent of duty show a full-open flow's
    # signature; a valve's own loading curve, warm or cold, shows none
    import diagnose_gross as G
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    def signature(p):
        return VOCABULARY["saturation"].absorbed(work_signals(G.record(p), None), {})

    assert "flattens at 128" in signature(G.Probe("plant", (("saturation", 128.0), ("coil_heating", 22.0)),
                                                  "breaths", 3601, 0.5))
    for p in (G.Probe("plant", (("coil_heating", 33.0),), "breaths", 3604, 0.5),
              G.Probe("foreign", (("coil_heating", 40.0),), "breaths", 6, 0.5),
              G.Probe("plant", (), "mixed", 3614, 0.5)):
        assert signature(p) is None


@pytest.mark.slow
def test_a_clip_a_refitted_pi_flattens_into_is_said_so():
    # beside a coil heating sized right, a PI fitted on the breaths flattens into the clip's plateau as
    # well as the clip (breaths never sample the descending branch there): the clip is said to be not
    # identifiable against it, rather than absent
    import diagnose_gross as G

    d = diagnose_response(G.record(G.Probe("plant", (("saturation", 128.0), ("coil_heating", 22.0)), "breaths",
                                           3601, 0.5)))
    named = {f.effect for f in d.findings}
    assert "coil_heating" in named
    assert "saturation" in named or "flattens at 128" in d.model["not_identifiable"]["saturation"]


@pytest.mark.slow  # ~4 s
def test_a_pi_refitted_under_a_clip_keeps_the_memory_of_a_breath_top_first_reached_held_out():
    # breaths on a valve clipped at 142 L/min whose running top grows twice within one holdout block
    # (30 and 33 s): the memory those breaths leave in the PI's widest operators is one no training row
    # shows, and only the clipped rows move those operators. Refitted for the holdout check under the
    # clip, the PI keeps the loading curve's slope there instead of inventing steps for them: after
    # those breaths it still has the valve shut at rest (within the noise), and the clip lowers the
    # held-out error of the baseline
    import types

    import diagnose_gross as G
    from models.diagnose import (_ChainFits, fit_baseline, make_folds, memory_start_s, raw_signals,
                                 running_rows, work_signals)
    from models.diagnose.design import clip, unbend

    noise = 0.3
    rec, rest = running_rows(G.record(G.Probe("plant", (("saturation", 142.0),), "breaths", 10143, noise)))
    raw, sig = raw_signals(rec, rest), work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    base = fit_baseline(sig, folds)
    chain = {"saturation": {"full_open_lpm": 142.0}}
    sel = types.SimpleNamespace(chain=chain, reference=unbend(base, sig, {}, folds.train))
    fits = _ChainFits(sel, sig, raw, folds, clip(base.predict(raw, {}), None, bool(base.shut(raw).any())))
    hold, y, x, t = folds.holdout_at(raw.t_s), raw.flow_lpm, raw.duty_pct, raw.t_s
    # the held-out rows after a top higher than any trained on before them, until the next training row
    top_trained = np.maximum.accumulate(np.where(folds.holdout_at(t) | (t < folds.start_s), -np.inf, x))
    first = np.flatnonzero(hold & (np.maximum.accumulate(x) > top_trained + 1.0))[0]
    unseen = hold & (np.arange(len(t)) >= first) & (np.cumsum(~hold) == np.cumsum(~hold)[first])
    at_rest = unseen & (y < 3.0 * noise) & (x < 35.0)
    assert at_rest.sum() > 100

    def rmse(e):
        return float(np.sqrt(np.mean(e * e)))

    clipped, baseline = fits.predict(chain), fits.predict({})
    assert rmse((clipped - y)[at_rest]) < 2.0 * noise
    assert rmse((clipped - y)[hold]) < rmse((baseline - y)[hold])


@pytest.mark.slow  # ~10 s
def test_a_clip_on_breaths_with_a_top_first_reached_held_out_is_named():
    # the same breaths: the clip is named at its size and lowers the held-out error; without it nothing
    # is named
    import diagnose_gross as G

    d = diagnose_response(G.record(G.Probe("plant", (("saturation", 142.0),), "breaths", 10143, 0.3)))
    (f,) = d.findings
    assert f.effect == "saturation" and f.params["full_open_lpm"] == pytest.approx(142.0, rel=0.01)
    assert f.holdout_rmse_after < f.holdout_rmse_before
    assert not diagnose_response(G.record(G.Probe("plant", (), "breaths", 10143, 0.3))).findings


@pytest.mark.slow  # ~60 s
@pytest.mark.parametrize("creep, full_open, seed", [(0.12, 140.0, 3701), (0.2, 128.0, 3702)])
def test_a_creep_beside_a_clip_on_the_paper_sweep_is_named_and_no_heating(creep, full_open, seed):
    # the paper's sweep reverses at its top under the clip: the creep after that reversal rises on the
    # plateau and holds the flow there after the valve without it has left. Both are named, the creep at
    # its size, and no coil warming from the first second takes up the creep's drift
    import diagnose_gross as G

    d = diagnose_response(G.record(G.Probe("plant", (("creep", creep), ("saturation", full_open)), "paper",
                                           seed, 0.5)))
    named = {f.effect: f.params for f in d.findings if f.alternative_to is None}
    assert set(named) == {"creep", "saturation"}
    assert named["creep"]["amplitude"] == pytest.approx(creep, rel=0.3)


@pytest.mark.slow  # ~60 s
@pytest.mark.parametrize("creep", [0.1, 0.0])
def test_a_creep_beside_a_warm_coil_on_a_chirp_is_named_and_the_coil_sized(creep):
    # a creep's drift after each reversal and a coil's warming both move the flow slowly along the
    # recording: a heating named first takes up part of the creep's drift in its size and time constant,
    # and the creep screened beside it so sized gains too little to be named. Tested with the heating
    # and its own time constant refined jointly with it, both are named at their sizes; on the same
    # chirp without the creep no creep is named
    import diagnose_gross as G

    effects = (("coil_heating", 22.0),) + ((("creep", creep),) if creep else ())
    d = diagnose_response(G.record(G.Probe("foreign", effects, "chirp", 3811, 1.0)))
    named = {f.effect: f.params for f in d.findings if f.alternative_to is None}
    assert set(named) == {w for w, _ in effects}
    assert named["coil_heating"]["rise55_k"] == pytest.approx(22.0, rel=0.15)
    if creep:
        assert named["creep"]["amplitude"] == pytest.approx(creep, rel=0.3)


def test_a_staircase_at_the_valves_memory_epochs_is_not_read_as_heat():
    # plant_sim's valve holds the highest breath so far in its widest operators: its flow steps at
    # each new highest breath (by 1.2 L/min, then 0.23, on this seed), which the 50-operator PI gets
    # wrong by a different amount in each memory epoch, and a coil's thermal state took the
    # staircase up. With a free offset per epoch a slow heating explains too little to be named (nor
    # is the one the search refines, its time constant now run onto the recording's bound; and a
    # baseline that holds its PI's input at the valve's seat leaves it under its margin before that); a
    # true heating on the same breaths is named at its rise, and a recording whose valve is open at its
    # first row has no epochs
    from models.diagnose import detectors as D
    from models.diagnose import load_margins, make_folds, memory_start_s, running_rows
    from models.diagnose.design import fit_baseline, memory_epochs, unbend
    from models.diagnose.signals import work_signals
    from models.diagnose.trace import BELOW_MARGIN, NOT_PHYSICAL

    rec = _plant_recording({}, "breaths", 300.0, seed=2011)
    E = memory_epochs(work_signals(rec, None))
    assert E.shape[1] >= 2 and np.all(np.diff(E, axis=0) >= 0)  # steps up, each once
    d = diagnose_response(rec)
    assert d.findings == []
    heat = [t for t in d.trace if t.word == "coil_heating"]
    assert heat and all(t.outcome in (BELOW_MARGIN, NOT_PHYSICAL) for t in heat)
    assert all("memory epoch" in t.why for t in heat if t.outcome == NOT_PHYSICAL)
    run, rest = running_rows(rec)
    sig = work_signals(run, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    cur, _ = D.reference(fit_baseline(sig, folds), sig, folds)
    slow = {"coil_heating": {"rise55_k": 3.0, "tau_s": 300.0, "start": 0.0}}
    why = D._memory_steps("coil_heating", {}, slow, cur, unbend(cur, sig, slow, folds.train), sig, folds,
                          load_margins())
    assert why is not None and "memory epoch" in why
    warm = diagnose_response(_plant_recording({"coil_heating": 20.0}, "breaths", 300.0, seed=2011))
    assert [f.effect for f in warm.findings] == ["coil_heating"]
    assert warm.findings[0].params["rise55_k"] == pytest.approx(20.0, rel=0.25)
    assert memory_epochs(work_signals(_plant_recording({}, "paper_identification", 60.0), None)).shape[1] == 0


def test_a_memory_epochs_offset_holds_on_every_row_a_warm_coil_is_explained_beyond():
    # the offset a fitted PI's memory epoch adds is flow the PI passes on any row, shut ones too:
    # zeroed where the reference has the valve shut, it was a step on the open rows only, near-collinear
    # with the offset and with a warm coil's slow rise (cond 2e8), and a coil 34.5 K warm was missed
    from models.diagnose.design import build, fit_baseline, memory_epochs, memory_start_s
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import running_rows, work_signals

    import diagnose_gross as G

    rec, rest = running_rows(G.record(G.Probe("plant", (("coil_heating", 34.5),), "breaths", 10226, 0.78)))
    sig = work_signals(rec, rest)
    root = fit_baseline(sig, make_folds(sig.t_s, start_s=memory_start_s(sig)))
    d = build(root, sig, {"coil_heating": {"rise55_k": 30.0, "tau_s": 180.0, "start": 0.0}}, memory=True)
    epochs = memory_epochs(sig)
    cols = d.X[:, [i for i, n in enumerate(d.names) if n == "memory"]]
    assert epochs.shape[1] >= 1 and cols.shape == epochs.shape
    np.testing.assert_array_equal(cols, epochs)


@pytest.mark.slow  # ~25 s
def test_a_warm_coil_on_breaths_is_named_beside_the_valves_memory_epochs():
    import diagnose_gross as G

    d = diagnose_response(G.record(G.Probe("plant", (("coil_heating", 34.5),), "breaths", 10226, 0.78)))
    assert [f.effect for f in d.findings] == ["coil_heating"]
    assert d.findings[0].params["rise55_k"] == pytest.approx(34.5, rel=0.25)
    assert d.findings[0].holdout_rmse_after < d.findings[0].holdout_rmse_before


def test_a_memory_epoch_a_fold_holds_out_whole_does_not_vouch_for_a_heating_beside_a_clip():
    # breaths resting at 30 % on a valve clipped at 139 L/min, no coil heating: the breaths before the
    # first growth of their top (the valve's widest operators still holding the first breath's top,
    # the flow some L/min above the later breaths at the same duty) and those of another short epoch
    # lie whole in one cross-validation fold (and the holdout). No fit that holds that fold out can
    # place their offset, so they are neither fitted nor scored when a drift is held against a free
    # offset per memory epoch; scored, both models missed them by their whole step and a cold coil's
    # warming, steepest at the start, took up part of it and was named beside the clip. It is now
    # refused as the valve's memory, and a true heating beside a clip on breaths is still named
    import diagnose_gross as G
    from models.diagnose import make_folds, memory_start_s, running_rows
    from models.diagnose.signals import work_signals
    from models.diagnose.trace import NOT_PHYSICAL

    rec = G.record(G.Probe("plant", (("saturation", 139.1),), "breaths", 10333, 0.3))
    d = diagnose_response(rec)
    assert [f.effect for f in d.findings] == ["saturation"]
    heat = [t for t in d.trace if t.word == "coil_heating" and t.outcome == NOT_PHYSICAL]
    assert heat and all("memory epoch" in t.why for t in heat)
    from models.diagnose.design import memory_epochs, unplaced_epochs

    run, rest = running_rows(rec)
    sig = work_signals(run, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    skip, epoch = unplaced_epochs(sig, folds), memory_epochs(sig).sum(axis=1)
    fitted = (folds.fold >= 0) & folds.fit_ok
    assert skip.any() and not skip.all()
    for e in np.unique(epoch):  # whole epochs: those fitted in one fold only
        rows = epoch == e
        assert skip[rows].all() == (len(np.unique(folds.fold[rows & fitted])) <= 1)
        assert skip[rows].all() or not skip[rows].any()
    assert skip[epoch == 0].all() and sig.t_s[skip].min() < 2.0  # the first breaths
    warm = diagnose_response(G.record(G.Probe("plant", (("saturation", 142.5), ("coil_heating", 30.0)), "breaths",
                                              10344, 1.0)))
    assert "coil_heating" in {f.effect for f in warm.findings}


@pytest.mark.slow  # ~15 s
def test_a_dead_zone_must_explain_more_than_the_valve_closed_at_its_rest():
    # effect-free breaths resting at 30 %, below plant_sim's seat at 38 %: the first breaths' peak held
    # in the valve's widest operators left the PI, pulled under zero flow at the rest, 3 L/min short at
    # their plateaus, and a dead zone at 34.8 % took that misfit (held-out error -59 %). The same law at
    # the rest, which shuts no row the valve does not rest shut on, explains all of it; and the valve's
    # flow, taken down to 34.8 % from above, does not jump open there: unsupported either way
    from models.diagnose.trace import UNSUPPORTED

    G = pytest.importorskip("diagnose_gross")
    d = diagnose_response(G.record(G.Probe("plant", (), "breaths", 2013, 0.3)))
    assert d.findings == []
    assert [t for t in d.trace if t.word == "dead_zone" and t.outcome == UNSUPPORTED]


@pytest.mark.slow  # ~13 s: make test keeps the suite under 5 minutes
def test_gross_dead_zone_is_named_at_its_cracking_duty():
    d = diagnose_response(_plant_recording({"dead_zone": 45.0}, "paper_identification", 300.0))
    named = {f.effect: f for f in d.findings}
    assert list(named)[0] == "dead_zone"
    assert named["dead_zone"].params["cracking_pct"] == pytest.approx(45.0, abs=0.5)


def _named(effects: dict, protocol: str, seed: int = 3) -> dict:
    d = diagnose_response(_plant_recording(effects, protocol, 300.0, seed))
    named = {f.effect: f for f in d.findings}
    # exactly the injected words (a lag may be named with a delay as the alternative it cannot be told from)
    assert {w for w, f in named.items() if f.alternative_to is None} == set(effects)
    for f in d.findings:
        assert f.holdout_rmse_after < f.holdout_rmse_before
    return named


@pytest.mark.slow
def test_gross_dead_zone_on_breaths():
    # a 45 % cracking duty on breaths that rest at 30 %: every breath opens late and shuts early
    named = _named({"dead_zone": 45.0}, "breaths")
    assert named["dead_zone"].params["cracking_pct"] == pytest.approx(45.0, abs=1.0)


@pytest.mark.slow
def test_gross_dead_zone_behind_a_lag_on_breaths():
    # a 44 % cracking duty behind a 50 ms lag: the jump at the cracking duty is judged at the valve
    # (the probe this was built on; on seed 5 the dead zone left after the lag is barely above the
    # noise, 0.59 against 0.5 L/min RMS, and is not named)
    named = _named({"dead_zone": 44.0, "valve_dynamics": 0.05}, "breaths", seed=3)
    assert named["dead_zone"].params["cracking_pct"] == pytest.approx(44.0, abs=1.0)
    assert named["valve_dynamics"].params["tau_s"] == pytest.approx(0.05, rel=0.2)


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.04, 0.0413])
def test_gross_dead_zone_behind_a_delay_on_breaths(delay_s):
    # a 45 % cracking duty behind a 40 ms delay: the flow arrives when the breath's duty is some 8 %
    # past the cracking duty, and the jump falls between two samples of the rise. Whether the delay
    # is a whole number of samples or not (the one refined to 0.04001 s missed the dead zone: its
    # leads, ranked on a fifth of the rows, tied, the few rows between them unseen)
    named = _named({"dead_zone": 45.0, "transport_delay": delay_s}, "breaths", seed=5)
    assert named["dead_zone"].params["cracking_pct"] == pytest.approx(45.0, abs=1.0)
    assert named["transport_delay"].params["delay_s"] == pytest.approx(delay_s, rel=0.2)


@pytest.mark.slow  # ~15 s
def test_a_lag_and_a_delay_together_share_the_lateness():
    # a 45 ms lag and a 25 ms delay behind a clip at 140 L/min (foreign chirp): the word named first took
    # up the whole lateness (a 77 ms lag, the delay only its alternative); tested beside it with the
    # lateness shared between the two, and the two refined together, each is named at its own size
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("foreign", (("valve_dynamics", 0.045), ("transport_delay", 0.025), ("saturation", 140.0)), "chirp",
                4101, 0.5)
    d = diagnose_response(G.record(p))
    assert G.judge(p, d) == []
    assert all(f.alternative_to is None for f in d.findings)


@pytest.mark.slow  # ~20 s
def test_a_lag_beside_a_heating_on_a_chirp_is_no_delay():
    # a 57 ms lag beside a coil 21 K warm (foreign chirp): the heating, named first and sized without
    # the lag, took up the lag's attenuation (it grows with the chirp's frequency as the coil warms),
    # and what was left of the lag, a phase, fitted a delay better: a delay was named, the lag its
    # alternative. Each judged with the heating refined beside it, the lag is named
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("foreign", (("coil_heating", 21.2), ("valve_dynamics", 0.057)), "chirp", 3102, 0.5)
    d = diagnose_response(G.record(p))
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    assert "transport_delay" not in named
    assert named["valve_dynamics"].params["tau_s"] == pytest.approx(0.057, rel=0.3)


@pytest.mark.slow  # ~60 s each
@pytest.mark.parametrize("probe", [
    # a cracking duty placed before the delay was known (where the late openings and closings average
    # out) and then held: a lag's smoothing took up its misplaced jump better than the delay, or a coil
    # warm from the start moved it onto the valve's
    ("chirp", (("transport_delay", 0.03), ("dead_zone", 45.0)), 9701, 1.0),
    # and the two, each searched with the other held, stopped 0.1 % and 6 ms off (for 22 ms)
    ("chirp", (("transport_delay", 0.022), ("dead_zone", 44.5)), 9702, 0.5),
])
def test_a_delay_beside_a_cracking_duty_is_named_as_a_delay(probe):
    G = pytest.importorskip("diagnose_gross")
    exc, effects, seed, noise = probe
    p = G.Probe("foreign", effects, exc, seed, noise)
    d = diagnose_response(G.record(p))
    assert G.judge(p, d) == []
    named = {f.effect for f in d.findings if f.alternative_to is None}
    assert "valve_dynamics" not in named and "coil_heating" not in named


@pytest.mark.slow
def test_a_delay_screened_behind_a_lag_is_refined_before_the_lag_is_named():
    # a 66 ms delay on plant_sim's ramps: its screen, at a setting of its grid, ranked 3 % behind the
    # lag's refined law, and the lag alone was named. Refined as well, the delay explains the ramps'
    # corners better (a lag rounds them) and is named, the lag as its alternative at most
    c = S.Case((("transport_delay", 0.0658),), "ramps", 2, 0.5)
    d = diagnose_response(S.record(c))
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    assert set(named) == {"transport_delay"}
    assert named["transport_delay"].params["delay_s"] == pytest.approx(0.0658, rel=0.1)


def test_a_delay_tied_with_a_lag_is_decided_again_beside_the_words_found_after_it():
    # a 21 ms delay at 50 Hz on the foreign valve's mixed excitation, beside an asymmetric loop found
    # after it: the two time responses tied when named, the delay refined to 19.7 ms with the
    # asymmetry not yet in place, and a lag of 6.7 ms (a sample's delay and a tail) was named. On the
    # final chain the delay, refined beside the asymmetry, fits better and is named, the lag its
    # alternative
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("foreign", (("transport_delay", 0.021), ("asymmetric_hysteresis", 9.0)), "mixed", 7101, 0.3)
    d = diagnose_response(G.record(p))
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    assert "valve_dynamics" not in named
    assert named["transport_delay"].params["delay_s"] == pytest.approx(0.021, rel=0.03)
    assert [f.effect for f in d.findings if f.alternative_to == "transport_delay"] in ([], ["valve_dynamics"])


def test_a_lag_alone_is_not_shared_with_a_delay():
    # a 60 ms lag on the foreign staircase: the delay tested beside it with the lateness shared explains
    # nothing more (a lag's step response is no delayed one), and is not named
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("foreign", (("valve_dynamics", 0.06),), "staircase", 4115, 0.3)
    d = diagnose_response(G.record(p))
    assert G.judge(p, d) == []
    assert [f.effect for f in d.findings] == ["valve_dynamics"]


def test_a_valve_opening_by_itself_on_breaths_shows_no_jump():
    # plant_sim's valve opens from zero flow with a steep start that flattens (some 4 then 2 L/min
    # per % duty): breaths sampling that start coarsely show no cracking duty at any duty
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    dz = VOCABULARY["dead_zone"]
    for seed in (3, 4, 5, 6):
        sig = work_signals(_plant_recording({}, "breaths", 300.0, seed))
        grid = dz.grid(sig, None)["cracking_pct"]
        assert not [c for c in grid if dz._opens_with_jump(sig, {"cracking_pct": c}, {})], seed


def test_a_valve_opening_by_itself_jumps_nowhere_and_a_cracking_duty_does():
    # on breaths the flow a valve passes just above the duty where it leaves zero is small, and it rises
    # through the band above: taken down to that duty it is zero (no jump), where below a cracking duty
    # the valve passes nothing and opens at once to the flow it would pass there
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    dz = VOCABULARY["dead_zone"]
    for seed in (3, 4):
        for effects, jumps in (({}, False), ({"dead_zone": 44.0}, True)):
            sig = work_signals(_plant_recording(effects, "breaths", 300.0, seed))
            (where,) = dz.placed(sig, {})
            assert dz._jumps(sig, where, {}) is jumps, (seed, effects, where)
            if jumps:
                assert where["cracking_pct"] == pytest.approx(44.0, abs=0.3)


@pytest.mark.slow
def test_dead_zone_a_fitted_pi_absorbs_is_not_identifiable():
    # a 45 % cracking duty behind a 40 ms lag on breaths resting at 42 %: the valve is shut at rest
    # and opens with a jump a PI fitted on the recording makes a steep opening of its own, and the
    # lag explains the rest to within the noise: not identifiable without a model of the valve
    duty = F.excitation("breaths", 5)
    rng = np.random.default_rng(5)

    def rec(effects):
        q = F.flow_of(effects, duty, 5)[0] + rng.normal(0.0, 0.5, len(duty))
        return Recording("<breaths>", {"t_s": np.arange(len(duty)) / F.RATE_HZ, "duty_pct": duty, "flow_lpm": q})

    d = diagnose_response(rec({"dead_zone": 45.0, "valve_dynamics": 0.04}))
    assert [f.effect for f in d.findings if f.alternative_to is None] == ["valve_dynamics"]
    why = d.model["not_identifiable"]["dead_zone"]
    assert "jump" in why and "--model" in why
    # the lag alone opens from zero flow at rest: nothing said of a dead zone
    d = diagnose_response(rec({"valve_dynamics": 0.04}))
    assert "dead_zone" not in d.model["not_identifiable"]


@pytest.mark.slow
def test_gross_heating_with_asymmetry():
    # each refined once more with the other in place: neither takes up part of the other
    named = _named({"coil_heating": 30.0, "asymmetric_hysteresis": 1.0}, "paper_identification", seed=5)
    assert named["coil_heating"].params["rise55_k"] == pytest.approx(30.0, rel=0.25)
    assert named["asymmetric_hysteresis"].params["extra_width"] == pytest.approx(1.0, rel=0.3)


@pytest.mark.slow
def test_a_heating_beside_an_asymmetry_is_refined_jointly_with_it():
    # a coil 32 K warm with the descending thresholds widened x8, on a mixed recording: refined one after
    # the other, the asymmetry was read as a widening in proportion to each threshold on a PI whose own
    # loop the refit shrank into it (x65, beyond any plausible asymmetry); refined jointly from the lift
    # of every threshold too, the chain's training error is lower and the asymmetry is of a plausible size
    G = pytest.importorskip("diagnose_gross")
    from models.diagnose.words import VOCABULARY

    p = G.Probe("plant", (("coil_heating", 32.0), ("asymmetric_hysteresis", 8.0)), "mixed", 5007, 0.7)
    d = diagnose_response(G.record(p))
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    assert set(named) == {"coil_heating", "asymmetric_hysteresis"}
    asym = named["asymmetric_hysteresis"].params
    assert VOCABULARY["asymmetric_hysteresis"].implausible(asym) is None
    assert named["coil_heating"].params["rise55_k"] == pytest.approx(32.0, rel=0.25)
    for f in d.findings:
        assert f.holdout_rmse_after < f.holdout_rmse_before


@pytest.mark.slow
def test_gross_heating_with_supply_wander():
    # a coil 30 K warm at 55 % duty while the supply wanders by 0.3 bar (recorded): both laws, no creep
    named = _named({"supply_pressure": 0.3, "coil_heating": 30.0}, "paper_identification")
    assert named["coil_heating"].params["rise55_k"] == pytest.approx(30.0, rel=0.25)
    assert named["supply_pressure"].params["exponent"] == pytest.approx(1.0, rel=0.3)  # choked flow


@pytest.mark.slow
def test_gross_saturation_with_creep():
    named = _named({"saturation": 140.0, "creep": 0.1}, "paper_identification")
    assert named["saturation"].params["full_open_lpm"] == pytest.approx(140.0, rel=0.02)
    assert 0.05 < named["creep"].params["amplitude"] < 0.2


def test_creep_stops_at_a_shut_valve():
    # breaths resting at 30 %, below the valve's opening: between breaths the plunger creeps on by
    # 15 % of the last step (some 17 L/min) but a shut valve passes nothing, so the creep shows only
    # while the valve is open. Held against the model file, creep and the sensor's offset (which is
    # all the shut valve's rows show) are each sized from their own rows
    rec = _plant_recording({"creep": 0.15, "sensor_offset": 1.5}, "breaths", 300.0, seed=11)
    named = {f.effect: f for f in diagnose_response(rec, load_model(S.MODEL_JSON)).findings}
    assert set(named) == {"creep", "sensor_offset"}
    assert named["creep"].params["amplitude"] == pytest.approx(0.15, rel=0.25)
    assert named["sensor_offset"].params["offset_lpm"] == pytest.approx(1.5, abs=0.2)


def test_a_model_files_misfit_of_the_loading_curve_is_no_drift_in_time():
    # breaths on a valve whose loading curve the model file misses by a smooth function of the duty
    # (1.2 L/min more at the breaths' top than at their foot): a creep of a small fraction, its state
    # following each breath's reversals up and down, matches that as a static curve of the duty does;
    # beside a free static curve it explains nothing more, and no drift in time is named
    rec = _plant_recording({}, "breaths", 300.0, seed=13)
    cols = dict(rec.columns)
    duty = cols["duty_pct"]
    cols["flow_lpm"] = cols["flow_lpm"] + np.where(cols["flow_lpm"] > 1.0, 1.2 * (duty - duty.min()) / np.ptp(duty), 0.0)
    named = {f.effect for f in diagnose_response(Recording("<misfit>", cols), load_model(S.MODEL_JSON)).findings}
    assert not named & {w for w in WORDS if VOCABULARY[w].drifts}


def _foreign_against_the_model_file(effects: tuple, exc: str):
    """A foreign valve's recording (seed 20001, noise 0.5) with ``effects``, held against the foreign suite's
    model file (a PI fitted on a staircase of another seed): its signals, folds and reference."""
    G = pytest.importorskip("diagnose_gross")
    from models.diagnose import detectors as D
    from models.diagnose import make_folds, memory_start_s
    from models.diagnose.design import fixed_base
    from models.diagnose.signals import work_signals

    sig = work_signals(G.record(G.Probe("foreign", effects, exc, 20001, 0.5)), None)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    return sig, folds, D.reference(fixed_base(F.model_file(), sig), sig, folds)[0]


def test_a_lateness_held_against_a_model_file_explains_more_than_a_misfit_of_the_valves_loop():
    # the foreign valve (20 operators), effect free, on triangles against its model file, which misses
    # the valve's loop by 3.9 x the noise: a lag (30 ms) or a delay shifts each ramp's flow by tau dq/dt,
    # a level on each branch, and took up the loop's misfit. Beside a free curve of the duty on each branch
    # (a free loop, rate-independent) it explains nothing, and is refused. A true lag of the valve on a
    # chirp (its rate sweeps) or on breaths (holds it relaxes into) explains more than any loop
    from models.diagnose import detectors as D
    from models.diagnose import load_margins
    from models.diagnose.words import DYNAMIC

    def misfit(word, params, effects, exc):
        sig, folds, cur = _foreign_against_the_model_file(effects, exc)
        return D._static_misfit(word, {}, {word: params}, cur, cur, sig, folds, load_margins())

    lag, delay = ("valve_dynamics", {"tau_s": 0.03, "phase": 0.0}), ("transport_delay", {"delay_s": 0.02})
    assert all(VOCABULARY[w].beyond_loop for w in DYNAMIC)
    for word, params in (lag, delay):
        why = misfit(word, params, (), "triangles")
        assert why is not None and "each branch" in why
    for exc in ("chirp", "breaths"):
        assert misfit("valve_dynamics", {"tau_s": 0.04, "phase": 0.0}, (("valve_dynamics", 0.04),), exc) is None


@pytest.mark.slow  # ~20 s
def test_a_valve_the_model_file_does_not_quite_describe_names_no_lag():
    # the same effect-free triangles diagnosed against the model file: a 30 ms lag (a 18 ms delay its
    # alternative) was named on the model's misfit of the valve's loop; now neither is named, and both are
    # said to be not identifiable against this model file
    from models.diagnose.words import DYNAMIC

    G = pytest.importorskip("diagnose_gross")
    d = diagnose_response(G.record(G.Probe("foreign", (), "triangles", 20001, 0.5)), F.model_file())
    assert not {f.effect for f in d.findings} & set(DYNAMIC)
    for w in DYNAMIC:
        assert "against this model file" in d.model["not_identifiable"][w]
    # nor is the model's misfit read as a sensor offset (0.49 L/min) on a valve never seen shut
    assert d.findings == []
    assert "no larger than the model file's own misfit" in d.model["not_identifiable"]["sensor_offset"]


def test_an_offset_no_shut_row_reads_must_exceed_the_model_files_misfit_of_the_loading_curve():
    # the foreign valve on triangles, never shut, held against its model file, which misses its loading
    # curve by about 1 L/min RMS from one duty to another: effect free, the constant it reads (0.5 L/min)
    # is within that misfit and cannot be told from a zero offset; an offset of 2.5 L/min can
    from models.diagnose import detectors as D

    for offset_lpm, told in ((0.0, False), (2.5, True)):
        sig, folds, cur = _foreign_against_the_model_file((("sensor_offset", offset_lpm),) if offset_lpm else (),
                                                          "triangles")
        why = D._level_within_misfit("sensor_offset", {}, D.Selection(reference=cur), sig, folds)
        assert (why is None) == told, why


def test_an_offset_a_model_file_misses_the_valves_loop_around_is_not_identifiable_rather_than_absent():
    """A foreign valve widened x5.4 with an offset of -1.0 L/min, on triangles never shut, held against
    its model file: the file's thresholds widened in proportion miss the valve's loop by three times the
    noise, the asymmetry's lift takes the offset up, and the constant then reads +0.1 L/min. The offset
    is said to be not identifiable, not absent; the asymmetry is named."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("asymmetric_hysteresis", 5.35), ("sensor_offset", -1.02)), "triangles", 11372, 0.46)
    d = diagnose_response(G.record(probe), F.model_file())
    assert G.judge(probe, d) == []
    assert "asymmetric_hysteresis" in {f.effect for f in d.findings}
    assert "misses the recording" in d.model["not_identifiable"]["sensor_offset"]


def test_an_asymmetry_against_a_model_file_must_also_show_beside_a_symmetric_pi_fitted_on_the_recording():
    # the foreign valve's loop, held against a PI fitted on its staircase, is missed by that file as a
    # loop a little too narrow at the top, which a descending-threshold lift takes up; the paper's PI
    # fitted on the recording is as symmetric as the file and takes that misfit up itself. A true
    # asymmetry (x5) shows beside it as it does against the file
    from models.diagnose import detectors as D
    from models.diagnose import load_margins

    for effects, asymmetric in (((), False), ((("asymmetric_hysteresis", 5.0),), True)):
        sig, folds, _ = _foreign_against_the_model_file(effects, "triangles")
        why = D._symmetric_misfit("asymmetric_hysteresis", {}, {"asymmetric_hysteresis": {}}, sig, folds,
                                  load_margins())
        assert (why is None) == asymmetric, why


def test_a_foreign_valves_loop_misfit_beside_an_offset_is_not_named_an_asymmetry():
    """A foreign valve with a 35 ms lag and an offset of -1.7 L/min on triangles, against its model file:
    an asymmetry (lift 1.3 % duty) was named on the file's misfit of the loop, and the offset beside it
    sized -2.8. Refused beside a symmetric PI fitted on the recording, the offset is named at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("sensor_offset", -1.69), ("valve_dynamics", 0.0351)), "triangles", 11188, 0.42)
    d = diagnose_response(G.record(probe), F.model_file())
    assert "asymmetric_hysteresis" not in {f.effect for f in d.findings}
    assert G.judge(probe, d) == []


@pytest.mark.slow  # ~30 s and ~60 s
@pytest.mark.parametrize("generator, heating_k, cracking_pct, excitation, seed, noise_lpm", [
    ("foreign", 32.65, 43.69, "breaths", 11590, 0.36), ("plant", 34.66, 45.88, "mixed", 10717, 0.33)])
def test_a_warm_coil_beside_a_dead_zone_is_named_with_it(generator, heating_k, cracking_pct, excitation, seed,
                                                         noise_lpm):
    """A coil 33-35 K warm beside a dead zone. Foreign breaths resting just below the cracking duty: alone,
    the heating's seat line passed flow where the valve measured shut (refused), and the dead zone alone,
    at a rest the warming coil moves, gained 0.2 %. plant_sim on a mixed excitation: the dead zone, refused
    as a misfit at the rest, gained most, and an asymmetry was named on the loop the warming smeared.
    Named together, each at its size, and nothing else."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe(generator, (("coil_heating", heating_k), ("dead_zone", cracking_pct)), excitation, seed,
                    noise_lpm)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []


@pytest.mark.slow  # ~60 s
def test_a_word_earns_its_place_against_the_others_refined_without_it():
    """plant_sim's valve with an asymmetry (x9.4) and a creep on the paper sweep: a coil 10 K warm from the
    start was named beside them, the asymmetry refined beside it read x5.1 and the heating gained 21 %
    against the two as they stood; against the asymmetry refined without it (x8.5) it gains 3 %, below
    its margin, and is dropped."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("asymmetric_hysteresis", 9.43), ("creep", 0.0931)), "paper", 11466, 0.49)
    d = diagnose_response(G.record(probe))
    assert "coil_heating" not in {f.effect for f in d.findings}
    assert G.judge(probe, d) == []


def test_a_warm_coil_and_an_offset_each_refused_alone_are_named_together():
    """plant_sim's valve 29 K warm with a sensor offset of 2.3 L/min, held against its model file on a mixed
    excitation: alone, the heating's time constant ran to its bound (the offset unexplained) and the offset's
    constant took up the warming (refused by the shut rows' reading). Named together, each at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("coil_heating", 28.51), ("sensor_offset", 2.29)), "mixed", 11651, 1.0)
    d = diagnose_response(G.record(probe), load_model(S.MODEL_JSON))
    assert G.judge(probe, d) == []


def test_a_clip_few_breaths_reach_is_named_and_a_loop_on_breaths_is_not_named_a_creep():
    """A foreign valve 30 K warm, clipped at 147 L/min and x3.4 asymmetric, on breaths: the clip holds only
    the highest breaths' tops (0.6 % of the rows, above every level of the clip's old grid, which read it
    at 144 L/min and refused it as exceeded there), and the asymmetric loop, which breaths cannot show,
    leaves a rest flow that follows the breath before: a creep of 0.0044 over 0.5 s fitted it, and the
    same law settled within a sample fitted it better. The heating and the clip are named at their sizes,
    and no creep."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("asymmetric_hysteresis", 3.37), ("coil_heating", 29.96), ("saturation", 147.25)),
                    "breaths", 11817, 0.62)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    assert {f.effect for f in d.findings} == {"coil_heating", "saturation"}


def test_a_lag_or_delay_decided_again_on_the_final_chain_is_weighed_against_the_named_one_refined_there_too():
    """A foreign valve with a 52 ms delay and a creep, on a chirp. The delay, named first, stayed at 45 ms
    once the creep was named beside it (the PI refitted under it had taken up the rest of the lateness),
    and its alternative, a lag refined again beside the creep, fitted better than that delay, and was named
    in its place. Refined there too, the delay reads 52 ms and fits better than the lag: it is named, at
    its size, with the lag as its alternative."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("creep", 0.1629), ("transport_delay", 0.0523)), "chirp", 11205, 0.67)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    named = {f.effect: f for f in d.findings if f.alternative_to is None}
    assert "transport_delay" in named and "valve_dynamics" not in named


@pytest.mark.slow  # ~1 min
def test_a_word_refused_just_below_its_margin_is_screened_again_beside_the_refined_chain():
    """plant_sim on breaths with a 36 ms delay, a coil 19 K warm and a creep of 0.084. Screened beside the
    delay and the heating as each was named (the PI refitted under each in turn), the creep explained
    5.7 % of the held-out error for 9.7 % needed; beside the chain refined together, with the
    reference's PI refitted under it, it explains 17.6 %, and is named at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("coil_heating", 18.75), ("creep", 0.0839), ("transport_delay", 0.0358)),
                    "breaths", 12305, 0.64)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []


@pytest.mark.slow  # ~1 min
def test_an_asymmetry_a_symmetric_pi_fitted_on_the_recording_takes_up_is_not_identifiable_against_the_model_file():
    """plant_sim x7.6 asymmetric, clipped at 140 L/min, its sensor 2.3 L/min high, held against its model
    file on a mixed excitation. The asymmetry explains 95 % of the held-out error against the file, but
    beside the paper's symmetric PI fitted on the recording only 0.75 %: the recording shows a loop the
    file misses, not that the valve's own loop is asymmetric. It is dropped and said to be not
    identifiable against the model file; the clip and the offset are named at their sizes."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("asymmetric_hysteresis", 7.64), ("saturation", 139.86), ("sensor_offset", 2.32)),
                    "mixed", 12383, 0.93)
    d = diagnose_response(G.record(probe), load_model(S.MODEL_JSON))
    assert "asymmetric_hysteresis" not in {f.effect for f in d.findings}
    assert "symmetric PI" in d.model["not_identifiable"]["asymmetric_hysteresis"]
    assert G.judge(probe, d) == []


def test_a_lag_settled_within_a_sample_gives_way_to_the_delay_it_ties_with():
    """A foreign valve with a 21 ms delay (one sample at 50 Hz) beside an asymmetry, on triangles. A lag of
    4 ms with its command 95 % of a sample late fits the recording as well (held-out error 1e-5 lower):
    a lag that has settled by the next sample shows only lateness, so the delay is named, the lag its
    alternative."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("asymmetric_hysteresis", 5.86), ("transport_delay", 0.0209)), "triangles",
                    12334, 0.33)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    lag = next(f for f in d.findings if f.effect == "valve_dynamics")
    assert lag.alternative_to == "transport_delay"


def test_a_warm_coils_input_floor_the_recording_refutes_gives_way_to_another_floor():
    """A coil 36 K warm on plant_sim's valve, seated at its lowest duty, on a mixed excitation. Its law
    refined best with the valve's input held at 37.8 %, where the seat's line below passes flow on rows a
    fifth of which measure the valve shut: that floor is refuted, and the law is named on the floor the
    recording bears out, at its size (it was refused, and nothing named)."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("coil_heating", 36.03),), "mixed", 12553, 0.69)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    assert not any(t["outcome"] == "unsupported" for t in d.model["trace"] if t["word"] == "coil_heating")


def test_a_law_short_of_a_fold_majority_is_named_beside_the_companion_it_needs():
    """A foreign valve on triangles with its supply wandering 0.14 bar and a sensor offset of 2.3 L/min,
    held against its model file. The supply's law lowers the held-out error by 18 % but in only half
    the folds (the offset biases its coefficient on the rows the model file misfits), the offset alone
    not at all; each beside the other earns its place in every fold, and both are named at their size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("sensor_offset", 2.27), ("supply_pressure", 0.1376)), "triangles", 12503, 0.75)
    d = diagnose_response(G.record(probe), F.model_file())
    assert G.judge(probe, d) == []
    assert {f.effect for f in d.findings} == {"sensor_offset", "supply_pressure"}


@pytest.mark.slow  # ~1-2 min
def test_an_asymmetry_refuted_by_a_law_named_before_it_is_read_again_beside_that_law_resized():
    """A foreign valve on triangles with an asymmetry x4.7 under a coil 42 K warm and a dead zone at
    44.6 %. The heating, named first, took up part of the loop's widening (10 K on 40 s), and its misfit
    was the residual where the asymmetry widens the loop most: the asymmetry was refused there. With the
    heating refined again beside it, each is named at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("asymmetric_hysteresis", 4.68), ("coil_heating", 41.99), ("dead_zone", 44.62)),
                    "triangles", 12524, 0.84)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []


@pytest.mark.slow  # ~2 min
def test_a_gross_misfit_left_by_the_greedy_search_is_searched_again_from_another_first_word():
    """A foreign valve with a dead zone at 46.8 % behind a 56 ms lag and a 47 ms delay, on a chirp: each law
    alone explains 20-40 % of the misfit and the three together 99.6 %. Greedy, the search named a coil
    heating first (40 %, the lag's attenuation growing with the chirp's frequency read as a warming) and
    ended 10 x the noise from the recording; started again from another word of the first round, it names
    the three, each at its size, and nothing else."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("foreign", (("dead_zone", 46.77), ("transport_delay", 0.0467), ("valve_dynamics", 0.0561)),
                    "chirp", 11658, 0.55)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    assert any("the search started from" in t["why"] for t in d.model["trace"])


def test_a_model_file_that_does_not_record_its_supply_is_held_at_the_reference_hardwares():
    """A foreign valve identified at 3.0 bar without a supply column, held against a recording whose supply
    wanders and droops with the flow to a mean of 2.97 bar, with an offset of 1.8 L/min: the model's flow
    scaled to the recording's mean supply read the droop's share of the flow as a constant (1.12 L/min);
    scaled to DESIGN.md's 3 bar, the offset is named at its size beside the supply's law."""
    G = pytest.importorskip("diagnose_gross")
    assert "supply_bar" not in F.model_file().meta
    probe = G.Probe("foreign", (("sensor_offset", 1.8), ("supply_pressure", 0.1732)), "chirp", 11268, 0.65)
    d = diagnose_response(G.record(probe), F.model_file())
    assert G.judge(probe, d) == []


def test_an_asymmetry_starts_where_a_warm_coils_valve_opens_on_the_duty_its_magnetics_see():
    # plant_sim's valve (seated at 38 %) 44 K warm on the paper sweep: it opens at a commanded duty that
    # rises as the coil warms, while its core's input opens at the seat; the asymmetry's widening is
    # sought from there, not from the commanded duty that splits the shut rows best (41 %)
    G = pytest.importorskip("diagnose_gross")
    from models.diagnose import make_folds, memory_start_s, running_rows, work_signals
    from models.diagnose.design import fit_baseline

    rec, rest = running_rows(G.record(G.Probe("plant", (("coil_heating", 44.35),), "paper", 11361, 0.47)))
    sig = work_signals(rec, rest)
    base = fit_baseline(sig, make_folds(sig.t_s, start_s=memory_start_s(sig)))
    asym = VOCABULARY["asymmetric_hysteresis"]
    heat = {"rise55_k": 44.35, "tau_s": 180.0, "start": 0.0}
    at = {name: base.shape_scale.from_unit(2.0 * asym._opening(sig, base, chain)["start"] - 1.0)
          for name, chain in (("warm", {"coil_heating": heat}), ("cold", {}))}
    assert abs(at["warm"] - 38.0) < 1.0 < at["cold"] - 38.0


def test_a_heating_beside_an_asymmetry_is_read_again_with_the_widening_started_at_the_opening():
    """The same coil 44 K warm on the paper sweep with x5.6: named first, the heating took up part of the
    widening (54 K, 263 s), and the widening then started at 43 %, above the valve's opening at 38 %,
    which holds the heating there. The asymmetry's other reading starts at the opening on the duty the
    magnetics see; refined jointly from it, the heating is read at its size with less training error."""
    G = pytest.importorskip("diagnose_gross")
    from models.diagnose import detectors as D
    from models.diagnose import make_folds, memory_start_s, running_rows, work_signals
    from models.diagnose.design import fit_baseline

    rec, rest = running_rows(G.record(G.Probe("plant", (("asymmetric_hysteresis", 5.61), ("coil_heating", 44.35)),
                                              "paper", 11361, 0.47)))
    sig = work_signals(rec, rest)
    folds = make_folds(sig.t_s, start_s=memory_start_s(sig))
    ref = D.reference(fit_baseline(sig, folds), sig, folds)[0]
    found = {"coil_heating": {"rise55_k": 54.1, "tau_s": 263.0, "start": 0.0},
             "asymmetric_hysteresis": {"widen": 0.001, "lift": 0.3035, "start": 0.153}}
    pair = ["coil_heating", "asymmetric_hysteresis"]
    readings = VOCABULARY["asymmetric_hysteresis"].readings(found["asymmetric_hysteresis"], sig, ref, found)
    at_opening = [(p, held) for p, held in readings if held == ("start",)]
    assert len(at_opening) == 1 and at_opening[0][0]["start"] < 0.02
    stay = D.refine_jointly(pair, found, ref, sig, folds)
    moved = D.refine_jointly(pair, {**found, "asymmetric_hysteresis": at_opening[0][0]}, ref, sig, folds,
                             held=(("asymmetric_hysteresis", "start"),))
    assert D._chain_sse(pair[0], moved, ref, sig, folds) < D._chain_sse(pair[0], stay, ref, sig, folds)
    assert abs(moved["coil_heating"]["rise55_k"] - 44.35) < 0.1 * 44.35 < abs(stay["coil_heating"]["rise55_k"] - 44.35)


def test_a_coil_so_warm_its_valve_stays_shut_between_breaths_is_named():
    # the matrix's coil 160 K warm on breaths resting at 40 %: after the first minutes the valve opens
    # only near each breath's top, and a floor fitted a little above its seat has its line pass flow on
    # 13 % of rows measured shut (a dead zone's jump read as a heating's floor: a third)
    d = diagnose_response(S.record(S.Case((("coil_heating", 160.0),), "breaths", 1, 0.5)))
    assert {f.effect for f in d.findings} >= {"coil_heating"}


def test_a_model_file_that_explains_a_valve_never_shut_says_it_has_no_offset():
    # plant_sim's valve against its own model file on random holds above its seat: no row reads the
    # sensor's zero, but the model explains the recording to the noise, so a constant would show: the
    # offset is absent, not "not identifiable"
    d = diagnose_response(S.record(S.Case((), "random_holds", 7, 0.5)), load_model(S.MODEL_JSON))
    assert d.findings == []
    assert "sensor_offset" not in d.model["not_identifiable"]


def test_a_coil_warming_from_cold_explains_more_than_a_model_files_misfit_of_the_loading_curve():
    # held against a model file a coil's heating must explain more than a free static curve of the duty
    # (the model's misfit, a constant included): a coil warm from the first row at the duty's mean is a
    # scale of the duty, which the curve takes; a coil warming from cold drifts in time, which it cannot
    from models.diagnose import detectors as D
    from models.diagnose import load_margins

    assert VOCABULARY["coil_heating"].beyond_curve
    heat = {"rise55_k": 30.0, "tau_s": 150.0, "start": 0.0}
    sig, folds, cur = _foreign_against_the_model_file((("coil_heating", 30.0),), "chirp")
    assert D._static_misfit("coil_heating", {}, {"coil_heating": heat}, cur, cur, sig, folds, load_margins()) is None
    sig, folds, cur = _foreign_against_the_model_file((), "chirp")
    warm = {"rise55_k": 1.0, "tau_s": 230.0, "start": 1.0}
    why = D._static_misfit("coil_heating", {}, {"coil_heating": warm}, cur, cur, sig, folds, load_margins())
    assert why is not None and "on each branch" not in why


@pytest.mark.parametrize("offset_lpm", [-2.0, 0.0])
def test_sensor_offset_is_read_where_the_valve_is_shut(offset_lpm):
    # a valve passing 4 % less flow than its model file, resting shut between breaths: over the
    # open valve a constant takes up the model's misfit too (-1.5 L/min), so the offset is what the
    # sensor reads where the model has the valve shut, and a constant the shut valve does not read
    # is no offset at all
    rec = _plant_recording({}, "breaths", 300.0, seed=12)
    cols = dict(rec.columns)
    cols["flow_lpm"] = 0.96 * cols["flow_lpm"] + offset_lpm
    named = {f.effect: f for f in diagnose_response(Recording("<weak valve>", cols), load_model(S.MODEL_JSON)).findings}
    if offset_lpm:
        assert named["sensor_offset"].params["offset_lpm"] == pytest.approx(offset_lpm, abs=0.2)
    else:
        assert "sensor_offset" not in named


@pytest.mark.slow
def test_gross_asymmetry_ten_times_the_loop():
    # descending thresholds lifted by 10 x the major loop's half-width at the top of the range
    named = _named({"asymmetric_hysteresis": 10.0}, "paper_identification")
    assert named["asymmetric_hysteresis"].params["extra_width"] == pytest.approx(10.0, rel=0.3)


@pytest.mark.slow  # ~60 s
def test_gross_asymmetry_beside_a_clip_is_screened_at_its_size():
    # x8 beside a clip at 148 L/min on the paper sweep: with the clip named, the PI refitted with the
    # first-order lift column bends its own loop towards the gross one, the column gained 1.7 % of
    # the training error (under its 3 % margin) and the exact law was never refined: the asymmetry
    # was missed. Its exact law is screened at gross lifts too (:meth:`Word.sized`), and refined from
    # the lift the screen chose, it is named within the bench's tolerance (x0.65-1.35)
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("plant", (("asymmetric_hysteresis", 8.0), ("saturation", 148.0)), "paper", 20001, 0.7)
    d = diagnose_response(G.record(p))
    assert G.judge(p, d) == []
    named = {f.effect: f for f in d.findings}
    assert named["asymmetric_hysteresis"].params["extra_width"] == pytest.approx(8.0, rel=0.35)


def test_asymmetry_on_breaths_resting_below_the_opening_is_not_identifiable():
    # breaths step down from their plateau to 30 %, below the valve's opening, within one sample: the
    # descending branch is never sampled open, so no size of asymmetry changes the flow. Said so,
    # rather than named absent; a sweep's descents show it
    d = diagnose_response(_plant_recording({"asymmetric_hysteresis": 8.0}, "breaths", 120.0, seed=4))
    assert d.findings == []
    assert "descending threshold" in d.model["not_identifiable"]["asymmetric_hysteresis"]
    d = diagnose_response(_plant_recording({}, "paper_identification", 120.0, seed=4))
    assert "asymmetric_hysteresis" not in d.model["not_identifiable"]


@pytest.mark.slow
def test_gross_asymmetry_on_a_recording_resting_below_the_opening():
    # breaths resting at 34 %, below the valve's opening, then a sweep and random holds: the
    # widening starts where the valve opens (the simulated valve's loop starts at 38 %), not at the
    # recording's 34 %, where it would lift every descending threshold by a constant the refitted
    # PI takes out of its own loop, and the extra width relative to that loop would come out half
    # as large again (x6 named 9.5)
    import diagnose_gross as G

    p = G.Probe("plant", (("asymmetric_hysteresis", 6.0),), "mixed", 3022, 0.5)
    named = {f.effect: f for f in diagnose_response(G.record(p)).findings}
    assert set(named) == {"asymmetric_hysteresis"}
    f = named["asymmetric_hysteresis"]
    assert f.params["extra_width"] == pytest.approx(6.0, rel=0.25)
    assert 36.0 < f.params["start_pct"] < 40.0
    assert f.holdout_rmse_after < f.holdout_rmse_before


def test_backward_check_drops_a_word_a_later_one_explains():
    # a 40 ms lag on steps. Say a 20 ms delay was named first (it took up part of the lag) and the lag
    # after it: with the lag in place the delay no longer earns its margin, so the backward check on
    # the final chain drops it (traced with its reason) and keeps the lag, which earns its place
    from models.diagnose import detectors as D
    from models.diagnose.calibrate import load_margins
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals
    from models.diagnose.trace import DROPPED, explain

    rec = _plant_recording({"valve_dynamics": 0.04}, "steps", 60.0)
    sig = work_signals(rec, None)
    folds = make_folds(sig.t_s)
    margins = load_margins()
    sel = D.Selection()
    sel.reference, _ = D.reference(fit_baseline(sig, folds), sig, folds)
    sel.chain = {"transport_delay": {"delay_s": 0.02}, "valve_dynamics": {"tau_s": 0.04, "phase": 1.0}}
    sel.params = {w: dict(p) for w, p in sel.chain.items()}
    none = np.zeros(folds.k)
    sel.steps = [D.Candidate(w, 0.5, folds.k, dict(p), none, none) for w, p in sel.chain.items()]

    assert D.earns("valve_dynamics", sel.chain, sel.reference, sig, folds, margins)[1] is None
    assert D._backward(sel, sig, folds, margins, rnd=2) == "transport_delay"
    assert list(sel.chain) == ["valve_dynamics"] and [s.word for s in sel.steps] == ["valve_dynamics"]
    assert set(sel.params) == {"valve_dynamics"}
    last = sel.trace[-1]
    assert (last.word, last.outcome, last.round) == ("transport_delay", DROPPED, 2)
    assert "valve_dynamics in place" in last.why and "backward check" in explain(last)
    # the lag left alone earns its place against the baseline: nothing more is dropped
    assert D._backward(sel, sig, folds, margins, rnd=3) is None


def test_a_word_does_not_earn_its_place_through_the_pi_its_refit_bent(monkeypatch):
    # a 40 ms lag on steps, and a creep beside it that the valve does not have. Say the PI refitted
    # under the lag alone came out bent (its refit is a constrained, censored problem of its own,
    # not the fit's: here, the PI refitted under nothing, which smooths the lag into its loop) while
    # the one refitted with the creep did not: the chain without the creep keeps that better PI, and
    # the creep, whose own column adds nothing, does not earn its place
    from models.diagnose import detectors as D
    from models.diagnose.calibrate import load_margins
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals

    rec = _plant_recording({"valve_dynamics": 0.04}, "steps", 60.0)
    sig = work_signals(rec, None)
    folds = make_folds(sig.t_s)
    root, _ = D.reference(fit_baseline(sig, folds), sig, folds)
    chain = {"valve_dynamics": {"tau_s": 0.04, "phase": 1.0}, "creep": {"tau_s": 5.0}}
    unbend = D.unbend
    monkeypatch.setattr(D, "unbend", lambda b, s, c, rows: unbend(b, s, c if "creep" in c else {}, rows))

    cand, why = D.earns("creep", chain, root, sig, folds, load_margins())
    assert why is not None and "held-out error" in why
    assert abs(cand.gain) < 0.01
    # the lag, which the bent PI cannot stand in for, still earns its place
    assert D.earns("valve_dynamics", chain, root, sig, folds, load_margins())[1] is None


def test_a_heating_slower_than_twice_the_recording_is_not_resolved():
    # over a 300 s recording a coil warming with a 700 s time constant rises along a near ramp in
    # time, which a slow drift of anything fits (a lag's misfit on a mixed excitation read as a coil
    # 11 K warm with a 1130 s time constant); within twice the recording its curvature shows
    from models.diagnose import detectors as D
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals
    from models.diagnose.words import VOCABULARY

    sig = work_signals(_plant_recording({"coil_heating": 30.0}, "paper_identification", 300.0), None)
    base = fit_baseline(sig, make_folds(sig.t_s))
    w = VOCABULARY["coil_heating"]
    span_s = sig.t_s[-1] - sig.t_s[0]
    slow = {"rise55_k": 30.0, "tau_s": 2.3 * span_s, "start": 0.0}
    assert "tau_s" in D._at_upper_bound(w, slow, sig, base)
    assert D._at_upper_bound(w, {**slow, "tau_s": 0.6 * span_s}, sig, base) is None


@pytest.mark.parametrize("order", [("valve_dynamics", "saturation", "coil_heating", "transport_delay"),
                                   ("transport_delay", "saturation", "coil_heating", "valve_dynamics")])
def test_holdout_confirms_each_word_with_the_others_in_place(order):
    # a coil 35 K warm, a clip at 140 L/min and a 30 ms lag (mixed excitation). The clip corrects
    # little until the heating that drives the flow to it is modelled (on the lag alone it raised the
    # holdout RMSE while the PI refitted under it ran off on held-out levels). Held against the whole
    # chain, every true word is confirmed whatever the order it was named in, and a 50 ms delay that
    # the chain does not need is not (traced with the words it was held against)
    from models.diagnose import _ChainFits, _confirm
    from models.diagnose import detectors as D
    from models.diagnose.design import clip, fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import raw_signals, work_signals
    from models.diagnose.trace import NAMED, UNCONFIRMED, Decision, explain

    G = pytest.importorskip("diagnose_gross")
    rec = G.record(G.Probe("plant", (("coil_heating", 35.0), ("saturation", 140.0), ("valve_dynamics", 0.03)),
                           "mixed", 7, 0.5))
    raw, sig = raw_signals(rec, None), work_signals(rec, None)
    folds = make_folds(sig.t_s)
    base = fit_baseline(sig, folds)
    hold, y = folds.holdout_at(raw.t_s), raw.flow_lpm
    laws = {"valve_dynamics": {"tau_s": 0.03, "phase": 1.0}, "saturation": {"full_open_lpm": 140.0},
            "coil_heating": {"rise55_k": 35.0, "tau_s": 180.0, "start": 0.0}, "transport_delay": {"delay_s": 0.05}}
    sel = D.Selection()
    sel.reference, _ = D.reference(base, sig, folds)
    sel.chain = {w: laws[w] for w in order}
    none = np.zeros(folds.k)
    sel.steps = [D.Candidate(w, 0.5, folds.k, dict(p), none, none) for w, p in sel.chain.items()]
    sel.trace = [Decision(w, i, 0.5, 0.1, folds.k, folds.k, folds.k, 2, "exact", NAMED) for i, w in enumerate(order)]
    fits = _ChainFits(sel, sig, raw, folds, clip(base.predict(raw, {}), None, bool(base.shut(raw).any())))

    def rmse(*words):
        return np.sqrt(np.mean((y - fits.predict(fits.chain(words)))[hold] ** 2))

    assert rmse("valve_dynamics", "saturation", "coil_heating") < rmse("valve_dynamics")
    words, unconfirmed = _confirm(sel, fits, y, hold)
    assert words == [w for w in order if w != "transport_delay"]
    assert [(d.word, d.outcome) for d in unconfirmed] == [("transport_delay", UNCONFIRMED)]
    assert "saturation" in unconfirmed[0].why and "not asserted" in explain(unconfirmed[0])


def test_whole_chain_refines_each_word_and_reports_it_from_the_chain():
    # a 40 ms lag and a wandering supply (recorded), as if each had been named with the other's residual
    # still in it: a lag read as 25 ms, a stale exponent. Refined with the whole chain, the lag's time
    # constant comes back to 40 ms and the supply's exponent (a linear coefficient) is reported from
    # the whole chain's fit: choked flow
    from models.diagnose import detectors as D
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals

    rec = _plant_recording({"valve_dynamics": 0.04, "supply_pressure": 0.3}, "steps", 120.0)
    sig = work_signals(rec, None)
    folds = make_folds(sig.t_s)
    sel = D.Selection()
    sel.reference, _ = D.reference(fit_baseline(sig, folds), sig, folds)
    sel.chain = {"valve_dynamics": {"tau_s": 0.025, "phase": 1.0}, "supply_pressure": {}}
    sel.params = {"valve_dynamics": {"tau_s": 0.025, "phase": 1.0}, "supply_pressure": {"exponent": 0.0}}
    none = np.zeros(folds.k)
    sel.steps = [D.Candidate(w, 0.5, folds.k, dict(p), none, none, base=sel.reference) for w, p in sel.chain.items()]
    D._backfit(sel, sig, folds)
    assert sel.chain["valve_dynamics"]["tau_s"] == pytest.approx(0.04, rel=0.15)
    assert sel.params["valve_dynamics"]["tau_s"] == sel.chain["valve_dynamics"]["tau_s"]
    assert sel.params["supply_pressure"]["exponent"] == pytest.approx(1.0, rel=0.3)


def test_closed_loop_run_is_diagnosed_against_its_feedforward_model():
    # a closed-loop run (ff+kf on a breath profile, 90 s at 200 Hz) of a valve with a 50 ms lag the model
    # leaves out, with the columns of valvectl run --record, held against the feedforward's model file
    model = load_model(S.MODEL_JSON)
    d = diagnose_response(S.closed_loop_recording((("valve_dynamics", 0.05),), 2, 0.5, duration_s=90.0), model)
    named = {f.effect: f for f in d.findings}
    assert set(named) & {"valve_dynamics", "transport_delay"} and not set(named) - {"valve_dynamics", "transport_delay"}
    if "valve_dynamics" in named and named["valve_dynamics"].alternative_to is None:
        assert named["valve_dynamics"].params["tau_s"] == pytest.approx(0.05, rel=0.3)
    assert diagnose_response(S.closed_loop_recording((), 2, 0.5, duration_s=90.0), model).findings == []


@pytest.mark.slow
def test_magnitude_by_excitation_matrix():
    # every word at 1, 5 and 30 times the noise on every excitation, and each excitation effect free
    hits, free_findings, worse = {}, [], []
    for case in S.matrix():
        d = diagnose_response(S.record(case), load_model(S.MODEL_JSON) if case.with_model else None)
        named = [f.effect for f in d.findings]
        worse += [(case.label(), f.effect) for f in d.findings if f.holdout_rmse_after >= f.holdout_rmse_before]
        if not case.words:
            free_findings += [(case.label(), named)] if named else []
        else:
            hits.setdefault(case.size, []).append(case.words[0] in named)
    assert free_findings == [] and worse == []
    for size, h in hits.items():
        assert np.mean(h) >= 0.95, (size, np.mean(h))


@pytest.mark.slow
def test_gross_saturation_with_heating_names_no_dead_zone():
    # a clip at 130 L/min hides a coil 30 K warm from the first round (the PI bends through the clipped
    # rows): the heating, refused then, is tried again once the saturation is named, and the residual
    # is not handed to a dead zone that was never there
    G = pytest.importorskip("diagnose_gross")
    p = G.Probe("plant", (("saturation", 130.0), ("coil_heating", 30.0)), "paper", 7, 0.5)
    d = diagnose_response(G.record(p))
    assert {f.effect for f in d.findings if f.alternative_to is None} == {"saturation", "coil_heating"}
    for f in d.findings:
        assert f.holdout_rmse_after < f.holdout_rmse_before


def test_rows_left_to_a_clip_are_chosen_by_the_measured_plateau():
    # a coil warming beside a clip at 130 L/min: rows measured below the plateau are fitted whatever
    # the heating's rise and time constant, and the plateau rows are the same for every setting
    # (chosen by the prediction, the fitted rows moved with the heating and its refinement stalled).
    # Behind a lag the plateau is the valve's, recovered through the lag: the lagged rise to it is
    # left to the clip at the valve too
    from models.diagnose import effects as fx
    from models.diagnose.design import PLATEAU_NOISE, build, fit_baseline, fit_final, unbend
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import noise_lpm, work_signals

    sig = work_signals(_plant_recording({"saturation": 130.0, "coil_heating": 30.0}, "paper_identification", 120.0))
    folds = make_folds(sig.t_s)
    root = fit_baseline(sig, folds)
    top = sig.flow_lpm >= 130.0 - PLATEAU_NOISE * noise_lpm(sig.flow_lpm)
    assert 0.01 < top.mean() < 0.5
    below = ~top & ~root.shut(sig)
    for rise, tau in ((5.0, 60.0), (30.0, 180.0), (80.0, 400.0)):
        chain = {"coil_heating": {"rise55_k": rise, "tau_s": tau, "start": 0.0}, "saturation": {"full_open_lpm": 130.0}}
        b = unbend(root, sig, chain, folds.train)
        assert np.array_equal(b.plateau(sig, chain)[0], top)
        assert build(b, sig, chain).fit_ok[below].all()
    # behind a 40 ms lag: the plateau is the valve's, recovered through the lag (the valve is at its
    # stop before the sensor shows it), and the prediction never passes the clip on the lagged rise
    sig = work_signals(_plant_recording({"saturation": 130.0, "valve_dynamics": 0.04}, "paper_identification", 120.0))
    folds = make_folds(sig.t_s)
    root = fit_baseline(sig, folds)
    lag = {"tau_s": 0.04, "phase": 1.0}
    chain = {"valve_dynamics": lag, "saturation": {"full_open_lpm": 130.0}}
    at_valve, at_sensor = root.plateau(sig, chain)[0], root.plateau(sig, chain, valve=False)[0]
    assert at_valve.sum() > at_sensor.sum() > 0
    assert fx.first_order_lag(at_valve.astype(float), sig.rate_hz, lag["tau_s"])[at_sensor].mean() > 0.9
    b = unbend(root, sig, chain, folds.train)
    d = build(b, sig, chain)
    assert d.predict(fit_final(d, sig.flow_lpm, folds.train)).max() <= 130.0


def test_the_plateau_behind_a_delay_between_samples_keeps_the_sensor_noise_band():
    # a delay of 2.5 samples is undone by interpolating two rows: each valve row keeps half the
    # noise's variance, but its second differences read a third of its standard deviation. The band
    # under the clip is the sensor's noise as the undoing passes it on, so the plateau at the valve
    # loses only the interpolated row at each end of a stretch (a band read off the undone flow lost
    # one plateau row in twenty to the noise, fitted as open)
    from models.diagnose.design import fit_baseline
    from models.diagnose.folds import make_folds
    from models.diagnose.signals import work_signals

    sig = work_signals(_plant_recording({"saturation": 130.0}, "paper_identification", 120.0))
    root = fit_baseline(sig, make_folds(sig.t_s))
    at_sensor = root.plateau(sig, {"saturation": {"full_open_lpm": 130.0}}, valve=False)[0]
    stretches = int(np.sum(np.diff(at_sensor.astype(int)) == 1))
    assert stretches >= 3
    for shift in (2.0, 2.25, 2.5):
        chain = {"transport_delay": {"delay_s": shift / sig.rate_hz}, "saturation": {"full_open_lpm": 130.0}}
        at_valve = root.plateau(sig, chain)[0]
        assert at_valve.sum() >= at_sensor.sum() - 2 * stretches - 0.01 * at_sensor.sum(), shift


def test_undoing_a_time_response_passes_white_noise_by_its_impulse_norm():
    # a delay between samples averages two rows ((1 - f)^2 + f^2 of the variance); a lag's one-step
    # inverse amplifies by sqrt(1 + a^2) / (1 - a); a static law passes the noise as it is
    from models.diagnose.design import undo_gain

    rate = 50.0
    assert undo_gain({"saturation": {"full_open_lpm": 130.0}}, rate) == pytest.approx(1.0)
    for f in (0.0, 0.25, 0.5):
        assert undo_gain({"transport_delay": {"delay_s": (2 + f) / rate}}, rate) == pytest.approx(
            np.hypot(1 - f, f))
    a = np.exp(-1.0 / (rate * 0.04))
    assert undo_gain({"valve_dynamics": {"tau_s": 0.04, "phase": 1.0}}, rate) == pytest.approx(
        np.sqrt(1 + a * a) / (1 - a))
    rng = np.random.default_rng(0)
    e = rng.standard_normal(200_000)
    chain = {"valve_dynamics": {"tau_s": 0.03, "phase": 0.5}, "transport_delay": {"delay_s": 0.035}}
    undone = e
    for w, p in reversed(chain.items()):
        undone = VOCABULARY[w].undo(undone, rate, p)
    assert undo_gain(chain, rate) == pytest.approx(np.std(undone[200:-200]), rel=0.01)


def test_an_asymmetry_alone_is_refined_from_a_lift_of_every_threshold_too():
    """x3.18 alone on a mixed recording resting below the valve's opening, no model file (the
    held-out probe 911): the exact law was refined from its best unrefined start only, a widening of
    each descending threshold in proportion to it (widen 2), into that valley's floor (widen 2.3, the
    PI refitted under it shrinking its own loop), with more training error than a lift of every
    threshold alone (plant_sim's law) and 2.4 L/min held out against the lift's 1.0 and the
    baseline's 1.75; its correction largest where it ran off (a held-out step down from 61 % to 44 %,
    7 L/min high), it was refused as another law's residual. The best start of each valley is refined
    (:meth:`Word.basin`), and the lift alone, at the lower end of the widening, is a setting of the
    law, not a refinement run off its box: the asymmetry is named at its size."""
    G = pytest.importorskip("diagnose_gross")
    probe = G.Probe("plant", (("asymmetric_hysteresis", 3.18),), "mixed", 10911, 0.74)
    d = diagnose_response(G.record(probe))
    assert G.judge(probe, d) == []
    assert [f.effect for f in d.findings] == ["asymmetric_hysteresis"]
    w = VOCABULARY["asymmetric_hysteresis"]
    assert w.basin({"widen": 1e-3, "lift": 0.1}) != w.basin({"widen": 2.0, "lift": 0.1})


def test_a_gross_asymmetry_is_screened_at_its_size_against_a_pi_fitted_on_the_recording_only():
    # against a model file the model's own misfit of a foreign valve's loop is as gross as the sizes
    # screened (a foreign valve on breaths beside a 44 K coil was named an extra width of 2.35 from them)
    from models.diagnose.design import fit_baseline

    sig, folds, cur = _foreign_against_the_model_file((), "breaths")
    word = VOCABULARY["asymmetric_hysteresis"]
    assert word.sized(sig, cur, {}) == []
    assert len(word.sized(sig, fit_baseline(sig, folds), {})) >= 2
