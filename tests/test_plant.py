"""The simulated valve: forward model, sensor, and each effect moving the flow the way physics says."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from models.fitting import evaluate, fit_model
from models.model import FittedModel
from models.pi import PIModel
from models.recording import InputError
from plant_sim.effects import EFFECTS
from plant_sim.kernel import normal
from plant_sim.plant import PLANT_KINDS, BatchPlant, Plant, load_plant
from plant_sim.protocols import paper_identification, sines

RATE = 100.0


@pytest.fixture(scope="module")
def clean():
    """The default plant without sensor noise or quantization: the physics alone."""
    return load_plant(noise_lpm=0.0, scale_factor=0.0)


@pytest.fixture(scope="module")
def default():
    return load_plant()


def hold_steps(*segments, rate=RATE):
    """Duty held at each ``(duty, seconds)`` in turn."""
    return np.concatenate([np.full(int(round(s * rate)), d, dtype=float) for d, s in segments])


def true_flow(params, duty, rate=RATE, seed=0):
    return Plant(params, rate, seed).simulate(duty)["true_flow_lpm"]


# -- forward model and sensor --------------------------------------------------

def test_default_plant_has_no_effects(default):
    assert default.effects == {}
    assert default.model.kind == "pi"


def test_effect_free_plant_is_the_fitted_model(clean):
    duty = sines(RATE, 60.0)  # within the identified range
    expected, _ = clean.model.predict(duty)
    np.testing.assert_allclose(true_flow(clean, duty), expected, rtol=0, atol=1e-9)  # to rounding


@pytest.fixture(scope="module")
def family_models(bench_identification):
    """Every kind, fitted on the first 600 s of the identification recording."""
    from models.recording import read_recording

    rec = read_recording(bench_identification)
    rows = rec.t_s < 600.0
    return {kind: fit_model(kind, rec.t_s[rows], rec.duty_pct[rows], rec.flow_lpm[rows]) for kind in PLANT_KINDS}


@pytest.mark.parametrize("kind", PLANT_KINDS)
def test_every_kind_as_plant_reproduces_its_own_predict(clean, family_models, kind):
    model = family_models[kind]
    duty = np.concatenate([sines(RATE, 30.0), paper_identification(RATE)[:3000]])
    duty = np.clip(duty, model.x_scale.center - model.x_scale.half_range, model.x_scale.center + model.x_scale.half_range)
    expected, _ = model.predict(duty)
    np.testing.assert_allclose(true_flow(clean.replace(model=model), duty), np.maximum(expected, 0.0), rtol=0, atol=1e-9)


def test_a_pi_mod_with_the_descending_envelope_as_plant_reproduces_its_own_predict(clean):
    """pi-mod's generalized plays (a > 0) run in the plant kernel as in the model."""
    from models.preprocess import Scaling
    from tests.test_pi_mod import GENERALIZED

    model = FittedModel("pi-mod", GENERALIZED, Scaling(55.0, 17.0), Scaling(98.0, 86.0))
    duty = np.clip(np.concatenate([sines(RATE, 30.0), paper_identification(RATE)[:3000]]), 38.0, 72.0)
    expected, _ = model.predict(duty)
    np.testing.assert_allclose(true_flow(clean.replace(model=model), duty), np.maximum(expected, 0.0), rtol=0, atol=1e-9)


def test_batch_of_mixed_kinds_is_each_plant_alone_bit_for_bit(family_models):
    params = [load_plant().replace(model=m, valve_dynamics=0.02, transport_delay=0.013, asymmetric_hysteresis=0.3)
              for m in family_models.values()]
    duty = np.concatenate([sines(RATE, 20.0), np.full(200, 30.0), sines(RATE, 10.0)])
    B = len(params)
    batch = BatchPlant(params, RATE, range(4, 4 + B)).simulate(np.broadcast_to(duty, (B, len(duty))))
    assert len(params) == len(PLANT_KINDS)
    for b, p in enumerate(params):
        alone = Plant(p, RATE, seed=4 + b).simulate(duty)
        for col in ("flow_lpm", "true_flow_lpm"):
            assert np.array_equal(batch[col][b], alone[col])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 100.0), min_size=2, max_size=40))
def test_flow_is_never_negative_and_closed_at_zero_duty(clean, levels):
    duty = np.repeat(np.asarray(levels), 5)
    q = true_flow(clean, np.append(duty, 0.0))
    assert np.all(q >= 0.0)
    assert q[-1] == 0.0


