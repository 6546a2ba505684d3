"""The discrete Preisach model: relay responses, wiping-out, congruency, NNLS recovery, numerical inverse."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from models.fitting import fit_model
from models.model import load_model, save_model
from models.preisach import (PreisachModel, fit_preisach, grid, levels, relaxed_state, relay_response,
                             relay_response_numpy, solve_input)
from tests.conftest import growing_sine


def known(n_h=10, seed=0) -> PreisachModel:
    rng = np.random.default_rng(seed)
    alpha, beta = grid(n_h)
    # A Preisach density heavier near the diagonal, as for a valve with narrow loops.
    mu = rng.uniform(0.0, 1.0, len(alpha)) * np.exp(-3.0 * (alpha - beta)) / len(alpha)
    return PreisachModel(alpha=alpha, beta=beta, mu=mu, offset=0.1)


def test_grid_is_the_papers_triangle():
    alpha, beta = grid(50)
    assert len(alpha) == 1275 and np.all(alpha >= beta)
    np.testing.assert_allclose(levels(4), [-0.75, -0.25, 0.25, 0.75])


def test_single_relay_switches_at_alpha_and_beta_and_holds_between():
    relay = PreisachModel(alpha=[0.5], beta=[-0.2], mu=[1.0])
    x = np.array([0.0, 0.4, 0.5, 0.1, -0.2, -0.21, 0.3, 0.49, 0.6, -1.0])
    y, _ = relay.predict(x, np.array([-1], dtype=np.int8))
    np.testing.assert_array_equal(y, [-1, -1, 1, 1, 1, -1, -1, -1, 1, -1])


def test_relaxed_state_is_split_by_the_line_alpha_plus_beta_equals_2x0():
    alpha, beta = grid(20)
    for x0 in (-0.3, 0.0, 0.55):
        g = relaxed_state(alpha, beta, x0)
        assert np.all(g[alpha <= x0] == 1) and np.all(g[beta > x0] == -1)
        between = (beta <= x0) & (alpha > x0)
        np.testing.assert_array_equal(g[between] == 1, (alpha + beta)[between] < 2 * x0)


@settings(max_examples=40, deadline=None)
@given(x=arrays(np.float64, st.integers(1, 200), elements=st.floats(-1.2, 1.2)), n_h=st.integers(1, 12))
def test_compiled_relays_equal_the_plain_loop(x, n_h):
    alpha, beta = grid(n_h)
    s0 = relaxed_state(alpha, beta, x[0])
    np.testing.assert_array_equal(relay_response(alpha, beta, x, s0), relay_response_numpy(alpha, beta, x, s0))
    m = PreisachModel(alpha, beta, np.linspace(0.1, 1, len(alpha)), 0.2)
    y, _ = m.predict(x, s0)
    np.testing.assert_allclose(y, relay_response_numpy(alpha, beta, x, s0) @ m.mu + 0.2, atol=1e-12)


def test_wiping_out_a_new_extremum_erases_the_history_it_dominates():
    m = known()
    tail = np.concatenate([np.linspace(0.2, 0.9, 30), np.linspace(0.9, -0.6, 50), np.linspace(-0.6, 0.3, 30)])
    # Two histories with different extrema, all inside [-0.6, 0.9] reached by the tail.
    ha = np.concatenate([np.linspace(0.0, 0.7, 20), np.linspace(0.7, -0.5, 30), np.linspace(-0.5, 0.2, 20)])
    hb = np.concatenate([np.linspace(0.0, -0.4, 20), np.linspace(-0.4, 0.5, 30), np.linspace(0.5, 0.2, 20)])
    ya, sa = m.predict(np.concatenate([ha, tail]))
    yb, sb = m.predict(np.concatenate([hb, tail]))
    assert not np.allclose(ya[len(ha):len(ha) + 10], yb[len(hb):len(hb) + 10])  # the histories show at first
    # From the dominating maximum on, every relay with alpha <= 0.9 is up, the rest untouched: same outputs.
    np.testing.assert_allclose(ya[len(ha) + 29:], yb[len(hb) + 29:], atol=1e-12)
    np.testing.assert_array_equal(sa, sb)


def test_minor_loops_between_the_same_extrema_are_congruent():
    m = known()
    loop = np.concatenate([np.linspace(0.05, 0.45, 40), np.linspace(0.45, 0.05, 40)[1:]])
    hist_a = np.concatenate([np.linspace(0, 1.0, 60), np.linspace(1.0, 0.05, 60)])
    hist_b = np.concatenate([np.linspace(0, -0.8, 60), np.linspace(-0.8, 0.7, 60), np.linspace(0.7, 0.05, 60)])
    ya, _ = m.predict(np.concatenate([hist_a, loop[1:], loop[1:]]))
    yb, _ = m.predict(np.concatenate([hist_b, loop[1:], loop[1:]]))
    la, lb = ya[-len(loop):], yb[-len(loop):]
    np.testing.assert_allclose(la - la[0], lb - lb[0], atol=1e-12)
    assert np.ptp(la) > 0 and abs(la[0] - lb[0]) > 1e-6  # real loops, at different heights


def rich_input(n=6000, seed=1):
    """Sweeps of every amplitude around moving centres plus a random walk: separates the relays."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    x = np.sin(2 * np.pi * 40 * k / n) * (0.1 + 0.9 * k / n) + 0.3 * np.sin(2 * np.pi * 3 * k / n)
    walk = np.clip(np.cumsum(rng.normal(0, 0.08, n)), -1, 1)
    return np.clip(np.concatenate([x, walk]), -1, 1)


