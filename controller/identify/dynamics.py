"""The valve's lag and delay from step tests, with their uncertainty.

Each step of the duty is fitted with a first-order lag behind a pure delay
(the structure of the valve's plunger and flow lag and its transport delay,
as ``valve_dynamics`` and ``transport_delay`` of DESIGN.md)::

    y(t) = y0 + dy (1 - exp(-(t - t0 - delay) / tau))   for t > t0 + delay, else y0

by nonlinear least squares (``y0, dy, tau, delay``), started from the 10 %
and 63 % crossing times (``t10 = delay + 0.105 tau``, ``t63 = delay + tau``).
The hysteresis answers a held step at once (it is rate independent), so a
step's transient is the dynamics alone. Steps too small to read against the
sensor noise (``|dy| < 20 sigma``) are skipped.

The valve's figures are the medians over the steps (robust to a step spoilt
by a disturbance); their standard error is ``1.2533 s / sqrt(n)`` (the
median's, for a normal spread ``s`` over the steps), and each step carries
the standard errors of its own fit (from the Jacobian).

Only steps read without a stall count: on a busy machine the session's loop
or the valve's bridge stalls for some milliseconds now and then, and a step
whose transient a stall fell into looks slower and later than the valve is
(a recording with a third of its periods missed read 25 ms and 17.5 ms for a
15 ms lag and a 10 ms delay; its clean steps, 15.1 ms and 10.0 ms). A step is
clean when no fresh reading in its transient (from the command to the delay
plus four lags, as all steps read them) came more than
:data:`CLEAN_GAP_PERIODS` periods after the one before. One clean step is
worth more than any number of disturbed ones; when none is clean, the
:data:`FALLBACK_STEPS` least disturbed are used.

``t0`` is the time of the row that commanded the step, so the delay is
the command-to-measurement delay a loop on the same transport sees
(transport latency included).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

#: A step must change the flow by this many noise standard deviations to be read.
MIN_SNR = 20.0
#: A step's transient is clean when no fresh reading in it came later than this many periods after the one before.
CLEAN_GAP_PERIODS = 2.5
#: When no step is clean, this many of the least disturbed make the figures.
FALLBACK_STEPS = 3
#: Corner of the zero-phase smoothing before the lag is inverted, Hz: ten times the fits' own
#: lowpass (:mod:`models.preprocess`: 0.4 of the 5 Hz Nyquist of the 10 Hz fit rate).
DECONVOLVE_HZ = 20.0


@dataclass(frozen=True)
class StepFit:
    """One step's fit.

    Attributes
    ----------
    t0_s : float
        Time the step was commanded, s.
    duty_from_pct, duty_to_pct : float
    y0_lpm, dy_lpm : float
        Flow before the step and its change, L/min.
    tau_s, delay_s : float
        Lag and delay, s.
    tau_se_s, delay_se_s : float
        Their standard errors from this fit, s.
    rmse_lpm : float
        Residual of the fit, L/min.
    """

    t0_s: float
    duty_from_pct: float
    duty_to_pct: float
    y0_lpm: float
    dy_lpm: float
    tau_s: float
    delay_s: float
    tau_se_s: float
    delay_se_s: float
    rmse_lpm: float

    def response(self, t_s: np.ndarray) -> np.ndarray:
        """The fitted response at ``t_s``, L/min."""
        return step_model(t_s - self.t0_s, self.y0_lpm, self.dy_lpm, self.tau_s, self.delay_s)


@dataclass(frozen=True)
class Dynamics:
    """The valve's lag and delay over all steps read.

    Attributes
    ----------
    tau_s, delay_s : float
        Medians over the steps, s.
    tau_se_s, delay_se_s : float
        Standard errors of the medians, s.
    tau_sd_s, delay_sd_s : float
        Spread over the steps (standard deviation), s.
    noise_lpm : float
        Sensor noise, standard deviation per reading, L/min.
    steps : tuple of StepFit
        The steps the figures are from.
    disturbed : int
        Steps read that a stall fell into (left out, unless every step was).
    """

    tau_s: float
    delay_s: float
    tau_se_s: float
    delay_se_s: float
    tau_sd_s: float
    delay_sd_s: float
    noise_lpm: float
    steps: tuple
    disturbed: int = 0
    read: int = 0

    @property
    def clean(self) -> bool:
        """Whether the figures are from steps no stall fell into (False: a machine too busy to read any step cleanly)."""
        return self.disturbed < self.read

    def to_json(self) -> dict:
        return {"tau_s": self.tau_s, "delay_s": self.delay_s, "tau_se_s": self.tau_se_s,
                "delay_se_s": self.delay_se_s, "tau_sd_s": self.tau_sd_s, "delay_sd_s": self.delay_sd_s,
                "noise_lpm": self.noise_lpm, "steps": len(self.steps), "steps_read": self.read,
                "steps_disturbed": self.disturbed, "clean": self.clean}


def step_model(dt_s: np.ndarray, y0: float, dy: float, tau_s: float, delay_s: float) -> np.ndarray:
    """First-order lag behind a pure delay, for a step at ``dt_s = 0``."""
    x = np.maximum(dt_s - delay_s, 0.0)
    return y0 + dy * (1.0 - np.exp(-x / tau_s))


def noise_std(flow_lpm: np.ndarray) -> float:
    """Sensor noise from second differences, robust to steps: ``MAD / 0.6745 / sqrt(6)``."""
    d2 = np.diff(np.asarray(flow_lpm, dtype=np.float64), 2)
    if len(d2) == 0:
        return 0.0
    return float(np.median(np.abs(d2 - np.median(d2))) / 0.6745 / math.sqrt(6.0))


def step_rows(duty_pct: np.ndarray, min_change_pct: float = 0.5) -> np.ndarray:
    """Rows where the duty jumps by more than ``min_change_pct`` from the row before."""
    return np.flatnonzero(np.abs(np.diff(duty_pct)) > min_change_pct) + 1


def fit_step(t_s: np.ndarray, flow_lpm: np.ndarray, t0_s: float, noise_lpm: float) -> StepFit | None:
    """Fit one step over ``t_s`` (from a little before ``t0_s`` to the next step); None if unreadable."""
    pre = flow_lpm[t_s < t0_s]
    post_t, post = t_s[t_s >= t0_s] - t0_s, flow_lpm[t_s >= t0_s]
    if len(pre) < 3 or len(post) < 20:
        return None
    hold = post_t[-1]
    y0 = float(np.mean(pre))
    y1 = float(np.mean(post[post_t > 0.7 * hold]))
    dy = y1 - y0
    if abs(dy) < MIN_SNR * max(noise_lpm, 1e-3):
        return None
    frac = (post - y0) / dy
    w = max(1, len(post) // 200)
    frac_s = np.convolve(frac, np.ones(w) / w, mode="same")
    t10 = post_t[int(np.argmax(frac_s > 0.1))]
    t63 = post_t[int(np.argmax(frac_s > 0.632))]
    tau0 = max((t63 - t10) / 0.895, 1e-3)
    d0 = max(t63 - tau0, 0.0)

    def resid(p):
        return step_model(post_t, p[0], p[1], p[2], p[3]) - post

    lo = [-np.inf, -np.inf, 1e-4, 0.0]
    hi = [np.inf, np.inf, hold / 2.0, hold / 2.0]
    p0 = np.clip([y0, dy, tau0, d0], np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    sol = least_squares(resid, p0, bounds=(lo, hi), x_scale=[abs(dy), abs(dy), tau0, max(tau0, 1e-3)])
    r = sol.fun
    dof = max(len(r) - 4, 1)
    s2 = float(r @ r) / dof
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se = np.full(4, np.nan)
    y0f, dyf, tau, d = (float(v) for v in sol.x)
    return StepFit(float(t0_s), math.nan, math.nan, y0f, dyf, tau, d, float(se[2]), float(se[3]), math.sqrt(s2))


def dynamics_from_steps(t_s: np.ndarray, duty_pct: np.ndarray, flow_lpm: np.ndarray, rows: np.ndarray,
                        fresh: np.ndarray | None = None) -> Dynamics:
    """Lag and delay from every readable step among ``rows`` (a boolean mask of the step-test rows).

    ``fresh`` (a boolean mask) marks the rows whose flow was received in that row's step; the
    others repeat an older reading (a loop over a network sees no new one in some periods) and
    are left out of the noise estimate and the fits. All rows are fresh when not given.

    Raises
    ------
    ValueError
        When no step could be read.
    """
    fresh = np.ones(len(t_s), dtype=bool) if fresh is None else np.asarray(fresh, dtype=bool)
    noise = noise_std(flow_lpm[rows & fresh])
    idx = np.flatnonzero(rows)
    starts = [int(k) for k in step_rows(duty_pct) if rows[k] and k > idx[0]]
    fits = []
    for j, k in enumerate(starts):
        end = starts[j + 1] if j + 1 < len(starts) else int(idx[-1]) + 1
        a = max(k - max(3, (end - k) // 20), 0)
        use = a + np.flatnonzero(fresh[a:end])
        f = fit_step(t_s[use], flow_lpm[use], float(t_s[k]), noise)
        if f is not None:
            fits.append(StepFit(f.t0_s, float(duty_pct[k - 1]), float(duty_pct[k]), *(getattr(f, n) for n in (
                "y0_lpm", "dy_lpm", "tau_s", "delay_s", "tau_se_s", "delay_se_s", "rmse_lpm"))))
    if not fits:
        raise ValueError("no step could be read (too small against the noise, or too short)")
    read = len(fits)
    fits, disturbed = undisturbed(fits, t_s[fresh], float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0)
    tau = np.array([f.tau_s for f in fits])
    d = np.array([f.delay_s for f in fits])
    n = len(fits)
    sd_t = float(np.std(tau, ddof=1)) if n > 1 else float(fits[0].tau_se_s)
    sd_d = float(np.std(d, ddof=1)) if n > 1 else float(fits[0].delay_se_s)
    return Dynamics(float(np.median(tau)), float(np.median(d)), 1.2533 * sd_t / math.sqrt(n),
                    1.2533 * sd_d / math.sqrt(n), sd_t, sd_d, noise, tuple(fits), disturbed, read)


def undisturbed(fits: list, fresh_t_s: np.ndarray, period_s: float) -> tuple[list, int]:
    """The steps whose transient no stall fell into (none: the :data:`FALLBACK_STEPS` least disturbed),
    and how many a stall fell into.

    A step's disturbance is the longest wait between fresh readings (times ``fresh_t_s``) from
    its command to the median delay plus four median lags over all steps (stalls lengthen
    those, so the window errs long).
    """
    window = float(np.median([f.delay_s for f in fits]) + 4.0 * np.median([f.tau_s for f in fits]))
    gaps = []
    for f in fits:
        a, b = np.searchsorted(fresh_t_s, [f.t0_s - period_s, f.t0_s + window])
        seen = fresh_t_s[a:b + 1]
        gaps.append(float(np.max(np.diff(seen))) if len(seen) > 1 else math.inf)
    gaps = np.array(gaps)
    clean = gaps <= CLEAN_GAP_PERIODS * period_s
    if clean.any():
        return [f for f, c in zip(fits, clean) if c], int(np.sum(~clean))
    return [fits[i] for i in sorted(np.argsort(gaps, kind="stable")[:FALLBACK_STEPS])], len(fits)


def static_flow(t_s: np.ndarray, flow_lpm: np.ndarray, fresh: np.ndarray, at_s: np.ndarray, tau_s: float,
                delay_s: float) -> np.ndarray:
    """The flow the valve's static characteristic gave at ``at_s``: the lag and delay taken out, L/min.

    The measured flow is advanced by the delay (``delay_s``: command to reading) and the
    first-order lag ``tau dq/dt = u - q`` is inverted, ``u = q + tau dq/dt``, so a static
    (rate-independent) model fitted to it is not smeared by the valve's dynamics: a sweep's
    branches are not shifted by its rate, and a reversal's corner is sharp. The flow is
    smoothed (zero phase, :data:`DECONVOLVE_HZ`) before the derivative, which the sensor
    noise would otherwise swamp; the fit's own lowpass is ten times lower, so nothing it
    keeps is lost.

    Parameters
    ----------
    t_s, flow_lpm : ndarray
        The recording.
    fresh : ndarray of bool
        Rows whose flow was received in that row's step (the others repeat an older reading).
    at_s : ndarray
        Times of the commands to give the static flow for, s (evenly spaced).
    tau_s, delay_s : float
        The valve's lag and its command-to-reading delay, s.
    """
    from models.preprocess import lowpass

    q = np.interp(np.asarray(at_s, dtype=np.float64) + delay_s, t_s[fresh], flow_lpm[fresh])
    if len(q) < 2 or tau_s <= 0.0:
        return q
    rate_hz = (len(at_s) - 1) / (at_s[-1] - at_s[0])
    q = lowpass(q, DECONVOLVE_HZ, rate_hz)
    return q + tau_s * np.gradient(q, at_s)


def steps_plot(dyn: Dynamics, t_s: np.ndarray, flow_lpm: np.ndarray, n: int = 6, ax=None):
    """Up to ``n`` steps (both directions), measured and fitted, time from each step's command; the figure."""
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(8, 4.5))
    else:
        fig = ax.figure
    ups = [f for f in dyn.steps if f.dy_lpm > 0]
    downs = [f for f in dyn.steps if f.dy_lpm < 0]
    chosen = ups[: (n + 1) // 2] + downs[: n // 2]
    span = 8.0 * dyn.tau_s + 3.0 * dyn.delay_s
    for i, f in enumerate(chosen):
        sel = (t_s >= f.t0_s - 0.2 * span) & (t_s <= f.t0_s + span)
        dt = t_s[sel] - f.t0_s
        color = f"C{i % 10}"
        ax.plot(dt * 1e3, (flow_lpm[sel] - f.y0_lpm) / f.dy_lpm, ".", ms=2, color=color, alpha=0.5)
        ax.plot(dt * 1e3, (f.response(t_s[sel]) - f.y0_lpm) / f.dy_lpm, color=color, lw=1.2,
                label=f"{f.duty_from_pct:.1f}->{f.duty_to_pct:.1f} %: tau {f.tau_s * 1e3:.1f} ms, delay {f.delay_s * 1e3:.1f} ms")
    ax.axvline(dyn.delay_s * 1e3, color="k", ls=":", lw=0.8)
    ax.axvline((dyn.delay_s + dyn.tau_s) * 1e3, color="k", ls="--", lw=0.8)
    ax.set_xlabel("time since the step was commanded (ms)")
    ax.set_ylabel("normalized flow change")
    ax.set_title(f"steps: tau {dyn.tau_s * 1e3:.1f} ± {dyn.tau_se_s * 1e3:.1f} ms, "
                 f"delay {dyn.delay_s * 1e3:.1f} ± {dyn.delay_se_s * 1e3:.1f} ms ({len(dyn.steps)} steps)")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig
