"""The inverse PI, Eq. (5)-(7): exact composition with the forward model, and the paper's check."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from models import play
from models.compare import inverse_check
from models.fitting import fit_model
from models.inverse_pi import NotInvertible, fit_inverse_pi, invert_pi
from models.pi import PIModel, thresholds
from models.recording import Recording
from tests.conftest import growing_sine


@st.composite
def invertible_pi(draw):
    n = draw(st.integers(1, 30))
    w0 = draw(st.floats(0.05, 2.0))
    rest = draw(arrays(np.float64, n, elements=st.floats(-0.5, 0.5)))
    w = np.concatenate([[w0], rest])
    # Keep every partial sum positive (Kuhnen's condition): shift the negative excursions.
    s = np.cumsum(w)
    if s.min() <= 0.01:
        w[0] += 0.01 - s.min()
    # A reachable operator memory: the states a random input history leaves behind.
    # (Eq. 3 with arbitrary y_i0 can give states no input produces, e.g. |y_i - y_j| > |r_i - r_j|.)
    r = thresholds(n)
    history = draw(arrays(np.float64, st.integers(1, 20), elements=st.floats(-1, 1)))
    _, y0 = play.play_response(r, history, np.zeros(n + 1))
    return PIModel(r=r, w=w, offset=draw(st.floats(-1, 1)), y0=y0)


@settings(max_examples=200, deadline=None)
@given(pi=invertible_pi(), x=arrays(np.float64, st.integers(1, 300), elements=st.floats(-1.5, 1.5)))
def test_inverse_of_forward_is_identity(pi, x):
    fs = pi.init(x[0])
    y, _ = pi.predict(x, fs)
    inv = invert_pi(pi)
    xr, _ = inv.predict(y, inv.init(y[0], forward_state=fs))
    scale = max(1.0, float(np.max(np.abs(x))))
    np.testing.assert_allclose(xr, x, atol=1e-9 * scale * max(1.0, np.max(np.abs(pi.w)) / pi.w[0]))


@settings(max_examples=100, deadline=None)
@given(pi=invertible_pi(), y=arrays(np.float64, st.integers(1, 300), elements=st.floats(-1.5, 1.5)))
def test_forward_of_inverse_is_identity(pi, y):
    # Start both sides relaxed: forward operators all at x0, the matching inverse memory by Eq. (7).
    x0 = (y[0] - pi.offset) / pi.w.sum()
    forward_state = np.full(len(pi.r), x0)
    inv = invert_pi(pi)
    x, _ = inv.predict(y, inv.init(y[0], forward_state=forward_state))
    yr, _ = pi.predict(x, forward_state)
    np.testing.assert_allclose(yr, y, atol=1e-9 * max(1.0, float(np.max(np.abs(y)))) * max(1.0, 1 / pi.w[0]))


def test_eq7_weights_match_the_paper_for_two_operators():
    pi = PIModel(r=np.array([0.0, 0.5]), w=np.array([2.0, 1.0]))
    inv = invert_pi(pi)
    assert inv.w[0] == pytest.approx(1 / 2.0)
    assert inv.w[1] == pytest.approx(-1.0 / (3.0 * 2.0))
    assert inv.r[1] == pytest.approx(2.0 * 0.5)  # w_1 (r_2 - r_1)


def test_non_invertible_model_is_refused():
    with pytest.raises(NotInvertible):
        invert_pi(PIModel(r=np.array([0.0, 0.5]), w=np.array([1.0, -2.0])))
    with pytest.raises(NotInvertible):
        invert_pi(PIModel(r=np.array([0.1, 0.5]), w=np.array([1.0, 1.0])))


def test_paper_inverse_check_on_a_synthetic_valve():
    duty = growing_sine(6000)
    t = np.arange(len(duty)) * 0.05
    truth = PIModel(r=thresholds(20), w=np.concatenate([[0.7], np.full(20, 0.02)]))
    rng = np.random.default_rng(3)
    flow = 100 + 80 * truth.predict((duty - 55) / 17)[0] + rng.normal(0, 0.5, len(duty))
    model = fit_model("pi", t, duty, flow)
    rec = Recording("synthetic", {"t_s": t, "duty_pct": duty, "flow_lpm": flow})
    check = inverse_check(model, rec)
    assert check.closed_form.mae < 1e-9  # Eq. (7) inverts the forward model exactly
    assert check.direct_fit.mae < 0.61  # the paper's direct n = 25 inverse on the paper's check
    # On measured flow, the error is the sensor noise seen through the inverse slope, ~0.5 L/min / slope.
    slope = np.polyfit(duty, flow, 1)[0]
    assert check.on_measured_flow.mae < 3 * 0.5 / slope


def test_direct_inverse_fit_returns_an_invertible_pi():
    y = np.sin(np.linspace(0, 20, 2000))
    x = y + 0.05 * np.sign(np.cos(np.linspace(0, 20, 2000)))
    assert fit_inverse_pi(y, x, n=25).invertible
