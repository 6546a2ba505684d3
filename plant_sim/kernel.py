"""The simulated valve's physics: one numba kernel that advances B plants N steps.

The single plant is the batch of one, so each effect has exactly one
implementation. Per plant ``b`` and step ``k`` with commanded duty ``d``
(% duty), in the order the physics runs:

1. coil heating: ``d_eff = d / (1 + alpha (T - T_amb))`` (current = V d / R(T));
   ``T`` is first order towards ``T_amb + heat (d/55)^2``, exact for a held duty;
2. the forward model, any kind (``pi``, ``pi-asym``, ``pi-mod``: the play
   operators of Eq. 1-4, an envelope, dead zones; ``preisach``,
   ``preisach-cont``, ``bouc-wen``), each through its own module's per-sample
   kernel: the normalized duty, clamped to the identified range [-1, 1] (the
   plunger is seated below it and fully open above it), drives it; below the
   range the flow closes along the model's mean gain. With
   ``asymmetric_hysteresis = a`` the model's input first passes a play operator
   of zero ascending and ``a s h`` descending threshold (``s = (u + 1)/2`` the
   position in the range, ``h`` the half-width of the model's major loop at mid
   flow), so the descending branch is ``1 + a`` times as wide at full flow; on a
   PI this is exactly every operator's descending threshold grown by ``a s h``;
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
from numba import carray, njit

from models import bouc_wen, pi_asym, pi_mod, play, preisach, preisach_cont
from models.borrow import borrow, pointer

# -- per-plant parameter vector P[b, :] (float64) --
(XC, XH, YC, YH, OFF, GAIN_LO, KIND, NM, NK, A_ENV, P_ENV, FLOOR,
 ASYM,
 HEAT_K, E_TH, T_AMB, ALPHA,
 P_NOM, P_MODEL_ABS, P_ATM, WANDER, E_W, SQ_W, DROOP,
 ORDER, PHI11, PHI21, PHI22, G1, G2,
 DELAY_N, DELAY_F,
 CRACK, SAT, CREEP, E_CREEP,
 NOISE, SENSOR_OFFSET, SCALE, RANGE_LO, RANGE_HI,
 N_PARAMS) = range(42)

# -- model kinds the kernel runs (P[b, KIND]) --
KIND_PI, KIND_PREISACH, KIND_PREISACH_CONT, KIND_BOUC_WEN = range(4)

# -- per-plant scalar state X[b, :] --
(S_TEMP, S_WANDER, S_LAG1, S_LAG2, S_CREEP, S_CREEP_TARGET, S_Q_REV, S_DIR,
 S_U_PREV, S_Q_PREV, S_QV_PREV, S_U_BACK, N_STATE) = range(13)

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


# -- one inline helper per stage, in the order the physics runs (Pb: the plant's parameters,
#    xb: its scalar states, both rows; each helper reads and writes only its own states) --

@njit(cache=True, inline="always")
def _coil(Pb, xb, d, settle):
    """1. Coil heating: the duty the magnetics see, ``d / (1 + alpha (T - T_amb))``, and T before the step."""
    temp = xb[S_TEMP]
    d_eff = d / (1.0 + Pb[ALPHA] * (temp - Pb[T_AMB]))
    if Pb[HEAT_K] > 0.0 and not settle:
        drive = Pb[T_AMB] + Pb[HEAT_K] * (d / 55.0) ** 2
        xb[S_TEMP] = drive + (temp - drive) * Pb[E_TH]
    return d_eff, temp


@njit(cache=True, inline="always")
def _model(Pb, MPb, EVb, MSb, xb, uc):
    """2. The forward model on the identified input range (normalized output, offset included).

    The asymmetric effect first: a play operator of zero ascending and ``lift`` descending
    threshold on the model's input (every kind's descending branch comes ``lift`` later; on a PI
    it is exactly every operator's descending threshold widened by ``lift``).
    """
    lift = Pb[ASYM] * (uc + 1.0) * 0.5
    u = play.eq1(xb[S_U_BACK], uc, 0.0, lift)
    xb[S_U_BACK] = u
    kind = int(Pb[KIND])
    m = int(Pb[NM])
    if kind == KIND_PI:
        k = int(Pb[NK])
        acc = play.bank_step(MPb[0:m], MPb[m:2 * m], pi_asym.down_scale(u, Pb[A_ENV], Pb[P_ENV]), MSb[0:m], u)
        return max(pi_mod.dead_zone(MPb[2 * m:2 * m + k], MPb[2 * m + k:2 * m + 2 * k], acc) + Pb[OFF], Pb[FLOOR])
    if kind == KIND_PREISACH:
        g = MSb[0:m]
        mu = MPb[2 * m:3 * m]
        preisach.switch(MPb[0:m], MPb[m:2 * m], g, u)
        acc = 0.0
        for i in range(m):
            acc += mu[i] * g[i]
        return acc + Pb[OFF]
    if kind == KIND_PREISACH_CONT:
        return preisach_cont.sample(EVb, MSb, u) + Pb[OFF]
    # Bouc-Wen: h integrated over the input increment
    h = bouc_wen.integrate(MSb[1], u - MSb[0], MPb[0], MPb[1], MPb[2], bouc_wen.MAX_SUBSTEP)
    MSb[0] = u
    MSb[1] = h
    return MPb[3] * u + MPb[4] * h + Pb[OFF]


@njit(cache=True, inline="always")
def _creep(Pb, xb, uc, q_model, settle):
    """3. Creep: after each reversal the flow drifts on towards a fraction of the last reversal step."""
    q = q_model
    if Pb[CREEP] > 0.0:
        if settle:
            xb[S_Q_REV] = q_model
        else:
            du = uc - xb[S_U_PREV]
            direction = 1.0 if du > 0.0 else (-1.0 if du < 0.0 else 0.0)
            if direction != 0.0:
                if xb[S_DIR] != 0.0 and direction != xb[S_DIR]:
                    xb[S_CREEP_TARGET] = Pb[CREEP] * (xb[S_Q_PREV] - xb[S_Q_REV])
                    xb[S_Q_REV] = xb[S_Q_PREV]
                xb[S_DIR] = direction
            zc = xb[S_CREEP]
            q += zc
            xb[S_CREEP] = xb[S_CREEP_TARGET] + (zc - xb[S_CREEP_TARGET]) * Pb[E_CREEP]
    xb[S_U_PREV] = uc
    xb[S_Q_PREV] = q_model
    return q


@njit(cache=True, inline="always")
def _dead_zone(Pb, d_eff, q):
    """4. Dead zone (closed below the cracking duty) and no reverse flow."""
    return 0.0 if (d_eff < Pb[CRACK] or q < 0.0) else q


@njit(cache=True, inline="always")
def _supply(Pb, xb, key, k, q, settle):
    """5. Supply: choked flow ∝ absolute upstream pressure; ``(flow, supply gauge bar)``."""
    supply = Pb[P_NOM]
    if Pb[WANDER] > 0.0:
        supply += xb[S_WANDER] - Pb[DROOP] * xb[S_QV_PREV] ** 2
        if not settle:
            xb[S_WANDER] = xb[S_WANDER] * Pb[E_W] + Pb[WANDER] * Pb[SQ_W] * normal(key, k)
    return q * (supply + Pb[P_ATM]) / Pb[P_MODEL_ABS], supply


@njit(cache=True, inline="always")
def _saturation(Pb, xb, q):
    """6. Saturation at the full-open flow."""
    if Pb[SAT] > 0.0 and q > Pb[SAT]:
        q = Pb[SAT]
    xb[S_QV_PREV] = q
    return q


@njit(cache=True, inline="always")
def _dynamics(Pb, xb, q, settle):
    """7. Valve dynamics: exact ZOH; the output is the state at the sample instant."""
    order = int(Pb[ORDER])
    if order == 0:
        return q
    if settle:
        xb[S_LAG1] = q
        xb[S_LAG2] = q
    x1 = xb[S_LAG1]
    x2 = xb[S_LAG2]
    xb[S_LAG1] = Pb[PHI11] * x1 + Pb[G1] * q
    xb[S_LAG2] = Pb[PHI21] * x1 + Pb[PHI22] * x2 + Pb[G2] * q
    return x1 if order == 1 else x2


@njit(cache=True, inline="always")
def _delay(Pb, bufb, k, qv, settle):
    """8. Transport delay: ring buffer indexed by the global step, linear interpolation in between."""
    L = bufb.shape[0]
    if L <= 1:
        return qv
    n_delay = int(Pb[DELAY_N])
    if settle:
        for i in range(L):
            bufb[i] = qv
    bufb[k % L] = qv
    q_sensor = bufb[(k - n_delay) % L]
    if Pb[DELAY_F] > 0.0:
        q_sensor += Pb[DELAY_F] * (bufb[(k - n_delay - 1) % L] - q_sensor)
    return q_sensor


@njit(cache=True, inline="always")
def _sensor(Pb, key, k, q_sensor):
    """9. Sensor: offset, noise, quantization (SFM3300 scale factor), range."""
    meas = q_sensor + Pb[SENSOR_OFFSET]
    if Pb[NOISE] > 0.0:
        meas += Pb[NOISE] * normal(key, k)
    if Pb[SCALE] > 0.0:
        meas = math.floor(meas * Pb[SCALE] + 0.5) / Pb[SCALE]
    return min(max(meas, Pb[RANGE_LO]), Pb[RANGE_HI])


@njit(cache=True)
def advance(duty, k0, settle, P, MP, EV, keys, ms_in, x_in, buf_in, ms_out, x_out, buf_out, out):
    """Advance B plants N steps (out of place: ``*_in`` are read, ``*_out`` written).

    Each plant runs the stages above in order; plants never interact, so a plant's
    results do not depend on the batch it runs in.

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
    MP : ndarray, shape (B, p)
        The forward model's arrays per plant (layout per kind: see ``plant_sim.plant``).
    EV : ndarray, shape (B, n, n)
        Everett meshes of ``preisach-cont`` plants (others: unused).
    keys : ndarray of uint64, shape (B, 2)
        Noise keys, sensor and supply wander (:func:`plant_keys`).
    ms_in, x_in, buf_in : ndarray
        State: model memory (B, s), scalar states (B, N_STATE), delay line (B, L).
    ms_out, x_out, buf_out : ndarray
        Same shapes; receive the state after the last step.
    out : ndarray, shape (N, B, N_OUT)
        Measured flow, flow at the sensor without sensor errors (L/min),
        supply (bar gauge), coil temperature (°C).
    """
    N, B = duty.shape
    ms_out[:] = ms_in
    x_out[:] = x_in
    buf_out[:] = buf_in
    for n in range(N):
        for b in range(B):
            o = out[n, b]
            o[O_FLOW], o[O_TRUE], o[O_SUPPLY], o[O_TEMP] = plant_step(
                P[b], MP[b], EV[b], keys[b], ms_out[b], x_out[b], buf_out[b], k0 + n, duty[n, b], settle)


@njit(cache=True, inline="always")
def plant_step(Pb, MPb, EVb, keys_b, msb, xb, bufb, k, d, settle):
    """One plant, one step, its state in place (rows of :func:`advance`'s arrays; ``k`` the global
    step, ``d`` the commanded duty, %): ``(measured flow, flow at the sensor, supply, coil temperature)``."""
    d_eff, temp = _coil(Pb, xb, d, settle)
    u = (d_eff - Pb[XC]) / Pb[XH]
    uc = min(max(u, -1.0), 1.0)
    q_model = _model(Pb, MPb, EVb, msb, xb, uc) * Pb[YH] + Pb[YC]
    if u < -1.0:  # below the identified range: closing along the model's mean gain
        q_model += Pb[GAIN_LO] * (d_eff - (Pb[XC] - Pb[XH]))
    q = _creep(Pb, xb, uc, q_model, settle)
    q = _dead_zone(Pb, d_eff, q)
    q, supply = _supply(Pb, xb, keys_b[1], k, q, settle)
    q = _saturation(Pb, xb, q)
    qv = _dynamics(Pb, xb, q, settle)
    q_sensor = _delay(Pb, bufb, k, qv, settle)
    return _sensor(Pb, keys_b[0], k, q_sensor), q_sensor, supply, temp


#: The live header (:class:`plant_sim.plant.RunningPlant`), int64: address and length of plant 0's rows of
#: P, MP, EV (n by n), keys and of its state ms, x, buf.
N_HEAD = 14


@njit(cache=True)
def step_at(head, k, duty):
    """:func:`plant_step` of one plant, in place, its rows found by address: the live loop's valve,
    stepped by a call of one address and two numbers (numba's entry point unboxes an array argument
    into a new owner record, ~0.5 us each on cold caches; models.borrow.pointer)."""
    h = carray(pointer(head, np.int64), N_HEAD)
    n_ev = h[5]
    return plant_step(carray(pointer(h[0], np.float64), h[1]), carray(pointer(h[2], np.float64), h[3]),
                      carray(pointer(h[4], np.float64), (n_ev, n_ev)), carray(pointer(h[6], np.uint64), h[7]),
                      carray(pointer(h[8], np.float64), h[9]), carray(pointer(h[10], np.float64), h[11]),
                      carray(pointer(h[12], np.float64), h[13]), k, duty, False)
