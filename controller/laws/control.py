"""The controllers the CLI names, composed from the laws: ``pid``, ``ff``, ``ff+pid``, ``ff+kf``.

=========  =====================================================  ==========================
word       duty                                                   feedback
=========  =====================================================  ==========================
``pid``    ``PID(ref - meas)``                                    PID alone
``ff``     ``inv(F r)``                                           none
``ff+pid`` ``inv(F r) + PID(ref - meas)``                         PID around the feedforward
``ff+kf``  ``inv(F r - bias_hat)``                                Kalman bias estimate
=========  =====================================================  ==========================

``r`` is the feedforward's reference: ``ref`` itself, or the reference
``preview_s`` ahead when the reference is a known profile (the loop passes
it as ``ref_ff_lpm``), which lets the feedforward act the valve's transport
delay early. ``F`` is the lag inversion of
:class:`controller.laws.feedforward.LeadParams` (identity when absent).
The feedback always compares the measured flow with ``ref`` now. ``inv`` is
the inverse of the feedforward's model, of any invertible kind
(:mod:`controller.laws.feedforward`), from the model's memory of the duty
actually applied.

Every duty passes the same rate limit and [min, max] clamp
(:mod:`controller.laws.limits`). :class:`Command` splits the applied duty
into ``ff_pct``, the feedforward of ``r`` alone; ``fb_pct``, the feedback
law's own output (the PID's ``kp e + I + D``; for ``ff+kf`` the duty the
bias correction adds, ``invPI(F r - bias_hat) - invPI(F r)``); and
``limit_pct``, what the rate limit and the clamp took away, so
``duty = ff + fb + limit`` always.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import feedforward as ffw
from . import kalman, limits, pid

MODES = ("pid", "ff", "ff+pid", "ff+kf")


@dataclass(frozen=True, eq=False)
class ControllerParams:
    """One controller word over a batch of candidates.

    Attributes
    ----------
    mode : str
        One of :data:`MODES` (the same for the whole batch).
    limits : Limits
    forward : ModelBank or None
        The feedforward's model (modes starting with ``ff``): its inverse is the
        feedforward, its forward part follows the applied duty (the memory the
        inverse starts from), and ``ff+kf`` takes the filter's model flow
        ``m[k]`` from it.
    pid : PIDParams or None
        ``pid`` and ``ff+pid``.
    kf : KFParams or None
        ``ff+kf``.
    lead : LeadParams or None
        Lag inversion on the feedforward's reference (modes starting with ``ff``).
    """

    mode: str
    limits: limits.Limits
    forward: ffw.ModelBank | None = None
    pid: pid.PIDParams | None = None
    kf: kalman.KFParams | None = None
    lead: ffw.LeadParams | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"unknown controller {self.mode!r} (one of {', '.join(MODES)})")
        need = {"ff": ("forward",), "pid": ("pid",), "ff+pid": ("forward", "pid"), "ff+kf": ("forward", "kf")}
        for name in need[self.mode]:
            if getattr(self, name) is None:
                raise ValueError(f"controller {self.mode!r} needs {name}")

    @property
    def batch(self) -> int:
        return self.limits.duty_min_pct.shape[0]


class ControllerState(NamedTuple):
    forward: np.ndarray | None  # forward operator memory: the valve's, as driven by the applied duty
    pid: pid.PIDState | None
    kf: kalman.KFState | None
    duty_pct: np.ndarray  # last applied duty (the rate limit's memory)
    lead: ffw.LeadState | None


class Command(NamedTuple):
    """Applied duty and its split (``duty = ff + fb + limit``), %, arrays of shape (B,)."""

    duty_pct: np.ndarray
    ff_pct: np.ndarray
    fb_pct: np.ndarray  # the feedback law's own output
    limit_pct: np.ndarray  # what the rate limit and the clamp changed


def init(p: ControllerParams, meas_lpm, duty0_pct=0.0) -> ControllerState:
    """Cold start: integral and bias zero, derivative and filter at ``meas_lpm``, valve at ``duty0_pct``."""
    b = (p.batch,)
    meas = np.broadcast_to(np.asarray(meas_lpm, dtype=np.float64), b)
    duty = np.broadcast_to(np.asarray(duty0_pct, dtype=np.float64), b).copy()
    fwd = ffw.init(p.forward, duty) if p.forward is not None else None
    pst = pid.init(p.pid, meas) if p.pid is not None else None
    kst = kalman.init(p.kf, meas) if p.kf is not None else None
    # The lead starts at rest at zero flow: the first reference is a step for it.
    lst = ffw.lead_init(p.lead, 0.0) if (p.lead is not None and p.forward is not None) else None
    return ControllerState(fwd, pst, kst, duty, lst)


def step(p: ControllerParams, s: ControllerState, ref_lpm: np.ndarray, meas_lpm: np.ndarray, dt_s: float,
         ref_ff_lpm: np.ndarray | None = None):
    """One period for every candidate: ``(state, Command)``.

    ``ref_ff_lpm`` is the feedforward's reference (``ref_lpm`` when None).
    """
    fwd, pst, kst, lst = s.forward, s.pid, s.kf, s.lead
    if p.mode == "pid":
        pst, duty = pid.step(p.pid, pst, ref_lpm, meas_lpm, dt_s, 0.0, s.duty_pct, p.limits)
        fb = pid.output(p.pid, s.pid, pst, ref_lpm, meas_lpm)
        return s._replace(pid=pst, duty_pct=duty), Command(duty, np.zeros_like(duty), fb, duty - fb)

    r = ref_lpm if ref_ff_lpm is None else ref_ff_lpm
    if lst is not None:
        lst, r = ffw.lead_step(p.lead, lst, r, dt_s)
    # The inverse starts from the forward model's memory, which saw the duty actually applied
    # (Eq. 7), so a duty the limits cut short leaves no mismatch behind and the forward
    # model's flow m[k] is exactly the flow the inverse aimed at.
    ff = ffw.invert(p.forward, fwd, r)
    if p.mode == "ff":
        duty = limits.apply(p.limits, ff, s.duty_pct, dt_s)
        fb = np.zeros_like(duty)
    elif p.mode == "ff+pid":
        pst, duty = pid.step(p.pid, pst, ref_lpm, meas_lpm, dt_s, ff, s.duty_pct, p.limits)
        fb = pid.output(p.pid, s.pid, pst, ref_lpm, meas_lpm)
    else:  # ff+kf
        kst = kalman.update(p.kf, kst, meas_lpm)
        # A reference of no flow closes the valve whatever the bias estimate says.
        u = np.where(r > 0.0, ffw.invert(p.forward, fwd, r - kst.bias_lpm), ff)
        duty = limits.apply(p.limits, u, s.duty_pct, dt_s)
        fb = u - ff
    fwd, model = ffw.step(p.forward, fwd, duty)
    if kst is not None:
        kst = kalman.push(kst, model)
    return ControllerState(fwd, pst, kst, duty, lst), Command(duty, ff, fb, duty - ff - fb)


def resume(p: ControllerParams, s: ControllerState, meas_lpm, duty_applied_pct) -> ControllerState:
    """Back to running after a gap in the measurements (bumpless).

    The rate limit starts from the duty actually applied (the safe duty) and
    the forward memory has seen it; the derivative memory and the flow
    estimate restart at the fresh measurement; the integral and the bias
    estimate are held from before the gap.
    """
    duty = np.broadcast_to(np.asarray(duty_applied_pct, dtype=np.float64), (p.batch,)).copy()
    return s._replace(
        forward=ffw.step(p.forward, s.forward, duty)[0] if s.forward is not None else None,
        pid=pid.resume(s.pid, meas_lpm) if s.pid is not None else None,
        kf=kalman.resume(s.kf, meas_lpm) if s.kf is not None else None,
        duty_pct=duty,
    )


def transfer(p: ControllerParams, s_old: ControllerState, ref_lpm, meas_lpm) -> ControllerState:
    """Bumpless switch to the controller ``p`` while running with state ``s_old``.

    The new law starts from the duty last applied: its rate limit continues
    from it and a PID integral takes what the feedforward and the P and D
    terms leave, so the first duty of the new law equals the last one of the
    old (within the rate limit). ``ff+kf`` keeps the bias estimate if the old
    law had one.
    """
    s = init(p, meas_lpm, s_old.duty_pct)
    if s.lead is not None:
        s = s._replace(lead=ffw.lead_init(p.lead, ref_lpm))
    if s_old.kf is not None and s.kf is not None:
        s = s._replace(kf=s.kf._replace(bias_lpm=s_old.kf.bias_lpm.copy()))
    if s.pid is not None:
        ff = ffw.invert(p.forward, s.forward, ref_lpm) if p.forward is not None else 0.0
        s = s._replace(pid=pid.transfer(p.pid, s.pid, ref_lpm, meas_lpm, ff, s_old.duty_pct))
    return s


def repeat(p: ControllerParams, times: int) -> ControllerParams:
    """The batch of ``p`` repeated ``times`` times along the candidate axis (to vary some gains after)."""
    import dataclasses

    def rep(obj):
        if obj is None:
            return None
        return dataclasses.replace(obj, **{f.name: np.repeat(getattr(obj, f.name), times, axis=0)
                                           for f in dataclasses.fields(obj)
                                           if isinstance(getattr(obj, f.name), np.ndarray)})

    return dataclasses.replace(p, **{k: rep(getattr(p, k)) for k in ("limits", "forward", "pid", "kf", "lead")})
