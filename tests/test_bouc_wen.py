"""The Bouc-Wen model: closed-form branches, closed loops, rate independence, fit recovery."""
from __future__ import annotations

import json

import numpy as np
import pytest

from models.bouc_wen import BoucWenModel, MAX_SUBSTEP, _hysteretic, fit_bouc_wen, hysteretic_naive
from models.fitting import fit_model
from models.model import load_model, save_model
from tests.conftest import growing_sine


def known(beta=2.0, gamma=0.5, n=1.5) -> BoucWenModel:
    return BoucWenModel(beta=beta, gamma=gamma, n=n, a=0.4, b=1.2, c=0.1)


def test_loading_and_unloading_follow_the_closed_form_for_n_equal_1():
    beta, gamma = 3.0, 1.0
    m = known(beta, gamma, 1.0)
    up = np.linspace(0.0, 0.8, 9)
    h_up, state = m.hysteretic(up)
    u = beta + gamma  # dh/dx = 1 - u h while loading (dx > 0, h > 0)
    np.testing.assert_allclose(h_up, (1 - np.exp(-u * up)) / u, rtol=1e-7)
    down = np.linspace(0.8, 0.62, 7)[1:]  # h stays positive (it crosses zero near x = 0.6)
    h_down, _ = m.hysteretic(down, state)
    v, h0 = beta - gamma, h_up[-1]  # dh/dx = 1 + v h while unloading (dx < 0, h > 0)
    np.testing.assert_allclose(h_down, ((1 + v * h0) * np.exp(v * (down - 0.8)) - 1) / v, rtol=1e-7)


def test_loop_closes_under_a_slow_sinusoid():
    # Started from h = 0 the first cycle is not closed; the loop then converges to a
    # closed limit cycle: the change from one period to the next shrinks towards zero.
    m = known()
    per = 2000
    t = np.linspace(0, 6, 6 * per, endpoint=False)
    x = 0.8 * np.sin(2 * np.pi * t)
    h, _ = m.hysteretic(x)
    drift = [np.max(np.abs(h[(k + 1) * per:(k + 2) * per] - h[k * per:(k + 1) * per])) for k in range(5)]
    assert all(b < a for a, b in zip(drift, drift[1:]))
    assert drift[-1] < 1e-6 * np.ptp(h)
    # A real loop: ascending and descending differ at the same input.
    last = h[-per:]
    assert abs(last[0] - last[per // 2]) > 0.05  # x = 0 rising and falling


def test_rate_independent_any_sampling_gives_the_same_output():
    m = known()
    x = 0.9 * np.sin(np.linspace(0, 6 * np.pi, 120)) * np.linspace(0.3, 1, 120)
    y, _ = m.predict(x)
    dense = np.interp(np.arange(0, 119.01, 0.125), np.arange(120), x)
    yd, _ = m.predict(dense)
    np.testing.assert_allclose(yd[::8], y, atol=1e-7)


def test_hysteretic_variable_stays_below_its_saturation():
    m = known()
    rng = np.random.default_rng(0)
    h, _ = m.hysteretic(np.clip(np.cumsum(rng.normal(0, 0.2, 3000)), -3, 3))
    assert np.max(np.abs(h)) <= (m.beta + m.gamma) ** (-1 / m.n) + 1e-9


def test_compiled_integration_equals_the_plain_loop():
    m = known()
    x = growing_sine(300) / 40 - 1.3
    h, _, _ = _hysteretic(x, x[0], 0.0, m.beta, m.gamma, m.n, MAX_SUBSTEP)
    np.testing.assert_allclose(h, hysteretic_naive(x, x[0], 0.0, m.beta, m.gamma, m.n), atol=1e-13)


def test_fit_recovers_a_known_model_from_its_own_output():
    truth = known()
    x = (growing_sine(3000) - 55) / 17
    y, _ = truth.predict(x)
    fit = fit_bouc_wen(x, y)
    other = 0.9 * np.sin(np.linspace(0, 7 * np.pi, 1000)) * np.linspace(1, 0.3, 1000)
    yt, _ = truth.predict(other)
    yf, _ = fit.predict(other)
    assert np.sqrt(np.mean((yf - yt) ** 2)) < 1e-4 * np.ptp(yt)


def test_chunked_prediction_and_step_equal_whole():
    m = known()
    x = (growing_sine(400) - 55) / 17
    whole, _ = m.predict(x)
    a, s = m.predict(x[:150])
    b, _ = m.predict(x[150:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), whole, atol=1e-14)
    s = m.init(x[0])
    for k in range(20):
        s, yk = m.step(s, x[k])
        assert yk == pytest.approx(whole[k], abs=1e-13)


def test_params_and_model_file_round_trip_exactly(tmp_path):
    duty = growing_sine(2000)
    t = np.arange(len(duty)) * 0.05
    flow = 100 + 60 * known().predict((duty - 55) / 17)[0]
    model = fit_model("bouc-wen", t, duty, flow)
    params = model.core.to_params()
    assert BoucWenModel.from_params(json.loads(json.dumps(params))).to_params() == params
    save_model(model, tmp_path / "m.json")
    np.testing.assert_array_equal(load_model(tmp_path / "m.json").predict(duty)[0], model.predict(duty)[0])
