"""Decision margins of the detectors, calibrated on effect-free recordings.

A detector names an effect when the augmented model lowers the pooled
held-out squared error by more than a margin and in most folds. On an
effect-free recording every detector still finds some gain: the grid search
of a nonlinear parameter adapts to the noise, and a baseline that is not
the exact model of the plant leaves structured residuals an extra column can
take up. The margin of each effect is therefore measured: the largest gain
the detector reaches on effect-free recordings (several seeds, noise levels
and excitations), times :data:`SAFETY`, and never below its floor (:func:`floor_of`).

The margins live in ``margins.json`` next to this module;
``bench/calibrate_diagnose.py`` regenerates it from simulated effect-free
recordings (:func:`calibrate`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .words import WORDS

PATH = Path(__file__).with_name("margins.json")
#: Margin over the largest effect-free gain.
SAFETY = 1.5
#: Smallest margin on the relative fall of the held-out squared error.
FLOOR = 0.03
#: Smaller floors for laws too specific to fit by chance. A dead zone reads exactly zero flow on
#: the rows below its cracking duty, and those are a small share of most recordings: a dead
#: zone a dozen noise widths deep on one per cent of the rows lowers the pooled error by about
#: one per cent.
FLOORS = {"dead_zone": 0.005}
#: Folds (of 6) whose held-out error must fall (a majority).
MIN_WINS = 4


@dataclass(frozen=True)
class Margins:
    """Per-effect margin on the relative held-out gain and the fold majority.

    Attributes
    ----------
    gain : dict
        Effect word -> smallest relative fall of the pooled held-out squared error.
    min_wins : int
        Folds whose held-out error must fall.
    """

    gain: dict
    min_wins: int = MIN_WINS

    def to_dict(self) -> dict:
        return {"gain": self.gain, "min_wins": self.min_wins}


def load_margins(path: str | Path = PATH) -> Margins:
    """The calibrated margins (the floor for any effect the file does not list)."""
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        d = {}
    gain = {w: max(float(d.get("gain", {}).get(w, floor_of(w))), floor_of(w)) for w in WORDS}
    return Margins(gain, int(d.get("min_wins", MIN_WINS)))


def floor_of(word: str) -> float:
    """Smallest margin of an effect word."""
    return FLOORS.get(word, FLOOR)


def calibrate(free_gains: dict, safety: float = SAFETY, min_wins: int = MIN_WINS) -> Margins:
    """Margins from the gains each detector reached on effect-free recordings.

    Parameters
    ----------
    free_gains : dict
        Effect word -> list of relative held-out gains on effect-free recordings.
    """
    gain = {w: max(floor_of(w), safety * float(np.max(g))) if len(g) else floor_of(w) for w, g in free_gains.items()}
    return Margins(gain, min_wins)
