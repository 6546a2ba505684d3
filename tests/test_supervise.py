"""Runtime switching, fallback, online alarms and mid-run plant changes, on the simulated clock."""
from __future__ import annotations

import json

import numpy as np
import pytest

from controller.alarms import AlarmSettings, Alarms
from controller.cli import main
from controller.config import load_run_config, preview_s, supervisor
from controller.laws import control
from controller.loop import Loop, ProfileReference, SimClock
from controller.transport.sim import SimTransport
from models.recording import InputError
from plant_sim.plant import Plant, load_plant
from plant_sim.protocols import BreathProfile
from tests.test_loop import cfg, model  # noqa: F401  (the run configuration and its model, as fixtures)


def plant(cfg, seed=0, rate_hz=None, **effects):
    pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects={**cfg["effects"], **effects})
    return Plant(pp, rate_hz or cfg.loop.rate_hz, seed=seed)


class Modes(SimTransport):
    """The simulated valve plus ``ctrl/mode`` requests at set times."""

    def __init__(self, plant, requests=(), injections=()):
        super().__init__(plant, 0.0, injections)
        self.requests = sorted(requests)
        self.t = 0.0

    def command(self, duty_pct, t_s):
        self.t = t_s + 1.0 / self.plant.rate_hz
        super().command(duty_pct, t_s)

    def poll_mode(self):
        if self.requests and self.requests[0][0] <= self.t + 1e-9:
            return self.requests.pop(0)[1], 0
        return None, 0


def breath_run(cfg, model, word, transport, duration_s, settings=None):
    prof = BreathProfile(**cfg["profile"])
    ref = ProfileReference(prof.value, preview_s(cfg, "profile"))
    loop = Loop(supervisor(cfg, word, model), transport, ref, settings or cfg.loop, clock=SimClock())
    return loop.run(duration_s)


def rate_step(cfg):
    return cfg["limits"]["rate_pct_per_s"] / cfg.loop.rate_hz


def test_mode_switches_take_over_within_one_step_without_a_duty_jump(cfg, model):
    # mid-inspiration (0.3, 0.6), at the end of one (0.99) and mid-expiration (1.5); a word the run lacks
    req = [(0.3, "ff+pid"), (0.6, "pid"), (0.99, "ff+kf"), (1.5, "ff"), (2.0, "bang-bang"), (2.2, "ff+pid")]
    res = breath_run(cfg, model, "ff+kf", Modes(plant(cfg), req), 3.0)
    c = res.columns
    t, words, duty = c["t_s"], c["controller"], c["duty_pct"]
    for t_req, w in req:
        if w == "bang-bang":
            continue
        i = int(np.searchsorted(t, t_req - 1e-9))
        assert words[i] == w and words[i - 1] != w  # in force at the step the request arrived
    assert np.max(np.abs(np.diff(duty))) <= rate_step(cfg) + 1e-9
    switch = np.flatnonzero(words[1:] != words[:-1]) + 1
    # bumpless: at each switch the duty moves no more than the law would have moved it anyway
    assert np.all(np.abs(duty[switch] - duty[switch - 1]) <= rate_step(cfg) + 1e-9)
    assert {f["kind"]: f["count"] for f in res.faults.to_list()} == {"bad_mode": 1}
    # and the new laws track: ff+pid, the last word, holds the steady error small
    late = (t > 2.4) & (t < 3.0)
    assert np.mean(np.abs(c["ref_lpm"][late] - c["flow_lpm"][late])) < 2.0


