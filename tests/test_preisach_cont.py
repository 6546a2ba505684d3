"""The continuous Preisach model: Everett evaluation, reversal curves, wiping-out, congruency, recovery."""
from __future__ import annotations

import json

import numpy as np
import pytest

from models.fitting import fit_model
from models.model import load_model, save_model
from models.recording import InputError
from models.preisach_cont import (STACK, ContinuousPreisachModel, _everett, fit_preisach_cont, relaxed_state,
                                  reversal_curves)
from tests.conftest import growing_sine


def quadratic_everett(alpha, beta, k=0.5):
    """Everett function of a uniform density k on the triangle: k (alpha - beta)^2 / 2."""
    return np.where(alpha > beta, 0.5 * k * (alpha - beta) ** 2, 0.0)


def known(n=40, k=0.5, offset=0.1) -> ContinuousPreisachModel:
    g = np.linspace(-1, 1, n + 1)
    A, B = np.meshgrid(g, g, indexing="ij")
    # A density growing with alpha: the loops are not point-symmetric.
    return ContinuousPreisachModel(everett=quadratic_everett(A, B, k) * (1.2 + 0.3 * A), offset=offset)


def test_everett_is_bilinear_on_the_mesh_and_zero_off_the_triangle():
    n = 8
    g = np.linspace(-1, 1, n + 1)
    A, B = np.meshgrid(g, g, indexing="ij")
    E = np.where(A > B, 2.0 + 0.5 * A - 0.25 * B + 0.1 * A * B, 0.0)
    rng = np.random.default_rng(0)
    for a, b in rng.uniform(-1, 1, (200, 2)):
        cell = lambda v: int(min((v + 1) / 2 * n, n - 1))  # noqa: E731
        if cell(b) + 1 < cell(a):  # a cell fully inside the triangle: the function is bilinear there
            assert _everett(E, a, b) == pytest.approx(2.0 + 0.5 * a - 0.25 * b + 0.1 * a * b, abs=1e-12)
        if a <= b:
            assert _everett(E, a, b) == 0.0


def test_descending_reversal_curve_falls_by_twice_the_everett_function():
    m = known()
    up = np.linspace(-1.0, 0.6, 81)  # from negative saturation up to the reversal at 0.6
    down = np.linspace(0.6, -0.6, 61)[1:]
    y, _ = m.predict(np.concatenate([[-1.0], up, down]), relaxed_state(-1.0, m.n_mesh))
    y_r = y[len(up)]
    expected = [2 * _everett(m.everett, 0.6, b) for b in down]
    np.testing.assert_allclose(y_r - y[len(up) + 1:], expected, atol=1e-12)


def test_reversal_curves_read_the_everett_function_back():
    m = known()
    x = (growing_sine(3000) - 55) / 17
    x /= np.max(np.abs(x))
    y, _ = m.predict(x)
    cv = reversal_curves(x, y, m.n_mesh)
    assert cv.reversals > 10
    truth = np.array([_everett(m.everett, a, b) for a, b in zip(cv.alpha, cv.beta)])
    np.testing.assert_allclose(cv.everett, truth, atol=1e-10)


def test_wiping_out_a_new_extremum_erases_the_history_it_dominates():
    m = known()
    tail = np.concatenate([np.linspace(0.2, 0.9, 30), np.linspace(0.9, -0.6, 50), np.linspace(-0.6, 0.3, 30)])
    ha = np.concatenate([np.linspace(0.0, 0.7, 20), np.linspace(0.7, -0.5, 30), np.linspace(-0.5, 0.2, 20)])
    hb = np.concatenate([np.linspace(0.0, -0.4, 20), np.linspace(-0.4, 0.5, 30), np.linspace(0.5, 0.2, 20)])
    ya, sa = m.predict(np.concatenate([ha, tail]))
    yb, sb = m.predict(np.concatenate([hb, tail]))
    assert not np.allclose(ya[len(ha):len(ha) + 10], yb[len(hb):len(hb) + 10])
    np.testing.assert_allclose(ya[len(ha) + 29:], yb[len(hb) + 29:], atol=1e-12)
    np.testing.assert_array_equal(sa[:3 + int(sa[2])], sb[:3 + int(sb[2])])  # the same staircase


