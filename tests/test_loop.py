"""The fixed-rate loop against the in-process simulated valve, on a simulated clock."""
from __future__ import annotations

import collections
import json
import math

import numpy as np
import pytest

from controller.alarms import AlarmSettings, Alarms
from controller.config import controller_params, load_run_config
from controller.loop import RECORD_COLUMNS, Loop, LoopSettings, ProfileReference, RealClock, SimClock
from controller.run_summary import steady_mask, summary, tracking
from controller.supervisor import Supervisor
from controller.transport.sim import SimTransport
from controller.watchdog import RUNNING, SAFE
from models.model import load_model
from models.recording import RecordingWriter, read_recording

RATE = 1000.0
SETTINGS = LoopSettings(rate_hz=RATE)


@pytest.fixture(scope="module")
def cfg():
    return load_run_config("config/run.toml")


@pytest.fixture(scope="module")
def model(cfg):
    return load_model(cfg.resolve(cfg[""]["model"]))


def sim_plant(cfg, seed=0, **effects):
    from plant_sim.plant import Plant, load_plant

    pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects={**cfg["effects"], **effects})
    return Plant(pp, RATE, seed=seed)


def square(t, peak=60.0, period_s=1.0):
    return peak if (t % period_s) < period_s / 2 else 20.0


class Dropout(SimTransport):
    """The simulated valve, with measurements lost in a time window or replaced by bad values."""

    def __init__(self, plant, gap=(None, None), bad_at=()):
        super().__init__(plant)
        self.gap, self.bad_at, self.t = gap, dict(bad_at), 0.0

    def poll_measurement(self, accept):
        v, n = super().poll_measurement(accept)
        step = int(round(self.t * RATE))
        if self.gap[0] is not None and self.gap[0] <= self.t < self.gap[1]:
            return None, 0
        if step in self.bad_at:
            bad = self.bad_at[step]
            return (None, 1) if not accept(bad) else (bad, 0)
        return v, n

    def command(self, duty_pct, t_s):
        self.t = t_s + 1.0 / RATE
        super().command(duty_pct, t_s)


def run(cfg, model, word="ff+kf", transport=None, ref=square, duration=2.0, settings=SETTINGS, writer=None,
        clock=None):
    params = controller_params(cfg, word, model)
    transport = transport or SimTransport(sim_plant(cfg))
    loop = Loop(params, transport, ProfileReference(ref), settings, clock=clock or SimClock(), writer=writer)
    return loop.run(duration)


def test_closed_loop_tracks_in_steady_state(cfg, model):
    res = run(cfg, model)
    c = res.columns
    assert res.steps == 2000 and res.overruns == 0
    assert np.all(c["state"][1:] == RUNNING)
    tr = tracking(c["t_s"], c["ref_lpm"], c["flow_lpm"], c["state"] == RUNNING)
    assert tr["steady_mae_lpm"] <= 1.0


def test_stale_measurements_put_the_loop_in_the_safe_state_and_it_resumes(cfg, model):
    stale_ms = SETTINGS.stale_ms
    res = run(cfg, model, transport=Dropout(sim_plant(cfg), gap=(0.7, 0.9)))
    c = res.columns
    safe = np.flatnonzero(c["state"] == SAFE)
    first_safe = safe[safe > 10][0]
    # Safe within stale_ms plus one period of the last fresh measurement, never earlier.
    assert stale_ms < c["meas_age_ms"][first_safe] <= stale_ms + 1e3 / RATE + 1e-9
    assert c["meas_age_ms"][first_safe - 1] <= stale_ms
    gap_rows = c["state"] == SAFE
    assert np.all(c["duty_pct"][gap_rows] == SETTINGS.safe_duty_pct)
    # Back to running on the first fresh measurement, from the safe duty within the rate limit.
    back = np.flatnonzero((c["state"][1:] == RUNNING) & (c["state"][:-1] == SAFE))[-1] + 1
    assert c["meas_age_ms"][back] == 0.0
    rate = cfg["limits"]["rate_pct_per_s"]
    assert abs(c["duty_pct"][back] - SETTINGS.safe_duty_pct) <= rate / RATE + 1e-9
    faults = {f["kind"]: f for f in res.faults.to_list()}
    assert faults["stale"]["count"] == 1
    assert faults["stale"]["first_s"] == pytest.approx(c["t_s"][first_safe])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e6, -300.0])
