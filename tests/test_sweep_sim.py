"""Batched sweep simulation against the live loop run once per candidate (controller/sweep/simulate.py)."""
from __future__ import annotations

import numpy as np
import pytest

from controller.config import load_run_config
from controller.loop import Loop, SimClock
from controller.run_summary import tracking
from controller.sweep import runner, simulate
from controller.sweep import spec as sp
from controller.transport.sim import SimTransport
from models.model import load_model
from plant_sim.plant import Plant

RUN = load_run_config("config/run.toml")


class IndexedReference:
    """The sweep's sampled reference served to the live loop by step index (no float drift in t)."""

    can_go_stale = False

    def __init__(self, ref, ahead, rate_hz, preview_s):
        self.ref, self.ahead_ref, self.rate, self.preview_s = ref, ahead, rate_hz, preview_s

    def poll(self, t_s, accept):
        return float(self.ref[int(round(t_s * self.rate))]), 0

    def ahead(self, t_s, accept):
        return float(self.ahead_ref[int(round(t_s * self.rate))])


def short_run():
    import copy
    import dataclasses

    sections = copy.deepcopy(RUN.sections)
    sections["profile"].update(breath_rate_bpm=120.0)  # 0.5 s breaths: a rise and a fall in 0.5 s
    return dataclasses.replace(RUN, sections=sections)


CASES = [("ff+pid", {"ff_pid.kp": 0.1, "ff_pid.ki": 30.0}), ("ff+pid", {"ff_pid.kp": 0.5, "ff_pid.kd": 0.002}),
         ("ff+kf", {"kf.q_bias_lpm": 0.02}), ("pid", {"pid.kp": 0.3}), ("ff", {"valve.tau_s": 0.0})]


@pytest.mark.parametrize("word,settings", CASES)
def test_batched_sweep_equals_the_live_loop_run_once_per_candidate(word, settings):
    """B candidates x V variants in one batch give, loop by loop, exactly the live loop's columns."""
    run = short_run()
    rate = run["loop"]["rate_hz"]
    ref = sp.reference(run, 0.5)
    plants = sp.plants(run, [{}, {"supply_bar": 2.5, "transport_delay": 0.03}], "test")
    models = {run.resolve(run[""]["model"]): load_model(run.resolve(run[""]["model"]))}
    rows = [settings, {**settings, "limits.rate_pct_per_s": 2000.0}, {**settings, "valve.delay_s": 0.011}]
    built = [runner.build_one(run, word, r, models) for r in rows]
    steps = np.array([int(round(pv * rate)) for _, pv in built])  # a preview per candidate
    V = len(plants)
    params = simulate.stack_params([p for p, _ in built for _ in range(V)])
    r = simulate.response(params, plants, ref, rate, run[""]["seed"], np.repeat(steps, V))
    for c, (p, preview_s) in enumerate(built):
        ahead = np.concatenate([ref[steps[c]:], np.full(steps[c], ref[-1])])
        for v, plant in enumerate(plants):
            transport = SimTransport(Plant(plant, rate, seed=run[""]["seed"]), run.loop.safe_duty_pct)
            res = Loop(p, transport, IndexedReference(ref, ahead, rate, preview_s), run.loop, clock=SimClock()).run(0.5)
            cols = res.columns
            np.testing.assert_array_equal(r.flow_lpm[c * V + v], cols["flow_lpm"])
            np.testing.assert_array_equal(r.duty_pct[c * V + v], cols["duty_pct"])
            # and the sweep's IAE and steady MAE are the run summary's
            figs = simulate.figures(r, V)
            summ = tracking(cols["t_s"], cols["ref_lpm"], cols["flow_lpm"], np.ones(len(ref), bool))
            assert figs["iae"][c, v] == pytest.approx(summ["iae"], rel=1e-12)
            assert figs["steady_mae_lpm"][c, v] == pytest.approx(summ["steady_mae_lpm"], rel=1e-12)


def test_stack_params_refuses_different_structures():
    models = {RUN.resolve(RUN[""]["model"]): load_model(RUN.resolve(RUN[""]["model"]))}
    a, _ = runner.build_one(RUN, "ff+pid", {}, models)
    b, _ = runner.build_one(RUN, "ff+pid", {"valve.tau_s": 0.0}, models)  # no lead
    assert runner.structure(a) != runner.structure(b)
    with pytest.raises(ValueError):
        simulate.stack_params([a, b])


def test_sweeps_batched_kalman_candidates_each_agree_with_their_filterpy_design():
    """ff+kf candidates as the sweep batches them (different noises, lags, delays): each row of the
    array filter is, step by step, the filterpy KalmanFilter designed for that candidate alone, started
    at its steady-state covariance (the array filter is the steady-state form)."""
    import scipy.linalg

    from controller.laws import kalman

    models = {RUN.resolve(RUN[""]["model"]): load_model(RUN.resolve(RUN[""]["model"]))}
    rows = [{"kf.q_flow_lpm": qf, "kf.q_bias_lpm": qb, "kf.r_lpm": r, "valve.tau_s": tau, "valve.delay_s": d}
            for qf, qb, r, tau, d in [(0.5, 0.01, 0.5, 0.02, 0.0), (3.0, 0.05, 0.3, 0.01, 0.005),
                                      (10.0, 0.2, 1.0, 0.03, 0.012)]]
    kf = simulate.stack_params([runner.build_one(RUN, "ff+kf", r, models)[0] for r in rows]).kf
    dt = 1.0 / RUN["loop"]["rate_hz"]
    n, B = 2000, len(rows)
    refs = []
    for r in rows:
        f = kalman.design(r["valve.tau_s"], dt, r["kf.q_flow_lpm"], r["kf.q_bias_lpm"], r["kf.r_lpm"], flow0_lpm=60.0)
        prior = scipy.linalg.solve_discrete_are(f.F.T, f.H.T, f.Q, f.R)
        gain = prior @ f.H.T / (f.H @ prior @ f.H.T + f.R)
        f.P = (np.eye(2) - gain @ f.H) @ prior  # posterior: the next predict gives the steady prior
        refs.append(f)
    rng = np.random.default_rng(5)
    model = 60 + 25 * np.sign(np.sin(np.arange(n) * dt * 2 * np.pi * 1.5))
    s = kalman.init(kf, np.full(B, 60.0), model0_lpm=np.full(B, model[0]))
    flow, bias = np.full(B, 60.0), np.array([-6.0, 4.0, 9.0])
    for k in range(n):
        m_in = model[np.maximum(k - 1 - kf.delay_steps, 0)]
        flow = kf.a * flow + (1 - kf.a) * (m_in + bias)
        z = flow + rng.normal(0, 0.5, B)
        for j, f in enumerate(refs):
            f.predict(u=np.array([[m_in[j]]]))
            f.update(np.array([[z[j]]]))
        s = kalman.push(kalman.update(kf, s, z), np.full(B, model[k]))
        np.testing.assert_allclose(s.flow_lpm, [f.x[0, 0] for f in refs], rtol=1e-9)
        np.testing.assert_allclose(s.bias_lpm, [f.x[1, 0] for f in refs], rtol=1e-9, atol=1e-9)
    for j, f in enumerate(refs):
        np.testing.assert_allclose(f.K.ravel(), [kf.k_flow[j], kf.k_bias[j]], rtol=1e-9)