def test_fit_recovers_a_known_model_from_its_own_output():
    truth = known()
    x = rich_input()
    y, _ = truth.predict(x)
    fit = fit_preisach(x, y, n_h=10)
    assert np.all(fit.mu >= 0)
    other = 0.95 * np.sin(np.linspace(0, 11 * np.pi, 2000)) * np.linspace(1, 0.2, 2000)
    yt, _ = truth.predict(other)
    yf, _ = fit.predict(other)
    np.testing.assert_allclose(yf, yt, atol=1e-6 * np.ptp(yt))


def test_chunked_prediction_and_step_equal_whole():
    m = known()
    x = rich_input(300)
    whole, _ = m.predict(x)
    a, s = m.predict(x[:100])
    b, _ = m.predict(x[100:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), whole, atol=1e-14)
    s = m.init(x[0])
    for k in range(30):
        s, yk = m.step(s, x[k])
        assert yk == pytest.approx(whole[k], abs=1e-12)


def test_params_and_model_file_round_trip_exactly(tmp_path):
    duty = growing_sine()
    t = np.arange(len(duty)) * 0.05
    flow = 100 + 80 * known().predict((duty - 55) / 17)[0]
    model = fit_model("preisach", t, duty, flow)
    back = PreisachModel.from_params(json.loads(json.dumps(model.core.to_params())))
    np.testing.assert_array_equal(back.mu, model.core.mu)
    save_model(model, tmp_path / "m.json")
    np.testing.assert_array_equal(load_model(tmp_path / "m.json").predict(duty)[0], model.predict(duty)[0])


# -- the numerical inverse (feedforward) --------------------------------------

def _level(m: PreisachModel, g: np.ndarray, x: float) -> float:
    """The weighted sum after input ``x`` from relay states ``g``, by the plain numpy relay update."""
    return float(m.mu @ relay_response_numpy(m.alpha, m.beta, np.array([x]), g)[0])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=8), st.floats(-1.5, 1.5))
def test_inverse_gives_the_reachable_level_nearest_the_target(history, target):
    """Every level one more sample can reach is the level at some switching level (or just below
    one, or a range end): the inverse's input gives the one nearest the target."""
    m = known()
    g = m.init(history[0])
    for x in history:
        g = relay_response_numpy(m.alpha, m.beta, np.array([x]), g)[0]
    x = solve_input(m.alpha, m.beta, m.mu, g, target, -1.0, 1.0)
    assert -1.0 <= x <= 1.0
    inputs = np.concatenate([m.alpha, np.nextafter(m.beta, -np.inf), m.beta, [-1.0, 1.0]])
    reachable = [_level(m, g, u) for u in inputs[(inputs >= -1.0) & (inputs <= 1.0)]]
    assert abs(_level(m, g, x) - target) == pytest.approx(min(abs(v - target) for v in reachable), abs=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=8), st.integers(0, 2**31))
@example([1.0], 100000000)  # every relay up, those above 0.9 of no weight: the top level's interval is wide
@example([-1.0], 100000000)  # and every relay down: the bottom level's
def test_inverse_is_continuous_and_non_decreasing_in_the_target(history, seed):
    """Also across each level's value (where it maps to the middle of the level's interval) and
    halfway between two (where it crosses the step), with relays of no weight among them (they
    switch nothing the output sees)."""
    truth = known()
    mu = truth.mu * (np.random.default_rng(seed).random(len(truth.mu)) > 0.3)
    m = PreisachModel(alpha=truth.alpha, beta=truth.beta, mu=mu)
    g = m.init(history[0])
    for x in history:
        g = relay_response_numpy(m.alpha, m.beta, np.array([x]), g)[0]
    levels_ = np.array(sorted({_level(m, g, u) for u in np.concatenate([m.alpha, np.nextafter(m.beta, -np.inf)])}))
    edges = np.concatenate([levels_, 0.5 * (levels_[1:] + levels_[:-1])])  # each level, and halfway to the next
    targets = np.sort(np.concatenate([np.linspace(-1.2, 1.2, 400), edges, edges + 1e-12, edges - 1e-12]))
    x = np.array([solve_input(m.alpha, m.beta, m.mu, g, t, -1.0, 1.0) for t in targets])
    assert np.all(np.diff(x) >= 0.0)
    close = np.diff(targets) <= 1e-12
    assert np.max(np.diff(x)[close], initial=0.0) < 1e-6


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=60))
def test_forward_of_inverse_reproduces_every_output_of_the_model(x):
    """The model's own outputs are levels: the inverse finds each exactly, and its relays follow."""
    m = known()
    y, _ = m.predict(np.array(x))
    state = m.init(x[0])
    x_back, _ = m.inverse().predict(y, state)
    y_back, _ = m.predict(x_back, state)
    np.testing.assert_allclose(y_back, y, atol=1e-12)


def test_inverse_beyond_the_levels_asks_for_the_range_ends():
    m = known()
    inv = m.inverse()
    top, _ = m.predict(np.array([1.0]), m.init(0.0))
    x, _ = inv.predict(np.array([top[0] + 0.5, -5.0]), m.init(0.0))
    np.testing.assert_array_equal(x, [1.0, -1.0])


def test_negative_weights_have_no_inverse():
    m = known()
    bad = PreisachModel(alpha=m.alpha, beta=m.beta, mu=-m.mu, offset=0.0)
    assert not bad.invertible
    with pytest.raises(ValueError, match="not invertible"):
        bad.inverse()


def test_feedforward_inverts_the_relays_as_the_models_inverse_does():
    """controller.laws.feedforward: the loop's inverse from the memory the forward model keeps."""
    from controller.laws import feedforward as ffw
    from models.model import FittedModel
    from models.preprocess import Scaling

    core = known()
    model = FittedModel("preisach", core, Scaling(55.0, 17.0), Scaling(98.0, 86.0), inverse=core.inverse())
    duty = 55.0 + 16.0 * np.sin(np.linspace(0.0, 14.0, 300)) * np.linspace(0.2, 1.0, 300)
    flow, _ = model.predict(duty)
    bank = ffw.bank(model, batch=2)
    s = ffw.init(bank, duty[0])
    inv_state = core.init((duty[0] - 55.0) / 17.0)
    for k in range(len(duty)):
        inv_state, expected = model.inverse.step(inv_state, (flow[k] - 98.0) / 86.0)
        u = ffw.invert(bank, s, np.full(2, flow[k]))
        np.testing.assert_allclose(u, 55.0 + 17.0 * expected, rtol=0, atol=1e-9)
        s, q = ffw.step(bank, s, u)
        np.testing.assert_allclose(q, flow[k], atol=1e-9)  # the model's outputs are levels it reaches exactly
