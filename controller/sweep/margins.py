"""Gain and phase margins of a candidate's loop, linearized at an operating flow (python-control).

The loop is broken at the valve input and written in discrete time at the
loop period ``dt`` (the laws are discrete, so no approximation there):

- valve: ``K z^-1 G_lag(z) z^-d``. ``K`` (L/min per %) is the slope of the
  simulated valve's ascending branch at the operating flow (with its static
  effects: supply, coil, dead zone), from a slow noise-free duty ramp through
  the plant kernel; ``z^-1`` is the loop's timing (the flow measured at step
  k answers the duty of step k-1, :mod:`controller.transport.sim`);
  ``G_lag`` the ``valve_dynamics`` lag, exact ZOH as the kernel steps it;
  ``d`` the ``transport_delay`` in whole periods;
- ``pid`` and ``ff+pid``: ``C(z) = kp + ki dt / (z - 1) + kd (z - 1) / ((tf + dt) z - tf)``,
  the discrete law of :mod:`controller.laws.pid` without its limits (the
  feedforward is a function of the reference alone and is not in the loop);
- ``ff+kf``: the steady-state Kalman filter of :mod:`controller.laws.kalman`
  with the feedforward ``u = invPI(ref - bias)`` linearized as
  ``du = -dbias / K_model`` (``K_model`` the forward model's slope there) and
  the filter's model flow ``dm = K_model du``: a state-space controller
  from measured flow to duty;
- ``ff``: no feedback, infinite margins.

python-control's ``stability_margins`` costs milliseconds per loop, so the
sweep asks it only for its top candidates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.laws import control
from controller.laws import feedforward as ffw

RAMP_STEPS = 4000  # 0 -> 100 % duty: 0.025 % per step
SLOPE_WINDOW_PCT = 1.0


@dataclass(frozen=True)
class OperatingPoint:
    """The valve linearized at a flow.

    Attributes
    ----------
    flow_lpm, duty_pct : float
        Operating flow and the duty giving it on the ascending branch.
    gain_lpm_per_pct : float
        Slope of the ascending branch there.
    lag_s : float
        ``valve_dynamics`` time constant, s (0: none).
    order : int
        Order of the lag (1 or 2).
    delay_steps : int
        ``transport_delay`` in whole loop periods.
    dt_s : float
        Loop period, s.
    """

    flow_lpm: float
    duty_pct: float
    gain_lpm_per_pct: float
    lag_s: float
    order: int
    delay_steps: int
    dt_s: float


def _slope_at(duty: np.ndarray, flow: np.ndarray, flow_lpm: float) -> tuple[float, float]:
    """Duty where an ascending ramp first reaches ``flow_lpm`` and the branch's slope there."""
    i = int(np.argmax(flow >= flow_lpm)) if (flow >= flow_lpm).any() else len(flow) - 1
    d0 = float(duty[i])
    m = np.abs(duty - d0) <= SLOPE_WINDOW_PCT
    return d0, float(np.polyfit(duty[m], flow[m], 1)[0])


def operating_point(plant_params, flow_lpm: float, rate_hz: float) -> OperatingPoint:
    """Linearize a simulated valve (:class:`plant_sim.plant.PlantParams`) at ``flow_lpm``."""
    from plant_sim.plant import BatchPlant

    static = plant_params.replace(noise_lpm=0.0, scale_factor=0.0, valve_dynamics=0.0, transport_delay=0.0)
    duty = np.linspace(0.0, 100.0, RAMP_STEPS)
    bp = BatchPlant([static], rate_hz, [0])
    _, cols = bp.run(bp.init(0.0), duty[None, :])
    d0, k = _slope_at(duty, cols["true_flow_lpm"][0], flow_lpm)
    dt = 1.0 / rate_hz
    return OperatingPoint(float(flow_lpm), d0, k, plant_params.valve_dynamics, plant_params.dynamics_order,
                          int(round(plant_params.transport_delay / dt)), dt)


def model_gain(forward: ffw.ModelBank, j: int, flow_lpm: float) -> float:
    """Slope (L/min per %) of candidate ``j``'s forward model on its ascending branch at ``flow_lpm``."""
    bank = _row(forward, j)
    duty = np.linspace(0.0, 100.0, RAMP_STEPS)
    s = ffw.init(bank, duty[0])
    flow = np.empty(len(duty))
    for k, d in enumerate(duty):
        s, y = ffw.step(bank, s, np.array([d]))
        flow[k] = y[0]
    return _slope_at(duty, flow, flow_lpm)[1]


def _row(bank: ffw.ModelBank, j: int) -> ffw.ModelBank:
    import dataclasses

    return dataclasses.replace(bank, **{f.name: getattr(bank, f.name)[j:j + 1] for f in dataclasses.fields(bank)
                                        if isinstance(getattr(bank, f.name), np.ndarray)})


