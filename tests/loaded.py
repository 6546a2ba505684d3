"""A loaded machine, emulated deterministically in-process: a session's stalls, and a valve that runs on
through them (tests and benches of ``valvectl identify``)."""
from __future__ import annotations

import numpy as np

from controller.loop import SimClock
from controller.transport.sim import SimTransport


class Busy(SimClock):
    """A loaded machine's clock, deterministic: each step, with probability ``p``, the process is
    descheduled for an exponentially distributed time (mean ``mean_s``)."""

    def __init__(self, p, mean_s, seed):
        super().__init__()
        self.p, self.mean_s, self.rng = p, mean_s, np.random.default_rng(seed)

    def wait_until(self, deadline):
        t = super().wait_until(deadline)
        if self.rng.random() < self.p:
            self.t = t + self.rng.exponential(self.mean_s)
        return self.t


class Bridge(SimTransport):
    """A valve whose bridge runs on its own clock through the session's stalls: it holds the last duty,
    and a poll reads its newest measurement (time ``clock.now()``)."""

    def __init__(self, plant, clock):
        super().__init__(plant)
        self.clock, self.k = clock, 0

    def _run_to(self, t_s):
        n = int(round(t_s * self.plant.rate_hz))
        while self.k < n:
            self.last = self._valve.step(self._duty)
            self._meas, self.k = self.last.flow_lpm, self.k + 1

    def poll_measurement(self, accept):
        self._run_to(self.clock.now())
        return super().poll_measurement(accept)

    def command(self, duty_pct, t_s):
        self._run_to(t_s)
        self._duty = duty_pct
