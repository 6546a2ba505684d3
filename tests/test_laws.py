"""The control laws over arrays of candidates (controller/laws)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.laws import control, kalman, limits, pid
from controller.laws import feedforward as ffw
from models.model import FittedModel
from models.pi import PIModel, thresholds
from models.preprocess import Scaling

DT = 1e-3


def synthetic_model(seed: int = 0, n: int = 12) -> FittedModel:
    """An invertible PI (positive loading slopes) with bench-like scalings: duty 38-72 %, flow 12-184 L/min."""
    rng = np.random.default_rng(seed)
    w = np.concatenate([[0.4], rng.uniform(0.0, 0.1, n)])
    core = PIModel(r=thresholds(n), w=w, offset=0.05)
    return FittedModel("pi", core, Scaling(55.0, 17.0), Scaling(98.0, 86.0), inverse=core.inverse())


MODEL = synthetic_model()


def pid_params(batch=1, **kw):
    return pid.PIDParams.make(batch, **{"kp": 0.2, "ki": 5.0, "kd": 0.0, "tf_s": 0.005, "tt_s": DT, **kw})


# -- feedforward --------------------------------------------------------------

def test_feedforward_matches_the_models_inverse_pi():
    """Inverting from the memory the forward model keeps is the model's own inverse (Eq. 7), sample by sample."""
    rng = np.random.default_rng(1)
    y = 98 + 50 * np.sin(np.linspace(0, 12, 400)) * np.linspace(0.1, 1, 400) + rng.normal(0, 2, 400)
    expected, _ = MODEL.inverse_predict(y)
    bank = ffw.bank(MODEL, batch=3)
    s = ffw.init(bank, expected[0])
    for k in range(len(y)):
        u = ffw.invert(bank, s, np.full(3, y[k]))
        np.testing.assert_allclose(u, expected[k], rtol=0, atol=1e-9)
        s, _ = ffw.step(bank, s, u)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(42.0, 68.0), min_size=2, max_size=60))
def test_inverse_of_forward_gives_the_duty_back(duty):
    """Eq. (7): the inverse fed with the forward model's flow returns the duty."""
    fwd = ffw.bank(MODEL)
    sf = ffw.init(fwd, duty[0])
    for d in duty:
        back = ffw.invert(fwd, sf, ffw.step(fwd, sf, np.array([d]))[1])
        sf, _ = ffw.step(fwd, sf, np.array([d]))
        assert back[0] == pytest.approx(d, abs=1e-9)


def test_feedforward_rejects_a_kind_without_inverse():
    from models.bouc_wen import BoucWenModel

    m = FittedModel("bouc-wen", BoucWenModel(1.0, 0.5, 1.0, 1.0, 0.1, 0.0), Scaling(55.0, 17.0), Scaling(98.0, 86.0))
    with pytest.raises(ValueError, match="no inverse"):
        ffw.bank(m)


def test_no_flow_asked_gives_the_ready_duty_below_the_onset():
    """A zero reference: ready_margin_pct below the duty where the model's flow starts (0 L/min)."""
    bank = ffw.bank(MODEL, ready_margin_pct=2.0)
    s = ffw.init(bank, 60.0)
    onset = ffw.invert(dataclasses.replace(bank, ready_margin_pct=np.zeros(1)), s, np.array([0.0]))[0]
    ready = ffw.invert(bank, s, np.array([0.0]))[0]
    assert ready == pytest.approx(onset - 2.0, abs=1e-12)
    # the model passes no flow at the ready duty, and some just above the onset
    assert ffw.step(bank, s, np.array([ready]))[1][0] == 0.0
    assert ffw.step(bank, s, np.array([onset + 0.5]))[1][0] > 0.0


# -- limits -------------------------------------------------------------------

@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-500, 500), min_size=1, max_size=40), st.floats(1.0, 5000.0))
def test_limits_clamp_and_rate(u, rate):
    lim = limits.Limits.make(1, 0.0, 100.0, rate)
    prev = np.array([50.0])
    for v in u:
        out = limits.apply(lim, np.array([v]), prev, DT)
        assert 0.0 <= out[0] <= 100.0
        assert abs(out[0] - prev[0]) <= rate * DT + 1e-9
        prev = out