def test_bad_measurements_are_counted_and_never_reach_the_command(cfg, model, bad):
    steps = range(200, 1800, 97)
    res = run(cfg, model, transport=Dropout(sim_plant(cfg), bad_at={k: bad for k in steps}))
    c = res.columns
    assert np.all(np.isfinite(c["duty_pct"])) and np.all(np.isfinite(c["flow_lpm"][1:]))
    assert res.faults.counts() == {"bad_measurement": len(steps)}
    assert np.all(c["state"][1:] == RUNNING)  # one lost sample is far from stale


def test_bad_references_are_counted_and_the_reference_is_clamped(cfg, model):
    def ref(t):
        k = int(round(t * RATE))
        return {300: math.nan, 400: math.inf, 500: -1e9}.get(k, 230.0 if 1000 <= k < 1100 else 50.0)

    res = run(cfg, model, ref=ref)
    c = res.columns
    assert res.faults.counts() == {"bad_reference": 3}
    assert np.all(np.isfinite(c["duty_pct"]))
    assert c["ref_lpm"].max() == SETTINGS.flow_max_lpm  # 230 clamped to the valve's range
    assert c["ref_lpm"][300] == 50.0  # the last good reference held


class LateClock(SimClock):
    """A simulated clock whose step at ``late_at`` takes ``periods`` periods of compute."""

    def __init__(self, late_at, periods):
        super().__init__()
        self.late_at, self.periods, self.calls = late_at, periods, 0

    def now(self):
        self.calls += 1
        if self.calls == 2 * self.late_at:  # the call after step late_at's compute
            self.t += self.periods / RATE
        return self.t


class LateWakeClock(SimClock):
    """A simulated clock that wakes the loop for its step ``late_at`` ``periods`` periods past the deadline (a host
    that froze the machine while the loop slept)."""

    def __init__(self, late_at, periods):
        super().__init__()
        self.late_at, self.periods, self.waits = late_at, periods, 0

    def wait_until(self, deadline, rehearse=None):
        self.waits += 1
        if self.waits == self.late_at + 1:
            self.t = deadline + self.periods / RATE
        return super().wait_until(deadline, rehearse)


@pytest.mark.parametrize("catch_up", [True, False])
def test_missed_deadlines_are_skipped_and_counted(cfg, model, catch_up):
    """A step computes for 3.5 periods: the next two deadlines pass whole without a step. With catch_up the step
    of the third starts at once, half a period late; without, it is skipped too. Every deadline is a step or an
    overrun."""
    import dataclasses

    res = run(cfg, model, duration=0.5, clock=LateClock(100, 3.5),
              settings=dataclasses.replace(SETTINGS, catch_up=catch_up))
    assert res.overruns == (2 if catch_up else 3)
    assert res.steps + res.overruns == 500
    late = res.columns["lateness_s"]
    if catch_up:
        assert np.count_nonzero(late > 1e-12) == 1 and late.max() == pytest.approx(0.5 / RATE)
    else:
        assert np.all(late < 1e-12)
    assert np.all(np.diff(res.columns["t_s"]) > 0)


@pytest.mark.parametrize("catch_up", [True, False])
def test_a_loop_woken_past_whole_periods_counts_them_and_never_reports_a_step_a_period_late(cfg, model, catch_up):
    """Woken 2.7 periods past deadline 100: with catch_up, 100 and 101 passed whole (overruns) and the step serves
    102, 0.7 periods late; without, it serves 100, 2.7 periods late, and skips 101 and 102. Either way each
    deadline is a step or an overrun, and the step's lateness is recorded as it was."""
    import dataclasses

    res = run(cfg, model, duration=0.5, clock=LateWakeClock(100, 2.7),
              settings=dataclasses.replace(SETTINGS, catch_up=catch_up))
    assert res.overruns == 2
    assert res.steps + res.overruns == 500
    late = res.columns["lateness_s"]
    assert late[100] == pytest.approx((0.7 if catch_up else 2.7) / RATE)
    if catch_up:
        assert np.all(late < 1 / RATE)


def test_record_is_a_recording_with_one_row_per_step_and_summary_has_the_design_keys(cfg, model, tmp_path):
    path = tmp_path / "run.csv"
    with RecordingWriter(path, RECORD_COLUMNS) as w:
        res = run(cfg, model, word="ff+pid", duration=0.5, writer=w)
    rec = read_recording(path)
    assert len(rec) == res.steps
    header = path.read_text().splitlines()[0].split(",")
    assert header[:8] == ["t_s", "ref_lpm", "flow_lpm", "duty_pct", "ff_duty_pct", "fb_duty_pct", "state",
                          "controller"]
    assert set(rec.text_columns["controller"]) == {"ff+pid"}
    s = json.loads(json.dumps(summary(res, "ff+pid", "sim")))
    design = {"controller", "plant", "rate_hz", "steps", "overruns", "lateness_us", "compute_us", "tracking",
              "faults", "alarms"}
    assert set(s) == design | {"compute_cpu_us", "steps_off_cpu"}  # DESIGN.md's keys, and two added beside them
    assert set(s["lateness_us"]) == set(s["compute_us"]) == set(s["compute_cpu_us"]) == {"p50", "p99", "max"}
    assert set(s["tracking"]) == {"mae_lpm", "rmse_lpm", "iae", "steady_mae_lpm"}


