"""Loop margins of sweep candidates (controller/sweep/margins.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.laws import control, kalman, limits, pid
from controller.sweep import margins as MG

DT = 1e-3


def pid_ctrl(batch=1, **kw):
    return control.ControllerParams("pid", limits.Limits.make(batch), pid=pid.PIDParams.make(batch, **kw))


def op(gain=1.5, lag_s=0.0, order=1, delay_steps=0):
    return MG.OperatingPoint(60.0, 50.0, gain, lag_s, order, delay_steps, DT)


@pytest.mark.parametrize("kp", [0.1, 0.3, 2.0])
def test_proportional_on_a_delayed_gain(kp):
    """L(z) = kp K z^-2 (loop timing and one period of delay): |L| = kp K at every frequency,
    phase -180 deg at half the Nyquist frequency: GM = 1/(kp K)."""
    m = MG.loop_margins(pid_ctrl(kp=kp), 0, op(gain=1.5, delay_steps=1))
    assert m.gain_margin_db == pytest.approx(-20 * math.log10(kp * 1.5), abs=1e-6)
    if kp * 1.5 < 1:
        assert math.isinf(m.phase_margin_deg)


@settings(max_examples=12, deadline=None)
@given(st.floats(0.01, 3.0), st.one_of(st.just(0.0), st.floats(1.0, 400.0)), st.floats(0.002, 0.05), st.integers(0, 4))
def test_positive_gain_margin_iff_the_closed_loop_is_stable(kp, ki, lag_s, delay):
    import control as ct

    o = op(gain=1.2, lag_s=lag_s, delay_steps=delay)
    p = pid_ctrl(kp=kp, ki=ki)
    m = MG.loop_margins(p, 0, o)
    cl = ct.feedback(MG.controller_lti(p, 0, o) * MG.plant_tf(o), 1)
    stable = np.max(np.abs(ct.poles(cl))) < 1.0 - 1e-9
    if abs(m.gain_margin_db) > 0.05 and (math.isinf(m.phase_margin_deg) or abs(m.phase_margin_deg) > 0.5):
        assert stable == (m.gain_margin_db > 0 and m.phase_margin_deg > 0)


def test_pid_transfer_function_is_the_law():
    """The controller's impulse response equals the PID law stepped on a measurement impulse (limits off)."""
    import control as ct

    p = pid_ctrl(kp=0.3, ki=20.0, kd=0.002, tf_s=0.004)
    lim = limits.Limits.make(1, -1e9, 1e9)
    s = pid.init(p.pid, 0.0)
    u_prev = np.zeros(1)
    law = []
    for k in range(60):
        meas = np.array([1.0 if k == 0 else 0.0])
        s, u_prev = pid.step(p.pid, s, np.zeros(1), meas, DT, 0.0, u_prev, lim)
        law.append(-u_prev[0])  # negative feedback sign
    c = MG.controller_lti(p, 0, op())
    _, y = ct.forced_response(c, T=np.arange(60) * DT, U=np.eye(1, 60)[0])
    np.testing.assert_allclose(y, law, rtol=1e-9, atol=1e-9)


def test_kalman_state_space_is_the_filter_around_a_linear_feedforward():
    """The ff+kf controller: the filter's bias estimate through u = -bias/K, m = K u, against kalman.update/push
    (about an open valve at m0: the filter holds its bias while the model has the valve closed)."""
    import control as ct

    kf = kalman.KFParams.make(0.02, 0.003, DT, 0.3, 0.05, 0.5)
    k_model, m0 = 1.7, 60.0
    c = MG._kalman_lti(kf, 0, k_model, DT)
    rng = np.random.default_rng(4)
    z = rng.normal(0, 1, 200)
    s = kalman.init(kf, m0, model0_lpm=m0)
    law = []
    for zk in z:
        s = kalman.update(kf, s, np.array([m0 + zk]))
        u = -s.bias_lpm / k_model
        s = kalman.push(s, m0 + k_model * u)
        law.append(-u[0])
    _, y = ct.forced_response(c, T=np.arange(200) * DT, U=z)
    np.testing.assert_allclose(y, law, rtol=1e-9, atol=1e-12)


def test_feedforward_alone_has_no_loop():
    from controller.laws import feedforward as ffw
    from tests.test_laws import MODEL

    p = control.ControllerParams("ff", limits.Limits.make(1), forward=ffw.bank(MODEL))
    m = MG.loop_margins(p, 0, op())
    assert math.isinf(m.gain_margin_db) and math.isinf(m.phase_margin_deg)