def test_a_switch_with_a_tight_rate_limit_is_still_bumpless(cfg, model, tmp_path):
    """With 0.2 %/step a law restarted cold (duty from 0) would show as a ramp; transfer continues the duty."""
    import re

    text = open("config/run.toml").read().replace("rate_pct_per_s = 10000.0", "rate_pct_per_s = 200.0")
    for key in ("model", "plant_config"):  # the copy lives elsewhere: its files by absolute path
        text = re.sub(rf'^{key} = "[^"]*"', f'{key} = "{cfg.resolve(cfg[""][key])}"', text, count=1, flags=re.M)
    path = tmp_path / "run.toml"
    path.write_text(text)
    tight = load_run_config(path)
    res = breath_run(tight, model, "ff+kf", Modes(plant(tight), [(0.5, "ff+pid")]), 0.8)
    duty = res.columns["duty_pct"]
    i = int(np.searchsorted(res.columns["t_s"], 0.5 - 1e-9))
    assert duty[i - 1] > 20.0  # mid-inspiration, the valve well open
    assert abs(duty[i] - duty[i - 1]) <= 0.2 + 1e-9


def test_a_non_finite_law_falls_back_to_ff_pid_then_to_the_safe_state(cfg, model, monkeypatch):
    real_step = control.Live.step  # the live loop's step of a law
    clock = {"t": 0.0}

    def nan_after(t_fail):
        def step(live, *a):
            if live.state.mode == control.FF_KF and clock["t"] >= t_fail:  # the filter's bias estimate turns NaN
                live.state.x[:, control.BIAS_EST] = np.nan
            return real_step(live, *a)
        return step

    class Clocked(Modes):
        def command(self, duty_pct, t_s):
            clock["t"] = t_s
            super().command(duty_pct, t_s)

    monkeypatch.setattr(control.Live, "step", nan_after(0.5))
    res = breath_run(cfg, model, "ff+kf", Clocked(plant(cfg)), 1.0)
    c = res.columns
    i = int(np.searchsorted(c["t_s"], 0.5 - 1e-9)) + 1  # the first step whose law reads the NaN
    assert set(c["controller"][:i - 1]) == {"ff+kf"} and set(c["controller"][i + 1:]) == {"ff+pid"}
    assert np.all(np.isfinite(c["duty_pct"])) and np.all(c["state"] == 0)
    assert np.max(np.abs(np.diff(c["duty_pct"]))) <= rate_step(cfg) + 1e-9
    kinds = {f["kind"] for f in res.faults.to_list()}
    assert "fallback" in kinds and kinds & {"bad_command", "innovation_diverged"}

    # the fallback fails too: the fault state, with the safe duty
    kf_nan = nan_after(0.5)

    def pid_nan(live, *a):
        if live.state.mode == control.FF_PID and clock["t"] >= 0.7:  # the PID's integral turns NaN
            live.state.x[:, control.INTEGRAL] = np.nan
        return kf_nan(live, *a)

    monkeypatch.setattr(control.Live, "step", pid_nan)
    res = breath_run(cfg, model, "ff+kf", Clocked(plant(cfg)), 1.0)
    c = res.columns
    after = c["t_s"] > 0.7 + 0.002
    assert np.all(c["state"][after] != 0) and np.all(c["duty_pct"][after] == cfg.loop.safe_duty_pct)
    assert "bad_command" in {f["kind"] for f in res.faults.to_list()}


def test_a_diverging_filter_hands_over_to_ff_pid(cfg, model, monkeypatch):
    """A filter whose flow estimate is scaled by 1.5 each step (a wrong gain) diverges: its innovation grows."""
    real_step = control.Live.step  # the live loop's step of a law
    clock = {"t": 0.0}

    def diverging(live, *a):
        out = real_step(live, *a)
        if live.state.mode == control.FF_KF and clock["t"] >= 0.4:
            live.state.x[:, control.FLOW_EST] *= 1.5
        return out

    class Clocked(Modes):
        def command(self, duty_pct, t_s):
            clock["t"] = t_s
            super().command(duty_pct, t_s)

    monkeypatch.setattr(control.Live, "step", diverging)
    res = breath_run(cfg, model, "ff+kf", Clocked(plant(cfg)), 1.0)
    c = res.columns
    kinds = {f["kind"]: f["first_s"] for f in res.faults.to_list()}
    assert "innovation_diverged" in kinds and "fallback" in kinds
    assert 0.4 < kinds["fallback"] <= 0.4 + cfg.loop.fallback.innovation_hold_s + 0.05
    assert c["controller"][-1] == "ff+pid"
    assert np.max(np.abs(np.diff(c["duty_pct"]))) <= rate_step(cfg) + 1e-9