def test_steady_mask_needs_100_ms_of_constant_reference():
    t = np.arange(0, 0.5, 0.001)
    ref = np.where(t < 0.2, 10.0, 30.0)
    m = steady_mask(t, ref)
    assert not m[: 100].any() and m[100:200].all()
    assert not m[200:300].any() and m[300:].all()


class SilentAfter:
    """A received reference (like ``…/ref/flow``) that stops arriving at ``t_end``."""

    can_go_stale = True
    preview_s = 0.0

    def __init__(self, value, t_end):
        self.value, self.t_end = value, t_end

    def poll(self, t_s, accept):
        return (self.value, 0) if t_s < self.t_end else (None, 0)


def test_a_reference_that_stops_arriving_drops_to_zero_after_ref_stale_ms(cfg, model):
    params = controller_params(cfg, "ff+kf", model)
    loop = Loop(params, SimTransport(sim_plant(cfg)), SilentAfter(70.0, 0.3), SETTINGS, clock=SimClock())
    res = loop.run(1.0)
    c = res.columns
    late = c["t_s"] - 0.3 + 1e-3  # age of the last reference received (at the step before 0.3 s)
    assert np.all(c["ref_lpm"][late <= SETTINGS.ref_stale_ms * 1e-3] == 70.0)
    assert np.all(c["ref_lpm"][late > SETTINGS.ref_stale_ms * 1e-3 + 1e-3] == 0.0)
    f = {x["kind"]: x for x in res.faults.to_list()}
    assert f["stale_reference"]["count"] == 1
    assert np.all(c["state"][1:] == RUNNING)  # a stale reference is not a stale valve


def test_the_simulated_valve_keeps_time_through_missed_deadlines(cfg, model):
    """After skipped deadlines the plant has stepped once per elapsed period, not once per loop step."""
    transport = SimTransport(sim_plant(cfg))
    res = run(cfg, model, transport=transport, duration=0.5, clock=LateClock(100, 3.5))
    assert res.overruns == 2  # the step ran 3.5 periods: two passed whole (catch_up)
    assert transport.state.k == 1 + res.steps + res.overruns  # the initial read, then one step per period


def test_batch_closed_loop_matches_the_live_loop(cfg, model):
    """The sweep's closed_loop (arrays of candidates) and the live loop (batch of one) agree step for step."""
    import dataclasses

    from controller.laws import control, pid
    from controller.sweep.simulate import closed_loop
    from plant_sim.plant import BatchPlant, load_plant

    def ref(t):
        return 60.0 + 30.0 * math.sin(2 * math.pi * 1.5 * t)

    pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
    kp = np.array([0.1, 0.4])
    base = controller_params(cfg, "ff+pid", model)
    batch = dataclasses.replace(control.repeat(base, 2),
                                pid=pid.PIDParams.make(2, kp=kp, ki=10.0, kd=0.001, tf_s=0.003, tt_s=0.01))
    n, preview = 400, 20
    sim = closed_loop(batch, BatchPlant([pp, pp], RATE, [0, 0]), np.array([ref(k / RATE) for k in range(n)]), RATE,
                      preview)
    for j in range(2):
        one = dataclasses.replace(base, pid=pid.PIDParams.make(1, kp=kp[j], ki=10.0, kd=0.001, tf_s=0.003, tt_s=0.01))
        loop = Loop(one, SimTransport(sim_plant(cfg, seed=0)), ProfileReference(ref, preview / RATE), SETTINGS,
                    clock=SimClock())
        res = loop.run(n / RATE)
        m = n - preview  # closed_loop holds the last reference past its end; the profile goes on
        np.testing.assert_allclose(res.columns["duty_pct"][:m], sim.duty_pct[:m, j], atol=1e-6)
        np.testing.assert_allclose(res.columns["flow_lpm"][:m], sim.flow_lpm[:m, j], atol=1e-6)


