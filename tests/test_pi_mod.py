"""The modified PI (models/pi_mod.py): dead-zone superposition, exact inverse, fit, model file.

Every property is held for Kuhnen's model (Eq. 1 plays, ``a = 0``, closed-form inverse) and for
the generalized one (descending envelope ``a > 0``, plays inverted per sample to rounding).
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models import pi_mod
from models.model import FittedModel, load_model, save_model
from models.pi import thresholds
from models.preprocess import Scaling
from tests import oracles


def valve_like(n: int = 10, seed: int = 0, a: float = 0.0, p: float = 1.0) -> pi_mod.ModifiedPIModel:
    """An invertible modified PI with a near-flat bottom (dead zone) and top (saturation);
    non-negative weights keep every falling slope positive whatever the envelope."""
    rng = np.random.default_rng(seed)
    w = np.concatenate([[0.5], rng.uniform(0.0, 0.08, n)])
    h = pi_mod.dead_zone_thresholds(-0.9, 0.9, 3)
    sigma = np.array([0.01, 0.3, 0.8, 1.0, 1.2, 0.4, 0.02])  # slopes: flat ends, steeper middle
    g = pi_mod._slopes_to_weights(h, sigma)
    return pi_mod.ModifiedPIModel(r=thresholds(n), w=w, h=h, g=g, offset=0.1, floor=-0.6, a=a, p=p)


MODEL = valve_like()
GENERALIZED = valve_like(a=3.0, p=2.0)
BOTH = pytest.mark.parametrize("model", [MODEL, GENERALIZED], ids=["kuhnen", "generalized"])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=30))
def test_dead_zone_superposition_is_kuhnens_sum_and_its_inverse_undoes_it(z):
    z = np.array(z)
    h, g = MODEL.h, MODEL.g
    np.testing.assert_allclose(pi_mod.apply_dead_zone(h, g, z), oracles.dead_zone_numpy(h, g, z), atol=1e-12)
    h_inv, g_inv = pi_mod.invert_dead_zone(h, g)
    back = pi_mod.apply_dead_zone(h_inv, g_inv, pi_mod.apply_dead_zone(h, g, z))
    np.testing.assert_allclose(back, z, atol=1e-9)


@BOTH
@settings(max_examples=40, deadline=None)
@given(x=st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=60))
def test_forward_of_inverse_is_the_identity_above_the_closed_flow(model, x):
    """Any reachable output above the closed level: the inverse's input gives it back (exact, Kuhnen)."""
    y, _ = model.predict(np.array(x))
    inv = model.inverse()
    state = model.init(x[0])
    x_back, _ = inv.predict(y, state)
    y_back, _ = model.predict(x_back, state)
    live = y > inv.closed
    np.testing.assert_allclose(y_back[live], y[live], atol=1e-9)


@BOTH
@settings(max_examples=40, deadline=None)
@given(x=st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=60))
def test_inverse_of_forward_gives_the_input_back_where_the_valve_passes_flow(model, x):
    x = np.array(x)
    y, _ = model.predict(x)
    inv = model.inverse()
    x_back, _ = inv.predict(y, model.init(x[0]))
    live = y > inv.closed
    np.testing.assert_allclose(x_back[live], x[live], atol=1e-9)


@BOTH
def test_inverse_in_the_dead_zone_gives_the_closed_valve(model):
    """A closed valve (output at or below the closed level) gives the bottom of the input range."""
    inv = model.inverse()
    x, _ = inv.predict(np.array([model.floor, inv.closed, model.floor - 1.0]), model.init(0.3))
    np.testing.assert_array_equal(x, inv.x_closed)


@BOTH
def test_inverse_at_saturation_asks_for_the_top_of_the_range(model):
    """Near full opening the model is nearly flat, yet the full-open flow inverts to the top exactly."""
    inv = model.inverse()
    rise = np.linspace(-1.0, 1.0, 50)
    y, _ = model.predict(rise)
    before_top = model.predict(rise[:-1])[1]
    x, _ = inv.predict(y[-1:], before_top)
    assert x[0] == pytest.approx(1.0, abs=1e-9)
    more, _ = inv.predict(y[-1:] + 0.01, before_top)  # more than the valve can pass: beyond the top
    assert more[0] > 1.0