def test_sensor_noise_quantization_and_range(default):
    duty = sines(RATE, 60.0)
    cols = Plant(default, RATE, seed=3).simulate(duty)
    err = cols["flow_lpm"] - cols["true_flow_lpm"]
    assert abs(np.std(err) / default.noise_lpm - 1.0) < 0.05
    counts = cols["flow_lpm"] * default.scale_factor
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    capped = Plant(default.replace(range_lpm=(-250.0, 100.0)), RATE, seed=3).simulate(duty)
    assert capped["flow_lpm"].max() == 100.0


def test_noise_is_standard_normal():
    from scipy import stats
    key = np.uint64(0x1234567890ABCDEF)
    z = np.array([normal(key, k) for k in range(200_000)])
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01
    assert stats.kstest(z, "norm").pvalue > 1e-3
    # the ziggurat's tail path: P(|z| > 3.5) = 4.65e-4
    assert 0.5 < np.mean(np.abs(z) > 3.5) / 4.65e-4 < 1.5


def test_fixed_seed_reproduces_bit_for_bit(default):
    duty = sines(RATE, 20.0)
    p = default.replace(supply_pressure=0.1, coil_heating=30.0, creep=0.05)
    a = Plant(p, RATE, seed=7).simulate(duty)
    b = Plant(p, RATE, seed=7).simulate(duty)
    c = Plant(p, RATE, seed=8).simulate(duty)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["flow_lpm"], c["flow_lpm"])


def all_effects(p):
    return p.replace(**{name: e.default for name, e in EFFECTS.items()})


def test_stepping_equals_simulate_and_step_is_pure(default):
    p = all_effects(default)
    duty = sines(RATE, 5.0)
    plant = Plant(p, RATE, seed=2)
    whole = plant.simulate(duty)
    state = plant.init(duty[0])
    flows = []
    for d in duty:
        before = [a.copy() for a in state[1:]]
        new, out = plant.step(state, d)
        assert all(np.array_equal(a, b) for a, b in zip(before, state[1:]))  # the old state is untouched
        assert plant.step(state, d)[1] == out  # same state and input, same output
        state = new
        flows.append(out.flow_lpm)
    assert np.array_equal(np.array(flows), whole["flow_lpm"])


def test_chunks_chain_like_lfilter(default):
    p = all_effects(default)
    duty = sines(RATE, 10.0)
    bp = BatchPlant(p, RATE, seed=4)
    s0 = bp.init(duty[0])
    _, whole = bp.run(s0, duty)
    s1, first = bp.run(s0, duty[:333])
    _, second = bp.run(s1, duty[333:])
    assert np.array_equal(np.concatenate([first["flow_lpm"], second["flow_lpm"]], axis=1), whole["flow_lpm"])


def test_batch_agrees_with_single_plants(default):
    other = FittedModel("pi", PIModel(default.model.core.r, 0.9 * default.model.core.w,
                                      default.model.core.offset), default.model.x_scale, default.model.y_scale)
    plants = [default, all_effects(default), default.replace(transport_delay=0.037, valve_dynamics=0.05,
                                                             dynamics_order=2),
              default.replace(model=other, dead_zone=40.0)]
    duty = np.stack([sines(RATE, 10.0), paper_identification(RATE, 10.0),
                     sines(RATE, 10.0, amplitude_pct=5.0), np.full(1000, 50.0)])
    batch = BatchPlant(plants, RATE, seed=10).simulate(duty)
    for i, p in enumerate(plants):
        single = Plant(p, RATE, seed=10 + i).simulate(duty[i])
        for k in ("flow_lpm", "true_flow_lpm", "supply_bar", "coil_temp_c"):
            assert np.array_equal(batch[k][i], single[k]), (i, k)


# -- effects -----------------------------------------------------------------------

def test_warmer_coil_gives_less_flow_at_the_same_duty(clean):
    rate, heat = 1.0, 40.0
    duty = hold_steps((60.0, 1800.0), rate=rate)
    cols = Plant(clean.replace(coil_heating=heat), rate).simulate(duty)
    temp, q = cols["coil_temp_c"], cols["true_flow_lpm"]
    assert np.all(np.diff(temp) > 0) and np.all(np.diff(q) < 0)
    # first order towards ambient + heat (d/55)^2, time constant coil_tau_s
    rise = heat * (60.0 / 55.0) ** 2
    t = np.arange(len(duty)) / rate
    assert np.allclose(temp, clean.ambient_c + rise * (1.0 - np.exp(-t / clean.coil_tau_s)), atol=1e-9)
    # the current falls with R = R0 (1 + alpha dT): a cold valve at duty / (1 + alpha dT),
    # reached by the same monotone descent, gives the same flow
    d_eff = 60.0 / (1.0 + clean.coil_alpha_per_k * (temp[-1] - clean.ambient_c))
    assert q[-1] == pytest.approx(true_flow(clean, hold_steps((60.0, 1.0), (d_eff, 1.0)))[-1], rel=1e-12)