class OwnClockSensor(SimClock):
    """A sensor on its own clock for ``trigger = "measurement"``, and the simulated clock: measurements
    arrive at ``arrivals_s``, each the flow of a first-order valve driven by the last command. The loop's
    hook is called at each arrival while the loop's thread sleeps through it (as the transport's thread
    would call it), with the clock at the arrival."""

    def __init__(self, arrivals_s):
        super().__init__()
        self.arrivals = np.asarray(arrivals_s)
        self.delivered = self.polled = 0  # arrivals handed to the hook, taken by a poll
        self.hook = None
        self.flow = 0.0
        self.commands = []

    def on_measurement(self, hook):
        self.hook = hook

    def sleep_until(self, deadline_s):
        while self.delivered < len(self.arrivals) and self.arrivals[self.delivered] <= deadline_s:
            self.t = max(self.t, float(self.arrivals[self.delivered]))
            self.delivered += 1
            if self.hook is not None:
                self.hook(self.t)
        return self.wait_until(deadline_s)

    def poll_measurement(self, accept):
        if self.delivered == self.polled:
            return None, 0
        self.polled = self.delivered
        return self.flow, 0

    def command(self, duty_pct, t_s):
        self.commands.append((self.now(), duty_pct))
        self.flow += 0.3 * (duty_pct - self.flow)

    def publish_error(self, t_s, error_lpm):
        pass

    def publish_status(self, t_s, status):
        pass


def test_measurement_trigger_steps_at_each_arrival_and_the_period_stays_the_watchdog(cfg, model):
    """Jittered arrivals (0.6-1.4 periods apart) each get a step at their own instant; when they stop,
    the watchdog steps every WATCHDOG_PERIODS periods and the loop goes safe with a stale fault."""
    import dataclasses

    from controller.loop import WATCHDOG_PERIODS

    period = 1.0 / RATE
    gaps = np.random.default_rng(3).uniform(0.6, 1.4, 400) * period
    arrivals = 0.0102 + np.cumsum(gaps)  # the first 10 ms without measurements
    sensor = OwnClockSensor(arrivals)
    settings = dataclasses.replace(SETTINGS, trigger="measurement")
    res = Loop(controller_params(cfg, "ff+pid", model), sensor, ProfileReference(lambda t: 30.0), settings,
               clock=sensor).run(arrivals[-1] + 0.2)
    t = res.columns["t_s"]
    stepped = set(np.round(t, 9))
    assert all(round(a, 9) in stepped for a in arrivals)  # a step at every arrival...
    during = (t >= arrivals[0]) & (t <= arrivals[-1])
    assert np.all(np.isin(np.round(t[during], 9), np.round(arrivals, 9)))  # ...and none between them
    assert np.all(res.columns["lateness_s"][during] == 0.0)  # each step at its measurement's arrival
    assert res.overruns == 0
    before, after = t[t < arrivals[0]], t[t > arrivals[-1]]
    for watchdog in (before, after):
        assert np.allclose(np.diff(watchdog), WATCHDOG_PERIODS * period)
    stale = {f["kind"]: f["first_s"] for f in res.faults.to_list()}
    assert arrivals[-1] + settings.stale_ms * 1e-3 <= stale["stale"] <= (arrivals[-1] + settings.stale_ms * 1e-3
                                                                         + WATCHDOG_PERIODS * period)
    assert np.all(res.columns["state"][t > stale["stale"]] == SAFE)
    assert np.all(res.columns["state"][during][5:] == RUNNING)


def test_measurement_trigger_needs_a_transport_that_signals_measurements(cfg, model):
    import dataclasses

    settings = dataclasses.replace(SETTINGS, trigger="measurement")
    loop = Loop(controller_params(cfg, "ff", model), SimTransport(sim_plant(cfg)), ProfileReference(lambda t: 30.0),
                settings, clock=SimClock())
    with pytest.raises(ValueError, match="signals measurements"):
        loop.run(0.01)


class ThreadedSensor:
    """Measurements delivered on a thread of their own (as Zenoh's), ``n`` of them ``gap_s`` apart; records
    which thread computed each command and whether two steps ever overlapped."""

    def __init__(self, n, gap_s):
        import threading

        self.n, self.gap_s, self.hook, self.done_at = n, gap_s, None, None
        self.kept = []
        self.inside = self.overlaps = 0
        self.by_thread = collections.Counter()
        self.thread = threading.Thread(target=self._deliver)

    def on_measurement(self, hook):
        self.hook = hook
        if hook is not None and not self.thread.is_alive():
            self.thread.start()

    def _deliver(self):
        import time

        for _ in range(self.n):
            time.sleep(self.gap_s)
            arrival = time.perf_counter()
            self.kept.append(20.0)
            self.hook(arrival)
        self.done_at = time.perf_counter()

    def poll_measurement(self, accept):
        return (self.kept.pop(), 0) if self.kept else (None, 0)

    def command(self, duty_pct, t_s):
        import threading
        import time

        self.inside += 1
        self.overlaps += self.inside > 1
        time.sleep(20e-6)  # a step long enough for the other thread to try
        self.by_thread[threading.get_ident()] += 1
        self.inside -= 1

    def publish_error(self, t_s, error_lpm):
        pass

    def publish_status(self, t_s, status):
        pass


def test_measurement_trigger_steps_on_the_transports_thread_and_never_twice_at_once(cfg, model):
    """Real clock, a delivering thread: its measurements are stepped on it (the command computed before
    the hook returns), the loop's thread steps only as the watchdog and rehearses the law before the next
    measurement is due, never while a step runs, and when the measurements stop the watchdog's steps take
    the loop to safe."""
    import dataclasses
    import threading

    import time

    sensor = ThreadedSensor(100, 1e-3)
    settings = dataclasses.replace(SETTINGS, trigger="measurement")
    stale_s = settings.stale_ms * 1e-3
    sup = Supervisor.fixed(controller_params(cfg, "ff", model))
    rehearsals, law_rehearse = [], sup.rehearse

    def rehearse(dt_s):  # counted as a step of the loop's thread: never while another runs
        rehearsals.append(threading.get_ident())
        sensor.inside += 1
        sensor.overlaps += sensor.inside > 1
        law_rehearse(dt_s)
        sensor.inside -= 1

    sup.rehearse = rehearse
    loop = Loop(sup, sensor, ProfileReference(lambda t: 30.0), settings, clock=RealClock(0.0))
    res = loop.run(stop=lambda: bool(sensor.done_at) and time.perf_counter() > sensor.done_at + 2 * stale_s)
    sensor.thread.join()
    assert sensor.overlaps == 0
    delivered = sensor.by_thread[sensor.thread.ident]
    assert delivered + res.overruns == 100  # each measurement stepped on its thread or taken by a watchdog step
    assert delivered > 0 and sensor.by_thread[threading.get_ident()] > 0  # the watchdog stepped too
    assert rehearsals and set(rehearsals) == {threading.get_ident()}  # the watchdog's thread rehearsed
    assert "stale" in res.faults.counts()
    assert res.columns["state"][-1] == SAFE


def test_rehearsals_change_nothing(cfg, model):
    """The loop's rehearsal before each deadline (a law's, the valve's and the alarms' step on scratch copies)
    leaves the law, the valve and the alarms exactly where they were: steps interleaved with rehearsals are
    bit-identical."""
    from controller.laws import control

    p = controller_params(cfg, "ff+kf", model)
    rng = np.random.default_rng(5)
    ref, meas = rng.uniform(0, 80, 200), rng.uniform(0, 80, 200)
    runs, alarm_lists = [], []
    for rehearse in (False, True):
        law, valve = control.Live(p), sim_plant(cfg, seed=1).running(sim_plant(cfg).init(0.0))
        alarms = Alarms(AlarmSettings(), 0.0, 100.0)
        law.load(control.init(p, 0.0))
        out = []
        for k in range(len(ref)):
            if rehearse:
                law.rehearse(1e-3)
                valve.rehearse(float(k % 70))
                alarms.rehearse(k * 1e-3 + 5e-4, k % 3 > 0, float(k % 100), -meas[k], meas[k] / 2, 1.0)  # any inputs
            duty = law.step(ref[k], meas[k], ref[k], 1e-3)
            alarms.step(k * 1e-3, True, duty[0], ref[k] - meas[k], meas[k] / 4, 3.0 - k / 50)
            out.append((*duty[:4], valve.step(duty[0]).flow_lpm))
        runs.append(np.array(out))
        alarm_lists.append(alarms.to_list())
    np.testing.assert_array_equal(runs[0], runs[1])
    assert alarm_lists[0] == alarm_lists[1] and alarm_lists[0]  # raised, the same, rehearsed or not


class RehearsingClock(RealClock):
    """Simulated time that rehearses before each deadline as the real clock does (a real clock to the loop,
    which rehearses only on one)."""

    def __init__(self):
        super().__init__(0.0)
        self.t, self.rehearsals = 0.0, 0

    def now(self):
        return self.t

    def wait_until(self, deadline, rehearse=None):
        if rehearse is not None and self.t < deadline:
            rehearse()
            self.rehearsals += 1
        self.t = max(self.t, deadline)
        return self.t

    sleep_until = wait_until