def alarm_first(res, kind):
    return {a["kind"]: a["first_s"] for a in res.alarms.to_list()}.get(kind)


def test_supply_drop_mid_inspiration_raises_alarms_within_200_ms(cfg, model):
    """Done-when: --inject supply_bar=0.3@9.2 on the default run (ff+kf, breath profile, noise)."""
    res = breath_run(cfg, model, "ff+kf", SimTransport(plant(cfg), 0.0, [(9.2, "supply_bar", 0.3)]), 9.6)
    assert res.columns["ref_lpm"][int(9.2 * cfg.loop.rate_hz)] > 0  # mid-inspiration indeed
    assert 9.2 < alarm_first(res, "supply_low") <= 9.4
    assert 9.2 < alarm_first(res, "model_mismatch") <= 9.4


def test_without_a_supply_reading_the_model_error_still_raises_an_alarm(cfg, model):
    class Blind(SimTransport):
        supply_bar = None

    res = breath_run(cfg, model, "ff+kf", Blind(plant(cfg), 0.0, [(9.2, "supply_bar", 0.3)]), 9.6)
    assert alarm_first(res, "supply_low") is None
    assert 9.2 < alarm_first(res, "model_mismatch") <= 9.4


def test_an_occlusion_saturates_the_duty_and_raises_saturated(cfg, model):
    """A valve capped at 30 L/min: ff+pid winds the duty to 100 % while the error stays: saturated."""
    res = breath_run(cfg, model, "ff+pid", SimTransport(plant(cfg), 0.0, [(3.2, "saturation", 30.0)]), 3.8)
    t = alarm_first(res, "saturated")
    assert t is not None and 3.2 < t < 3.8
    assert alarm_first(res, "model_mismatch") is None  # ff+pid has no model estimate


def test_normal_breaths_with_noise_raise_no_alarm(cfg, model):
    res = breath_run(cfg, model, "ff+kf", SimTransport(plant(cfg, seed=3)), 30.0)
    assert res.alarms.to_list() == [] and res.faults.to_list() == []


@pytest.mark.slow
@pytest.mark.timeout(2400)  # 600 000 loop steps: minutes on a busy 2-core machine
@pytest.mark.parametrize("word", ["ff+kf", "ff+pid"])
def test_ten_minutes_of_normal_breaths_raise_no_alarm(cfg, model, word):
    res = breath_run(cfg, model, word, SimTransport(plant(cfg, seed=11)), 600.0)
    assert res.alarms.to_list() == [] and res.faults.to_list() == []


def test_alarm_holds_and_counts():
    a = Alarms(AlarmSettings(supply_low_bar=2.0, supply_hold_s=0.02), 0.0, 100.0)
    t = np.arange(0, 0.2, 0.001)
    supply = np.where((t > 0.05) & (t < 0.06), 1.0, 3.0)  # 10 ms dip: shorter than the hold
    supply[(t >= 0.1) & (t < 0.15)] = 1.0  # 50 ms: raised once, 20 ms in
    for ti, p in zip(t, supply):
        a.step(ti, True, 50.0, 0.0, float("nan"), p)
    (al,) = a.to_list()
    assert al["kind"] == "supply_low" and al["count"] == 1 and al["first_s"] == pytest.approx(0.12, abs=1.5e-3)
    assert a.active() == []


