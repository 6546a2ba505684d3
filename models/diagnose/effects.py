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
from numba import njit

from .. import play

#: Temperature coefficient of copper resistance (1/K): +0.393 %/K.
ALPHA_CU_PER_K = 0.00393
#: Standard atmosphere (bar), to turn gauge into absolute pressure.
P_ATM_BAR = 1.01325
#: Supply (bar gauge) of DESIGN.md's reference hardware: what a model file that does not record the
#: supply of its identification recording was identified at.
REFERENCE_SUPPLY_BAR = 3.0
#: Duty at which DESIGN.md states the steady coil temperature rise (%).
HEATING_REF_DUTY_PCT = 55.0


def first_order_lag(x: np.ndarray, rate_hz: float, tau_s: float, x0=None, phase: float = 1.0) -> np.ndarray:
    """``tau dy/dt = x - y`` sampled, ``y[k] = a y[k-1] + (1 - a) ((1 - phase) x[k] + phase x[k-1])``.

    ``a = exp(-1 / (rate tau))``. With ``phase`` 1 the input is held between
    samples (exact zero-order hold): a sample reflects the input up to the
    previous sample, as a valve driven by a sampled command and read just
    before the next command; as ``tau -> 0`` it tends to a one-sample delay.
    With ``phase`` 0 a sample already reflects its own row's input (a flow read
    at the end of the period, or averaged over it), and as ``tau -> 0`` it
    tends to the input itself. Which one a recording follows is its timing
    convention, not the valve's physics.

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
    phase : float
        Share of the previous sample's input in each update, 0..1.
    """
    x = np.asarray(x, dtype=np.float64)
    if tau_s <= 0:
        return x.copy()
    a = np.exp(-1.0 / (rate_hz * tau_s))
    y0 = x[0] if x0 is None else np.broadcast_to(np.asarray(x0, dtype=np.float64), x.shape[1:])
    # every column through one compiled pass over the rows: lfilter along axis 0 of a tall,
    # narrow array walked it column by column with a strided copy each, and the shifted input
    # and the update were two more arrays of its size (the lag's screen and every PI refit
    # under a lag run this on N x 51 operator outputs)
    cols = np.ascontiguousarray(x.reshape(len(x), -1))
    y = _lag(cols, np.ascontiguousarray(np.reshape(y0, -1), dtype=np.float64), float(a), float(phase))
    return y.reshape(x.shape)


@njit(cache=True)
def _lag(x, y0, a, phase):
    """:func:`first_order_lag`'s recursion down each column, compiled.

    ``y[k] = a y[k-1] + (1 - a) u[k]`` with ``u[k] = (1 - phase) x[k] + phase x[k-1]`` and
    ``x[-1] = y[-1] = y0``; each step's operations in the order
    ``lfilter([1 - a], [1, -a], u, zi=a y0)`` takes them, so the two agree bit for bit.

    Parameters
    ----------
    x : ndarray, shape (N, p), C-contiguous
        Input, any unit.
    y0 : ndarray, shape (p,)
        Initial output and previous input (the input's unit).
    a : float
        ``exp(-1 / (rate tau))``, the pole (dimensionless).
    phase : float
        Share of the previous sample's input in each update, 0..1.

    Returns
    -------
    ndarray, shape (N, p)
        Output, the input's unit.
    """
    out = np.empty_like(x)
    b = 1.0 - a
    y = y0.copy()
    prev = y0.copy()
    for k in range(x.shape[0]):
        for j in range(x.shape[1]):
            u = prev[j] if phase == 1.0 else (1.0 - phase) * x[k, j] + phase * prev[j]
            y[j] = a * y[j] + b * u
            out[k, j] = y[j]
            prev[j] = x[k, j]
    return out


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

    def back(k):
        # x[max(i - k, 0)] for every row i, as a contiguous copy rather than a gather by index
        # (the delay's screen runs this on every column of the design)
        k = min(k, n)
        return np.concatenate([np.repeat(x[:1], k, axis=0), x[:n - k]])

    return (1.0 - frac) * back(m) + frac * back(m + 1)