def test_a_rehearsed_run_records_exactly_what_an_unrehearsed_one_does(cfg, model):
    """The loop's whole rehearsal before each deadline (the law's, the valve's and the alarms' steps on scratch
    copies, the reference, the record's next row written ahead) changes nothing: the records, the faults and the
    alarms (raised by a supply drop) of runs with and without it are identical."""
    import dataclasses

    res = []
    for rehearse in (False, True):
        clock = RehearsingClock()
        valve = SimTransport(sim_plant(cfg), 0.0, [(0.6, "supply_bar", 0.3)])
        res.append(run(cfg, model, transport=valve, duration=1.0, clock=clock,
                       settings=dataclasses.replace(SETTINGS, rehearse=rehearse)))
        assert clock.rehearsals == (999 if rehearse else 0)  # every deadline but the first (the start itself)
    (a, b) = res
    assert {al["kind"] for al in b.alarms.to_list()} >= {"supply_low"}
    assert a.alarms.to_list() == b.alarms.to_list() and a.faults.to_list() == b.faults.to_list()
    assert a.columns.keys() == b.columns.keys()
    for k in a.columns:
        if k not in ("compute_s", "cpu_s"):
            np.testing.assert_array_equal(a.columns[k], b.columns[k], err_msg=k)


def test_real_clock_rehearses_before_the_deadline_only():
    """The rehearsal runs once, after the sleep and before the deadline (a host that woke the loop past the
    deadline skips it); a deadline already passed gets none."""
    import time

    clock, at = RealClock(50e-6), []
    deadline = time.perf_counter() + 20e-3
    woke = clock.wait_until(deadline, lambda: at.append(time.perf_counter()))
    # the callback's own timestamp may trail the decision on a busy machine: bounded by the wake, not the deadline
    assert len(at) <= 1 and all(deadline - 20e-3 + 5e-3 < a <= woke for a in at) and woke >= deadline
    at.clear()
    clock.wait_until(time.perf_counter() - 1e-3, lambda: at.append(time.perf_counter()))
    assert at == []


class NodeLink:
    """A valve node's transport that never commands; ``on_publish(seq)`` is called at each measurement."""

    def __init__(self, on_publish=None):
        self.seq, self.on_publish = 0, on_publish

    def poll_command(self, accept):
        return None, 0, None

    def publish_flow(self, t_s, flow_lpm):
        self.seq += 1
        if self.on_publish is not None:
            self.on_publish(self.seq)
        return self.seq

    def publish_aux(self, t_s, values):
        pass


def test_the_loop_and_the_valve_node_run_with_the_collector_paused_and_restore_it(cfg, model):
    """A full collection stands a process still for longer than stale_ms: neither the loop nor the node lets one
    start while it runs, and both hand the collector back as they found it."""
    import gc

    from controller.valve_node import ValveNode

    seen = []

    def stop():
        seen.append((gc.isenabled(), gc.get_freeze_count() > 0))
        return len(seen) >= 5

    assert gc.isenabled()
    loop = Loop(controller_params(cfg, "pid", model), SimTransport(sim_plant(cfg)), ProfileReference(square), SETTINGS,
                clock=SimClock())
    loop.run(None, stop=stop)
    ValveNode(sim_plant(cfg), NodeLink(), RATE, 0.1, SimClock()).run(None, stop=stop)
    assert seen and all(s == (False, True) for s in seen)
    assert gc.isenabled() and gc.get_freeze_count() == 0


@pytest.mark.parametrize("catch_up", [True, False])
def test_the_valve_node_reports_its_longest_gap_between_measurements(cfg, catch_up):
    """A node that stands still (here: one publication taking 70.5 ms) reports that gap, so a controller's stale
    fault can be told apart from a transport that lost the measurements. The deadlines it stood still over count
    as the loop's do (catch_up: the one in progress when it resumes is served at once)."""
    from controller.valve_node import ValveNode

    clock = SimClock()

    def stand_still(seq):
        if seq == 6:
            clock.t += 0.0705

    st = ValveNode(sim_plant(cfg), NodeLink(stand_still), RATE, 0.1, clock, catch_up=catch_up).run(0.2)
    assert st.publish_gap_max_s == pytest.approx(0.0705 + 1 / RATE)
    assert st.to_json()["publish_gap_ms"]["max"] == pytest.approx(71.5)
    assert st.overruns == (69 if catch_up else 70)


