"""The effect words of DESIGN.md: the physics a fitted PI leaves out.

Each effect takes one parameter in the units DESIGN.md fixes; 0 switches it
off and effects combine freely. :data:`EFFECTS` documents each one with a
default magnitude (what ``--effect NAME`` without a value uses, chosen to be
clearly visible on the identification protocol) and a plausible range for a
valve of the reference class (Bürkert 2873-like, 3 bar, 0-200 L/min). The
physics itself is in :mod:`plant_sim.kernel`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from models.recording import InputError


@dataclass(frozen=True)
class Effect:
    """One effect word.

    Attributes
    ----------
    name : str
        The word of DESIGN.md.
    unit : str
        Unit of the parameter.
    default : float
        Default magnitude (used when the word is given without a value).
    plausible : tuple of float
        Plausible range for a valve of the reference class.
    limits : tuple of float
        Values outside this closed interval are rejected as bad input.
    physics : str
        One line on what it does.
    """

    name: str
    unit: str
    default: float
    plausible: tuple[float, float]
    limits: tuple[float, float]
    physics: str


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("asymmetric_hysteresis", "relative", 0.3, (0.05, 1.0), (0.0, 10.0),
           "descending branch wider than the ascending one, growing with flow: a play operator "
           "of descending threshold a s h on the model's input (on a PI, every operator's "
           "descending threshold grown by a s h), h the half-width of the model's major loop "
           "at mid flow, s = 0 at the bottom and 1 at the top of the identified duty range "
           "(a = 1: twice as wide at full flow); any model kind"),
    Effect("coil_heating", "K", 20.0, (5.0, 40.0), (0.0, 200.0),
           "coil temperature, first order (tau minutes) driven by coil power ∝ duty², "
           "settles this many K above ambient at 55 % duty; resistance +0.393 %/K, so the "
           "current (the duty the magnetics see) falls as the coil warms"),
    Effect("supply_pressure", "bar", 0.1, (0.02, 0.3), (0.0, 2.0),
           "choked flow ∝ upstream absolute pressure; the supply wanders slowly "
           "(Ornstein-Uhlenbeck, this standard deviation) and droops ∝ flow²"),
    Effect("valve_dynamics", "s", 0.02, (0.005, 0.1), (0.0, 60.0),
           "plunger and flow lag, first order (or critically damped second order, "
           "total lag tau) between the static flow and the flow at the valve"),
    Effect("transport_delay", "s", 0.01, (0.002, 0.05), (0.0, 10.0),
           "pure delay between the flow at the valve and the flow at the sensor"),
    Effect("dead_zone", "%", 42.0, (36.0, 45.0), (0.0, 100.0),
           "valve held closed (flow 0) while the duty is below this cracking duty; "
           "the fitted model already closes near 35 %, so smaller values change nothing"),
    Effect("saturation", "L/min", 160.0, (120.0, 200.0), (0.0, 1000.0),
           "flow capped at this full-open flow (the fitted model reaches about 185 L/min)"),
    Effect("creep", "fraction", 0.05, (0.01, 0.15), (0.0, 1.0),
           "after each reversal the flow keeps drifting the way it went, towards this "
           "fraction of the last reversal-to-reversal flow step, with the creep time constant"),
    Effect("sensor_offset", "L/min", 2.0, (-5.0, 5.0), (-50.0, 50.0),
           "zero offset of the flow sensor, added to every reading"),
)}


def parse_effect(text: str, source: str = "--effect") -> tuple[str, float]:
    """Parse ``NAME=VALUE`` (or ``NAME`` for the default magnitude).

    Raises
    ------
    InputError
        Unknown name, non-number or value outside the effect's limits.
    """
    name, sep, value = text.partition("=")
    name = name.strip()
    if name not in EFFECTS:
        raise InputError(f"{source} {text}: unknown effect {name!r} (one of {', '.join(EFFECTS)})")
    if not sep:
        return name, EFFECTS[name].default
    try:
        v = float(value)
    except ValueError:
        raise InputError(f"{source} {text}: value {value.strip()!r} is not a number") from None
    try:
        return name, check_effect(name, v)
    except InputError:
        lo, hi = EFFECTS[name].limits
        raise InputError(f"{source} {text}: outside {lo:g}..{hi:g} {EFFECTS[name].unit}") from None


def check_effect(name: str, value: float, source: str = "effect") -> float:
    """Validate one effect value against its limits; returns it as float."""
    if name not in EFFECTS:
        raise InputError(f"{source}: unknown effect {name!r} (one of {', '.join(EFFECTS)})")
    e = EFFECTS[name]
    v = float(value)
    lo, hi = e.limits
    if not math.isfinite(v) or not lo <= v <= hi:
        raise InputError(f"{source} {name}={value}: outside {lo:g}..{hi:g} {e.unit}")
    return v
