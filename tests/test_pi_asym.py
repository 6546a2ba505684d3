"""The asymmetric (generalized) PI: single-operator responses, fit recovery, invertibility, inverse."""
from __future__ import annotations

import json

import control as ct
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import minimize

from models import play
from models.fitting import fit_model
from models.model import load_model, save_model
from models.pi import thresholds
from models.pi_asym import (AsymmetricPIModel, InverseAsymmetricPI, _compressed, _least_distance, envelope,
                             fit_pi_asym)
from tests.conftest import growing_sine


def single(r, a=0.0, p=1.0) -> AsymmetricPIModel:
    return AsymmetricPIModel(r=[r], w=[1.0], a=a, p=p)


def known(n=10, a=3.0, p=2.0, seed=0) -> AsymmetricPIModel:
    """A valve-like model: S-shaped loading (negative weights at large thresholds), invertible."""
    rng = np.random.default_rng(seed)
    w = np.concatenate([[0.5], rng.uniform(0.0, 0.08, n // 2), rng.uniform(-0.05, 0.0, n - n // 2)])
    return AsymmetricPIModel(r=thresholds(n), w=w, a=a, p=p, offset=0.05)


def sweep(n=3000):
    """Growing sinusoid with max|x| = 1 (Eq. 2 thresholds then match a known model's)."""
    x = (growing_sine(n) - 55.0) / 17.0
    return x / np.max(np.abs(x))


def test_without_widening_one_operator_is_python_controls_backlash():
    rng = np.random.default_rng(1)
    x = np.clip(np.cumsum(rng.normal(0, 0.05, 400)), -1, 1)
    b = 0.3
    nl = ct.friction_backlash_nonlinearity(b)
    ref = np.array([nl(xk) for xk in x])
    # python-control starts its backlash centred at 0: the relaxed state at x0 = 0.
    x = np.concatenate([[0.0], x])
    ref = np.concatenate([[0.0], ref])
    y, _ = single(b / 2).predict(x)
    np.testing.assert_allclose(y, ref, atol=1e-12)


def test_descending_threshold_widens_by_a_psi():
    r, a, p = 0.1, 2.0, 2.0
    up = np.linspace(-1, 0.8, 50)
    down = np.linspace(0.8, -1, 80)[1:]
    y, _ = single(r, a, p).predict(np.concatenate([up, down]))
    np.testing.assert_allclose(y[1:50], np.maximum(up[1:] - r, -1.0))  # rising: Eq. (1) lower edge
    top = 0.8 - r
    expected = np.minimum(top, down + r * (1 + a * envelope(down, p)))  # falling: widened upper edge
    np.testing.assert_allclose(y[50:], expected, atol=1e-12)
    # The widening holds the output longer than a symmetric play would.
    sym, _ = single(r).predict(np.concatenate([up, down]))
    assert np.all(y[50:] >= sym[50:] - 1e-15) and np.any(y[50:] > sym[50:] + 1e-3)


@settings(max_examples=40, deadline=None)
@given(x=arrays(np.float64, st.integers(2, 150), elements=st.floats(-1, 1)),
       a=st.floats(0, 10), p=st.floats(1, 6))
def test_compiled_bank_equals_a_plain_loop_and_zero_widening_is_the_play(x, a, p):
    m = known(6, a, p)
    Y, end = m.response(x)
    s = m.init(x[0])
    hi = 1 + a * envelope(x, p)
    for k, xk in enumerate(x):
        s = np.maximum(xk - m.r, np.minimum(xk + m.r * hi[k], s))
        np.testing.assert_allclose(Y[k], s, atol=1e-14)
        s = Y[k]  # follow the kernel: pow may round differently in numba
    np.testing.assert_allclose(m.predict(x)[0], Y @ m.w + m.offset, atol=1e-12)
    flat = AsymmetricPIModel(r=m.r, w=m.w, a=0.0)
    P, _ = play.play_response(m.r, x, np.full(len(m.r), x[0]))
    np.testing.assert_array_equal(flat.response(x)[0], P)


def test_rate_independent_denser_sampling_gives_the_same_outputs():
    m = known()
    x = sweep(400)
    dense = np.interp(np.arange(0, 399.01, 0.25), np.arange(400), x)
    y, _ = m.predict(x)
    yd, _ = m.predict(dense)
    np.testing.assert_allclose(yd[::4], y, atol=1e-12)


def test_minor_loops_between_the_same_extrema_are_congruent():
    # Each operator is, after one cycle, either wiped out by the loop or frozen:
    # loops between the same extrema differ only by a constant, as for the PI.
    m = known()
    loop = np.concatenate([np.linspace(0.1, 0.5, 50), np.linspace(0.5, 0.1, 50)[1:]])
    cycles = np.concatenate([loop, loop[1:], loop[1:]])
    hist_a = np.concatenate([np.linspace(0, 1.0, 60), np.linspace(1.0, 0.1, 60)])
    hist_b = np.concatenate([np.linspace(0, -0.8, 60), np.linspace(-0.8, 0.9, 60), np.linspace(0.9, 0.1, 60)])
    ya, _ = m.predict(np.concatenate([hist_a, cycles[1:]]))
    yb, _ = m.predict(np.concatenate([hist_b, cycles[1:]]))
    la, lb = ya[-len(loop):], yb[-len(loop):]
    np.testing.assert_allclose(la - la[0], lb - lb[0], atol=1e-12)
    assert ya[-1] == pytest.approx(ya[-len(loop)], abs=1e-12)  # and the loop closes


def test_chunked_prediction_and_step_equal_whole():
    m = known()
    x = sweep(500)
    whole, end = m.predict(x)
    a, s = m.predict(x[:200])
    b, s2 = m.predict(x[200:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), whole, atol=1e-14)
    st_ = m.init(x[0])
    for k in range(10):
        st_, yk = m.step(st_, x[k])
        assert yk == pytest.approx(whole[k], abs=1e-14)


def test_fit_recovers_a_known_model_from_its_own_output():
    truth = known()
    x = sweep()
    y, _ = truth.predict(x)
    fit = fit_pi_asym(x, y, n=10)
    # Judged on a different input than the one fitted.
    other = 0.9 * np.sin(np.linspace(0, 9 * np.pi, 1500)) * np.linspace(1, 0.3, 1500)
    yt, _ = truth.predict(other)
    yf, _ = fit.predict(other)
    assert np.sqrt(np.mean((yf - yt) ** 2)) < 1e-3 * np.ptp(yt)
    assert fit.a == pytest.approx(truth.a, rel=0.05) and fit.p == pytest.approx(truth.p, rel=0.05)


def test_fit_of_a_symmetric_recording_finds_little_widening():
    truth = known(a=0.0)
    x = sweep()
    y, _ = truth.predict(x)
    fit = fit_pi_asym(x, y, n=10)
    yf, _ = fit.predict(x)
    assert np.sqrt(np.mean((yf - y) ** 2)) < 1e-3 * np.ptp(y)


def test_fit_keeps_the_model_invertible_where_the_free_optimum_is_not():
    # A truth whose output falls back when the input falls at high level (falling
    # slope negative): least squares alone would return it; the constrained fit must not.
    r = thresholds(10)
    w = np.array([0.3, 0.05, 0.05, 0.0, 0.0, -0.1, -0.1, -0.05, 0.0, 0.0, 0.0])
    truth = AsymmetricPIModel(r=r, w=w, a=10.0, p=2.0)
    assert not truth.invertible
    x = sweep()
    y, _ = truth.predict(x)
    fit = fit_pi_asym(x, y, n=10, envelope=(10.0, 2.0))
    up, down = fit.slopes()
    assert fit.invertible and np.all(up >= 1e-3 * (1 - 1e-6)) and np.all(down >= 1e-3 * (1 - 1e-6))
    assert np.sqrt(np.mean((fit.predict(x)[0] - y) ** 2)) < 0.05 * np.ptp(y)  # still a fit


def test_least_distance_solver_matches_a_general_qp_solver():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(200, 6))
    b = rng.normal(size=200)
    C = rng.normal(size=(8, 6))
    d = C @ rng.normal(size=6) - 0.5  # feasible: a known point meets every constraint with margin
    t = _least_distance(*_compressed(A, b)[:2], C, d)
    H, g = A.T @ A, A.T @ b
    ref = minimize(lambda v: 0.5 * v @ H @ v - g @ v, np.zeros(6), jac=lambda v: H @ v - g, method="SLSQP",
                   constraints=[{"type": "ineq", "fun": lambda v: C @ v - d, "jac": lambda v: C}],
                   options={"ftol": 1e-15, "maxiter": 1000})
    assert np.all(C @ t >= d - 1e-9)
    np.testing.assert_allclose(t, ref.x, atol=1e-6)


@st.composite
def invertible_model(draw):
    n = draw(st.integers(1, 20))
    a = draw(st.floats(0, 15))
    p = draw(st.floats(1, 6))
    w = np.concatenate([[draw(st.floats(0.05, 1.0))], draw(arrays(np.float64, n, elements=st.floats(-0.3, 0.3)))])
    m = AsymmetricPIModel(r=thresholds(n), w=w, a=a, p=p, offset=draw(st.floats(-1, 1)))
    up, down = m.slopes()
    # Lift the zero-threshold weight until every rising and falling slope is positive.
    w[0] += max(0.0, 0.01 - min(up.min(), down.min()))
    return AsymmetricPIModel(r=m.r, w=w, a=a, p=p, offset=m.offset)


@settings(max_examples=80, deadline=None)
@given(m=invertible_model(), x=arrays(np.float64, st.integers(1, 200), elements=st.floats(-1, 1)))
def test_inverse_of_forward_is_identity(m, x):
    assert m.invertible
    fs = m.init(x[0])
    y, _ = m.predict(x, fs)
    inv = m.inverse()
    xr, _ = inv.predict(y, inv.init(y[0], forward_state=fs))
    np.testing.assert_allclose(xr, x, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(m=invertible_model(), x=arrays(np.float64, st.integers(1, 200), elements=st.floats(-1, 1)))
def test_forward_of_inverse_is_identity_from_a_relaxed_start(m, x):
    y, _ = m.predict(x)  # reachable outputs
    inv = m.inverse()
    xi, _ = inv.predict(y)
    yr, _ = m.predict(xi)
    np.testing.assert_allclose(yr, y, atol=1e-9)


def test_step_of_inverse_equals_predict():
    m = known()
    y, _ = m.predict(sweep(300))
    inv = m.inverse()
    xs, _ = inv.predict(y)
    s = inv.init(y[0])
    for k in range(20):
        s, xk = inv.step(s, y[k])
        assert xk == pytest.approx(xs[k], abs=1e-12)


def test_params_and_model_file_round_trip_exactly(tmp_path):
    duty = growing_sine()
    t = np.arange(len(duty)) * 0.05
    flow = 100 + 80 * known().predict((duty - 55) / 17)[0]
    model = fit_model("pi-asym", t, duty, flow)
    core = model.core
    back = AsymmetricPIModel.from_params(json.loads(json.dumps(core.to_params())))
    np.testing.assert_array_equal(back.w, core.w)
    assert (back.a, back.p, back.offset) == (core.a, core.p, core.offset)
    save_model(model, tmp_path / "m.json")
    loaded = load_model(tmp_path / "m.json")
    assert isinstance(loaded.inverse, InverseAsymmetricPI)
    np.testing.assert_array_equal(loaded.predict(duty)[0], model.predict(duty)[0])
    flow_pred = model.predict(duty)[0]
    duty_back, _ = loaded.inverse_predict(flow_pred)
    np.testing.assert_allclose(duty_back, duty, atol=1e-6)