def _can_fifo() -> bool:
    """Whether this process may put a thread under SCHED_FIFO (asked of a thread of its own, which then ends)."""
    import os
    import threading

    ok = []

    def probe():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            ok.append(True)
        except (AttributeError, PermissionError):
            ok.append(False)

    t = threading.Thread(target=probe)
    t.start()
    t.join()
    return ok[0]


def test_measurement_trigger_runs_the_steps_at_the_loops_priority_and_restores_it(cfg, model):
    """The transport's thread that steps runs under SCHED_FIFO at the loop's rt_priority during the run, and
    under its own scheduling again after it."""
    import dataclasses
    import os
    import threading
    import time

    if not _can_fifo():
        pytest.skip("no permission for SCHED_FIFO")
    seen, after, release = [], [], threading.Event()

    class Sensor(ThreadedSensor):
        """Its thread started before the run (under the scheduling of the test), delivering once hooked."""

        def on_measurement(self, hook):
            self.hook = hook
            hooked.set()

        def command(self, duty_pct, t_s):
            if threading.current_thread() is self.thread:
                seen.append(os.sched_getscheduler(0))

        def _deliver(self):
            before = os.sched_getscheduler(0)
            hooked.wait(30)
            super()._deliver()
            release.wait(30)
            after.append((before, os.sched_getscheduler(0)))

    hooked = threading.Event()
    sensor = Sensor(30, 1e-3)
    sensor.thread.start()
    settings = dataclasses.replace(SETTINGS, trigger="measurement", rt_priority=1)
    loop = Loop(controller_params(cfg, "ff", model), sensor, ProfileReference(lambda t: 30.0), settings,
                clock=RealClock(0.0))
    loop.run(stop=lambda: bool(sensor.done_at) and time.perf_counter() > sensor.done_at + 0.01)
    release.set()
    sensor.thread.join()
    assert seen and all(p == os.SCHED_FIFO for p in seen)
    assert after == [(after[0][0], after[0][0])] and after[0][0] != os.SCHED_FIFO  # restored after the run


def test_measurement_trigger_a_flood_of_measurements_steps_at_most_at_twice_the_rate_on_average(cfg, model):
    """Measurements 0.1 period apart (a faulty or hostile publisher): they step the laws at most at twice the
    rate on average (plus the burst), every measurement is either stepped or counted as an overrun, and the
    loop keeps running on them."""
    import dataclasses

    from controller.loop import BURST_STEPS

    period = 1.0 / RATE
    arrivals = 0.0005 + np.arange(2000) * 0.1 * period
    sensor = OwnClockSensor(arrivals)
    settings = dataclasses.replace(SETTINGS, trigger="measurement")
    res = Loop(controller_params(cfg, "ff+pid", model), sensor, ProfileReference(lambda t: 30.0), settings,
               clock=sensor).run(arrivals[-1] + 1e-4)
    t = res.columns["t_s"]
    during = t >= arrivals[0]
    assert during.sum() <= 2 * (arrivals[-1] - arrivals[0]) / period + BURST_STEPS + 1
    assert during.sum() + res.overruns >= len(arrivals)  # each stepped, or counted (watchdog steps take some)
    assert np.all(res.columns["state"][during][1:] == RUNNING) and "stale" not in res.faults.counts()


def test_cpu_time_beside_compute_time_leaves_out_the_time_off_cpu(cfg, model):
    """Each step records its thread's CPU time beside its wall time (``compute_s``): a step whose thread slept
    3 ms (off its CPU, as a step the host stole from) has 3 ms more wall than CPU time and counts in
    ``steps_off_cpu``; ``compute_us`` stays the wall figure."""
    import time

    from controller.run_summary import OFF_CPU_US

    sleepers = {100, 250, 400}

    class Sleepy(Dropout):
        n = 0

        def command(self, duty_pct, t_s):
            if self.n in sleepers:
                time.sleep(3e-3)
            self.n += 1
            super().command(duty_pct, t_s)

    res = run(cfg, model, transport=Sleepy(sim_plant(cfg)), duration=0.5)
    c = res.columns
    wall, cpu = c["compute_s"], c["cpu_s"]
    assert np.all(cpu > 0) and np.all(np.isfinite(cpu))
    k = sorted(sleepers)
    assert np.all(wall[k] >= 3e-3) and np.all(wall[k] - cpu[k] >= 2.5e-3)  # the sleep is wall time, not CPU
    assert np.median(cpu - wall) <= 5e-6  # the CPU reads enclose the wall reads: no more than their own cost
    s = summary(res, "ff+kf", "sim")
    assert s["compute_us"]["max"] == pytest.approx(float(np.max(wall)) * 1e6)
    assert s["compute_cpu_us"]["max"] == pytest.approx(float(np.max(cpu)) * 1e6)
    assert s["steps_off_cpu"] == int(np.count_nonzero(wall - cpu > OFF_CPU_US * 1e-6)) >= len(sleepers)