# -- PID ----------------------------------------------------------------------

def run_pid(p, lim, ref, meas, u_bias=0.0):
    s = pid.init(p, meas[0])
    u = np.zeros(p.kp.shape)
    out = []
    for r, m in zip(ref, meas):
        s, u = pid.step(p, s, np.asarray(r, float), np.asarray(m, float), DT, u_bias, u, lim)
        out.append((u.copy(), s.integral_pct.copy()))
    return out


def test_back_calculation_bounds_the_integral_under_saturation():
    """A reference the valve cannot reach: the integral stays bounded with back-calculation, winds up without."""
    lim = limits.Limits.make(2, 0.0, 100.0)
    p = pid.PIDParams.make(2, kp=0.2, ki=5.0, tt_s=np.array([DT, np.inf]))
    n = 3000
    out = run_pid(p, lim, np.full((n, 2), 250.0), np.full((n, 2), 180.0))
    u, i = out[-1]
    np.testing.assert_allclose(u, 100.0)
    assert i[0] <= 100.0  # back-calculated: v = kp e + I is held near the clamp
    assert i[1] == pytest.approx(5.0 * 70.0 * n * DT, rel=1e-9)  # plain integral: ki e t


def test_no_derivative_kick_on_reference_step():
    lim = limits.Limits.make()
    p = pid.PIDParams.make(1, kp=0.0, ki=0.0, kd=1.0, tf_s=0.002)
    ref = np.concatenate([np.zeros(10), np.full(10, 80.0)])[:, None]
    out = run_pid(p, lim, ref, np.full((20, 1), 30.0), u_bias=40.0)
    assert all(u[0] == 40.0 for u, _ in out)


@settings(max_examples=20, deadline=None)
@given(st.floats(-2000.0, 2000.0), st.floats(1e-3, 0.05), st.floats(0.0, 0.05))
def test_filtered_derivative_of_a_ramp_settles_at_minus_kd_slope(slope, kd, tf_s):
    lim = limits.Limits.make(1, -1e9, 1e9)
    p = pid.PIDParams.make(1, kp=0.0, ki=0.0, kd=kd, tf_s=tf_s)
    n = 2000
    meas = (100.0 + slope * DT * np.arange(n))[:, None]
    u, _ = run_pid(p, lim, np.zeros((n, 1)), meas)[-1]
    assert u[0] == pytest.approx(-kd * slope, rel=1e-6, abs=1e-9)


def test_batch_candidates_are_independent():
    """Each candidate of a batch runs exactly as it would alone."""
    kp = np.array([0.05, 0.2, 0.6])
    ki = np.array([0.0, 3.0, 10.0])
    rng = np.random.default_rng(2)
    ref = rng.uniform(0, 150, 300)
    meas = rng.uniform(0, 150, 300)
    lim = limits.Limits.make(3, 0.0, 100.0, 2000.0)
    both = run_pid(pid.PIDParams.make(3, kp=kp, ki=ki, kd=0.01), lim,
                   np.repeat(ref[:, None], 3, 1), np.repeat(meas[:, None], 3, 1))
    for j in range(3):
        alone = run_pid(pid.PIDParams.make(1, kp=kp[j], ki=ki[j], kd=0.01), limits.Limits.make(1, 0, 100, 2000.0),
                        ref[:, None], meas[:, None])
        np.testing.assert_array_equal([u[j] for u, _ in both], [u[0] for u, _ in alone])


# -- Kalman ---------------------------------------------------------------------

