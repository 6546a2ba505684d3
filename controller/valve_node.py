"""The simulated valve as a node of its own: the stand-in for the hardware bridge.

It steps a :class:`plant_sim.plant.Plant` at a fixed rate (the loop's
scheduling, :class:`controller.loop.RealClock`), applies the newest valid
``cmd/duty`` and publishes the measured flow every step. Its own command
timeout closes the valve: a dead controller commands nothing, so after
``command_timeout_ms`` without a command the duty falls to 0 %.
"""
from __future__ import annotations

from dataclasses import dataclass

from .watchdog import Watchdog, in_range


@dataclass
class NodeStats:
    steps: int = 0
    overruns: int = 0
    commands: int = 0
    bad_commands: int = 0
    timeouts: int = 0  # times the command timeout closed the valve


class ValveNode:
    """Parameters: a plant (stepped at ``rate_hz``), a transport with ``poll_command(accept)``
    and ``publish_flow(t_s, flow)``, the command timeout (s) and a clock."""

    def __init__(self, plant, transport, rate_hz: float, command_timeout_s: float, clock):
        self.plant, self.transport, self.rate_hz = plant, transport, rate_hz
        self.timeout_s, self.clock = command_timeout_s, clock

    def run(self, duration_s: float | None = None, stop=None) -> NodeStats:
        period = 1.0 / self.rate_hz
        accept = in_range(0.0, 100.0)
        st = NodeStats()
        state = self.plant.init(0.0)
        duty, closed = 0.0, True
        clock = self.clock
        t0 = clock.now()
        dog = Watchdog(self.timeout_s, 0.0)
        deadline = t0
        while True:
            now = clock.wait_until(deadline)
            t = now - t0
            v, bad = self.transport.poll_command(accept)
            st.bad_commands += bad
            if v is not None:
                duty, closed = v, False
                st.commands += 1
                dog.fresh(t)
            elif dog.stale(t) and not closed:
                duty, closed = 0.0, True
                st.timeouts += 1
            state, out = self.plant.step(state, duty)
            self.transport.publish_flow(t, out.flow_lpm)
            st.steps += 1
            if (duration_s is not None and t >= duration_s) or (stop is not None and stop()):
                return st
            deadline += period
            behind = clock.now() - deadline
            if behind > 0:
                missed = int(behind / period) + 1
                deadline += missed * period
                st.overruns += missed
