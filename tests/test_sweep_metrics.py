"""Sweep metrics against textbook responses (controller/sweep/metrics.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.sweep import metrics as M

DT = 1e-4


def step_case(y_after, n_before=2000, n_after=30000, lo=0.0, hi=1.0):
    """Reference stepping lo -> hi after ``n_before`` samples, response ``y_after(t)`` from the step on."""
    t = np.arange(n_after) * DT
    ref = np.concatenate([np.full(n_before, lo), np.full(n_after, hi)])
    y = np.concatenate([np.full(n_before, lo), lo + (hi - lo) * y_after(t)])
    return ref, y


def second_order(zeta, wn):
    wd = wn * math.sqrt(1 - zeta**2)
    return lambda t: 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))


def test_first_order_rise_is_tau_ln9_and_settling_tau_ln50():
    tau = 0.2
    ref, y = step_case(lambda t: 1 - np.exp(-t / tau))
    # the response at the first sample of the new hold is still 0: shift by one sample, as a sampled lag does
    y = np.concatenate([[0.0], y[:-1]])
    f = M.tracking_figures(ref, y[None], np.zeros((1, len(y))), DT)
    assert f["rise_ms"][0] == pytest.approx(tau * math.log(9) * 1e3, abs=1e-3)
    assert f["settle_ms"][0] == pytest.approx((tau * math.log(50) + DT) * 1e3, abs=1e-3)
    assert f["overshoot_lpm"][0] == 0.0


@pytest.mark.parametrize("zeta", [0.2, 0.45, 0.7])
def test_second_order_overshoot_and_step_info(zeta):
    import control as ct

    wn = 40.0
    ref, y = step_case(second_order(zeta, wn), lo=20.0, hi=80.0)
    f = M.tracking_figures(ref, y[None], np.zeros((1, len(y))), DT)
    mp = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    assert f["overshoot_lpm"][0] == pytest.approx(60.0 * mp, rel=1e-4)
    # python-control as the reference for rise and settling (10-90 %, 2 % band)
    t = np.arange(30000) * DT
    info = ct.step_info(second_order(zeta, wn)(t), T=t, SettlingTimeThreshold=0.02, RiseTimeLimits=(0.1, 0.9))
    assert f["rise_ms"][0] == pytest.approx(info["RiseTime"] * 1e3, abs=2 * DT * 1e3)
    assert f["settle_ms"][0] == pytest.approx(info["SettlingTime"] * 1e3, abs=2 * DT * 1e3)


def test_iae_and_ise_of_a_known_error():
    """e = A sin(2 pi f t) over whole periods: ∫|e| = 2 A T / pi, ∫e² = A² T / 2."""
    amp, f_hz, dur = 12.0, 5.0, 2.0
    t = np.arange(int(dur / DT)) * DT
    ref = np.full(len(t), 50.0)
    y = ref - amp * np.sin(2 * np.pi * f_hz * t)
    got = M.tracking_figures(ref, y[None], np.zeros((1, len(t))), DT)
    assert got["iae"][0] == pytest.approx(2 * amp * dur / math.pi / 60.0, rel=1e-6)
    assert got["ise"][0] == pytest.approx(amp**2 * dur / 2, rel=1e-6)


def test_duty_total_variation_of_a_triangle():
    cycles, amp = 7, 30.0
    tri = amp * np.abs(((np.arange(cycles * 200) / 200.0) % 1.0) * 2 - 1)  # starts at amp, down, up...
    got = M.tracking_figures(np.zeros(len(tri)), np.zeros((1, len(tri))), tri[None], 1e-3)
    assert got["duty_tv"][0] == pytest.approx(2 * amp * cycles, rel=1e-2)


def test_steady_mae_counts_only_after_100ms_of_constant_reference():
    dt = 1e-3
    ref = np.concatenate([np.full(300, 10.0), np.full(300, 60.0)])
    y = ref.copy()
    y[300:400] += 5.0  # first 100 ms after the step: excluded
    y[400:] += 1.0
    got = M.tracking_figures(ref, y[None], np.zeros((1, 600)), dt)
    from controller.run_summary import steady_mask

    mask = steady_mask(np.arange(600) * dt, ref)
    assert not mask[:100].any() and mask[100:300].all() and not mask[300:400].any() and mask[400:].all()
    expected = 1.0 * 200 / mask.sum()
    assert got["steady_mae_lpm"][0] == pytest.approx(expected)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.005, 0.1), st.floats(0.1, 0.9), st.floats(5.0, 150.0))
def test_falling_step_mirrors_rising(tau, zeta, peak):
    """A fall peak -> 0 whose response mirrors a rise 0 -> peak has the same figures."""
    wn = 3.0 / tau
    ref_up, y_up = step_case(second_order(zeta, wn), n_before=500, n_after=8000, lo=0.0, hi=peak)
    ref_dn, y_dn = peak - ref_up, peak - y_up
    up = M.tracking_figures(ref_up, y_up[None], np.zeros((1, len(y_up))), DT)
    dn = M.tracking_figures(ref_dn, y_dn[None], np.zeros((1, len(y_dn))), DT)
    for k in M.NAMES:
        assert dn[k][0] == pytest.approx(up[k][0], rel=1e-9, abs=1e-9), k


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_batch_rows_equal_single_rows(b, seed):
    rng = np.random.default_rng(seed)
    ref = np.repeat(rng.uniform(0, 100, 6), 400)
    y = ref + rng.normal(0, 3, (b, len(ref))).cumsum(axis=1) * 0.05
    u = rng.uniform(0, 100, (b, len(ref)))
    both = M.tracking_figures(ref, y, u, 1e-3)
    for j in range(b):
        one = M.tracking_figures(ref, y[j:j + 1], u[j:j + 1], 1e-3)
        for k in M.NAMES:
            np.testing.assert_allclose(both[k][j], one[k][0], rtol=1e-12)


def test_never_reaching_and_never_settling_is_inf_and_no_steps_is_nan():
    ref, y = step_case(lambda t: 0.5 * (1 - np.exp(-t / 0.01)), n_after=3000)
    f = M.tracking_figures(ref, y[None], np.zeros((1, len(y))), DT)
    assert math.isinf(f["rise_ms"][0]) and math.isinf(f["settle_ms"][0])
    flat = M.tracking_figures(np.full(100, 5.0), np.zeros((1, 100)), np.zeros((1, 100)), DT)
    assert math.isnan(flat["rise_ms"][0]) and flat["iae"][0] == pytest.approx(5.0 * 100 * DT / 60)


def test_worst_case_is_the_largest_over_variants():
    f = {"iae": np.array([[1.0, 3.0, 2.0], [0.5, 0.4, 0.6]])}
    np.testing.assert_array_equal(M.worst_case(f)["iae"], [3.0, 0.6])