def plant_tf(op: OperatingPoint):
    """Duty % -> measured flow L/min of the linearized valve, including the loop's one-period delay."""
    import control as ct

    dt = op.dt_s
    g = ct.tf([op.gain_lpm_per_pct], [1.0, 0.0], dt)  # K z^-1
    if op.lag_s > 0:
        if op.order == 1:
            lag = ct.tf([1.0], [op.lag_s, 1.0])
        else:  # critically damped, both poles at 2/tau (plant_sim.kernel)
            lag = ct.tf([1.0], [(op.lag_s / 2) ** 2, op.lag_s, 1.0])
        g = g * ct.c2d(lag, dt, "zoh")
    if op.delay_steps:
        g = g * ct.tf([1.0], [1.0] + [0.0] * op.delay_steps, dt)
    return g


def controller_lti(p: control.ControllerParams, j: int, op: OperatingPoint, k_model: float | None = None):
    """Candidate ``j``'s feedback, measured flow -> duty with the sign of negative feedback; None for ``ff``.

    ``k_model``: the forward model's slope at the operating flow (``ff+kf``;
    computed by :func:`model_gain` when not given).
    """
    import control as ct

    dt = op.dt_s
    if p.mode in ("pid", "ff+pid"):
        kp, ki, kd, tf = (float(getattr(p.pid, n)[j]) for n in ("kp", "ki", "kd", "tf_s"))
        c = ct.tf([kp], [1.0], dt)
        if ki > 0:
            c = c + ct.tf([ki * dt], [1.0, -1.0], dt)
        if kd > 0:
            c = c + ct.tf([kd, -kd], [tf + dt, -tf], dt)
        return c
    if p.mode == "ff+kf":
        if k_model is None:
            k_model = model_gain(p.forward, j, op.flow_lpm)
        return _kalman_lti(p.kf, j, k_model, dt)
    return None


def _kalman_lti(kf, j: int, k_model: float, dt: float):
    """The steady-state filter closed through the linearized feedforward, as a state space.

    State ``[flow, bias, m[k-1], ..., m[k-1-d]]``; per step: predict
    ``p = a flow + (1-a)(m[k-1-d] + bias)``, correct with the measurement z,
    ``u = -bias' / K_model`` and ``m[k] = K_model u = -bias'``.
    """
    import control as ct

    a, kfl, kb, d = float(kf.a[j]), float(kf.k_flow[j]), float(kf.k_bias[j]), int(kf.delay_steps[j])
    n = 3 + d
    pred = np.zeros(n)
    pred[0], pred[1], pred[n - 1] = a, 1.0 - a, 1.0 - a
    e_b = np.zeros(n)
    e_b[1] = 1.0
    A = np.zeros((n, n))
    B = np.zeros((n, 1))
    A[0], B[0, 0] = (1.0 - kfl) * pred, kfl
    A[1], B[1, 0] = e_b - kb * pred, kb
    A[2], B[2, 0] = -(e_b - kb * pred), -kb  # m[k] = -bias'
    for i in range(3, n):
        A[i, i - 1] = 1.0  # shift the history
    # negative-feedback sign: -u = bias' / K_model
    C = ((e_b - kb * pred) / k_model)[None, :]
    D = np.array([[kb / k_model]])
    return ct.ss(A, B, C, D, dt)


@dataclass(frozen=True)
class Margins:
    """Gain margin (dB) and phase margin (degrees) of one loop; ``inf`` when not crossed."""

    gain_margin_db: float
    phase_margin_deg: float


def loop_margins(p: control.ControllerParams, j: int, op: OperatingPoint, k_model: float | None = None) -> Margins:
    """Margins of candidate ``j`` of ``p`` around the valve linearized at ``op`` (``k_model``: see :func:`controller_lti`).

    A delayed loop crosses -180 degrees and unit gain several times; python-control
    finds every crossing (``returnall``), and the margins are the worst of them:
    the least gain margin, and the least phase margin with the phase unwrapped
    from low frequency (a crossing at -190 degrees is a margin of -10, not 170).
    """
    import warnings

    import control as ct

    c = controller_lti(p, j, op, k_model)
    if c is None:
        return Margins(math.inf, math.inf)
    loop = ct.series(c, plant_tf(op)) if isinstance(c, ct.StateSpace) else c * plant_tf(op)
    nyquist = math.pi / op.dt_s
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # epsw: an integrator's loop "crosses" at w = 0, where its gain is infinite; not a margin
        gms, _, _, _, wgcs, _ = ct.stability_margins(loop, returnall=True, epsw=1e-6 * nyquist)
        gms = np.asarray(gms, dtype=np.float64)
        gm = float(np.min(gms)) if gms.size else math.inf
        wgcs = np.asarray(wgcs, dtype=np.float64)
        pm = math.inf
        if wgcs.size:
            w = np.geomspace(nyquist * 1e-6, nyquist, 20000)
            phase = np.unwrap(np.angle(np.asarray(loop(np.exp(1j * w * op.dt_s))).ravel()))
            pm = float(np.min(180.0 + np.degrees(np.interp(wgcs, w, phase))))
    gm_db = 20.0 * math.log10(gm) if np.isfinite(gm) and gm > 0 else math.inf
    return Margins(gm_db, pm)