@pytest.mark.parametrize("text", ["supply_bar=0.3", "supply_bar@3", "=1@2", "supply_bar=x@1", "supply_bar=1@-1"])
def test_bad_inject_is_one_line_exit_2(text, capsys):
    assert main(["run", "--duration", "0.01", "--inject", text]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--inject" in err


def test_inject_on_the_cli_and_an_unknown_setting(tmp_path, capsys):
    assert main(["run", "--duration", "0.01", "--inject", "pressure=1@0"]) == 2
    assert "pressure" in capsys.readouterr().err
    out = tmp_path / "s.json"
    assert main(["run", "--duration", "0.6", "--inject", "supply_bar=0.3@0.2", "--json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert [a["kind"] for a in s["alarms"]][:1] == ["supply_low"]


def test_retune_scales_the_flow_as_choked_flow_does(cfg):
    """Flow ∝ absolute upstream pressure: the static flow after the change is (p1 + atm)/(p0 + atm) of before."""
    p = Plant(load_plant(cfg.resolve(cfg[""]["plant_config"]), noise_lpm=0.0, scale_factor=0.0), 1000.0)
    s = p.init(50.0)
    for _ in range(5):
        s, before = p.step(s, 50.0)
    p.retune(supply_bar=0.3)
    s, after = p.step(s, 50.0)
    atm, p0 = p.params.atmosphere_bar, 3.0
    assert after.flow_lpm == pytest.approx(before.flow_lpm * (0.3 + atm) / (p0 + atm), rel=1e-9)
    assert after.supply_bar == pytest.approx(0.3)
    with pytest.raises(InputError):
        p.retune(pressure=1.0)
    with pytest.raises(InputError):
        p.retune(transport_delay=1.0)  # longer than the delay line this plant was built with


def test_recorded_reference_replays_a_run_recording(tmp_path, cfg):
    ref = tmp_path / "ref.csv"
    ref.write_text("t_s,ref_lpm,other\n10.0,0,a\n10.1,40,b\n10.3,10,c\n")
    rec, out = tmp_path / "run.csv", tmp_path / "s.json"
    assert main(["run", "--reference", str(ref), "--record", str(rec), "--json", str(out),
                 "--controller", "ff+pid"]) == 0
    lines = rec.read_text().splitlines()[1:]
    t = np.array([float(x.split(",")[0]) for x in lines])
    r = np.array([float(x.split(",")[1]) for x in lines])
    assert t[-1] == pytest.approx(0.3, abs=2e-3)  # the file's span
    assert np.all(r[t < 0.1 - 1e-9] == 0) and np.all(r[(t >= 0.1) & (t < 0.3 - 1e-9)] == 40)
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,ref_lpm\n0,1\n0,2\n")
    assert main(["run", "--reference", str(bad)]) == 2


def test_warm_up_loads_every_kernel_the_live_steps_use_and_leaves_the_supervisor_as_it_was(cfg, model):
    """After the warm-up, live steps of every word, a resume and switches compile or load nothing more
    (a kernel loaded in a live step costs milliseconds: overruns and a late command)."""
    from controller.laws import kalman
    from controller.watchdog import Faults

    sup = supervisor(cfg, "ff+kf", model)
    sup.warm_up(1e-3, 0.0)
    assert (sup.word, sup.pending, sup.mismatch_lpm != sup.mismatch_lpm) == ("ff+kf", None, True)
    kernels = [f for f in (*vars(control).values(), *vars(kalman).values()) if hasattr(f, "signatures")]
    before = {f: len(f.signatures) for f in kernels}
    ctrl = sup.init(30.0, 0.0)
    faults = Faults()
    for k, word in enumerate(sup.laws):
        sup.request(word)
        for i in range(3):
            ctrl, cmd = sup.step(ctrl, 40.0, 30.0 + i, 1e-3, 40.0, k * 0.01 + i * 1e-3, faults)
        ctrl = sup.resume(ctrl, 31.0, cmd[0])
    assert {f: len(f.signatures) for f in kernels} == before
