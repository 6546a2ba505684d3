"""The simulated valve's physics: one numba kernel that advances B plants N steps.

The single plant is the batch of one, so each effect has exactly one
implementation. Per plant ``b`` and step ``k`` with commanded duty ``d``
(% duty), in the order the physics runs:

1. coil heating: ``d_eff = d / (1 + alpha (T - T_amb))`` (current = V d / R(T));
   ``T`` is first order towards ``T_amb + heat (d/55)^2``, exact for a held duty;
2. forward PI, Eq. (1)-(4): the normalized duty, clamped to the identified range
   [-1, 1] (the plunger is seated below it and fully open above it), drives the
   play operators; with ``asymmetric_hysteresis = a`` the descending threshold
   of every operator grows by ``a s h``, ``s = (u + 1)/2`` the position in the
   range and ``h`` the half-width of the model's major loop at mid flow, so
   the descending branch is ``1 + a`` times as wide at full flow (``a = 0``
   is Eq. 1). One lift for all operators keeps the descending flow above the
   symmetric model's: the operators that move on a descent are those of the
   smallest thresholds, and their weights sum to a loading slope > 0 (Kuhnen);
   below the identified range the flow closes along the model's mean gain;
3. creep: plus a state relaxing towards ``creep`` times the last
   reversal-to-reversal flow step;
4. dead zone (closed below the cracking duty), no reverse flow;
5. supply: choked flow ∝ absolute upstream pressure; the gauge supply is
   nominal + Ornstein-Uhlenbeck wander - droop ∝ flow² (droop and wander only
   with the ``supply_pressure`` effect);
6. saturation at the full-open flow;
7. valve dynamics: first order, or critically damped second order (two poles
   at ``2/tau``), discretized exactly for a held input (ZOH); the output is the
   state at the sample instant, so a step reaches 63.2 % at ``tau`` exactly;
8. transport delay: a ring buffer, exact for whole samples, linear
   interpolation for a fractional remainder;
9. sensor: offset, white noise, quantization, range.

Noise is counter-based (SplitMix64 of the plant's key and the step index,
then a ziggurat), so a plant's noise depends only on its seed and the step: the
kernel is a pure function of its inputs, batches agree with single plants
bit for bit, and no generator state is carried.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from models import pi_asym, pi_mod, play

# -- per-plant parameter vector P[b, :] (float64) --
(XC, XH, YC, YH, OFF, GAIN_LO, A_ENV, P_ENV, FLOOR,
 ASYM,
 HEAT_K, E_TH, T_AMB, ALPHA,
 P_NOM, P_MODEL_ABS, P_ATM, WANDER, E_W, SQ_W, DROOP,
 ORDER, PHI11, PHI21, PHI22, G1, G2,
 DELAY_N, DELAY_F,
 CRACK, SAT, CREEP, E_CREEP,
 NOISE, SENSOR_OFFSET, SCALE, RANGE_LO, RANGE_HI,
 N_PARAMS) = range(39)

# -- per-plant scalar state X[b, :] --
(S_TEMP, S_WANDER, S_LAG1, S_LAG2, S_CREEP, S_CREEP_TARGET, S_Q_REV, S_DIR,
 S_U_PREV, S_Q_PREV, S_QV_PREV, N_STATE) = range(12)

# -- outputs out[n, b, :] --
(O_FLOW, O_TRUE, O_SUPPLY, O_TEMP, N_OUT) = range(5)

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_LOW7 = np.uint64(127)
_STEP = np.uint64(((1 << 16) * int(_GAMMA)) % 2**64)  # counters reserved per step (a draw uses 1, rarely 3+)
_TWO_M53 = 2.0 ** -53


def _ziggurat_tables(blocks: int = 128):
    """Layer edges ``x`` and ratios ``x[i+1]/x[i]`` of the normal ziggurat (Doornik's ZIGNOR)."""
    r, v = 3.442619855899, 9.91256303526217e-3
    x = np.zeros(blocks + 1)
    f = math.exp(-0.5 * r * r)
    x[0], x[1] = v / f, r
    for i in range(2, blocks):
        x[i] = math.sqrt(-2.0 * math.log(v / x[i - 1] + f))
        f = math.exp(-0.5 * x[i] * x[i])
    return x, x[1:] / x[:-1], r


_ZX, _ZR, _ZTAIL = _ziggurat_tables()


@njit(cache=True, inline="always")
def _mix(z):
    """SplitMix64 output function."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def plant_keys(seed: int) -> np.ndarray:
    """A plant's two noise keys (sensor, supply wander) from its seed."""
    g = int(_GAMMA)
    return np.array([_mix(np.uint64((int(seed) * g + (j + 1) * g) % 2**64)) for j in range(2)], dtype=np.uint64)


@njit(cache=True, inline="always")
def _uniform(base, j):
    """Uniform in (0, 1] from counter ``j`` of a step's SplitMix64 stream."""
    return (np.float64(_mix(base + np.uint64(j) * _GAMMA) >> _S11) + 1.0) * _TWO_M53


@njit(cache=True)
def normal(key, k):
    """Standard normal for step ``k`` of a stream: SplitMix64 by counter, ziggurat (ZIGNOR).

    A pure function of ``(key, k)``: the fast path (about 99 % of draws) costs one
    hash, a compare and a multiply.
    """
    base = key + np.uint64(k) * _STEP
    j = 0
    while True:
        j += 1
        h = _mix(base + np.uint64(j) * _GAMMA)
        i = int(h & _LOW7)  # layer from the low bits, sign and position from the high bits
        u = 2.0 * np.float64(h >> _S11) * _TWO_M53 - 1.0
        if abs(u) < _ZR[i]:
            return u * _ZX[i]
        if i == 0:  # the tail beyond r (Marsaglia)
            while True:
                xt = math.log(_uniform(base, j + 1)) / _ZTAIL
                yt = math.log(_uniform(base, j + 2))
                j += 2
                if -2.0 * yt >= xt * xt:
                    return xt - _ZTAIL if u < 0.0 else _ZTAIL - xt
        xu = u * _ZX[i]
        f0 = math.exp(-0.5 * (_ZX[i] * _ZX[i] - xu * xu))
        f1 = math.exp(-0.5 * (_ZX[i + 1] * _ZX[i + 1] - xu * xu))
        j += 1
        if f1 + _uniform(base, j) * (f0 - f1) < 1.0:
            return xu


@njit(cache=True)
def advance(duty, k0, settle, P, R, W, H, G, keys, play_in, x_in, buf_in, play_out, x_out, buf_out, out):
    """Advance B plants N steps (out of place: ``*_in`` are read, ``*_out`` written).

    Time runs in the outer loop and the plants in the inner loops, so the play
    operators of all plants update as one vector while each plant still sums
    its operators in the order of :mod:`models.play` (results identical to the
    fitted model's ``predict``).

    Parameters
    ----------
    duty : ndarray, shape (N, B)
        Commanded duty, %.
    k0 : int
        Global index of the first step (noise counter and ring-buffer phase).
    settle : bool
        Initialization: with N = 1, put the lag and the delay line at the
        static flow of ``duty`` (a plant at rest) and leave the slow states.
    P : ndarray, shape (B, N_PARAMS)
        Parameters (see the index constants).
    R, W : ndarray, shape (m, B) or (m, 1)
        Play thresholds and weights in normalized units (padding: w = 0);
        one column when every plant has the same model.
    H, G : ndarray, shape (k, B) or (k, 1)
        Dead-zone superposition on the play output (``pi-mod``; ``[0], [1]``: identity; padding g = 0).
    keys : ndarray of uint64, shape (B, 2)
        Noise keys, sensor and supply wander (:func:`plant_keys`).
    play_in, x_in, buf_in : ndarray
        State: operator outputs (m, B), scalar states (B, N_STATE), delay line (B, L).
    play_out, x_out, buf_out : ndarray
        Same shapes; receive the state after the last step.
    out : ndarray, shape (N, B, N_OUT)
        Measured flow, flow at the sensor without sensor errors (L/min),
        supply (bar gauge), coil temperature (°C).
    """
    N, B = duty.shape
    m = R.shape[0]
    per_plant = R.shape[1] > 1  # else one model shared by every plant
    L = buf_in.shape[1]
    x_out[:] = x_in
    buf_out[:] = buf_in
    d_eff = np.empty(B)
    u = np.empty(B)
    uc = np.empty(B)
    lift = np.empty(B)
    scale = np.empty(B)
    acc = np.empty(B)
    temp = np.empty(B)
    for n in range(N):
        k = k0 + n
        ops = play_in if n == 0 else play_out

        # 1. coil heating: the magnetics see the current, V d / R(T)
        for b in range(B):
            d = duty[n, b]
            temp[b] = x_out[b, S_TEMP]
            d_eff[b] = d / (1.0 + P[b, ALPHA] * (temp[b] - P[b, T_AMB]))
            if P[b, HEAT_K] > 0.0 and not settle:
                drive = P[b, T_AMB] + P[b, HEAT_K] * (d / 55.0) ** 2
                x_out[b, S_TEMP] = drive + (temp[b] - drive) * P[b, E_TH]
            u[b] = (d_eff[b] - P[b, XC]) / P[b, XH]
            uc[b] = min(max(u[b], -1.0), 1.0)
            lift[b] = P[b, ASYM] * (uc[b] + 1.0) * 0.5
            scale[b] = pi_asym.down_scale(uc[b], P[b, A_ENV], P[b, P_ENV])
            acc[b] = 0.0

        # 2. forward model of the PI family on the identified input range: Eq. (1) (descending
        # thresholds scaled by pi-asym's envelope, widened by the asymmetric effect), Eq. (4),
        # pi-mod's dead-zone superposition and closed flow
        for i in range(m):
            for b in range(B):
                j = b if per_plant else 0
                yi = play.eq1(ops[i, b], uc[b], R[i, j], R[i, j] * scale[b] + lift[b])
                play_out[i, b] = yi
                acc[b] += W[i, j] * yi

        for b in range(B):
            j = b if per_plant else 0
            y_model = max(pi_mod.dead_zone(H[:, j], G[:, j], acc[b]) + P[b, OFF], P[b, FLOOR])
            q_model = y_model * P[b, YH] + P[b, YC]          # Eq. (4)
            if u[b] < -1.0:
                q_model += P[b, GAIN_LO] * (d_eff[b] - (P[b, XC] - P[b, XH]))

            # 3. creep: drift on after each reversal, towards a fraction of the last step
            q = q_model
            if P[b, CREEP] > 0.0:
                if settle:
                    x_out[b, S_Q_REV] = q_model
                else:
                    du = uc[b] - x_out[b, S_U_PREV]
                    direction = 1.0 if du > 0.0 else (-1.0 if du < 0.0 else 0.0)
                    if direction != 0.0:
                        if x_out[b, S_DIR] != 0.0 and direction != x_out[b, S_DIR]:
                            x_out[b, S_CREEP_TARGET] = P[b, CREEP] * (x_out[b, S_Q_PREV] - x_out[b, S_Q_REV])
                            x_out[b, S_Q_REV] = x_out[b, S_Q_PREV]
                        x_out[b, S_DIR] = direction
                    zc = x_out[b, S_CREEP]
                    q += zc
                    x_out[b, S_CREEP] = x_out[b, S_CREEP_TARGET] + (zc - x_out[b, S_CREEP_TARGET]) * P[b, E_CREEP]
            x_out[b, S_U_PREV] = uc[b]
            x_out[b, S_Q_PREV] = q_model

            # 4. dead zone and no reverse flow
            if d_eff[b] < P[b, CRACK] or q < 0.0:
                q = 0.0

            # 5. supply: choked flow ∝ absolute upstream pressure
            supply = P[b, P_NOM]
            if P[b, WANDER] > 0.0:
                supply += x_out[b, S_WANDER] - P[b, DROOP] * x_out[b, S_QV_PREV] ** 2
                if not settle:
                    x_out[b, S_WANDER] = x_out[b, S_WANDER] * P[b, E_W] + P[b, WANDER] * P[b, SQ_W] * normal(keys[b, 1], k)
            q *= (supply + P[b, P_ATM]) / P[b, P_MODEL_ABS]

            # 6. saturation at the full-open flow
            if P[b, SAT] > 0.0 and q > P[b, SAT]:
                q = P[b, SAT]
            x_out[b, S_QV_PREV] = q

            # 7. valve dynamics (exact ZOH; output is the state at the sample instant)
            order = int(P[b, ORDER])
            if order > 0:
                if settle:
                    x_out[b, S_LAG1] = q
                    x_out[b, S_LAG2] = q
                x1 = x_out[b, S_LAG1]
                x2 = x_out[b, S_LAG2]
                qv = x1 if order == 1 else x2
                x_out[b, S_LAG1] = P[b, PHI11] * x1 + P[b, G1] * q
                x_out[b, S_LAG2] = P[b, PHI21] * x1 + P[b, PHI22] * x2 + P[b, G2] * q
            else:
                qv = q

            # 8. transport delay: ring buffer indexed by the global step
            if L > 1:
                n_delay = int(P[b, DELAY_N])
                if settle:
                    for i in range(L):
                        buf_out[b, i] = qv
                buf_out[b, k % L] = qv
                q_sensor = buf_out[b, (k - n_delay) % L]
                if P[b, DELAY_F] > 0.0:
                    q_sensor += P[b, DELAY_F] * (buf_out[b, (k - n_delay - 1) % L] - q_sensor)
            else:
                q_sensor = qv

            # 9. sensor: offset, noise, quantization (SFM3300 scale factor), range
            meas = q_sensor + P[b, SENSOR_OFFSET]
            if P[b, NOISE] > 0.0:
                meas += P[b, NOISE] * normal(keys[b, 0], k)
            if P[b, SCALE] > 0.0:
                meas = math.floor(meas * P[b, SCALE] + 0.5) / P[b, SCALE]
            meas = min(max(meas, P[b, RANGE_LO]), P[b, RANGE_HI])

            out[n, b, O_FLOW] = meas
            out[n, b, O_TRUE] = q_sensor
            out[n, b, O_SUPPLY] = supply
            out[n, b, O_TEMP] = temp[b]
    if N == 0:
        play_out[:] = play_in
