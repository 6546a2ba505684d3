"""The play operator, Eq. (1) and (3): known single-operator responses and the compiled kernels."""
from __future__ import annotations

import control as ct
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from models import play
from tests import oracles

finite = st.floats(-2, 2, allow_nan=False)


def test_initial_state_is_eq3_clamp():
    r = np.array([0.0, 0.2, 0.5])
    np.testing.assert_allclose(play.init(r, 0.4, 0.0), [0.4, 0.2, 0.0])
    np.testing.assert_allclose(play.init(r, -0.4, 1.0), [-0.4, -0.2, 0.1])


def test_single_play_follows_backlash_on_a_triangle():
    r = np.array([0.25])
    x = np.concatenate([np.linspace(0, 1, 11), np.linspace(1, -1, 21), np.linspace(-1, 0.5, 16)])
    y, _ = play.play_response(r, x, np.zeros(1))
    y = y[:, 0]
    # Rising from 0: stuck until x passes r, then x - r.
    np.testing.assert_allclose(y[:11], np.maximum(x[:11] - 0.25, 0.0))
    # After the reversal at 1 the output holds at 0.75 until x falls below 0.75 - r... i.e. x < 1 - 2r.
    falling = x[11:32]
    np.testing.assert_allclose(y[11:32], np.minimum(0.75, falling + 0.25))
    rising = x[32:]
    np.testing.assert_allclose(y[32:], np.maximum(-0.75, rising - 0.25))


def test_play_equals_python_control_backlash():
    # ct.friction_backlash_nonlinearity(b) is a play operator of half-width b/2.
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(0, 0.05, 500))
    b = 0.3
    nl = ct.friction_backlash_nonlinearity(b)
    ref = np.empty_like(x)
    for k, xk in enumerate(x):
        ref[k] = nl(xk)
    # The python-control block starts with center 0, which is Eq. (3) with y_i0 = 0.
    ours, _ = play.play_response(np.array([b / 2]), x, play.init(np.array([b / 2]), x[0], 0.0))
    np.testing.assert_allclose(ours[:, 0], ref, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(
    x=arrays(np.float64, st.integers(1, 200), elements=finite),
    r=arrays(np.float64, st.integers(1, 8), elements=st.floats(0, 1)),
    y0=finite,
)
def test_compiled_kernels_equal_the_plain_loop(x, r, y0):
    s0 = play.init(r, x[0], y0)
    ref, ref_end = oracles.play_response_numpy(r, x, s0)
    Y, end = play.play_response(r, x, s0)
    np.testing.assert_array_equal(Y, ref)
    np.testing.assert_array_equal(end, ref_end)
    w = np.linspace(1, 2, len(r))
    yw, end_w = play.play_weighted(r, w, x, s0)
    np.testing.assert_allclose(yw, ref @ w, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(end_w, ref_end)


@settings(max_examples=30, deadline=None)
@given(x=arrays(np.float64, st.integers(2, 100), elements=finite), cut=st.integers(1, 99))
def test_chunks_with_passed_state_equal_one_pass(x, cut):
    cut = min(cut, len(x) - 1)
    r = np.array([0.0, 0.1, 0.4])
    s0 = play.init(r, x[0])
    whole, _ = play.play_response(r, x, s0)
    a, s = play.play_response(r, x[:cut], s0)
    b, _ = play.play_response(r, x[cut:], s)
    np.testing.assert_array_equal(np.vstack([a, b]), whole)


def test_outputs_stay_within_threshold_of_input():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, 1000)
    r = np.linspace(0, 0.9, 10)
    Y, _ = play.play_response(r, x, play.init(r, x[0]))
    assert np.all(np.abs(Y - x[:, None]) <= r[None, :] + 1e-15)