def test_minor_loops_between_the_same_extrema_are_congruent():
    m = known()
    loop = np.concatenate([np.linspace(0.05, 0.45, 40), np.linspace(0.45, 0.05, 40)[1:]])
    hist_a = np.concatenate([np.linspace(0, 1.0, 60), np.linspace(1.0, 0.05, 60)])
    hist_b = np.concatenate([np.linspace(0, -0.8, 60), np.linspace(-0.8, 0.7, 60), np.linspace(0.7, 0.05, 60)])
    ya, _ = m.predict(np.concatenate([hist_a, loop[1:], loop[1:]]))
    yb, _ = m.predict(np.concatenate([hist_b, loop[1:], loop[1:]]))
    la, lb = ya[-len(loop):], yb[-len(loop):]
    np.testing.assert_allclose(la - la[0], lb - lb[0], atol=1e-12)
    assert np.ptp(la) > 0 and abs(la[0] - lb[0]) > 1e-6


def test_fit_recovers_a_known_model_from_its_reversal_curves():
    truth = known()
    k = np.arange(6000)
    # Growing then shrinking sinusoids around moving centres: reversal curves over the whole triangle.
    env = np.concatenate([np.linspace(0.05, 1.2, 3000), np.linspace(1.2, 0.05, 3000)])  # reaches both ends
    x = np.clip(env * np.sin(2 * np.pi * 30 * k / 6000) + 0.2 * np.sin(2 * np.pi * 2.5 * k / 6000), -1, 1)
    y, _ = truth.predict(x)
    fit = fit_preisach_cont(x, y, n_mesh=40)
    other = 0.9 * np.sin(np.linspace(0, 9 * np.pi, 1500)) * np.linspace(1, 0.3, 1500)
    yt, _ = truth.predict(other)
    yf, _ = fit.predict(other)
    assert np.sqrt(np.mean((yf - yt) ** 2)) < 0.01 * np.ptp(yt)


def test_deep_nesting_beyond_the_stack_stays_finite_and_bounded():
    m = known()
    amp = 0.9 * 0.995 ** np.arange(2 * STACK)
    x = amp * np.where(np.arange(2 * STACK) % 2 == 0, 1.0, -1.0)
    y, s = m.predict(np.concatenate([[0.0], x]))
    assert np.all(np.isfinite(y)) and int(s[2]) <= STACK
    lo, _ = m.predict(np.array([-1.0, -1.0]), relaxed_state(-1.0, m.n_mesh))
    hi, _ = m.predict(np.array([-1.0, 1.0]), relaxed_state(-1.0, m.n_mesh))
    assert np.all((y >= lo[0] - 1e-9) & (y <= hi[1] + 1e-9))


def test_chunked_prediction_and_step_equal_whole():
    m = known()
    x = (growing_sine(400) - 55) / 17
    whole, _ = m.predict(x)
    a, s = m.predict(x[:150])
    b, _ = m.predict(x[150:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), whole, atol=1e-13)
    s = m.init(x[0])
    for k in range(20):
        s, yk = m.step(s, x[k])
        assert yk == pytest.approx(whole[k], abs=1e-13)


def test_params_and_model_file_round_trip_exactly(tmp_path):
    duty = growing_sine(2000)
    t = np.arange(len(duty)) * 0.05
    flow = 100 + 60 * known().predict((duty - 55) / 17)[0]
    model = fit_model("preisach-cont", t, duty, flow)
    back = ContinuousPreisachModel.from_params(json.loads(json.dumps(model.core.to_params())))
    np.testing.assert_array_equal(back.everett, model.core.everett)
    save_model(model, tmp_path / "m.json")
    np.testing.assert_array_equal(load_model(tmp_path / "m.json").predict(duty)[0], model.predict(duty)[0])


def test_a_recording_without_reversals_is_refused_in_one_line():
    x = np.linspace(-1, 1, 200)
    with pytest.raises(InputError, match="reversal curves"):
        fit_preisach_cont(x, x**3)