def test_array_filter_agrees_with_filterpy():
    """Same F, B, H, Q, R: filterpy's gain converges to the DARE gain and the estimates meet."""
    tau, delay, qf, qb, r = 0.02, 0.005, 0.3, 0.02, 0.5
    kp = kalman.KFParams.make(tau, delay, DT, qf, qb, r)
    ref_kf = kalman.design(tau, DT, qf, qb, r, flow0_lpm=60.0)
    rng = np.random.default_rng(3)
    n = 4000
    model = 60 + 20 * np.sign(np.sin(np.arange(n) * DT * 2 * np.pi * 2))
    s = kalman.init(kp, 60.0, model0_lpm=model[0])
    flow, bias = 60.0, 7.0
    d = int(kp.delay_steps[0])
    for k in range(n):
        m_in = model[max(k - 1 - d, 0)]
        flow = kp.a[0] * flow + (1 - kp.a[0]) * (m_in + bias)
        z = flow + rng.normal(0, r)
        ref_kf.predict(u=np.array([[m_in]]))
        ref_kf.update(np.array([[z]]))
        s = kalman.push(kalman.update(kp, s, np.array([z])), np.array([model[k]]))
    np.testing.assert_allclose(ref_kf.K.ravel(), [kp.k_flow[0], kp.k_bias[0]], rtol=1e-6)
    assert s.flow_lpm[0] == pytest.approx(ref_kf.x[0, 0], abs=1e-3)
    assert s.bias_lpm[0] == pytest.approx(ref_kf.x[1, 0], abs=1e-3)
    assert s.bias_lpm[0] == pytest.approx(bias, abs=1.0)


# -- composed controllers on a lag + delay plant with a model error ------------

def lag_delay_plant(model: FittedModel, tau_s, delay_s, bias_lpm, n, batch):
    """The forward model plus a constant flow error, first-order lag and pure delay (noise-free)."""
    fwd = ffw.bank(model, batch)
    a = np.exp(-DT / tau_s)
    d = int(round(delay_s / DT))
    return fwd, a, d


def closed_loop(params: control.ControllerParams, ref: np.ndarray, tau_s=0.02, delay_s=0.005, bias_lpm=-8.0):
    b = params.batch
    fwd, a, d = lag_delay_plant(MODEL, tau_s, delay_s, bias_lpm, len(ref), b)
    sf = ffw.init(fwd, 0.0)
    flow = np.zeros(b)
    queue = [np.zeros(b)] * (d + 1)
    s = control.init(params, flow)
    flows, duties = [], []
    for r in ref:
        s, cmd = control.step(params, s, np.full(b, r), flow, DT)
        sf, static = ffw.step(fwd, sf, cmd.duty_pct)
        queue.append(np.maximum(static + bias_lpm, 0.0))
        flow = a * flow + (1 - a) * queue.pop(0)
        flows.append(flow.copy())
        duties.append(cmd)
    return np.array(flows), duties


def make(mode, batch=1, **pid_kw):
    return control.ControllerParams(
        mode, limits.Limits.make(batch, 0, 100, 5000.0),
        forward=ffw.bank(MODEL, batch),
        pid=pid_params(batch, **pid_kw), kf=kalman.KFParams.make(0.02, 0.005, DT, 0.5, 0.05, 0.3, batch),
    )


@pytest.mark.parametrize("mode", ["pid", "ff+pid", "ff+kf"])
def test_feedback_removes_the_model_error_in_steady_state(mode):
    ref = np.full(3000, 90.0)
    flows, _ = closed_loop(make(mode), ref)
    assert flows[-1, 0] == pytest.approx(90.0, abs=0.05)


def test_feedforward_alone_keeps_the_model_error():
    flows, _ = closed_loop(make("ff"), np.full(3000, 90.0), bias_lpm=-8.0)
    assert flows[-1, 0] == pytest.approx(90.0 - 8.0, abs=0.05)


def test_duty_split_adds_up_and_respects_the_limits():
    ref = np.concatenate([np.full(300, 30.0), np.full(300, 150.0), np.full(300, 10.0)])
    for mode in control.MODES:
        _, cmds = closed_loop(make(mode), ref)
        duty = np.array([c.duty_pct[0] for c in cmds])
        np.testing.assert_allclose([c.ff_pct[0] + c.fb_pct[0] + c.limit_pct[0] for c in cmds], duty, atol=1e-9)
        assert duty.min() >= 0 and duty.max() <= 100
        assert np.max(np.abs(np.diff(duty))) <= 5000.0 * DT + 1e-9
        # fb is the law's own output: where neither limit acts, the limit part is zero
        step = np.abs(np.diff(duty, prepend=0.0))
        free = (duty > 0) & (duty < 100) & (step < 5000.0 * DT - 1e-6)
        assert free.sum() > 100
        np.testing.assert_allclose([c.limit_pct[0] for c, f in zip(cmds, free) if f], 0.0, atol=1e-9)


