"""The simulated valve as a node of its own: the stand-in for the hardware bridge.

It steps a :class:`plant_sim.plant.Plant` at a fixed rate (the loop's
scheduling, :class:`controller.loop.RealClock`), applies the newest valid
``cmd/duty`` and publishes the measured flow every step. Its own command
timeout closes the valve: a dead controller commands nothing, so after
``command_timeout_ms`` without a command the duty falls to 0 %.

It also publishes the supply pressure and the coil temperature at
``aux_hz`` (the plant's outputs; keys :data:`controller.transport.zenoh.AUX_KEYS`),
and times the round trip from publishing a measurement to receiving the
command computed from it (the command's ``meas_seq``), and keeps the longest time
between two of its measurements: a controller's ``stale`` fault with a gap here
as long is the node standing still, not the transport. Like the control loop,
it runs with the garbage collector paused.
"""
from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np

from .loop import Deadlines, gc_paused
from .watchdog import Watchdog, in_range

#: Publication times kept for the round trip, by ``seq`` modulo this (s of measurements at 1 kHz).
SEQ_RING = 4096


@dataclass
class NodeStats:
    steps: int = 0
    overruns: int = 0
    commands: int = 0
    bad_commands: int = 0
    timeouts: int = 0  # times the command timeout closed the valve
    compute_max_s: float = 0.0  # longest step, wake to end, s
    publish_gap_max_s: float = 0.0  # longest time between two published measurements, s (the node standing still)
    round_trip_s: array = field(default_factory=lambda: array("d"))  # measurement published -> its command received

    def to_json(self) -> dict:
        """N.json of DESIGN.md."""
        rt = np.frombuffer(self.round_trip_s, dtype=np.float64) if len(self.round_trip_s) else np.empty(0)
        pct = {k: (float(np.percentile(rt, q)) * 1e6 if len(rt) else None) for k, q in (("p50", 50), ("p99", 99))}
        return {"steps": self.steps, "overruns": self.overruns, "commands": self.commands,
                "bad_commands": self.bad_commands, "command_timeouts": self.timeouts,
                "round_trip_us": {**pct, "n": len(rt)}, "compute_us": {"max": self.compute_max_s * 1e6},
                "publish_gap_ms": {"max": self.publish_gap_max_s * 1e3}}


class ValveNode:
    """Parameters: a plant (stepped at ``rate_hz``), a transport with ``poll_command(accept) ->
    (duty | None, n_bad, meas_seq | None)``, ``publish_flow(t_s, flow) -> seq`` and
    ``publish_aux(t_s, {column: value})``, the command timeout (s), a clock, the rate of
    the auxiliary measurements (Hz, 0: none) and the loop's rule for late steps
    (:attr:`controller.loop.LoopSettings.catch_up`)."""

    def __init__(self, plant, transport, rate_hz: float, command_timeout_s: float, clock, aux_hz: float = 0.0,
                 catch_up: bool = True):
        self.plant, self.transport, self.rate_hz, self.catch_up = plant, transport, rate_hz, catch_up
        self.timeout_s, self.clock = command_timeout_s, clock
        self.aux_every = max(1, int(round(rate_hz / aux_hz))) if aux_hz > 0 else 0
        self.stats = NodeStats()

    def run(self, duration_s: float | None = None, stop=None) -> NodeStats:
        """Step until ``duration_s`` or ``stop()``, the garbage collector paused (:func:`controller.loop.gc_paused`:
        a full collection here stood the node still for ~0.1 s, past the controller's ``stale_ms``)."""
        with gc_paused():
            return self._run(duration_s, stop)

    def _run(self, duration_s: float | None, stop) -> NodeStats:
        period = 1.0 / self.rate_hz
        accept = in_range(0.0, 100.0)
        st = self.stats = NodeStats()  # kept on the node: an interrupted run still reports
        state = self.plant.init(0.0)
        duty, closed = 0.0, True
        clock = self.clock
        t0 = clock.now()
        dog = Watchdog(self.timeout_s, 0.0)
        deadlines = Deadlines(t0, period, self.catch_up)
        sent_t = np.full(SEQ_RING, np.nan)  # publication time of measurement seq, at seq % SEQ_RING
        sent_seq = np.full(SEQ_RING, -1, dtype=np.int64)
        last_published = t0
        while True:
            now = clock.wait_until(deadlines.next)
            st.overruns += deadlines.woken(now)  # woken after whole periods: missed (controller.loop)
            t = now - t0
            v, bad, meas_seq = self.transport.poll_command(accept)
            st.bad_commands += bad
            if v is not None:
                duty, closed = v, False
                st.commands += 1
                dog.fresh(t)
                if meas_seq is not None and meas_seq >= 0 and sent_seq[meas_seq % SEQ_RING] == meas_seq:
                    st.round_trip_s.append(now - sent_t[meas_seq % SEQ_RING])
            elif dog.stale(t) and not closed:
                duty, closed = 0.0, True
                st.timeouts += 1
            state, out = self.plant.step(state, duty)
            seq = self.transport.publish_flow(t, out.flow_lpm)
            published = clock.now()
            if st.steps:
                st.publish_gap_max_s = max(st.publish_gap_max_s, published - last_published)
            last_published = published
            sent_t[seq % SEQ_RING], sent_seq[seq % SEQ_RING] = published, seq
            if self.aux_every and st.steps % self.aux_every == 0:
                self.transport.publish_aux(t, {"supply_bar": out.supply_bar, "coil_temp_c": out.coil_temp_c})
            st.steps += 1
            st.compute_max_s = max(st.compute_max_s, clock.now() - now)
            if (duration_s is not None and t >= duration_s) or (stop is not None and stop()):
                return st
            st.overruns += deadlines.ended(clock.now())
