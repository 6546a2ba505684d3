"""The in-process simulated valve: the loop steps a :class:`plant_sim.plant.Plant` directly.

Each command steps the plant one period; the flow it measures is the loop's
measurement at the next step, one period later, as a sensor read at the
start of the period would be. The plant's rate is the loop's rate. When the
loop missed deadlines, the valve went on in the meantime: the plant first
steps through the missed periods with the duty it had, so simulated time
keeps up with the loop's clock.

Injections (``valvectl run --inject NAME=VALUE@T``) change a setting of the
running valve (:meth:`plant_sim.plant.Plant.retune`) at the first command
at or after their time, so a test can fail the gas supply mid-breath.
"""
from __future__ import annotations


class SimTransport:
    """Loop transport around one simulated valve.

    Parameters
    ----------
    plant : plant_sim.plant.Plant
        Stepped at the loop rate.
    duty0_pct : float
        Duty the valve rests at before the loop starts (0 = closed).
    injections : sequence of (float, str, float)
        ``(t_s, setting, value)``: from ``t_s`` on, the valve's ``setting`` is ``value``.
    """

    def __init__(self, plant, duty0_pct: float = 0.0, injections=()):
        self.plant = plant
        self._rate_hz = plant.rate_hz
        self._injections = sorted(injections, key=lambda x: x[0])
        self._valve = plant.running(plant.init(duty0_pct))
        out = self._valve.step(duty0_pct)
        self._meas = out.flow_lpm
        self.last = out
        self._duty = duty0_pct
        self._k = None  # period of the last command (t_s / period, whole)

    @property
    def state(self):
        """The valve's state now (a copy)."""
        return self._valve.state

    def poll_measurement(self, accept) -> tuple[float | None, int]:
        v, self._meas = self._meas, None
        if v is None:
            return None, 0
        return (v, 0) if accept(v) else (None, 1)

    def supply_bar(self) -> float:
        """The supply pressure the valve saw at its last step, bar gauge."""
        return self.last.supply_bar

    def command(self, duty_pct: float, t_s: float) -> None:
        while self._injections and self._injections[0][0] <= t_s + 1e-9:
            _, name, value = self._injections.pop(0)
            self.plant.retune(**{name: value})
        # The period this step falls in: a step starts within its deadline's period (the loop's catch_up), so
        # the valve steps once per period, missed ones (the duty held) included, however late the steps start.
        k = int(t_s * self._rate_hz + 1e-6)
        if self._k is not None and k - self._k > 1:  # missed periods
            for _ in range(k - self._k - 1):
                self._valve.step(self._duty)
        self._k, self._duty = k, duty_pct
        self.last = self._valve.step(duty_pct)
        self._meas = self.last.flow_lpm

    def rehearse(self) -> None:
        """The valve's next step on a scratch copy (:meth:`plant_sim.plant.RunningPlant.rehearse`): nothing changes."""
        self._valve.rehearse(self._duty)

    def publish_error(self, t_s: float, error_lpm: float) -> None:
        """Nothing listens in-process: the loop records the error."""

    def publish_status(self, t_s: float, status) -> None:
        """Nothing listens in-process."""

    def close(self) -> None:
        """Nothing to release."""