def test_transfer_is_bumpless():
    """Switching ff -> ff+pid mid-run: the first duty of the new law equals the last of the old."""
    old, new = make("ff"), make("ff+pid", kp=0.3)
    s = control.init(old, 70.0)
    for _ in range(50):
        s, cmd = control.step(old, s, np.array([80.0]), np.array([70.0]), DT)
    s2 = control.transfer(new, s, 80.0, np.array([70.0]))
    _, cmd2 = control.step(new, s2, np.array([80.0]), np.array([70.0]), DT)
    assert cmd2.duty_pct[0] == pytest.approx(cmd.duty_pct[0], abs=5.0 * DT * 0.3 * 10 + 1e-6)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(0.0, 200.0), min_size=1, max_size=50), st.floats(0.0, 0.05))
def test_lead_with_equal_time_constants_is_the_identity(ref, tau):
    p = ffw.LeadParams.make(1, lead_s=tau, lag_s=tau)
    s = ffw.lead_init(p, 0.0)
    for r in ref:
        s, y = ffw.lead_step(p, s, np.array([r]), DT)
        assert y[0] == pytest.approx(r, abs=1e-9)


def test_lead_cancels_the_valve_lag():
    """Lead(tau) then the valve's lag(tau): the step response is the lead's own lag (lag_s), not tau."""
    tau, lag = 0.02, 0.004
    p = ffw.LeadParams.make(1, lead_s=tau, lag_s=lag)
    s = ffw.lead_init(p, 0.0)
    flow, a = 0.0, tau / (tau + DT)  # backward-Euler lag, the lead's own discretization
    for k in range(int(5 * lag / DT)):
        s, y = ffw.lead_step(p, s, np.array([1.0]), DT)
        flow = a * flow + (1 - a) * y[0]
    assert flow == pytest.approx(1 - (lag / (lag + DT)) ** int(5 * lag / DT), abs=1e-9)


def test_stacked_banks_step_like_each_model_alone():
    other = synthetic_model(seed=5)
    both = ffw.stack([ffw.bank(MODEL), ffw.bank(other)])
    alone = [ffw.bank(MODEL), ffw.bank(other)]
    duty = [50.0, 62.0, 45.0, 55.0]
    s2 = ffw.init(both, duty[0])
    s1 = [ffw.init(b, duty[0]) for b in alone]
    for d in duty:
        u2 = ffw.invert(both, s2, np.full(2, 100.0))
        s2, q2 = ffw.step(both, s2, np.full(2, d))
        for j, b in enumerate(alone):
            assert u2[j] == ffw.invert(b, s1[j], np.array([100.0]))[0]
            s1[j], q1 = ffw.step(b, s1[j], np.array([d]))
            assert q2[j] == q1[0]


def test_kalman_holds_its_bias_while_the_model_has_the_valve_closed():
    """A closed valve says nothing of the model's error on an open one: the bias learnt on one breath is
    kept through the expiration for the next; the flow estimate follows the closed valve to zero."""
    kp = kalman.KFParams.make(0.02, 0.005, DT, 0.5, 0.05, 0.5)
    s = kalman.init(kp, 70.0, model0_lpm=60.0, bias0_lpm=10.0)
    d = int(kp.delay_steps[0])
    bias = []
    for _ in range(500):  # the model closes the valve (seen d + 1 periods later), and the valve closes
        s = kalman.push(kalman.update(kp, s, np.array([0.0])), np.array([0.0]))
        bias.append(s.bias_lpm[0])
    assert len(set(bias[d + 1:])) == 1 and bias[d] != bias[0] and abs(s.flow_lpm[0]) < 0.01
    for _ in range(d + 2):  # open again: the measurement moves the bias once the model's flow arrives
        s = kalman.push(kalman.update(kp, s, np.array([70.0])), np.array([60.0]))
    assert s.bias_lpm[0] > bias[-1]
