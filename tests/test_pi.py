"""The PI model, Eq. (1)-(4): thresholds, fitting, invertibility, congruency, model files."""
from __future__ import annotations

import json

import numpy as np
import pytest

from models.fitting import evaluate, fit_model, fit_recording
from models.model import FittedModel, load_model, save_model
from models.pi import PIModel, fit_pi, regressors, thresholds
from models.preprocess import preprocess
from models.recording import InputError, Recording, read_recording
from tests.conftest import growing_sine


def known_pi(n=10, seed=0) -> PIModel:
    rng = np.random.default_rng(seed)
    r = thresholds(n)
    w = np.concatenate([[0.6], rng.uniform(0.0, 0.1, n)])
    return PIModel(r=r, w=w, offset=0.1)


def test_thresholds_follow_eq2_after_a_zero_threshold():
    r = thresholds(50, x_max=2.0)
    assert r[0] == 0.0 and len(r) == 51
    np.testing.assert_allclose(r[1:], np.arange(1, 51) / 51 * 2.0)


def test_fit_recovers_a_known_pi_from_its_own_output():
    truth = known_pi()
    x = np.sin(np.linspace(0, 12 * np.pi, 3000)) * np.linspace(0.2, 1.0, 3000)
    x /= np.max(np.abs(x))  # Eq. (2) scales thresholds by max|x|: match the truth's
    y, _ = truth.predict(x)
    fit = fit_pi(x, y, n=10)
    np.testing.assert_allclose(fit.w, truth.w, atol=1e-6)
    assert fit.offset == pytest.approx(truth.offset, abs=1e-6)


def test_constrained_fit_keeps_loading_slopes_positive_where_plain_least_squares_does_not():
    # A falling (anti-monotone) relation cannot be fit with positive slopes: the constraint must bind.
    x = np.sin(np.linspace(0, 8 * np.pi, 2000))
    y = -x + 0.05 * np.sign(np.cos(np.linspace(0, 8 * np.pi, 2000)))
    free = fit_pi(x, y, n=10, constrained=False)
    bound = fit_pi(x, y, n=10, constrained=True)
    assert not free.invertible
    assert bound.invertible and np.all(bound.loading_slopes() >= 1e-3 - 1e-12)


def test_minor_loops_between_the_same_extrema_are_congruent():
    # PI property: loops between the same input extrema have the same shape, whatever the history.
    pi = known_pi()
    loop = np.concatenate([np.linspace(0.1, 0.5, 50), np.linspace(0.5, 0.1, 50)[1:], np.linspace(0.1, 0.5, 50)[1:]])
    hist_a = np.concatenate([np.linspace(0, 1.0, 60), np.linspace(1.0, 0.1, 60)])
    hist_b = np.concatenate([np.linspace(0, -0.8, 60), np.linspace(-0.8, 0.9, 60), np.linspace(0.9, 0.1, 60)])
    ya, _ = pi.predict(np.concatenate([hist_a, loop[1:]]))
    yb, _ = pi.predict(np.concatenate([hist_b, loop[1:]]))
    la, lb = ya[-len(loop) + 1:], yb[-len(loop) + 1:]
    # Congruent: equal up to a vertical shift.
    np.testing.assert_allclose(la - la[0], lb - lb[0], atol=1e-12)


def test_chunked_prediction_equals_whole():
    pi = known_pi()
    x = growing_sine(500) / 50 - 1
    whole, _ = pi.predict(x)
    a, s = pi.predict(x[:200])
    b, _ = pi.predict(x[200:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), whole, atol=1e-14)


def test_step_is_predict_of_one_sample():
    pi = known_pi()
    x = np.array([0.0, 0.3, -0.2, 0.5])
    s = pi.init(x[0])
    ys = []
    for xk in x:
        s, y = pi.step(s, xk)
        ys.append(y)
    np.testing.assert_allclose(ys, pi.predict(x)[0], atol=1e-14)


def test_model_file_round_trips_exactly(tmp_path):
    duty = growing_sine()
    t = np.arange(len(duty)) * 0.05
    pi = known_pi()
    flow = 100 + 80 * pi.predict((duty - 55) / 17)[0]
    model = fit_model("pi", t, duty, flow)
    save_model(model, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    np.testing.assert_array_equal(back.core.w, model.core.w)
    np.testing.assert_array_equal(back.core.r, model.core.r)
    np.testing.assert_array_equal(back.inverse.w, model.inverse.w)
    assert back.x_scale == model.x_scale and back.y_scale == model.y_scale
    np.testing.assert_array_equal(back.predict(duty)[0], model.predict(duty)[0])
    assert not list(tmp_path.glob("*.tmp*"))  # atomic write leaves no temporary


@pytest.mark.parametrize("content,words", [("{", "not valid JSON"), ("[]", "JSON object"),
                                           ('{"format": "other"}', "not a valvectl model"),
                                           ('{"format": "valvectl-model", "kind": "pi"}', "version: missing")])
def test_bad_model_file_is_one_line(tmp_path, content, words):
    p = tmp_path / "bad.json"
    p.write_text(content)
    with pytest.raises(InputError, match=words):
        load_model(p)


def test_a_model_file_records_the_supply_it_was_identified_at(bench_identification):
    rec = read_recording(bench_identification)
    model = fit_recording("pi", rec)
    assert model.meta["supply_bar"] == pytest.approx(float(np.mean(rec.columns["supply_bar"])))
    without = Recording(rec.path, {k: v for k, v in rec.columns.items() if k != "supply_bar"})
    assert "supply_bar" not in fit_recording("pi", without).meta


def test_fit_on_bench_is_no_worse_than_plain_least_squares_of_the_paper(bench_identification):
    rec = read_recording(bench_identification)
    ours = evaluate(fit_recording("pi", rec), rec.duty_pct, rec.flow_lpm)
    # Plain: Eq. (2) thresholds only (no zero threshold, no offset), unconstrained least squares,
    # on the same preprocessed and normalized data.
    model = fit_recording("pi", rec)
    pre = preprocess(rec.t_s, rec.duty_pct, rec.flow_lpm)
    xu, yu = model.x_scale.to_unit(pre.x), model.y_scale.to_unit(pre.y)
    r = thresholds(50, float(np.max(np.abs(xu))))[1:]
    w, *_ = np.linalg.lstsq(regressors(r, xu), yu, rcond=None)
    plain = PIModel(r=r, w=w)
    pred = model.y_scale.from_unit(plain.predict(model.x_scale.to_unit(rec.duty_pct))[0])
    plain_mae = float(np.mean(np.abs(pred - rec.flow_lpm)))
    assert ours.mae <= plain_mae
    assert np.isfinite(ours.rmse) and ours.r > 0.99