def test_higher_supply_gives_more_flow(clean):
    duty = sines(RATE, 20.0)
    q3 = true_flow(clean, duty)
    q4 = true_flow(clean.replace(supply_bar=4.0), duty)
    ratio = (4.0 + clean.atmosphere_bar) / (clean.model_supply_bar + clean.atmosphere_bar)
    assert np.allclose(q4, q3 * ratio, rtol=1e-12)  # choked flow ∝ absolute upstream pressure


def test_supply_wander_moves_flow_with_it(clean):
    duty = hold_steps((55.0, 120.0))
    p = clean.replace(supply_pressure=0.2)
    cols = Plant(p, RATE, seed=5).simulate(duty)
    q0 = true_flow(clean, duty)
    abs_ratio = (cols["supply_bar"] + p.atmosphere_bar) / (p.model_supply_bar + p.atmosphere_bar)
    assert np.allclose(cols["true_flow_lpm"], q0 * abs_ratio, rtol=1e-12)
    assert np.std(cols["supply_bar"]) > 0.01


def test_supply_droops_with_flow(clean):
    p = clean.replace(supply_pressure=1e-9)  # droop on, wander negligible
    duty = hold_steps((45.0, 2.0), (70.0, 2.0))
    cols = Plant(p, RATE).simulate(duty)
    q, s = cols["true_flow_lpm"], cols["supply_bar"]
    expected = p.supply_bar - p.droop_bar * (q[-2] / p.droop_ref_lpm) ** 2
    assert s[-1] == pytest.approx(expected, abs=1e-6)
    assert s[-1] < s[150]


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 60), st.sampled_from([20.0, 100.0, 1000.0]))
def test_delay_shifts_a_step_by_exactly_the_delay(clean, n, rate):
    duty = hold_steps((45.0, 0.5), (65.0, 0.5), rate=rate)
    q0 = true_flow(clean, duty, rate)
    q = true_flow(clean.replace(transport_delay=n / rate), duty, rate)
    assert np.array_equal(q[n:], q0[:-n])
    assert np.all(q[:n] == q0[0])


def test_fractional_delay_interpolates(clean):
    duty = hold_steps((45.0, 0.5), (65.0, 0.5))
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(transport_delay=2.25 / RATE), duty)
    k = 50 + 2  # the step at sample 50, two whole samples and a quarter late
    assert q[k - 1] == q0[0]
    assert q[k] == pytest.approx(q0[0] + 0.75 * (q0[-1] - q0[0]))
    assert q[k + 1] == q0[-1]


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 200), st.sampled_from([100.0, 1000.0]))
def test_first_order_lag_reaches_63_percent_at_tau(clean, n_tau, rate):
    tau = n_tau / rate
    duty = hold_steps((45.0, 0.2), (65.0, 12 * tau + 0.2), rate=rate)
    k0 = int(round(0.2 * rate))
    q0 = true_flow(clean, duty, rate)
    q = true_flow(clean.replace(valve_dynamics=tau), duty, rate)
    frac = (q - q0[0]) / (q0[-1] - q0[0])
    assert frac[k0 + n_tau] == pytest.approx(1.0 - math.exp(-1.0), abs=1e-9)
    assert np.all(np.diff(frac[k0:]) > -1e-12) and frac[-1] == pytest.approx(1.0, abs=1e-4)


def test_second_order_lag_is_critically_damped_with_total_lag_tau(clean):
    tau = 0.1
    duty = hold_steps((45.0, 0.2), (65.0, 2.0))
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(valve_dynamics=tau, dynamics_order=2), duty)
    frac = (q - q0[0]) / (q0[-1] - q0[0])
    # two poles at 2/tau: 1 - (1 + 2t/tau) exp(-2t/tau); at t = tau, 1 - 3 e^-2
    assert frac[20 + 10] == pytest.approx(1.0 - 3.0 * math.exp(-2.0), abs=1e-9)
    assert np.all(frac <= 1.0 + 1e-12)  # no overshoot


