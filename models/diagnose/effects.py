"""Physical models of the effects a hysteresis simulation may leave out.

Each function is one law, written from the physics of a proportional
solenoid valve and its flow sensor, in physical units. The augmented model
(:mod:`models.diagnose.design`) chains them around the hysteresis core::

    duty -> coil heating (effective duty) -> hysteresis
         -> dead zone, asymmetric descending branch -> supply pressure gain
         -> transport delay, plunger/flow lag -> creep -> saturation -> + sensor offset

Every function takes whole arrays and is causal, so chunked use only needs
the initial value (``x0``/``state``) as ``lfilter``'s ``zi`` would.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

#: Temperature coefficient of copper resistance (1/K): +0.393 %/K.
ALPHA_CU_PER_K = 0.00393
#: Standard atmosphere (bar), to turn gauge into absolute pressure.
P_ATM_BAR = 1.01325
#: Duty at which DESIGN.md states the steady coil temperature rise (%).
HEATING_REF_DUTY_PCT = 55.0
#: Full-scale flow of the valve class (L/min), DESIGN.md: 0-200 L/min.
FULL_FLOW_LPM = 200.0


def first_order_lag(x: np.ndarray, rate_hz: float, tau_s: float, x0=None) -> np.ndarray:
    """``tau dy/dt = x - y`` with ``x`` held between samples (exact zero-order-hold discretization).

    ``y[k+1] = a y[k] + (1 - a) x[k]``, ``a = exp(-1 / (rate tau))``: a sample
    reflects the input up to the previous sample, as a valve driven by a
    sampled command does; as ``tau -> 0`` it tends to a one-sample delay.

    Parameters
    ----------
    x : ndarray, shape (N,) or (N, p)
        Input, any unit; filtered along axis 0.
    rate_hz : float
        Sample rate (Hz).
    tau_s : float
        Time constant (s); 0 returns ``x``.
    x0 : float or ndarray, optional
        Initial output (default: the first input, i.e. starting at rest).
    """
    x = np.asarray(x, dtype=np.float64)
    if tau_s <= 0:
        return x.copy()
    a = np.exp(-1.0 / (rate_hz * tau_s))
    y0 = np.asarray(x[0] if x0 is None else np.broadcast_to(np.asarray(x0, dtype=np.float64), x.shape[1:]))
    # y[k] = a y[k-1] + (1 - a) x[k-1]: filter the input shifted by one sample, starting at y0
    xs = np.concatenate([np.broadcast_to(y0, (1,) + x.shape[1:]), x[:-1]], axis=0)
    zi = (a * y0)[None, ...] if x.ndim > 1 else np.atleast_1d(a * y0)
    y, _ = lfilter([1.0 - a], [1.0, -a], xs, axis=0, zi=zi)
    return y


def delayed(x: np.ndarray, rate_hz: float, delay_s: float) -> np.ndarray:
    """``x(t - delay)`` by linear interpolation between samples; the first value is held before the start.

    Parameters
    ----------
    x : ndarray, shape (N,) or (N, p)
        Signal sampled at ``rate_hz``.
    delay_s : float
        Pure delay (s), >= 0.
    """
    x = np.asarray(x, dtype=np.float64)
    if delay_s <= 0:
        return x.copy()
    shift = delay_s * rate_hz
    m, frac = int(np.floor(shift)), shift - np.floor(shift)
    n = x.shape[0]
    idx = np.arange(n) - m
    i0 = np.clip(idx, 0, n - 1)
    i1 = np.clip(idx - 1, 0, n - 1)
    return (1.0 - frac) * x[i0] + frac * x[i1]


def coil_temperature_rise(duty_pct: np.ndarray, rate_hz: float, tau_s: float, rise55_k: float,
                          t0_k: float | None = None) -> np.ndarray:
    """Coil temperature rise above ambient (K), a first-order thermal state.

    The PWM current through the coil's inductance is about ``duty * V / R``,
    so the dissipated power and the steady rise go with ``duty**2``::

        tau dT/dt = rise55 * (duty / 55 %)**2 - T

    Parameters
    ----------
    duty_pct : ndarray
        Command duty (%).
    tau_s : float
        Thermal time constant (s).
    rise55_k : float
        Steady rise at 55 % duty (K), the parameter of DESIGN.md.
    t0_k : float, optional
        Rise at the first sample; default: steady state for the first duty.
    """
    steady = rise55_k * (np.asarray(duty_pct, dtype=np.float64) / HEATING_REF_DUTY_PCT) ** 2
    return first_order_lag(steady, rate_hz, tau_s, steady[0] if t0_k is None else t0_k)


def effective_duty(duty_pct: np.ndarray, rise_k: np.ndarray, ref_rise_k: float = 0.0) -> np.ndarray:
    """Duty that gives the same coil current at the reference temperature (%).

    The magnetic force follows the current ``duty * V / R(T)`` with
    ``R(T) = R_ref (1 + alpha (T - T_ref))``.
    """
    return np.asarray(duty_pct) * (1.0 + ALPHA_CU_PER_K * ref_rise_k) / (1.0 + ALPHA_CU_PER_K * np.asarray(rise_k))


def pressure_gain(supply_bar: np.ndarray, ref_bar: float, exponent: float) -> np.ndarray:
    """Flow gain from the upstream pressure: ``((p + p_atm) / (p_ref + p_atm)) ** exponent``.

    Choked flow through an orifice is proportional to the upstream absolute
    pressure (exponent 1); subsonic flow depends on it more weakly.
    """
    return ((np.asarray(supply_bar) + P_ATM_BAR) / (ref_bar + P_ATM_BAR)) ** exponent


def reversal_step(flow_lpm: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Signed flow change between the last two reversals (L/min), held until the next reversal.

    Parameters
    ----------
    flow_lpm : ndarray
        Flow (L/min).
    direction : ndarray
        +1 / -1 for the branch the input is on (0 before its first motion);
        a reversal is where it changes sign.
    """
    flow_lpm = np.asarray(flow_lpm, dtype=np.float64)
    rev = np.flatnonzero((direction[1:] != direction[:-1]) & (direction[:-1] != 0)) + 1
    # the reversal instant is the last sample of the old branch (the extreme of the input)
    at = flow_lpm[np.maximum(rev - 1, 0)]
    step = np.concatenate([[0.0], np.diff(at)])  # step j holds from reversal j on (none before the second)
    which = np.full(len(flow_lpm), -1)
    which[rev] = np.arange(len(rev))
    np.maximum.accumulate(which, out=which)
    return np.where(which >= 0, step[np.maximum(which, 0)], 0.0)


