"""Kuhnen's modified PI (models/pi_mod.py): dead-zone superposition, exact inverse, fit, model file."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models import pi_mod
from models.model import FittedModel, load_model, save_model
from models.pi import thresholds
from models.preprocess import Scaling
from tests import oracles


def valve_like(n: int = 10, seed: int = 0) -> pi_mod.ModifiedPIModel:
    """An invertible modified PI with a near-flat bottom (dead zone) and top (saturation)."""
    rng = np.random.default_rng(seed)
    w = np.concatenate([[0.5], rng.uniform(0.0, 0.08, n)])
    h = pi_mod.dead_zone_thresholds(-0.9, 0.9, 3)
    sigma = np.array([0.01, 0.3, 0.8, 1.0, 1.2, 0.4, 0.02])  # slopes: flat ends, steeper middle
    g = pi_mod._slopes_to_weights(h, sigma)
    return pi_mod.ModifiedPIModel(r=thresholds(n), w=w, h=h, g=g, offset=0.1, floor=-0.6)


MODEL = valve_like()


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=30))
def test_dead_zone_superposition_is_kuhnens_sum_and_its_inverse_undoes_it(z):
    z = np.array(z)
    h, g = MODEL.h, MODEL.g
    np.testing.assert_allclose(pi_mod.apply_dead_zone(h, g, z), oracles.dead_zone_numpy(h, g, z), atol=1e-12)
    h_inv, g_inv = pi_mod.invert_dead_zone(h, g)
    back = pi_mod.apply_dead_zone(h_inv, g_inv, pi_mod.apply_dead_zone(h, g, z))
    np.testing.assert_allclose(back, z, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=60))
def test_forward_of_inverse_is_the_identity_above_the_closed_flow(x):
    """Any reachable output above the closed level: the inverse's input gives it back (exact, Kuhnen)."""
    y, _ = MODEL.predict(np.array(x))
    inv = MODEL.inverse()
    state = MODEL.init(x[0])
    x_back, _ = inv.predict(y, state)
    y_back, _ = MODEL.predict(x_back, state)
    live = y > inv.closed
    np.testing.assert_allclose(y_back[live], y[live], atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=60))
def test_inverse_of_forward_gives_the_input_back_where_the_valve_passes_flow(x):
    x = np.array(x)
    y, _ = MODEL.predict(x)
    inv = MODEL.inverse()
    x_back, _ = inv.predict(y, MODEL.init(x[0]))
    live = y > inv.closed
    np.testing.assert_allclose(x_back[live], x[live], atol=1e-9)


def test_inverse_in_the_dead_zone_gives_the_closed_valve():
    """A closed valve (output at or below the closed level) gives the bottom of the input range."""
    inv = MODEL.inverse()
    x, _ = inv.predict(np.array([MODEL.floor, inv.closed, MODEL.floor - 1.0]), MODEL.init(0.3))
    np.testing.assert_array_equal(x, inv.x_closed)


def test_inverse_at_saturation_asks_for_the_top_of_the_range():
    """Near full opening the model is nearly flat, yet the full-open flow inverts to the top exactly."""
    inv = MODEL.inverse()
    rise = np.linspace(-1.0, 1.0, 50)
    y, _ = MODEL.predict(rise)
    before_top = MODEL.predict(rise[:-1])[1]
    x, _ = inv.predict(y[-1:], before_top)
    assert x[0] == pytest.approx(1.0, abs=1e-9)
    more, _ = inv.predict(y[-1:] + 0.01, before_top)  # more than the valve can pass: beyond the top
    assert more[0] > 1.0


def test_fit_recovers_a_modified_pi_and_its_dead_zone():
    x = np.concatenate([np.linspace(-1, 1, 400), np.linspace(1, -1, 400), np.linspace(-1, 0.4, 300),
                        np.linspace(0.4, -0.2, 200), np.linspace(-0.2, 1, 300)])
    y, _ = MODEL.predict(x)
    fit = pi_mod.fit_pi_mod(x, y, n=10, k=3)
    assert fit.invertible
    pred, _ = fit.predict(x)
    assert np.sqrt(np.mean((pred - y) ** 2)) < 0.02 * np.ptp(y)


def test_model_file_round_trip(tmp_path):
    m = FittedModel("pi-mod", MODEL, Scaling(50.0, 50.0), Scaling(68.0, 68.0), inverse=MODEL.inverse())
    save_model(m, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    duty = np.array([0.0, 40.0, 80.0, 55.0, 100.0])
    np.testing.assert_array_equal(back.predict(duty)[0], m.predict(duty)[0])
    np.testing.assert_array_equal(back.inverse_predict([10.0, 60.0])[0], m.inverse_predict([10.0, 60.0])[0])


def test_compare_reports_each_invertible_kinds_inverse_on_measured_flow():
    """DESIGN.md compare JSON: models.KIND.inverse.on_measured_flow for invertible kinds, rows >= 2 L/min."""
    from models.compare import compare_response
    from models.recording import Recording

    t = np.arange(3000) / 10.0
    duty = 50.0 + 45.0 * np.sin(2 * np.pi * t / 60.0) * np.minimum(t / 100.0, 1.0)
    m = FittedModel("pi-mod", MODEL, Scaling(50.0, 50.0), Scaling(68.0, 68.0), inverse=MODEL.inverse())
    flow, _ = m.predict(duty)
    rec = Recording("synthetic", {"t_s": t, "duty_pct": duty, "flow_lpm": flow})
    out = compare_response(rec, kinds=("pi", "pi-mod", "bouc-wen")).to_json()["models"]
    assert "inverse" not in out["bouc-wen"]
    for kind in ("pi", "pi-mod"):
        assert set(out[kind]["inverse"]["on_measured_flow"]) == {"duty_mae_pct", "duty_rmse_pct", "r"}
    # the kind that made the flow inverts it best
    assert out["pi-mod"]["inverse"]["on_measured_flow"]["duty_mae_pct"] < out["pi"]["inverse"]["on_measured_flow"]["duty_mae_pct"]