def test_the_envelope_widens_the_descending_branch_more_at_the_top():
    """a > 0: coming down from the top the output holds longer than Kuhnen's (pi-asym's envelope)."""
    down = np.linspace(1.0, -1.0, 201)
    rise = np.linspace(-1.0, 1.0, 201)
    for m in (MODEL, GENERALIZED):
        assert m.predict(rise)[0][-1] == pytest.approx(MODEL.predict(rise)[0][-1], abs=1e-12)  # same rising
    top = MODEL.predict(rise)[1]
    y_k, _ = MODEL.predict(down, top)
    y_g, _ = GENERALIZED.predict(down, top)
    assert np.all(y_g >= y_k - 1e-12) and np.max(y_g - y_k) > 0.01


X_FIT = np.concatenate([np.linspace(-1, 1, 400), np.linspace(1, -1, 400), np.linspace(-1, 0.4, 300),
                        np.linspace(0.4, -0.2, 200), np.linspace(-0.2, 1, 300), np.linspace(1, -0.5, 300)])


def test_fit_recovers_a_modified_pi_and_its_dead_zone():
    y, _ = MODEL.predict(X_FIT)
    fit = pi_mod.fit_pi_mod(X_FIT, y, n=10, k=3, envelope=(0.0, 1.0))
    assert fit.invertible and fit.a == 0.0
    pred, _ = fit.predict(X_FIT)
    assert np.sqrt(np.mean((pred - y) ** 2)) < 0.02 * np.ptp(y)


def test_fit_is_never_worse_in_sample_than_the_pi_or_the_asymmetric_pi():
    """Both are among the candidates (S the identity), so the kept fit's error is at most theirs."""
    from models.pi import fit_pi
    from models.pi_asym import fit_pi_asym

    y, _ = GENERALIZED.predict(X_FIT)
    fit = pi_mod.fit_pi_mod(X_FIT, y, n=10, k=3)
    assert fit.invertible

    def sse(m):
        return float(np.sum((m.predict(X_FIT)[0] - y) ** 2))

    assert sse(fit) <= sse(fit_pi(X_FIT, y, n=10)) * (1 + 1e-9)
    assert sse(fit) <= sse(fit_pi_asym(X_FIT, y, n=10)) * (1 + 1e-9)
    assert np.sqrt(sse(fit) / len(y)) < 0.02 * np.ptp(y)


@BOTH
def test_model_file_round_trip(tmp_path, model):
    m = FittedModel("pi-mod", model, Scaling(50.0, 50.0), Scaling(68.0, 68.0), inverse=model.inverse())
    save_model(m, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    duty = np.array([0.0, 40.0, 80.0, 55.0, 100.0])
    np.testing.assert_array_equal(back.predict(duty)[0], m.predict(duty)[0])
    np.testing.assert_array_equal(back.inverse_predict([10.0, 60.0])[0], m.inverse_predict([10.0, 60.0])[0])


def test_a_model_file_without_the_envelope_is_kuhnens(tmp_path):
    """Files written before the envelope keys existed load as Eq. (1) plays (a = 0)."""
    m = FittedModel("pi-mod", MODEL, Scaling(50.0, 50.0), Scaling(68.0, 68.0), inverse=MODEL.inverse())
    save_model(m, tmp_path / "m.json")
    doc = json.loads((tmp_path / "m.json").read_text())
    for part in (doc["params"], doc["inverse"]["params"]["forward"]):
        del part["a"], part["p"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    back = load_model(tmp_path / "old.json")
    assert back.core.a == 0.0 and back.core.exact
    duty = np.array([0.0, 40.0, 80.0, 55.0, 100.0])
    np.testing.assert_array_equal(back.predict(duty)[0], m.predict(duty)[0])


@BOTH
def test_feedforward_is_the_models_inverse_and_returns_the_duty(model):
    """The loop's feedforward (controller.laws.feedforward) inverts the model as the model's own inverse does."""
    from controller.laws import feedforward as ffw

    m = FittedModel("pi-mod", model, Scaling(50.0, 50.0), Scaling(68.0, 68.0), inverse=model.inverse())
    bank = ffw.bank(m)
    assert bank.method[0] == (0 if model.exact else 1)
    duty = 50.0 + 45.0 * np.sin(np.linspace(0.0, 9.0, 120)) * np.linspace(0.3, 1.0, 120)
    s = ffw.init(bank, duty[0])
    for d in duty:
        flow = ffw.step(bank, s, np.array([d]))[1][0]
        if flow > (model.inverse().closed + 1e-6) * 68.0 + 68.0:
            assert ffw.invert(bank, s, np.array([flow]))[0] == pytest.approx(d, abs=1e-7)
        s, _ = ffw.step(bank, s, np.array([d]))


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