def advanced(x: np.ndarray, rate_hz: float, delay_s: float) -> np.ndarray:
    """``x(t + delay)``, the inverse of :func:`delayed` (the last value held past the end)."""
    return delayed(np.asarray(x)[::-1], rate_hz, delay_s)[::-1]


def lag_input(y: np.ndarray, rate_hz: float, tau_s: float, phase: float = 1.0) -> np.ndarray:
    """The input of :func:`first_order_lag` recovered from its output (a one-step inverse).

    ``(y[k] - a y[k-1]) / (1 - a)`` is the input's update ``(1 - phase) x[k] + phase x[k-1]``, and
    is returned ``round(phase)`` samples earlier, aligned with ``x``; the last value is held. It
    amplifies white noise on ``y`` by ``sqrt(1 + a^2) / (1 - a)``.
    """
    y = np.asarray(y, dtype=np.float64)
    if tau_s <= 0 or len(y) < 2:
        return y.copy()
    a = np.exp(-1.0 / (rate_hz * tau_s))
    u = np.concatenate([y[:1], (y[1:] - a * y[:-1]) / (1.0 - a)])
    if round(phase) >= 1:
        u = np.concatenate([u[1:], u[-1:]])
    return u


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
    """Signed flow change between the last two turning points (L/min), held until the next reversal.

    The recording starts at rest at its first input (Eq. 3 with ``y_i0 = x(0)``),
    so its start is the first turning point: from the first reversal on, the
    step is the flow change since the start.

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
    if not len(rev):  # never turned back: no step to creep after
        return np.zeros(len(flow_lpm))
    # the reversal instant is the last sample of the old branch (the extreme of the input)
    at = np.concatenate([[flow_lpm[0]], flow_lpm[np.maximum(rev - 1, 0)]])
    step = np.diff(at)  # step j holds from reversal j on
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


def descending_lift(play_out: np.ndarray, x_unit: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Sensitivity of each play operator to a descending threshold that grows with the input level.

    The generalized play operator (Al Janaideh, Rakheja & Su 2009) of an
    asymmetric valve is ``y_i = max(x - r_i, min(x + r_i + l(x), y_i(k-1)))``
    with a lift ``l(x) = c s(x)`` of its descending threshold, ``s`` the position
    in the input range (0 at the bottom, 1 at the top). To first order in ``c``,
    ``dy_i/dc`` is ``s(x)`` while the descending bound drives the operator, keeps
    the value it had when the bound let go, and is 0 once the ascending bound
    takes over (the ascending side of Eq. 1 does not move).

    Parameters
    ----------
    play_out : ndarray, shape (N, m)
        Symmetric play operator outputs, Eq. (1), normalized input units.
    x_unit : ndarray, shape (N,)
        Normalized input in [-1, 1].
    r : ndarray, shape (m,)
        Thresholds.

    Returns
    -------
    ndarray, shape (N, m)
        ``dy_i/dc`` per row and operator, in [0, 1].
    """
    x = np.ascontiguousarray(x_unit, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    tol = 1e-9 + 1e-9 * np.abs(r)
    # one compiled pass over the rows: the array version built six N x m temporaries and a
    # gather (a third of a second on 150 000 rows and 51 operators)
    return _lift(np.ascontiguousarray(play_out, dtype=np.float64), x, r > tol, r - tol, -r + tol)


@njit(cache=True)
def _lift(play_out, x, wide, top_gap, bottom_gap):
    """:func:`descending_lift` row by row.

    Parameters
    ----------
    play_out : ndarray, shape (N, m)
        Symmetric play operator outputs (normalized input units).
    x : ndarray, shape (N,)
        Normalized input.
    wide : ndarray of bool, shape (m,)
        Operators whose threshold is above the tolerance.
    top_gap, bottom_gap : ndarray, shape (m,)
        ``y - x`` at or above which the descending bound drives a wide operator, at or below which
        the ascending one does (normalized input units: the thresholds within their tolerance).

    Returns
    -------
    ndarray, shape (N, m)
        ``dy_i/dc``, in [0, 1].
    """
    n, m = play_out.shape
    out = np.empty((n, m))
    for k in range(n):
        s = min(max((x[k] + 1.0) / 2.0, 0.0), 1.0)
        dx = x[k] - x[k - 1] if k > 0 else 0.0
        for i in range(m):
            gap = play_out[k, i] - x[k]
            if wide[i]:
                top, bottom = gap >= top_gap[i], gap <= bottom_gap[i]
            else:
                # a zero threshold sits on both bounds: only the motion says which one drives it
                # (at rest, the lifted descending bound keeps holding it up)
                top, bottom = dx < 0.0, dx > 0.0
            if top or bottom or k == 0:  # pinned to a bound (at rest at the first input: no lift yet)
                out[k, i] = s if top else 0.0
            else:  # between the bounds: the value the bound left
                out[k, i] = out[k - 1, i]
    return out


def loop_offset(play_out: np.ndarray, x_unit: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Signed distance of a PI output from its anhysteretic curve: ``sum_i w_i (y_i - x)``.

    Positive on descending branches, negative on ascending ones; scaling it
    widens or narrows the whole loop (what a baseline fitted with a lag or an
    asymmetry present has bent its weights to).
    """
    return (play_out - np.asarray(x_unit)[:, None]) @ np.asarray(w)


def open_mask(duty_pct: np.ndarray, cracking_pct: float, edge_pct: float = 0.0) -> np.ndarray:
    """1 where the duty exceeds the cracking duty, 0 where the valve stays shut; with an ``edge_pct``
    a smooth step of that width instead, ``(1 + tanh((duty - cracking) / edge)) / 2``."""
    x = np.asarray(duty_pct, dtype=np.float64)
    if edge_pct > 0.0:
        return 0.5 * (1.0 + np.tanh((x - cracking_pct) / edge_pct))
    return (x > cracking_pct).astype(np.float64)


@njit(cache=True)
def _generalized(r, x, scale, lift, state):
    out = np.empty((x.shape[0], r.shape[0]))
    y = state.copy()
    for k in range(x.shape[0]):
        for i in range(r.shape[0]):
            y[i] = play.eq1(y[i], x[k], r[i], r[i] * scale[k] + lift[k])
            out[k, i] = y[i]
    return out


def generalized_play(r: np.ndarray, x_unit: np.ndarray, widen: float, lift: float, start: float = 0.0,
                     y0=np.nan) -> np.ndarray:
    """Play operators whose descending thresholds grow with the input level (Al Janaideh, Rakheja
    & Su's generalized PI): ``r_i (1 + widen s) + lift s``, ``s`` the position in the input range
    above where the widening starts (0 there and below, 1 at the top), so at the top every
    descending threshold is ``r_i (1 + widen) + lift``.

    ``widen`` widens each operator in proportion to its threshold; ``lift`` adds one amount to
    all (what lifts the zero-threshold operator too). ``start`` is where the widening starts, as a
    position ``(x + 1) / 2`` in the input range: a valve's loop starts where its plunger leaves its
    seat, which a recording resting below the valve's opening places above its own bottom.
    Operators start by Eq. (3) from ``y0`` (NaN: at rest at the first input).

    Parameters
    ----------
    r : ndarray, shape (m,)
        Thresholds (normalized input units).
    x_unit : ndarray, shape (N,)
        Normalized input.
    widen, lift : float
        Relative and absolute (normalized units) widening of the descending thresholds at the top.
    start : float
        Position in the input range (0..1) below which the thresholds are not widened.

    Returns
    -------
    ndarray, shape (N, m)
    """
    x = np.ascontiguousarray(x_unit, dtype=np.float64)
    s = np.clip(((x + 1.0) / 2.0 - start) / (1.0 - start), 0.0, 1.0)
    r = np.ascontiguousarray(r, dtype=np.float64)
    return _generalized(r, x, 1.0 + widen * s, lift * s, play.init(r, x[0], y0))
