"""The vocabulary of the diagnosis and its checks against their equations: one object per effect word,
the holdout slope and correlation, the noise estimate, the range-end support, closed-loop rows."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.diagnose import follows
from models.diagnose import effects as fx
from models.diagnose.calibrate import load_margins
from models.diagnose.signals import Signals, noise_lpm, running_rows
from models.diagnose.trace import BELOW_MARGIN, Decision, explain
from models.diagnose.words import VOCABULARY, WORDS, thermal_fit
from models.recording import InputError, Recording
from plant_sim.effects import EFFECTS as PLANT_EFFECTS


def _sig(duty, flow, rate=100.0, **kw):
    t = np.arange(len(duty)) / rate
    return Signals(t, np.asarray(duty, float), np.asarray(flow, float), kw.get("supply"), kw.get("temp"), rate)


def test_one_object_per_design_word():
    # the diagnosis' words are DESIGN.md's (plant_sim implements the same list), each one object
    assert set(WORDS) == set(PLANT_EFFECTS)
    assert list(VOCABULARY) == list(WORDS)
    for w, word in VOCABULARY.items():
        assert word.word == w and word.physics
        assert set(word.plausible) <= set(word.units)  # every checked parameter has a unit
    assert set(load_margins().gain) == set(WORDS)


@settings(max_examples=20, deadline=None)
@given(scale=st.floats(0.1, 10.0), noise=st.floats(0.0, 0.5), seed=st.integers(0, 1000))
def test_follows_recovers_the_slope_of_a_scaled_correction(scale, noise, seed):
    rng = np.random.default_rng(seed)
    delta = rng.normal(size=4000)
    resid = scale * delta + noise * rng.normal(size=4000)
    slope, corr = follows(resid, delta)
    # least squares through the origin: the slope and the correlation are each the truth within five
    # of their standard errors (noise / sqrt(n) and (1 - rho^2) / sqrt(n): a fixed 0.03 is 2.4 of them
    # at rho = 0.45, which one seed in fifty exceeds)
    rho = scale / np.sqrt(scale ** 2 + noise ** 2)
    assert slope == pytest.approx(scale, abs=5 * noise / np.sqrt(4000) + 1e-9)
    assert corr == pytest.approx(rho, abs=5 * (1 - rho ** 2) / np.sqrt(4000) + 1e-9)


def test_a_correction_ten_times_the_residual_does_not_follow_it():
    # the README's old dead zone: a correction peaking at 11 L/min against a residual of about 1
    rng = np.random.default_rng(1)
    resid = rng.normal(size=2000)
    slope, _ = follows(resid, 10 * resid + rng.normal(size=2000))
    assert slope < 0.15


def test_noise_estimate_from_second_differences():
    rng = np.random.default_rng(2)
    t = np.arange(20000) / 100.0
    smooth = 80 + 40 * np.sin(2 * np.pi * t / 7.0) + 10 * (t > 50)  # a step does not count
    assert noise_lpm(smooth + rng.normal(0, 0.5, len(t))) == pytest.approx(0.5, rel=0.05)


def test_dead_zone_needs_the_flow_to_stop():
    dz = VOCABULARY["dead_zone"]
    duty = np.r_[np.linspace(30, 70, 1000), np.linspace(70, 30, 1000)]
    before = np.clip((duty - 35) * 4, 0, None)  # the model before it: flow from 35 %
    shut = np.where(duty < 42, 0.0, before)
    rng = np.random.default_rng(3)
    assert dz.support(_sig(duty, shut + rng.normal(0, 0.5, len(duty))), {"cracking_pct": 42.0}, before, 0.5) is None
    # the flow goes on below the cracking duty: no dead zone there, whatever the fit says
    why = dz.support(_sig(duty, before + rng.normal(0, 0.5, len(duty))), {"cracking_pct": 42.0}, before, 0.5)
    assert "does not stop" in why


def test_dead_zone_against_an_extrapolated_model_needs_a_jump():
    # a PI run on below the rows it was fitted on may predict flow where a valve closing by itself
    # passes none: that is no cracking duty unless the flow jumps open above it
    dz = VOCABULARY["dead_zone"]
    duty = np.r_[np.linspace(30, 70, 1000), np.linspace(70, 30, 1000)]
    extrapolated = (duty - 30) * 4 + 10  # flow all the way down
    closing = np.clip((duty - 35) * 4, 0, None)  # the valve closes by itself at 35 %
    assert "jump" in dz.support(_sig(duty, closing), {"cracking_pct": 34.0}, extrapolated, 0.5, extrapolated=True)
    cracking = np.where(duty < 42, 0.0, closing)  # shut until 42 %, then 28 L/min at once
    assert dz.support(_sig(duty, cracking), {"cracking_pct": 42.0}, extrapolated, 0.5, extrapolated=True) is None


def test_dead_zone_jump_is_seen_through_a_lag():
    # breaths that open in 0.2 s through a 42 % cracking duty, the flow lagged by 50 ms: the jump at
    # the cracking duty is smoothed past the band above it at the sensor, not at the valve
    dz, lag = VOCABULARY["dead_zone"], {"tau_s": 0.05, "phase": 1.0}
    t = np.arange(30000) / 100.0
    phase = t % 3.0
    duty = np.where(phase < 1.0, 30 + 35 * np.clip(phase / 0.2, 0, 1), 30.0)
    valve = np.where(duty <= 42, 0.0, (duty - 35) * 4)  # 28 L/min at the cracking duty
    flow = fx.first_order_lag(valve, 100.0, 0.05) + np.random.default_rng(3).normal(0, 0.5, len(t))
    sig = _sig(duty, flow)
    assert dz._jumps(sig, {"cracking_pct": 42.0}, {"valve_dynamics": lag})
    # a valve closing by itself at 35 % comes to zero continuously: no jump at a duty below that
    smooth = fx.first_order_lag(np.clip((duty - 35) * 4, 0, None), 100.0, 0.05)
    assert not dz._jumps(_sig(duty, smooth), {"cracking_pct": 33.0}, {"valve_dynamics": lag})
    # without the lag taken back, the smoothed jump is not seen in the band above the cracking duty
    assert not dz._jumps(sig, {"cracking_pct": 42.0}, {})


def test_dead_zone_jump_is_read_on_the_valve_opening_from_shut():
    # breaths and held levels open the valve from shut through a 42 % cracking duty, onto 28 L/min; a
    # sweep turning back above it holds the valve on a branch its memory keeps far above that. The
    # jump is the flow on the opening from shut taken down to the cracking duty (a parabola over both
    # branches dived to zero flow at its foot); a valve opening by itself there from zero flow, however
    # steeply, shows none beside the same sweep
    dz, rate, crack = VOCABULARY["dead_zone"], 100.0, 42.0
    t = np.arange(0.0, 60.0, 1.0 / rate)
    phase = t % 3.0
    breaths = np.where(phase < 1.0, 30.0 + 35.0 * np.clip(phase / 0.2, 0.0, 1.0), 30.0)
    holds = np.where((t[:3000] % 5.0) < 2.5, 38.0, 43.7)
    sweep = 44.5 + 25.5 * np.abs(((t / 20.0) % 1.0) * 2 - 1)
    duty = np.r_[breaths, holds, sweep]
    opens = duty[:-len(sweep)]
    noise = np.random.default_rng(1).normal(0, 0.3, len(duty))
    cracking = np.r_[np.where(opens <= crack, 0.0, 28.0 + 3.0 * (opens - crack)), 70.0 + 3.0 * (sweep - 44.5)]
    sig = _sig(duty, cracking + noise)
    assert dz._jumps(sig, {"cracking_pct": crack}, {}) and dz._opens_with_jump(sig, {"cracking_pct": crack}, {})
    by_itself = np.r_[np.clip(10.0 * (opens - crack), 0.0, None), 70.0 + 3.0 * (sweep - 44.5)]
    sig = _sig(duty, by_itself + noise)
    assert not dz._jumps(sig, {"cracking_pct": crack}, {})
    assert not dz._opens_with_jump(sig, {"cracking_pct": crack}, {})


def test_dead_zone_rows_are_read_at_the_sensor_behind_a_delay():
    # breaths through a 42 % cracking duty, the flow 30 ms late: the last shut rows at the sensor are
    # those whose duty has already risen past the cracking duty, and there a model without the law
    # (its PI smoothed through the jump) predicts flow while the measured flow is still zero
    dz, delay = VOCABULARY["dead_zone"], {"delay_s": 0.03}
    t = np.arange(30000) / 100.0
    phase = t % 3.0
    duty = np.where(phase < 1.0, 30 + 35 * np.clip(phase / 0.2, 0, 1), 30.0)
    late = lambda q: fx.delayed(q, 100.0, 0.03)  # noqa: E731
    valve = np.where(duty <= 42, 0.0, (duty - 35) * 4)  # 28 L/min at the cracking duty
    smoothed = np.clip(np.minimum((duty - 38) * 7, (duty - 35) * 4), 0, None)  # from 38 %, not 42 %
    before = late(smoothed)
    rng = np.random.default_rng(3)
    shut = late(valve) + rng.normal(0, 0.5, len(t))
    chain = {"transport_delay": delay}
    assert dz.support(_sig(duty, shut), {"cracking_pct": 42.0}, before, 0.5, chain) is None
    # the flow that goes on where the law would stop it at the sensor is no dead zone
    goes_on = before + rng.normal(0, 0.5, len(t))
    assert dz.support(_sig(duty, goes_on), {"cracking_pct": 42.0}, before, 0.5, chain) is not None


def test_behind_a_delay_between_whole_samples_the_cracking_duty_is_placed_within_the_rows_read():
    # a valve cracking at 45.3 % behind a 26.3 ms delay, sampled at 50 Hz: read back at the valve, a row
    # at each crossing falls between a shut and an open sample, and its interpolated flow (a share of
    # the jump) reads open below the cracking duty. Those rows are left undecided, and the placement
    # offers both ends of the gap the rows read leave, the cracking duty between them
    dz, rate, fine = VOCABULARY["dead_zone"], 50.0, 1000.0
    t = np.arange(int(600 * fine)) / fine
    duty = 45.0 + 8.0 * np.sin(2 * np.pi * (0.05 + 0.004 * t) * t)  # a chirp through the cracking duty
    valve = lambda d: np.where(d > 45.3, 20.0 + 4.0 * (d - 45.3), 0.0)  # noqa: E731
    late = int(round(0.0263 * fine))
    flow = valve(np.concatenate([np.full(late, duty[0]), duty[:-late]]))
    every = int(fine / rate)
    rng = np.random.default_rng(5)
    sig = _sig(duty[::every], flow[::every] + rng.normal(0, 0.5, len(t[::every])), rate=rate)
    leads = [p["cracking_pct"] for p in dz.placed(sig, {"transport_delay": {"delay_s": 0.0263}})]
    assert min(leads) <= 45.3 <= max(leads)
    assert max(leads) - min(leads) < 0.2


def test_a_delays_error_is_searched_between_whole_samples():
    # a delay between whole samples interpolates its neighbours: the training error has a kink at each
    # whole sample, and each piece between them is searched on its own
    delay = VOCABULARY["transport_delay"]
    assert delay.pieces("delay_s", 0.011, 0.028, 50.0) == [(0.011, 0.02), (0.02, 0.028)]
    assert delay.pieces("delay_s", 0.021, 0.039, 50.0) == [(0.021, 0.039)]
    assert VOCABULARY["valve_dynamics"].pieces("tau_s", 0.011, 0.028, 50.0) == [(0.011, 0.028)]


def test_dead_zone_jump_between_two_samples_of_a_breath_shows_the_law():
    # breaths rising some 2 % per sample through a 42 % cracking duty, 30 ms late: the jump falls
    # between two samples of each rise, where a PI fitted without the law puts a steep opening of
    # its own, so the model before it predicts no flow where the law shuts the valve
    dz, chain = VOCABULARY["dead_zone"], {"transport_delay": {"delay_s": 0.03}}
    rng = np.random.default_rng(4)
    t = np.arange(30000) / 100.0
    phase, breath = t % 3.0, (t // 3.0).astype(int)
    peak = rng.uniform(30.0, 40.0, breath[-1] + 1)[breath]  # each rise sampled at other duties
    duty = np.where(phase < 1.0, 30 + peak * np.clip(phase / 0.2, 0, 1), 30.0)

    def late(q):
        return fx.delayed(q, 100.0, 0.03)

    cracking = np.where(duty <= 42, 0.0, (duty - 35) * 4)  # 28 L/min at once
    absorbed = late(cracking)  # the model before it: the jump as a steep opening of its PI
    sig = _sig(duty, absorbed + rng.normal(0, 0.5, len(t)))
    assert dz.support(sig, {"cracking_pct": 42.0}, absorbed, 0.5, chain) is None
    # a valve opening by itself at 42 %, steeply but from zero flow: no jump, no cracking duty
    steep = late(np.clip((duty - 42) * 20, 0, None))
    sig = _sig(duty, steep + rng.normal(0, 0.5, len(t)))
    assert dz.support(sig, {"cracking_pct": 42.0}, steep, 0.5, chain) is not None
    # nor at any duty of a valve opening by itself at 38 %
    smooth = late(np.clip((duty - 38) * 4, 0, None))
    sig = _sig(duty, smooth + rng.normal(0, 0.5, len(t)))
    assert not any(dz._opens_with_jump(sig, {"cracking_pct": c}, chain) for c in np.arange(32.0, 60.0, 0.5))


def _holds(levels, rows=300):
    """A duty holding each of ``levels`` (%) for ``rows`` rows, in order."""
    return np.repeat(np.asarray(levels, float), rows)


def test_dead_zone_grid_is_one_point_per_set_of_shut_rows():
    # held levels 1 % apart, wider than the grid's step over the span: no two grid points shut the
    # same rows, and every gap between two levels up to 80 % of the span has one
    rng = np.random.default_rng(4)
    levels = rng.permutation(np.arange(40.0, 72.0, 1.0))
    duty = _holds(levels, 50)
    grid = VOCABULARY["dead_zone"].grid(_sig(duty, np.zeros(len(duty))), None)["cracking_pct"]
    shut = [int(np.sum(duty <= c)) for c in grid]
    assert len(set(shut)) == len(shut)
    for level in np.arange(40.0, 40.0 + 0.8 * 31.0 - 1.0, 1.0):
        assert np.any((grid > level) & (grid < level + 1.0))


def test_dead_zone_cracking_settles_over_shut_held_levels():
    # shut held levels above a cracking duty set too low (a PI censored at zero closes by itself
    # over them) move it up to the last of them; a continuous excitation leaves it where the fit put it
    dz = VOCABULARY["dead_zone"]
    duty = _holds([50.0, 56.8, 60.0, 58.8, 59.0, 62.0, 54.0, 64.0])
    flow = np.where(duty <= 58.8, 0.0, 100.0 + 5.0 * (duty - 59.0))
    flow = flow + np.random.default_rng(5).normal(0, 0.5, len(duty))
    settled = dz.settle(_sig(duty, flow), {"cracking_pct": 55.0}, {})["cracking_pct"]
    assert 58.8 < settled < 59.0
    ramp = np.r_[np.linspace(30, 70, 2000), np.linspace(70, 30, 2000)]
    closing = np.clip((ramp - 35) * 4, 0, None)  # a valve closing by itself at 35 %
    assert dz.settle(_sig(ramp, closing), {"cracking_pct": 33.0}, {}) == {"cracking_pct": 33.0}


def test_dead_zone_cracking_is_set_midway_between_the_training_rows_that_place_it():
    # breaths rising a few per cent per sample cross the cracking duty between two rows: any cracking
    # duty between the highest shut training row and the lowest open one fits them alike, and a
    # holdout row inside that gap is predicted right most often from its middle
    dz = VOCABULARY["dead_zone"]
    rng = np.random.default_rng(7)
    rise = np.concatenate([np.r_[np.full(20, 42.0), 42.0 + np.arange(1, 12) * rng.uniform(1.5, 2.0)]
                           for _ in range(40)])
    flow = np.where(rise > 46.7, 50.0 + 2.0 * (rise - 46.7), 0.0) + rng.normal(0, 0.5, len(rise))
    train = np.arange(len(rise)) % 5 != 0
    top = float(np.min(rise[train & (rise > 46.7)])) - 1e-6  # the fit's choice at the top of the gap
    at = dz.midway(_sig(rise, flow), {"cracking_pct": top}, {}, train)["cracking_pct"]
    shut, opened = rise[train & (rise <= at)], rise[train & (rise > at)]
    assert np.max(shut) < 46.7 < np.min(opened)
    assert at == pytest.approx(0.5 * (np.max(shut) + np.min(opened)))
    # the holdout rows do not place it
    hold_only = dz.midway(_sig(rise, flow), {"cracking_pct": at}, {}, ~train)["cracking_pct"]
    assert hold_only != at


def test_behind_a_time_response_the_cracking_duty_stays_where_the_fit_put_it():
    # behind a lag the rows after each crossing place the cracking duty (the lagged flow of the row
    # opened one sample later); the midway setting, which the rows at the valve cannot tell from the
    # fit's, moved those lagged openings on holdout rows. Without the lag it is moved to the middle
    from models.diagnose.design import fit_baseline
    from models.diagnose.detectors import _midway
    from models.diagnose.folds import make_folds

    rng = np.random.default_rng(7)
    rise = np.concatenate([np.r_[np.full(40, 42.0), 42.0 + np.arange(1, 30) * rng.uniform(1.0, 1.5)]
                           for _ in range(60)])
    flow = np.where(rise > 46.7, 50.0 + 2.0 * (rise - 46.7), 0.0) + rng.normal(0, 0.5, len(rise))
    sig = _sig(rise, flow, rate=50.0)
    folds = make_folds(sig.t_s)
    base = fit_baseline(sig, folds)
    x = sig.duty_pct[folds.train]
    top = float(np.min(x[x > 46.7])) - 1e-6  # the fit's choice at the top of the gap
    lag = {"valve_dynamics": {"tau_s": 0.04, "phase": 1.0}}
    assert _midway("dead_zone", lag, {"cracking_pct": top}, base, sig, folds) == {"cracking_pct": top}
    assert _midway("dead_zone", {}, {"cracking_pct": top}, base, sig, folds)["cracking_pct"] < top


def test_coil_rise_beyond_copper_is_named_with_a_caveat():
    coil = VOCABULARY["coil_heating"]
    assert coil.caveat({"rise55_k": 30.0, "tau_s": 100.0}) is None
    assert coil.implausible({"rise55_k": 150.0}) is None
    assert "more than a coil's copper" in coil.caveat({"rise55_k": 150.0, "tau_s": 100.0})
    # a measured temperature is the coil's own: no caveat on the rise it shows
    assert coil.caveat({"copper_law_ratio": 1.0, "rise55_k": 150.0}) is None


def test_saturation_needs_the_flow_to_flatten():
    sat = VOCABULARY["saturation"]
    duty = np.linspace(40, 70, 3000)
    before = (duty - 35) * 5  # up to 175 L/min
    flat = np.minimum(before, 150.0)
    assert sat.support(_sig(duty, flat), {"full_open_lpm": 150.0}, before, 0.5) is None
    assert "does not flatten" in sat.support(_sig(duty, before), {"full_open_lpm": 150.0}, before, 0.5)


def test_saturation_bounds_the_flow_everywhere():
    # a loading curve that only bends over its top (the model before it too steep there) is near a
    # clip at its median, but rises on past it: no full-open flow bounds it
    sat = VOCABULARY["saturation"]
    duty = np.linspace(40, 70, 3000)
    before = (duty - 35) * 5  # up to 175 L/min
    bent = np.where(before > 150.0, 150.0 + 0.2 * (before - 150.0), before)
    assert "exceeds the full-open flow" in sat.support(_sig(duty, bent), {"full_open_lpm": 150.0}, before, 0.5)
    # a clip with the noise of the sensor on it is one
    noisy = np.minimum(before, 150.0) + 0.5 * np.random.default_rng(1).normal(size=len(duty))
    assert sat.support(_sig(duty, noisy), {"full_open_lpm": 150.0}, before, 0.5) is None


def test_a_clip_held_against_a_model_file_holds_the_flow_where_the_model_rises():
    # a model file is flat above its identified range (full open at 155 L/min from 66 % duty): a clip
    # holds the measured flow where the model still rises past it; a flow that rises with the model
    # under its plateau is a level there, and one a noise's width under it cannot be told from a misfit
    sat = VOCABULARY["saturation"]
    duty = np.linspace(40, 75, 3500)
    rng = np.random.default_rng(2)
    model = np.minimum((duty - 35) * 5, 155.0)
    for full_open in (140.0, 152.5):
        clipped = np.minimum(model, full_open) + rng.normal(0, 0.5, len(duty))
        assert sat.support(_sig(duty, clipped), {"full_open_lpm": full_open}, model, 0.5, fixed=True) is None
    level = model - 2.5 + rng.normal(0, 0.5, len(duty))
    assert "rises with it" in sat.support(_sig(duty, level), {"full_open_lpm": 152.5}, model, 0.5, fixed=True)
    near = np.minimum(model, 154.0) + rng.normal(0, 1.0, len(duty))
    assert "at most 1" in sat.support(_sig(duty, near), {"full_open_lpm": 154.0}, model, 1.0, fixed=True)
    # a PI fitted on the recording bends into a plateau it sees: no claim of its own to test
    assert sat.support(_sig(duty, level), {"full_open_lpm": 152.5}, model, 0.5) is None


def test_thermal_fit_recovers_the_heating_law_from_a_measured_temperature():
    rate = 10.0
    duty = np.r_[np.full(3000, 60.0), np.full(3000, 45.0)]
    rise = fx.coil_temperature_rise(duty, rate, 150.0, 25.0, 0.0)
    p = thermal_fit(_sig(duty, np.zeros(len(duty)), rate, temp=22.0 + rise))
    assert p["rise55_k"] == pytest.approx(25.0, rel=0.01)
    assert p["tau_s"] == pytest.approx(150.0, rel=0.01)
    assert p["ambient_c"] == pytest.approx(22.0, abs=0.05)


def test_closed_loop_recording_keeps_its_longest_running_stretch():
    n = 100
    state = ["safe"] * 10 + ["running"] * 30 + ["fault"] * 5 + ["running"] * 50 + ["safe"] * 5
    duty = np.r_[np.full(10, 3.0), np.arange(10.0, 100.0)]  # the safe duty before the run
    rec = Recording("<run>", {"t_s": np.arange(n) / 10.0, "duty_pct": duty, "flow_lpm": 2 * duty}, {"state": state})
    cut, rest = running_rows(rec)
    assert rest == 3.0
    # the longest stretch (rows 45-94), each duty paired with the flow the next step measured
    assert len(cut) == 49 and cut.t_s[0] == pytest.approx(4.6)
    np.testing.assert_array_equal(cut.flow_lpm, 2 * (cut.duty_pct + 1))
    plain = Recording("<open>", rec.columns)
    same, rest = running_rows(plain)
    assert same is plain and rest is None
    with pytest.raises(InputError, match="running"):
        running_rows(Recording("<x>", rec.columns, {"state": ["safe"] * n}))


def test_decision_trace_is_data_the_report_words():
    d = Decision("creep", 0, 0.01, 0.03, 2, 3, 6, 4, "linearized", BELOW_MARGIN)
    assert d.to_dict()["outcome"] == BELOW_MARGIN
    assert "-1.00 %" in explain(d) and "needs below -3.00 %" in explain(d)



def test_asymmetry_must_explain_the_residual_where_its_widening_is_largest():
    # loops of varying amplitude; the correction of a descending branch widened with the input level
    # (the PI refitted with and without it). A residual that is that correction is supported, beside a
    # slow drift of another law too; a residual the correction follows everywhere but where it is
    # largest (another law's, which a held-out gain alone takes for the widening) is refused
    asym = VOCABULARY["asymmetric_hysteresis"]
    t = np.arange(30000) / 100.0
    x = (0.4 + 0.6 * np.abs(np.sin(2 * np.pi * t / 97.0))) * (2.0 * np.abs((t / 7.0) % 2.0 - 1.0) - 1.0)
    duty = 55.0 + 15.0 * x
    r = np.linspace(0.0, 0.6, 12)
    sym, gen = fx.generalized_play(r, x, 0.0, 0.0), fx.generalized_play(r, x, 0.0, 0.3)
    y = 100.0 + 80.0 * gen @ np.exp(-r / 0.2) / np.exp(-r / 0.2).sum()

    def pi(ops):
        A = np.column_stack([ops, np.ones(len(t))])
        return A @ np.linalg.lstsq(A, y, rcond=None)[0]

    before, after = pi(sym), pi(gen)
    delta = after - before
    largest = np.abs(delta) >= np.quantile(np.abs(delta), 0.9)
    noise = np.random.default_rng(3).normal(0.0, 0.5, len(t))
    drift = 2.0 * (before - 100.0) / 80.0 * (1.0 - np.exp(-t / 120.0))
    params = {"widen": 1e-3, "lift": 0.3}
    for resid in (delta, delta + drift):
        assert asym.support(_sig(duty, before + resid + noise), params, before, 0.5, after_lpm=after) is None
    elsewhere = np.where(largest, 0.0, delta)
    why = asym.support(_sig(duty, before + elsewhere + noise), params, before, 0.5, after_lpm=after)
    assert "where its correction is largest" in why


@given(tau=st.floats(0.002, 0.3), phase=st.sampled_from([0.0, 0.5, 1.0]), delay=st.floats(0.001, 0.2),
       rate=st.sampled_from([50.0, 100.0, 200.0]))
@settings(max_examples=30, deadline=None)
def test_lateness_is_the_first_moment_of_the_time_response(tau, phase, delay, rate):
    from models.diagnose.detectors import split, without

    impulse = np.zeros(int(rate * (40 * tau + delay)) + 50)
    impulse[10] = 1.0
    k = (np.arange(len(impulse)) - 10) / rate
    lag, late = VOCABULARY["valve_dynamics"], VOCABULARY["transport_delay"]
    for word, p in ((lag, {"tau_s": tau, "phase": phase}), (late, {"delay_s": delay})):
        h = word.dynamics(impulse, rate, p)
        assert word.lateness_s(p, rate) == pytest.approx(k @ h / h.sum(), abs=1e-9)
        assert word.with_lateness(p, word.lateness_s(p, rate), rate) == pytest.approx(p, rel=1e-9)
    # a delay beside a named lag takes its share of the lag's lateness, and gives it back when it goes
    chain = {"saturation": {"full_open_lpm": 120.0}, "valve_dynamics": {"tau_s": tau, "phase": phase}}
    sig = _sig(np.full(100, 50.0), np.zeros(100), rate)
    whole = lag.lateness_s(chain["valve_dynamics"], rate)
    shared = split("transport_delay", {"delay_s": delay}, chain, sig, None)
    # the lag as it was, then at each phase of its grid, each as far as it can be made that early
    phases = [phase] + list(lag.grid(sig, None)["phase"])
    assert [s["valve_dynamics"]["phase"] for s in shared] == [p for p in phases if delay + p / rate < whole]
    for s in shared:
        assert lag.lateness_s(s["valve_dynamics"], rate) + delay == pytest.approx(whole, rel=1e-9)
        # without the delay: the lag with its own share only, or made as late as the two were
        kept, back = without({**s, "transport_delay": {"delay_s": delay}}, "transport_delay", rate)
        assert kept == s and list(back) == list(chain) and back["saturation"] == chain["saturation"]
        assert lag.lateness_s(back["valve_dynamics"], rate) == pytest.approx(whole, rel=1e-9)
    if delay + phase / rate < whole:  # the lag as it was: given the delay's share back, it is as it was
        assert without({**shared[0], "transport_delay": {"delay_s": delay}}, "transport_delay", rate)[-1][
            "valve_dynamics"] == pytest.approx(chain["valve_dynamics"], rel=1e-6)


def test_an_asymmetrys_other_reading_is_every_threshold_lifted_by_its_size():
    # a widening in proportion to each threshold and a lift of every threshold both widen the top of the
    # loop: the other reading of the same extra width (on the loop of the PI fitted without the law) is
    # the lift alone, with the widening in proportion held at its lower bound while the two laws on the
    # valve's input are refined jointly
    from types import SimpleNamespace

    from models.diagnose.design import major_loop_half_width

    asym = VOCABULARY["asymmetric_hysteresis"]
    r = np.linspace(0.0, 0.6, 12)
    w = np.exp(-r / 0.2)
    w /= w.sum()
    # (a valve never seen shut: no reading from its opening)
    base = SimpleNamespace(shape=SimpleNamespace(r=r), lift_w=w, shut=lambda sig: np.zeros(len(sig.duty_pct), bool))
    h = major_loop_half_width(r, w)
    sig = _sig(np.full(100, 50.0), np.zeros(100))
    params = {"widen": 1.5, "lift": 0.2 * h, "start": 0.1}
    ((other, held),) = asym.readings(params, sig, base, {})
    assert held == ("widen",)
    assert other["widen"] == asym.bounds(sig, base)["widen"][0]
    assert other["start"] == params["start"]
    assert other["widen"] + other["lift"] / h == pytest.approx(1.7, rel=0.01)
    # the linearized law has no other reading; nor has a word with one law on the input
    assert asym.readings({}, sig, base, {}) == []
    assert VOCABULARY["coil_heating"].readings({"rise55_k": 30.0, "tau_s": 180.0}, sig, base, {}) == []