def test_each_status_has_the_counts_a_recount_gives(cfg, model, monkeypatch):
    """The status reuses its faults' and alarms' counts until they change (Faults.changes, the alarms' change
    count): every status published carries exactly what a recount at that step gives, through faults, an
    alarm raised and cleared, and a stale gap."""
    import msgspec

    import controller.loop as loop_mod

    made = {}

    class Watched(loop_mod.Faults):
        def __init__(self):
            super().__init__()
            made["faults"] = self

    class WatchedAlarms(loop_mod.Alarms):
        def __init__(self, *a):
            super().__init__(*a)
            made["alarms"] = self

    monkeypatch.setattr(loop_mod, "Faults", Watched)
    monkeypatch.setattr(loop_mod, "Alarms", WatchedAlarms)
    statuses, recounts = [], []

    class Watching(Dropout):
        def publish_status(self, t_s, status):
            statuses.append(msgspec.to_builtins(status))
            f, a = made["faults"], made["alarms"]
            recounts.append(json.loads(json.dumps({"faults": f.counts(), "alarms": a.active(),
                                                   "alarm_counts": a.counts()})))

    valve = Watching(sim_plant(cfg), gap=(1.5, 1.6), bad_at={300: math.nan, 320: 1e6, 1750: math.inf})
    valve._injections = [(0.5, "supply_bar", 0.3), (0.9, "supply_bar", 3.0), (1.2, "supply_bar", 0.3),
                         (1.4, "supply_bar", 3.0)]
    res = run(cfg, model, transport=valve, duration=2.0)
    assert len(statuses) == 20
    for st, rc in zip(statuses, recounts):
        assert {k: st[k] for k in rc} == rc
    assert any("supply_low" in st["alarms"] for st in statuses) and "supply_low" not in statuses[-1]["alarms"]
    assert statuses[-1]["alarm_counts"]["supply_low"] == 2
    assert set(statuses[-1]["faults"]) == {"bad_measurement", "stale"} == set(res.faults.counts())


def test_alarms_change_count_moves_whenever_an_alarm_is_raised_or_cleared():
    """The alarms' change count (the status's cue to recount) moves exactly when the active alarms or the
    counts change."""
    alarms = Alarms(AlarmSettings(), 0.0, 100.0)
    rng = np.random.default_rng(3)
    seen = (alarms.view[alarms.CHANGES_AT], alarms.active(), alarms.counts())
    moved = 0
    for k in range(3000):
        supply = 1.0 if (k // 200) % 2 else 3.0
        alarms.step(k * 1e-3, True, float(rng.uniform(0, 100)), float(rng.normal(0, 3)),
                    float(rng.normal(0, 12)), supply)
        now = (alarms.view[alarms.CHANGES_AT], alarms.active(), alarms.counts())
        assert (now[0] != seen[0]) == (now[1:] != seen[1:])
        moved += now[0] != seen[0]
        seen = now
    assert moved >= 10


def test_a_status_is_published_as_the_dict_it_replaces_and_reads_by_key():
    """The status record (msgspec Struct) makes the very payload the dict of the same fields made, JSON or not
    (numpy scalars take ``json``'s path), and reads by key as the dict did (the run's progress line)."""
    import numpy as np

    from controller.loop import Status
    from controller.transport.payload import encode

    fields = dict(state="running", controller="ff+kf", ref_lpm=40.0, flow_lpm=None, duty_pct=51.5,
                  error_lpm=None, iae=0.25, steps=1200, overruns=3, lateness_us_max=12.5, compute_us_max=31.0,
                  faults={"stale": 1}, alarms=["supply_low"], alarm_counts={"supply_low": 2})
    st = Status(**fields)
    assert encode(1.5, 7, st) == encode(1.5, 7, dict(fields))
    assert json.loads(encode(1.5, 7, st))["value"] == fields
    assert all(st[k] == v for k, v in fields.items())
    numpy_st = Status(**{**fields, "duty_pct": np.float64(51.5), "iae": np.float64(0.25)})
    assert json.loads(encode(1.5, 7, numpy_st))["value"] == fields