def test_dead_zone_keeps_the_valve_closed_below_cracking(clean):
    duty = hold_steps((41.0, 1.0), (43.0, 1.0), (60.0, 1.0), (41.5, 1.0))
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(dead_zone=42.0), duty)
    below = duty < 42.0
    assert np.all(q[below] == 0.0) and np.all(q0[below] > 0.0)
    assert np.array_equal(q[~below], q0[~below])


def test_saturation_caps_the_flow(clean):
    duty = sines(RATE, 30.0)
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(saturation=150.0), duty)
    assert q0.max() > 150.0 and q.max() == 150.0
    assert np.array_equal(q, np.minimum(q0, 150.0))


def test_sensor_offset_shifts_the_reading(default):
    duty = sines(RATE, 10.0)
    a = Plant(default, RATE, seed=1).simulate(duty)["flow_lpm"]
    b = Plant(default.replace(sensor_offset=2.5), RATE, seed=1).simulate(duty)["flow_lpm"]
    assert np.allclose(b - a, 2.5, atol=1.0 / default.scale_factor + 1e-9)


def test_asymmetric_hysteresis_widens_the_descending_branch_more_at_high_flow(clean):
    up = np.linspace(38.0, 72.0, 3000)
    duty = np.concatenate([up, up[::-1]])
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(asymmetric_hysteresis=1.0), duty)
    assert np.array_equal(q[:3000], q0[:3000])  # ascending branch from the bottom: unchanged
    gap = (q - q0)[3000:]
    assert np.all(gap >= -1e-9) and gap.max() > 1.0  # descending flow higher at the same duty
    mid = 3000 + np.searchsorted(-duty[3000:], -55.0)
    assert gap[: mid - 3000].mean() > 0.0
    # same descent from a lower top: the widening grows with flow, so the gap is smaller
    low = np.concatenate([np.linspace(38.0, 55.0, 1500), np.linspace(55.0, 38.0, 1500)])
    gap_low = (true_flow(clean.replace(asymmetric_hysteresis=1.0), low) - true_flow(clean, low))[1500:]
    assert gap_low.max() < gap.max()


def test_creep_relaxes_towards_a_fraction_of_the_last_reversal_step(clean):
    a, tau = 0.1, clean.creep_tau_s
    duty = hold_steps((45.0, 1.0), (65.0, 1.0), (55.0, 12 * tau))
    q0 = true_flow(clean, duty)
    q = true_flow(clean.replace(creep=a), duty)
    drift = q - q0
    assert np.all(drift[:200] == 0.0)  # no reversal yet
    step = q0[150] - q0[0]  # the last reversal-to-reversal flow step, 45 % -> 65 %
    assert drift[-1] == pytest.approx(a * step, rel=1e-4)
    assert np.all(np.diff(drift[201:]) >= 0.0)  # keeps drifting the way it went


# -- fitting and files --------------------------------------------------------------

def test_effect_free_recording_is_fit_by_the_pi_to_the_noise_level(default):
    rate = 20.0
    duty = paper_identification(rate, 600.0)
    cols = Plant(default, rate, seed=11).simulate(duty)
    model = fit_model("pi", cols["t_s"], duty, cols["flow_lpm"])
    m = evaluate(model, duty, cols["flow_lpm"])
    assert m.rmse < 1.1 * default.noise_lpm


def test_load_plant_rejects_bad_input(tmp_path):
    with pytest.raises(InputError, match="unknown"):
        load_plant(effects={"warp_drive": 1.0})
    with pytest.raises(InputError, match="effects.dead_zone: must be <= 100"):
        load_plant(effects={"dead_zone": 150.0})
    bad = tmp_path / "plant.toml"
    bad.write_text('model = "valve_model.json"\n[sensor]\nnoise = 1\n')
    with pytest.raises(InputError, match="sensor.noise"):
        load_plant(bad)
    bad.write_text("model = \n")
    with pytest.raises(InputError, match="TOML"):
        load_plant(bad)
    for ref in ("1e-300", "1e308"):  # squared by the droop: 0 and overflow
        bad.write_text(f'model = "valve_model.json"\n[supply]\ndroop_ref_lpm = {ref}\n')
        with pytest.raises(InputError, match="supply.droop_ref_lpm"):
            load_plant(bad)