def creep(flow_lpm: np.ndarray, direction: np.ndarray, rate_hz: float, tau_s: float) -> np.ndarray:
    """Creep per unit amplitude (L/min): after each reversal the flow drifts on the way it went,
    towards the last reversal-to-reversal flow step, with time constant ``tau_s``.

    ``tau dz/dt = s(t) - z`` with ``s`` the :func:`reversal_step`; the creep is
    ``a z`` for an amplitude ``a`` (fraction of the last reversal step).
    """
    return first_order_lag(reversal_step(flow_lpm, direction), rate_hz, tau_s, 0.0)


def descending_excess(play_out: np.ndarray, x_unit: np.ndarray, w: np.ndarray) -> np.ndarray:
    """How far the play operators hold the output above the input: ``sum_i w_i max(y_i - x, 0)``.

    On a descending branch each operator lags the input from above
    (``y_i = x + r_i`` once it moves), so this is the part of the loop width
    the descending branch adds, in the output unit of ``w``; it is zero on an
    ascending branch. Scaling it by the flow level gives a descending branch
    that widens at high flow.
    """
    return np.maximum(play_out - np.asarray(x_unit)[:, None], 0.0) @ np.asarray(w)


def loop_offset(play_out: np.ndarray, x_unit: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Signed distance of a PI output from its anhysteretic curve: ``sum_i w_i (y_i - x)``.

    Positive on descending branches, negative on ascending ones; scaling it
    widens or narrows the whole loop (what a baseline fitted with a lag or an
    asymmetry present has bent its weights to).
    """
    return (play_out - np.asarray(x_unit)[:, None]) @ np.asarray(w)


def open_mask(duty_pct: np.ndarray, cracking_pct: float) -> np.ndarray:
    """1 where the duty exceeds the cracking duty, 0 where the valve stays shut."""
    return (np.asarray(duty_pct) > cracking_pct).astype(np.float64)
